"""Conversions between ROS messages and the core's arrays and records (pure functions, no ROS graph).

Reading functions (``*_from_msg``) are duck-typed: they accept rclpy messages and the messages rosbags decodes from
a bag alike (same field names), so live topics and bag replay share one code path. Writing functions
(``*_msg_from_*``) build rclpy messages.

Conventions: stamps in nanoseconds (``stamp_ns``); ``T_a_b`` maps frame ``b`` into frame ``a``; CameraInfo's
principal point has the centre of the top-left pixel at (0, 0) (OpenCV's convention too), transforms.json's
the top-left corner (``cx_transforms = cx_ros + 0.5``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.data.undistortion import DISTORTION_MODELS, LensUndistorter
from fruitnerfpp_ros.core.streams.tf_buffer import TfBuffer
from fruitnerfpp_ros.core.geometry import (principal_point_transforms_from_ros, quaternion_from_transform,
                                           transform_from_quaternion)
from fruitnerfpp_ros.errors import ConversionError, FruitNerfError

__all__ = [
    'QUATERNION_NORM_TOLERANCE', 'CameraModel', 'stamp_ns_from_header', 'time_msg_from_ns', 'image_from_msg',
    'mask_from_msg', 'depth_from_msg', 'camera_model_from_camera_info', 'intrinsics_from_camera_info',
    'undistort_image', 'undistort_mask', 'undistort_depth', 'undistorter_for', 'valid_pixels',
    'transform_from_pose_msg', 'transform_from_transform_msg', 'add_tf_message', 'pose_msg_from_transform',
    'image_msg_from_array', 'camera_info_msg_from_intrinsics', 'header_msg', 'bytes_of'
]

_IMAGE_ENCODINGS = {  # encoding -> (channels, dtype)
    'rgb8': (3, np.uint8), 'bgr8': (3, np.uint8), 'rgba8': (4, np.uint8), 'bgra8': (4, np.uint8),
    'mono8': (1, np.uint8), '8UC1': (1, np.uint8), '8UC3': (3, np.uint8),
}
_MASK_ENCODINGS = {
    'mono16': np.uint16, '16UC1': np.uint16, '32SC1': np.int32, '32UC1': np.uint32, 'mono8': np.uint8,
    '8UC1': np.uint8,
}
#: Depth encodings -> (dtype, metres per unit): REP 118 (16UC1 millimetres, 32FC1 metres); mono16 as 16UC1.
_DEPTH_ENCODINGS = {'16UC1': (np.uint16, 1e-3), 'mono16': (np.uint16, 1e-3), '32FC1': (np.float32, 1.0)}
_DISTORTION_MODELS = ('plumb_bob', 'rational_polynomial', 'equidistant')
#: Coefficient counts OpenCV undoes per model (ROS: plumb_bob 5, rational_polynomial 8, equidistant 4).
_DISTORTION_SIZES = {'plumb_bob': (4, 5, 8, 12, 14), 'rational_polynomial': (4, 5, 8, 12, 14),
                     'equidistant': (4,)}
#: A pose's quaternion may differ this much from unit length (float rounding); beyond, the pose is refused.
QUATERNION_NORM_TOLERANCE = 1e-3


class CameraModel(NamedTuple):
    """A camera as CameraInfo describes it.

    Attributes:
        intrinsics: pinhole intrinsics of the *undistorted* image, transforms.json convention.
        K: 3x3 intrinsic matrix, ROS/OpenCV convention (centre of the top-left pixel at 0, 0).
        D: distortion coefficients as CameraInfo lists them.
        distortion_model: ``plumb_bob``, ``rational_polynomial``, ``equidistant`` or '' (none).
        frame_id: the optical frame of the camera.
    """

    intrinsics: CameraIntrinsics
    K: np.ndarray
    D: np.ndarray
    distortion_model: str
    frame_id: str

    @property
    def is_distorted(self) -> bool:
        return bool(self.D.size and np.any(self.D != 0.0))


# ----------------------------------------------------------------------------------------------- stamps

def stamp_ns_from_header(header: Any) -> int:
    """Nanoseconds of a ``std_msgs/Header`` (or of a ``builtin_interfaces/Time`` directly)."""
    stamp = getattr(header, 'stamp', header)
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def time_msg_from_ns(stamp_ns: int) -> Any:
    """``builtin_interfaces/Time`` of a stamp in nanoseconds."""
    from builtin_interfaces.msg import Time
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def header_msg(frame_id: str, stamp_ns: int) -> Any:
    """``std_msgs/Header`` of ``frame_id`` at ``stamp_ns``."""
    from std_msgs.msg import Header
    return Header(stamp=time_msg_from_ns(stamp_ns), frame_id=frame_id)


# ----------------------------------------------------------------------------------------------- images

def bytes_of(data: Any) -> np.ndarray:
    """A message's ``data`` field (bytes, array.array or numpy array, as rclpy or rosbags give it) as uint8."""
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def _pixels(msg: Any, channels: int, dtype: type, topic: str) -> np.ndarray:
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    row_bytes = width * channels * itemsize
    if height <= 0 or width <= 0:
        raise ConversionError(f'{topic}: empty image ({width}x{height})')
    if step < row_bytes:
        raise ConversionError(f'{topic}: step {step} is smaller than width {width} x {channels} x {itemsize} bytes')
    raw = bytes_of(msg.data)
    if raw.size < step * height:
        raise ConversionError(f'{topic}: image data has {raw.size} bytes, expected step {step} x height {height}')
    rows = raw[:step * height].reshape(height, step)[:, :row_bytes]
    order = '>' if getattr(msg, 'is_bigendian', 0) else '<'
    pixels = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order) if itemsize > 1 else dtype)
    return pixels.reshape(height, width, channels).astype(dtype, copy=False)


