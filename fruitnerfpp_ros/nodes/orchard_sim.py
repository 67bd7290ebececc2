"""The ``orchard_sim`` node: a synthetic orchard drive published as live topics (the robot stand-in).

Sources (parameter ``source``):

- a transforms.json dataset written by ``fruitnerfpp synth`` (images/, instances/): one frame per tick, stamped
  with the node clock: ``sensor_msgs/Image`` rgb8 on ``image_topic``, ``CameraInfo`` (``cx_ros = cx - 0.5``),
  ``PoseStamped`` of ``camera_frame`` in ``world_frame``, instance masks mono16, and (when tf2_msgs is importable)
  ``/tf`` ``world_frame -> base_frame`` plus ``/tf_static`` ``base_frame -> camera_frame``;
- a rosbag2 (directory or .mcap / .db3): its messages re-published as they are (raw CDR bytes), one stamp group
  per tick;
- '' (default): a small scene is generated first (``fruit``, ``count``, ``views``, ``resolution``,
  ``trajectory``, ``seed``).
"""

from __future__ import annotations

import importlib
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import invert_transform, optical_from_opengl
from fruitnerfpp_ros.errors import DatasetError
from fruitnerfpp_ros.nodes.conversions import (camera_info_msg_from_intrinsics, image_msg_from_array,
                                               pose_msg_from_transform, time_msg_from_ns)
from fruitnerfpp_ros.nodes.node_main import spin_node

__all__ = ['OrchardSimNode', 'main', 'T_BASE_OPTICAL']

#: REP-103: the optical frame (z forward, x right, y down) of a camera looking along the base's x axis.
T_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])

_PARAMS = {  # name: (default, description)
    'source': ('', "transforms.json dataset dir or rosbag2 to publish; '' = generate a small scene first"),
    'fruit': ('apple', 'generated scene: fruit type'),
    'count': (20, 'generated scene: number of fruits'),
    'views': (48, 'generated scene: number of camera views'),
    'resolution': (96, 'generated scene: square image size, px'),
    'trajectory': ('hemisphere', 'generated scene: hemisphere or row'),
    'seed': (0, 'generated scene: random seed'),
    'rate_hz': (5.0, 'frames published per second'),
    'loop': (False, 'start over after the last frame'),
    'wait_for_subscribers_s': (10.0, 'wait up to this long for a subscriber of image_topic before publishing'),
    'image_topic': ('/camera/image_raw', 'sensor_msgs/Image rgb8'),
    'camera_info_topic': ('/camera/camera_info', 'sensor_msgs/CameraInfo'),
    'pose_topic': ('/camera/pose', 'geometry_msgs/PoseStamped of camera_frame in world_frame'),
    'mask_topic': ('/camera/instance_mask', 'sensor_msgs/Image mono16 instance ids'),
    'world_frame': ('map', 'fixed frame'),
    'base_frame': ('base_link', 'robot frame on /tf'),
    'camera_frame': ('camera_optical', 'camera optical frame'),
}


