"""Write a synthetic scene as a rosbag2 recording (rosbags; mcap by default, sqlite3 optional).

Topics (identical header stamps per frame; images carry frame_id ``camera_optical``; ``world`` is the writer's
``world_frame``, ``map`` by default):

- ``/camera/image_raw``      sensor_msgs/msg/Image, rgb8 (``image_format='raw'``), or instead
- ``/camera/image_raw/compressed``  sensor_msgs/msg/CompressedImage, format ``rgb8; jpeg compressed bgr8`` as
                             image_transport's compressed plugin names and writes it (``image_format='jpeg'``)
- ``/camera/camera_info``    sensor_msgs/msg/CameraInfo, ROS principal point (cx_ros = cx_transforms - 0.5),
                             plumb_bob D = [k1, k2, p1, p2, k3] (zeros for an undistorted camera)
- ``/camera/pose``           geometry_msgs/msg/PoseStamped, pose of ``camera_optical`` in ``world`` (REP-103 axes)
- ``/camera/instance_mask``  sensor_msgs/msg/Image, mono16 instance ids (0 = background; never compressed)
- ``/camera/aligned_depth_to_color/image_raw``  (``depth=True``) sensor_msgs/msg/Image, 16UC1 depth in millimetres
                             aligned to the colour image (0 = no return), as realsense2_camera publishes it
- ``/tf``                    tf2_msgs/msg/TFMessage, ``world`` -> ``base_link``
- ``/tf_static``             tf2_msgs/msg/TFMessage, ``base_link`` -> ``camera_optical`` (once, latched QoS)
- ``/gnss/fix``              (``gnss=True``) sensor_msgs/msg/NavSatFix of the GNSS antenna (frame ``gnss_link``), a
                             few Hz (a row of trees, ``row_scene.py``)

``base_link`` is chosen so that ``T_world_base_link @ T_base_link_camera_optical`` equals the optical pose.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.data.depth_image import depth_units_from_metres
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.synthetic.lens import distortion_coefficients
from fruitnerfpp_ros.core.geometry import (invert_transform, optical_from_opengl,
                                           principal_point_ros_from_transforms, quaternion_from_transform)
from fruitnerfpp_ros.errors import SynthError

__all__ = ['BagWriter', 'TOPICS', 'T_BASE_LINK_CAMERA_OPTICAL', 'BAG_START_NS', 'FRAME_PERIOD_NS',
           'MAP_FRAME', 'BASE_FRAME', 'CAMERA_FRAME', 'STORAGES', 'COMPRESSED_IMAGE_TOPIC', 'JPEG_FORMAT',
           'DEPTH_TOPIC', 'image_topic', 'GNSS_TOPIC', 'GNSS_FRAME']

TOPICS = {
    'image': '/camera/image_raw',
    'camera_info': '/camera/camera_info',
    'pose': '/camera/pose',
    'instance_mask': '/camera/instance_mask',
    'tf': '/tf',
    'tf_static': '/tf_static',
}
#: The JPEG image topic: image_transport's name for the compressed transport of ``TOPICS['image']``.
COMPRESSED_IMAGE_TOPIC = TOPICS['image'] + '/compressed'
#: The depth topic of a bag written with ``depth=True`` (realsense2_camera's aligned depth).
DEPTH_TOPIC = '/camera/aligned_depth_to_color/image_raw'
#: The GNSS topic of a bag written with ``gnss=True`` and the frame_id of its fixes.
GNSS_TOPIC, GNSS_FRAME = '/gnss/fix', 'gnss_link'
#: ``CompressedImage.format`` as compressed_image_transport writes it for an rgb8 image encoded as JPEG.
JPEG_FORMAT = 'rgb8; jpeg compressed bgr8'
MAP_FRAME, BASE_FRAME, CAMERA_FRAME = 'map', 'base_link', 'camera_optical'
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
#: Stamp of the first frame (fixed, so bags are byte-identical between runs), nanoseconds.
BAG_START_NS = 1_700_000_000_000_000_000
#: Time between frames, nanoseconds (10 Hz).
FRAME_PERIOD_NS = 100_000_000

#: Fixed camera mount: optical axes (z forward, x right, y down) on a base_link with x forward, z up; the camera
#: sits 0.2 m ahead of and 0.5 m above base_link, pitched 10 degrees down.
T_BASE_LINK_CAMERA_OPTICAL = np.eye(4)
T_BASE_LINK_CAMERA_OPTICAL[:3, :3] = Rotation.from_euler('y', 10.0, degrees=True).as_matrix() @ np.array(
    [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_BASE_LINK_CAMERA_OPTICAL[:3, 3] = [0.2, 0.0, 0.5]

_FOREVER = QosTime(2147483647, 4294967295)
#: Offered QoS of /tf_static: reliable, transient local (latched), as robot_state_publisher offers it.
_LATCHED_QOS = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, _FOREVER,
                   _FOREVER, QosLiveliness.AUTOMATIC, _FOREVER, False)


def image_topic(image_format: str) -> str:
    """The camera image topic of a bag written with ``image_format`` (``raw`` or ``jpeg``)."""
    return COMPRESSED_IMAGE_TOPIC if image_format == 'jpeg' else TOPICS['image']


class BagWriter:
    """Context manager writing frames of a synthetic scene into a rosbag2 directory.

    Args:
        path: bag directory to create. An existing rosbag2 directory (with ``metadata.yaml``) is replaced; any
            other existing path is refused.
        storage: ``mcap`` (default) or ``sqlite3``.
        image_format: ``raw`` (Image rgb8 on ``/camera/image_raw``) or ``jpeg`` (CompressedImage on
            ``/camera/image_raw/compressed``).
        jpeg_quality: 1..100, for ``jpeg``.
        world_frame: fixed frame of the pose topic and parent of ``base_link`` on /tf.
        depth: also write depth images on :data:`DEPTH_TOPIC` (16UC1 millimetres).
        gnss: also offer :data:`GNSS_TOPIC` (sensor_msgs/NavSatFix) for :meth:`write_gnss_fix`.

    Raises:
        SynthError: unknown storage or image format, or ``path`` exists and is not a bag, or cannot be written.
    """

    def __init__(self, path: str | Path, storage: str = 'mcap', *, image_format: str = 'raw', jpeg_quality: int = 90,
                 world_frame: str = MAP_FRAME, depth: bool = False, gnss: bool = False) -> None:
        if storage not in STORAGES:
            raise SynthError(f'unknown bag storage {storage!r}; expected one of {", ".join(STORAGES)}')
        if image_format not in ('raw', 'jpeg'):
            raise SynthError(f'unknown bag image format {image_format!r}; expected raw or jpeg')
        self.path = Path(path)
        self.storage = storage
        self.image_format = image_format
        self.jpeg_quality = int(jpeg_quality)
        self.world_frame = world_frame
        #: Topic of each role in this bag (``image`` depends on the image format).
        self.topics = {**TOPICS, 'image': image_topic(image_format)}
        if depth:
            self.topics['depth'] = DEPTH_TOPIC
        if gnss:
            self.topics['gnss'] = GNSS_TOPIC
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self._writer: Writer | None = None
        self._conns: dict[str, Any] = {}
        self._static_written = False

    def __enter__(self) -> 'BagWriter':
        if self.path.exists():
            if self.path.is_dir() and (self.path / 'metadata.yaml').exists():
                shutil.rmtree(self.path)
            else:
                raise SynthError(f'bag path {self.path} exists and is not a rosbag2 directory; choose another --bag')
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = Writer(self.path, version=9, storage_plugin=STORAGES[self.storage])
            self._writer.open()
        except OSError as err:
            raise SynthError(f'cannot write bag {self.path}: {err.strerror or err}') from err
        w, ts, topics = self._writer, self.typestore, self.topics
        image_type = 'sensor_msgs/msg/CompressedImage' if self.image_format == 'jpeg' else 'sensor_msgs/msg/Image'
        self._conns = {
            'image': w.add_connection(topics['image'], image_type, typestore=ts),
            'camera_info': w.add_connection(topics['camera_info'], 'sensor_msgs/msg/CameraInfo', typestore=ts),
            'pose': w.add_connection(topics['pose'], 'geometry_msgs/msg/PoseStamped', typestore=ts),
            'instance_mask': w.add_connection(topics['instance_mask'], 'sensor_msgs/msg/Image', typestore=ts),
            'tf': w.add_connection(topics['tf'], 'tf2_msgs/msg/TFMessage', typestore=ts),
            'tf_static': w.add_connection(topics['tf_static'], 'tf2_msgs/msg/TFMessage', typestore=ts,
                                          offered_qos_profiles=[_LATCHED_QOS]),
        }
        if 'depth' in topics:
            self._conns['depth'] = w.add_connection(topics['depth'], 'sensor_msgs/msg/Image', typestore=ts)
        if 'gnss' in topics:
            self._conns['gnss'] = w.add_connection(topics['gnss'], 'sensor_msgs/msg/NavSatFix', typestore=ts)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    # ------------------------------------------------------------------ messages
    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        T = self.typestore.types
        stamp = T['builtin_interfaces/msg/Time'](sec=int(stamp_ns // 1_000_000_000),
                                                 nanosec=int(stamp_ns % 1_000_000_000))
        return T['std_msgs/msg/Header'](stamp=stamp, frame_id=frame_id)

    def _image(self, stamp_ns: int, array: np.ndarray, encoding: str) -> Any:
        h, w = array.shape[:2]
        data = np.ascontiguousarray(array).astype(array.dtype.newbyteorder('<'), copy=False)
        step = data.strides[0]
        return self.typestore.types['sensor_msgs/msg/Image'](
            header=self._header(stamp_ns, CAMERA_FRAME), height=h, width=w, encoding=encoding, is_bigendian=0,
            step=step, data=np.frombuffer(data.tobytes(), dtype=np.uint8))

    def _jpeg(self, stamp_ns: int, rgb: np.ndarray) -> Any:
        ok, data = cv2.imencode('.jpg', np.ascontiguousarray(rgb[..., ::-1]),
                                [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise SynthError(f'cannot encode a {rgb.shape[1]}x{rgb.shape[0]} image as JPEG')
        return self.typestore.types['sensor_msgs/msg/CompressedImage'](
            header=self._header(stamp_ns, CAMERA_FRAME), format=JPEG_FORMAT,
            data=np.frombuffer(data.tobytes(), dtype=np.uint8))

    def _camera_info(self, stamp_ns: int, K: CameraIntrinsics) -> Any:
        T = self.typestore.types
        cx, cy = principal_point_ros_from_transforms(K.cx, K.cy)
        roi = T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return T['sensor_msgs/msg/CameraInfo'](
            header=self._header(stamp_ns, CAMERA_FRAME), height=K.h, width=K.w, distortion_model='plumb_bob',
            d=distortion_coefficients(K), k=np.array([K.fl_x, 0.0, cx, 0.0, K.fl_y, cy, 0.0, 0.0, 1.0]),
            r=np.eye(3).reshape(-1),
            p=np.array([K.fl_x, 0.0, cx, 0.0, 0.0, K.fl_y, cy, 0.0, 0.0, 0.0, 1.0, 0.0]), binning_x=0, binning_y=0,
            roi=roi)

    def _pose(self, T_world_frame: np.ndarray) -> Any:
        T = self.typestore.types
        t, q = quaternion_from_transform(T_world_frame)
        return T['geometry_msgs/msg/Pose'](position=T['geometry_msgs/msg/Point'](x=t[0], y=t[1], z=t[2]),
                                           orientation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2],
                                                                                         w=q[3]))

    def _transform_stamped(self, stamp_ns: int, parent: str, child: str, T_parent_child: np.ndarray) -> Any:
        T = self.typestore.types
        t, q = quaternion_from_transform(T_parent_child)
        transform = T['geometry_msgs/msg/Transform'](
            translation=T['geometry_msgs/msg/Vector3'](x=t[0], y=t[1], z=t[2]),
            rotation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2], w=q[3]))
        return T['geometry_msgs/msg/TransformStamped'](header=self._header(stamp_ns, parent), child_frame_id=child,
                                                       transform=transform)

    def _write(self, key: str, stamp_ns: int, msg: Any) -> None:
        assert self._writer is not None
        conn = self._conns[key]
        self._writer.write(conn, stamp_ns, self.typestore.serialize_cdr(msg, conn.msgtype))

    def write_frame(self, stamp_ns: int, rgb: np.ndarray, instance: np.ndarray, T_world_camera: np.ndarray,
                    K: CameraIntrinsics, depth: np.ndarray | None = None) -> None:
        """Write one frame: RGB [H, W, 3] uint8, instance ids [H, W] uint16, camera-to-world pose in OpenGL axes
        (transforms.json convention) and transforms.json intrinsics (top-left-corner principal point; its
        ``distortion`` k1, k2, p1, p2, k3 go into CameraInfo's D); ``depth`` [H, W] metres (0 = no return) when the
        writer was opened with ``depth=True``."""
        T_world_optical = optical_from_opengl(T_world_camera)
        types = self.typestore.types
        if not self._static_written:
            tf_static = types['tf2_msgs/msg/TFMessage'](transforms=[
                self._transform_stamped(stamp_ns, BASE_FRAME, CAMERA_FRAME, T_BASE_LINK_CAMERA_OPTICAL)])
            self._write('tf_static', stamp_ns, tf_static)
            self._static_written = True
        T_world_base = T_world_optical @ invert_transform(T_BASE_LINK_CAMERA_OPTICAL)
        self._write('tf', stamp_ns, types['tf2_msgs/msg/TFMessage'](transforms=[
            self._transform_stamped(stamp_ns, self.world_frame, BASE_FRAME, T_world_base)]))
        pose = types['geometry_msgs/msg/PoseStamped'](header=self._header(stamp_ns, self.world_frame),
                                                      pose=self._pose(T_world_optical))
        self._write('pose', stamp_ns, pose)
        self._write('camera_info', stamp_ns, self._camera_info(stamp_ns, K))
        image = self._jpeg(stamp_ns, rgb.astype(np.uint8)) if self.image_format == 'jpeg' \
            else self._image(stamp_ns, rgb.astype(np.uint8), 'rgb8')
        self._write('image', stamp_ns, image)
        self._write('instance_mask', stamp_ns, self._image(stamp_ns, instance.astype(np.uint16), 'mono16'))
        if depth is not None and 'depth' in self._conns:
            self._write('depth', stamp_ns, self._image(stamp_ns, depth_units_from_metres(depth), '16UC1'))

    def write_gnss_fix(self, fix: Any) -> None:
        """Write one ``sensor_msgs/NavSatFix`` (a :class:`~fruitnerfpp_ros.core.orchard.gnss.GnssFix`: stamp,
        latitude, longitude, ellipsoidal height, ENU covariance, status) when opened with ``gnss=True``."""
        T = self.typestore.types
        status = T['sensor_msgs/msg/NavSatStatus'](status=int(fix.status), service=1)  # SERVICE_GPS
        covariance = np.zeros(9) if fix.covariance is None else np.asarray(fix.covariance, np.float64)
        msg = T['sensor_msgs/msg/NavSatFix'](
            header=self._header(fix.stamp_ns, GNSS_FRAME), status=status, latitude=float(fix.latitude_deg),
            longitude=float(fix.longitude_deg), altitude=float(fix.altitude_m), position_covariance=covariance,
            position_covariance_type=0 if fix.covariance is None else 2)  # UNKNOWN / DIAGONAL_KNOWN
        self._write('gnss', fix.stamp_ns, msg)