def image_from_msg(msg: Any, *, topic: str = 'image') -> np.ndarray:
    """[H, W, 3] uint8 RGB from ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``CompressedImage``.

    Raises:
        ConversionError: unknown encoding, inconsistent size or undecodable compressed data.
    """
    if hasattr(msg, 'format') and not hasattr(msg, 'encoding'):  # sensor_msgs/CompressedImage
        decoded = cv2.imdecode(bytes_of(msg.data), cv2.IMREAD_COLOR)
        if decoded is None:
            raise ConversionError(f'{topic}: cannot decode CompressedImage (format {msg.format!r})')
        return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
    encoding = str(msg.encoding)
    if encoding not in _IMAGE_ENCODINGS:
        raise ConversionError(f'{topic}: unsupported image encoding {encoding!r}; '
                              f'expected one of {", ".join(_IMAGE_ENCODINGS)}')
    channels, dtype = _IMAGE_ENCODINGS[encoding]
    pixels = _pixels(msg, channels, dtype, topic)
    if channels == 1:
        return np.repeat(pixels, 3, axis=2)
    if encoding.startswith('bgr'):
        pixels = pixels[..., 2::-1]
    return np.ascontiguousarray(pixels[..., :3])


def mask_from_msg(msg: Any, *, topic: str = 'mask', expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """[H, W] uint16 instance ids (0 = background) from a mono16 / 16UC1 / 32SC1 / mono8 ``sensor_msgs/Image``.

    Negative ids (32SC1) count as background.

    Raises:
        ConversionError: unknown encoding, ids above 65535, or a size other than ``expected_shape`` (H, W).
    """
    encoding = str(msg.encoding)
    if encoding not in _MASK_ENCODINGS:
        raise ConversionError(f'{topic}: unsupported mask encoding {encoding!r}; '
                              f'expected one of {", ".join(_MASK_ENCODINGS)}')
    ids = _pixels(msg, 1, _MASK_ENCODINGS[encoding], topic)[..., 0]
    if expected_shape is not None and ids.shape != tuple(expected_shape):
        raise ConversionError(f'{topic}: mask is {ids.shape[1]}x{ids.shape[0]} but the image is '
                              f'{expected_shape[1]}x{expected_shape[0]}')
    if ids.dtype.kind == 'i':
        ids = np.maximum(ids, 0)
    if ids.size and int(ids.max()) > 65535:
        raise ConversionError(f'{topic}: instance id {int(ids.max())} does not fit in 16 bits')
    return ids.astype(np.uint16)


def depth_from_msg(msg: Any, *, topic: str = 'depth', expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """[H, W] float32 depth in metres (0 = no return) from a ``sensor_msgs/Image`` 16UC1 (millimetres, 0 = no
    return) or 32FC1 (metres; NaN, inf and values <= 0 = no return), as REP 118 defines them.

    Raises:
        ConversionError: another encoding, an inconsistent size, or a size other than ``expected_shape`` (H, W).
    """
    encoding = str(msg.encoding)
    if encoding not in _DEPTH_ENCODINGS:
        raise ConversionError(f'{topic}: unsupported depth encoding {encoding!r}; expected 16UC1 (millimetres) or '
                              '32FC1 (metres)')
    dtype, unit_m = _DEPTH_ENCODINGS[encoding]
    raw = _pixels(msg, 1, dtype, topic)[..., 0]
    if expected_shape is not None and raw.shape != tuple(expected_shape):
        raise ConversionError(f'{topic}: depth image is {raw.shape[1]}x{raw.shape[0]} but the colour image is '
                              f'{expected_shape[1]}x{expected_shape[0]}; publish depth aligned to the colour camera')
    metres = raw.astype(np.float32) * np.float32(unit_m)
    return np.where(np.isfinite(metres) & (metres > 0), metres, np.float32(0.0))


def image_msg_from_array(pixels: np.ndarray, encoding: str, frame_id: str, stamp_ns: int) -> Any:
    """``sensor_msgs/Image`` from [H, W, 3] uint8 (``rgb8``) or [H, W] uint16 (``mono16``) pixels."""
    from sensor_msgs.msg import Image
    pixels = np.ascontiguousarray(pixels)
    height, width = pixels.shape[:2]
    return Image(header=header_msg(frame_id, stamp_ns), height=height, width=width, encoding=encoding,
                 is_bigendian=0, step=int(pixels.strides[0]), data=pixels.tobytes())


# ----------------------------------------------------------------------------------------------- cameras

def camera_model_from_camera_info(msg: Any, *, topic: str = 'camera_info') -> CameraModel:
    """The camera of a ``sensor_msgs/CameraInfo``.

    Raises:
        ConversionError: uncalibrated (zero focal length) or a distortion model that cannot be undone.
    """
    K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    D = np.asarray(msg.d, dtype=np.float64).reshape(-1)
    width, height = int(msg.width), int(msg.height)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or width <= 0 or height <= 0:
        raise ConversionError(f'{topic}: camera is not calibrated (K={K.ravel().tolist()}, {width}x{height})')
    model = str(msg.distortion_model)
    if D.size and np.any(D != 0.0) and model not in _DISTORTION_MODELS:
        raise ConversionError(f'{topic}: distortion model {model!r} is not supported; '
                              f'expected one of {", ".join(_DISTORTION_MODELS)}')
    if not np.all(np.isfinite(D)):
        raise ConversionError(f'{topic}: distortion coefficients are not finite: {D.tolist()}')
    if D.size and np.any(D != 0.0) and D.size not in _DISTORTION_SIZES[model]:
        raise ConversionError(f'{topic}: {D.size} distortion coefficients for model {model!r}; expected '
                              f'{" or ".join(map(str, _DISTORTION_SIZES[model]))}')
    cx, cy = principal_point_transforms_from_ros(float(K[0, 2]), float(K[1, 2]))
    intrinsics = CameraIntrinsics(float(K[0, 0]), float(K[1, 1]), cx, cy, width, height)
    return CameraModel(intrinsics, K, D, model, str(msg.header.frame_id))


def intrinsics_from_camera_info(msg: Any, *, topic: str = 'camera_info') -> CameraIntrinsics:
    """transforms.json intrinsics of a CameraInfo (``cx = cx_ros + 0.5``), for the undistorted image."""
    return camera_model_from_camera_info(msg, topic=topic).intrinsics


def camera_info_msg_from_intrinsics(intrinsics: CameraIntrinsics, frame_id: str, stamp_ns: int) -> Any:
    """``sensor_msgs/CameraInfo`` (no distortion) of transforms.json intrinsics (``cx_ros = cx - 0.5``)."""
    from sensor_msgs.msg import CameraInfo
    cx, cy = intrinsics.cx - 0.5, intrinsics.cy - 0.5
    fx, fy = intrinsics.fl_x, intrinsics.fl_y
    return CameraInfo(header=header_msg(frame_id, stamp_ns), width=int(intrinsics.w), height=int(intrinsics.h),
                      distortion_model='plumb_bob', d=[0.0] * 5, k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                      r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                      p=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


#: Undistorters by camera (a few cameras per process; cleared when more than 8 appear).
_UNDISTORTERS: dict[tuple, LensUndistorter] = {}


def undistorter_for(camera: CameraModel) -> LensUndistorter | None:
    """The (cached) undistorter of a CameraInfo camera, or None when it has no distortion."""
    if not camera.is_distorted:
        return None
    key = (camera.K.tobytes(), camera.D.tobytes(), camera.distortion_model, camera.intrinsics.w,
           camera.intrinsics.h)
    if key not in _UNDISTORTERS:
        if len(_UNDISTORTERS) > 8:
            _UNDISTORTERS.clear()
        model = camera.distortion_model if camera.distortion_model in DISTORTION_MODELS else 'plumb_bob'
        try:
            _UNDISTORTERS[key] = LensUndistorter(camera.K, camera.D, model,
                                                 (camera.intrinsics.w, camera.intrinsics.h))
        except (cv2.error, FruitNerfError) as err:
            raise ConversionError(f'camera {camera.frame_id!r}: cannot build its undistortion maps: '
                                  f'{str(err).strip().splitlines()[-1]}') from err
    return _UNDISTORTERS[key]


def undistort_image(image: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Undo the lens distortion of an image (bilinear); the result has the pinhole camera ``camera.K``."""
    undistorter = undistorter_for(camera)
    return image if undistorter is None else undistorter.image(image)


def undistort_mask(mask: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Undo the lens distortion of an instance mask (nearest neighbour, so ids never blend)."""
    undistorter = undistorter_for(camera)
    return mask if undistorter is None else undistorter.labels(mask)


def undistort_depth(depth: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Undo the lens distortion of a depth image aligned to the colour image (nearest neighbour, so depths never
    blend across an edge; 0 where the undistorted image holds no data)."""
    undistorter = undistorter_for(camera)
    return depth if undistorter is None else undistorter.labels(depth)


def valid_pixels(camera: CameraModel) -> np.ndarray | None:
    """[H, W] bool, False where the undistorted image holds no data; None for an undistorted camera."""
    undistorter = undistorter_for(camera)
    return None if undistorter is None else undistorter.valid


# ----------------------------------------------------------------------------------------------- poses

def _checked_transform(translation: np.ndarray, quaternion: np.ndarray, what: str) -> np.ndarray:
    if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(quaternion))):
        raise ConversionError(f'{what}: pose is not finite (t={translation.tolist()}, q={quaternion.tolist()})')
    norm = float(np.linalg.norm(quaternion))
    if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:  # also a zero or overflowing quaternion
        raise ConversionError(f'{what}: quaternion is not unit length (|q| = {norm:.6g}, q={quaternion.tolist()})')
    return transform_from_quaternion(translation, quaternion)


def transform_from_pose_msg(pose: Any, *, topic: str = 'pose') -> np.ndarray:
    """4x4 transform of a ``geometry_msgs/Pose`` (also accepts PoseStamped / PoseWithCovariance[Stamped]).

    Raises:
        ConversionError: NaN/inf values or a quaternion that is not unit length (within
            :data:`QUATERNION_NORM_TOLERANCE`).
    """
    while not hasattr(pose, 'position'):
        pose = pose.pose
    p, q = pose.position, pose.orientation
    return _checked_transform(np.array([p.x, p.y, p.z], float), np.array([q.x, q.y, q.z, q.w], float), topic)


def transform_from_transform_msg(transform: Any, *, topic: str = 'tf') -> np.ndarray:
    """4x4 transform of a ``geometry_msgs/Transform`` (or TransformStamped)."""
    transform = getattr(transform, 'transform', transform)
    t, q = transform.translation, transform.rotation
    return _checked_transform(np.array([t.x, t.y, t.z], float), np.array([q.x, q.y, q.z, q.w], float), topic)


def add_tf_message(buffer: TfBuffer, msg: Any, *, static: bool = False) -> int:
    """Store every transform of a ``tf2_msgs/TFMessage`` (rclpy or rosbags) in ``buffer``; returns how many.

    Transforms that are not finite are skipped (and raise after the others were stored).
    """
    stored, bad = 0, []
    for ts in msg.transforms:
        try:
            T = transform_from_transform_msg(ts, topic=f'tf {ts.header.frame_id}->{ts.child_frame_id}')
        except ConversionError as err:
            bad.append(str(err))
            continue
        buffer.set_transform(str(ts.header.frame_id), str(ts.child_frame_id), stamp_ns_from_header(ts.header), T,
                             static=static)
        stored += 1
    if bad:
        raise ConversionError('; '.join(bad))
    return stored


def pose_msg_from_transform(T: np.ndarray) -> Any:
    """``geometry_msgs/Pose`` of a 4x4 transform."""
    from geometry_msgs.msg import Point, Pose, Quaternion
    t, q = quaternion_from_transform(T)
    return Pose(position=Point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