class OrchardSimNode(Node):
    """Publishes a synthetic drive; ``done`` turns True after the last frame (when not looping)."""

    def __init__(self, node_name: str = 'orchard_sim', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        from rcl_interfaces.msg import ParameterDescriptor
        p = {name: self.declare_parameter(name, default, ParameterDescriptor(description=text)).value
             for name, (default, text) in _PARAMS.items()}
        self.p = p
        self.done = False
        self.published = 0
        self._index = 0
        self._waited_since = time.monotonic()
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        source = str(p['source'])
        if not source:
            source = str(self._generate())
        path = Path(source)
        if (path / 'transforms.json').exists():
            self._init_dataset(path, qos)
        elif path.exists():
            self._init_bag(path, qos)
        else:
            raise DatasetError(f'orchard_sim source {path}: neither a transforms.json dataset nor a rosbag2')
        self.create_timer(1.0 / float(p['rate_hz']), self._tick)

    # ------------------------------------------------------------------ sources
    def _generate(self) -> Path:
        from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
        out = Path(tempfile.mkdtemp(prefix='orchard_sim_'))
        p = self.p
        cfg = SynthConfig(fruit=p['fruit'], count=int(p['count']), views=int(p['views']),
                          resolution=(int(p['resolution']), int(p['resolution'])), trajectory=p['trajectory'],
                          seed=int(p['seed']))
        result = generate_orchard(cfg, out)
        self.get_logger().info(f'generated a {p["fruit"]} tree with {result.n_fruits} fruits in {out}')
        return out

    def _tf_message_class(self) -> Any:
        try:
            from tf2_msgs.msg import TFMessage
            return TFMessage
        except ImportError:
            self.get_logger().warning('tf2_msgs is not installed (not on PyPI): /tf and /tf_static are not '
                                      'published; the pose is on the PoseStamped topic')
            return None

    def _init_dataset(self, path: Path, qos: QoSProfile) -> None:
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import CameraInfo, Image
        p = self.p
        self.mode = 'dataset'
        self.dataset = read_transforms(path)
        self.dataset_dir = path
        self.n_frames = len(self.dataset.frames)
        self._pubs = {'image': self.create_publisher(Image, p['image_topic'], qos),
                      'camera_info': self.create_publisher(CameraInfo, p['camera_info_topic'], qos),
                      'pose': self.create_publisher(PoseStamped, p['pose_topic'], qos),
                      'mask': self.create_publisher(Image, p['mask_topic'], qos)}
        TFMessage = self._tf_message_class()
        if TFMessage is not None:
            self._pubs['tf'] = self.create_publisher(TFMessage, '/tf', 100)
            self._pubs['tf_static'] = self.create_publisher(TFMessage, '/tf_static', QoSProfile(
                depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
            self._pubs['tf_static'].publish(TFMessage(transforms=[self._transform_msg(
                p['base_frame'], p['camera_frame'], T_BASE_OPTICAL, self.get_clock().now().nanoseconds)]))
        self.get_logger().info(f'publishing {self.n_frames} frames of {path} at {p["rate_hz"]} Hz')

    def _init_bag(self, path: Path, qos: QoSProfile) -> None:
        from rosbags.highlevel import AnyReader
        self.mode = 'bag'
        groups: dict[int, list[tuple[str, bytes]]] = {}
        self._pubs = {}
        skipped = set()
        with AnyReader([path]) as reader:
            for connection in reader.connections:
                package, _, name = connection.msgtype.split('/')
                try:
                    msg_class = getattr(importlib.import_module(f'{package}.msg'), name)
                except (ImportError, AttributeError):
                    skipped.add(f'{connection.topic} [{connection.msgtype}]')
                    continue
                self._pubs.setdefault(connection.topic, self.create_publisher(msg_class, connection.topic, qos))
            for connection, stamp, raw in reader.messages():
                if connection.topic in self._pubs:
                    groups.setdefault(stamp, []).append((connection.topic, bytes(raw)))
        if skipped:
            self.get_logger().warning(f'message packages not installed, not published: {", ".join(sorted(skipped))}')
        self._groups = [groups[k] for k in sorted(groups)]
        self.n_frames = len(self._groups)
        self.get_logger().info(f'publishing {self.n_frames} stamp groups of {path} at {self.p["rate_hz"]} Hz')

    # ------------------------------------------------------------------ publishing
    def _transform_msg(self, parent: str, child: str, T: np.ndarray, stamp_ns: int) -> Any:
        from geometry_msgs.msg import Quaternion, TransformStamped, Vector3
        from std_msgs.msg import Header
        pose = pose_msg_from_transform(T)
        msg = TransformStamped(header=Header(stamp=time_msg_from_ns(stamp_ns), frame_id=parent), child_frame_id=child)
        msg.transform.translation = Vector3(x=pose.position.x, y=pose.position.y, z=pose.position.z)
        msg.transform.rotation = Quaternion(x=pose.orientation.x, y=pose.orientation.y, z=pose.orientation.z,
                                            w=pose.orientation.w)
        return msg

    def _tick(self) -> None:
        if self.done:
            return
        if self.published == 0 and time.monotonic() - self._waited_since < float(self.p['wait_for_subscribers_s']):
            waiting = [topic for topic, pub in self._pubs.items()
                       if topic not in ('tf', 'tf_static', '/tf', '/tf_static') and pub.get_subscription_count() == 0]
            if waiting:
                return
        if self.mode == 'dataset':
            self._publish_frame(self._index)
        else:
            for topic, raw in self._groups[self._index]:
                self._pubs[topic].publish(raw)
        self.published += 1
        self._index += 1
        if self._index >= self.n_frames:
            if self.p['loop']:
                self._index = 0
            else:
                self.done = True
                self.get_logger().info(f'published all {self.n_frames} frames')

    def _publish_frame(self, index: int) -> None:
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import Header
        p = self.p
        frame = self.dataset.frames[index]
        stamp_ns = self.get_clock().now().nanoseconds
        rgb = cv2.imread(str(self.dataset_dir / frame.file_path), cv2.IMREAD_COLOR)
        instances = cv2.imread(str(self.dataset_dir / frame.instance_path), cv2.IMREAD_UNCHANGED) \
            if frame.instance_path else None
        if rgb is None or instances is None:
            self.get_logger().error(f'{self.dataset_dir}: cannot read frame {index} ({frame.file_path})')
            return
        T_world_optical = optical_from_opengl(frame.T_world_camera)
        camera = p['camera_frame']
        self._pubs['camera_info'].publish(camera_info_msg_from_intrinsics(self.dataset.intrinsics_of(index), camera,
                                                                          stamp_ns))
        header = Header(stamp=time_msg_from_ns(stamp_ns), frame_id=p['world_frame'])
        self._pubs['pose'].publish(PoseStamped(header=header, pose=pose_msg_from_transform(T_world_optical)))
        if 'tf' in self._pubs:
            from tf2_msgs.msg import TFMessage
            T_world_base = T_world_optical @ invert_transform(T_BASE_OPTICAL)
            self._pubs['tf'].publish(TFMessage(transforms=[self._transform_msg(p['world_frame'], p['base_frame'],
                                                                               T_world_base, stamp_ns)]))
        self._pubs['mask'].publish(image_msg_from_array(instances.astype(np.uint16), 'mono16', camera, stamp_ns))
        self._pubs['image'].publish(image_msg_from_array(rgb[..., ::-1], 'rgb8', camera, stamp_ns))


def main(args: list[str] | None = None) -> int:
    """Run the node (``ros2 run fruitnerfpp_ros orchard_sim --ros-args -p source:=DIR``)."""
    return spin_node('orchard_sim', OrchardSimNode, SingleThreadedExecutor, args)


if __name__ == '__main__':
    sys.exit(main())
