"""Tiny hand-made rosbag2 recordings with injectable faults (no renderer needed: milliseconds to write).

Frames: a camera moving 0.2 m per frame along x, looking along the world's +y; textured random RGB; one square
fruit mask per frame. Topics are the synthetic bag's (fruit_counter's defaults).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.nodes.conversions import (camera_info_msg_from_intrinsics, image_msg_from_array,
                                               pose_msg_from_transform, time_msg_from_ns)

START_NS = 1_600_000_000_000_000_000
PERIOD_NS = 100_000_000
H, W = 24, 32
INTRINSICS = CameraIntrinsics(30.0, 30.0, 16.0, 12.0, W, H)
#: Optical axes looking along world +y (z forward = +y, x right = +x, y down = -z).
R_WORLD_OPTICAL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def frame_pose(k: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R_WORLD_OPTICAL
    T[0, 3] = 0.2 * k
    return T


def frame_pixels(k: int) -> tuple[np.ndarray, np.ndarray]:
    rgb = np.random.default_rng(k).integers(0, 255, (H, W, 3), dtype=np.uint8)
    mask = np.zeros((H, W), np.uint16)
    mask[4 + k % 5:10 + k % 5, 6:12] = 1 + k % 3
    return rgb, mask


def messages(n: int = 6, *, camera_info: bool = True, bad_encoding_at: tuple[int, ...] = (),
             nan_pose_at: tuple[int, ...] = (), small_mask_at: tuple[int, ...] = (),
             mask_offset_ns: int = 0) -> list[tuple[str, str, int, Any]]:
    """(topic, type, stamp, rclpy message) for n frames with the requested faults."""
    out = []
    for k in range(n):
        stamp = START_NS + k * PERIOD_NS
        rgb, mask = frame_pixels(k)
        image = image_msg_from_array(rgb, 'rgb8', 'camera_optical', stamp)
        if k in bad_encoding_at:
            image.encoding = 'yuv422'
        if k in small_mask_at:
            mask = mask[::2, ::2].copy()
        pose = PoseStamped(header=Header(stamp=time_msg_from_ns(stamp), frame_id='map'),
                           pose=pose_msg_from_transform(frame_pose(k)))
        if k in nan_pose_at:
            pose.pose.position.y = float('nan')
        if camera_info:
            out.append(('/camera/camera_info', 'sensor_msgs/msg/CameraInfo', stamp,
                        camera_info_msg_from_intrinsics(INTRINSICS, 'camera_optical', stamp)))
        out.append(('/camera/image_raw', 'sensor_msgs/msg/Image', stamp, image))
        out.append(('/camera/pose', 'geometry_msgs/msg/PoseStamped', stamp, pose))
        out.append(('/camera/instance_mask', 'sensor_msgs/msg/Image', stamp + mask_offset_ns,
                    image_msg_from_array(mask, 'mono16', 'camera_optical', stamp + mask_offset_ns)))
    return out


def dataset_messages(dataset_dir: Path, period_ns: int = PERIOD_NS) -> list[tuple[str, str, int, Any]]:
    """(topic, type, stamp, rclpy message) of every view of a transforms.json dataset, one frame per period."""
    import cv2

    from fruitnerfpp_ros.core.data.transforms_format import read_transforms
    from fruitnerfpp_ros.core.geometry import optical_from_opengl

    data = read_transforms(dataset_dir)
    out = []
    for k, frame in enumerate(data.frames):
        stamp = START_NS + k * period_ns
        rgb = cv2.imread(str(dataset_dir / frame.file_path))[..., ::-1]
        ids = cv2.imread(str(dataset_dir / frame.instance_path), cv2.IMREAD_UNCHANGED).astype(np.uint16)
        pose = PoseStamped(header=Header(stamp=time_msg_from_ns(stamp), frame_id='map'),
                           pose=pose_msg_from_transform(optical_from_opengl(frame.T_world_camera)))
        out += [('/camera/camera_info', 'sensor_msgs/msg/CameraInfo', stamp,
                 camera_info_msg_from_intrinsics(data.intrinsics_of(k), 'camera_optical', stamp)),
                ('/camera/image_raw', 'sensor_msgs/msg/Image', stamp,
                 image_msg_from_array(rgb, 'rgb8', 'camera_optical', stamp)),
                ('/camera/pose', 'geometry_msgs/msg/PoseStamped', stamp, pose),
                ('/camera/instance_mask', 'sensor_msgs/msg/Image', stamp,
                 image_msg_from_array(ids, 'mono16', 'camera_optical', stamp))]
    return out


def write_bag(path: Path, msgs: list[tuple[str, str, int, Any]], storage: str = 'mcap',
              tf_frames: int = 0) -> Path:
    """Write ``msgs`` (and, with tf_frames, /tf map->base_link + /tf_static base_link->camera_optical)."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections: dict[str, Any] = {}
        for topic, msgtype, stamp, msg in msgs:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
            writer.write(connections[topic], stamp, serialize_message(msg))
        if tf_frames:
            _write_tf(writer, typestore, tf_frames)
    return path


def _tf_msg(typestore: Any, parent: str, child: str, T: np.ndarray, stamp: int) -> Any:
    from fruitnerfpp_ros.core.geometry import quaternion_from_transform
    t, q = quaternion_from_transform(T)
    Ty = typestore.types
    time = Ty['builtin_interfaces/msg/Time'](sec=stamp // 10**9, nanosec=stamp % 10**9)
    header = Ty['std_msgs/msg/Header'](stamp=time, frame_id=parent)
    tr = Ty['geometry_msgs/msg/Transform'](translation=Ty['geometry_msgs/msg/Vector3'](x=t[0], y=t[1], z=t[2]),
                                           rotation=Ty['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2],
                                                                                       w=q[3]))
    return Ty['tf2_msgs/msg/TFMessage'](transforms=[Ty['geometry_msgs/msg/TransformStamped'](
        header=header, child_frame_id=child, transform=tr)])


T_BASE_CAMERA = np.eye(4)
T_BASE_CAMERA[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_BASE_CAMERA[2, 3] = 0.5


def _write_tf(writer: Writer, typestore: Any, n: int) -> None:
    tf = writer.add_connection('/tf', 'tf2_msgs/msg/TFMessage', typestore=typestore)
    static = writer.add_connection('/tf_static', 'tf2_msgs/msg/TFMessage', typestore=typestore)
    writer.write(static, START_NS, typestore.serialize_cdr(
        _tf_msg(typestore, 'base_link', 'camera_optical', T_BASE_CAMERA, START_NS), 'tf2_msgs/msg/TFMessage'))
    for k in range(n):
        stamp = START_NS + k * PERIOD_NS
        T_world_base = frame_pose(k) @ np.linalg.inv(T_BASE_CAMERA)
        writer.write(tf, stamp, typestore.serialize_cdr(_tf_msg(typestore, 'map', 'base_link', T_world_base, stamp),
                                                        'tf2_msgs/msg/TFMessage'))


__all__ = ['messages', 'dataset_messages', 'write_bag', 'frame_pose', 'frame_pixels', 'INTRINSICS', 'START_NS',
           'PERIOD_NS', 'CameraInfo']
