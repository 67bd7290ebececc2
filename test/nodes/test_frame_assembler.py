"""The shared collector: camera_info arriving late, odometry + extrinsic, undistortion, log throttling."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from nav_msgs.msg import Odometry

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import opengl_from_optical, quaternion_from_transform
from fruitnerfpp_ros.nodes.conversions import pose_msg_from_transform
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogLevel, ThrottledLog
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.nodes import bag_factory as bf

ROLE = {'/camera/image_raw': 'image', '/camera/camera_info': 'camera_info', '/camera/pose': 'pose',
        '/camera/instance_mask': 'mask'}


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))


def test_frames_wait_for_late_camera_info(tmp_path: Path) -> None:
    logs = Logs()
    assembler = FrameAssembler(settings_from_parameters({'min_translation_m': 0.1}), KeyframeStore(tmp_path), logs)
    msgs = bf.messages(4)
    for topic, _, _, msg in msgs:
        if topic != '/camera/camera_info':
            assembler.on_message(ROLE[topic], msg)
    assert len(assembler.store) == 0 and assembler.status().waiting == 4
    assembler.on_message('camera_info', msgs[0][3])
    assert len(assembler.store) == 4


def test_camera_info_that_never_comes_is_reported(tmp_path: Path) -> None:
    logs = Logs()
    assembler = FrameAssembler(settings_from_parameters({'pending_timeout_s': 0.15}), KeyframeStore(tmp_path), logs)
    for topic, _, _, msg in bf.messages(5, camera_info=False):
        assembler.on_message(ROLE[topic], msg)
    assembler.flush()
    assert assembler.dropped_pending == 5 and len(assembler.store) == 0
    assert any('no CameraInfo received on /camera/camera_info' in m for _, m in logs)


def test_odometry_with_extrinsic_parameter(tmp_path: Path) -> None:
    t, q = quaternion_from_transform(bf.T_BASE_CAMERA)
    settings = settings_from_parameters({'pose_source': 'odometry', 'min_translation_m': 0.1,
                                         'camera_extrinsic': ' '.join(str(v) for v in [*t, *q])})
    assembler = FrameAssembler(settings, KeyframeStore(tmp_path), Logs())
    for topic, _, stamp, msg in bf.messages(3):
        if topic == '/camera/pose':
            odom = Odometry(header=msg.header, child_frame_id='base_link')
            odom.pose.pose = pose_msg_from_transform(bf.frame_pose((stamp - bf.START_NS) // bf.PERIOD_NS)
                                                     @ np.linalg.inv(bf.T_BASE_CAMERA))
            assembler.on_message('odometry', odom)
        else:
            assembler.on_message(ROLE[topic], msg)
    frames = read_transforms(tmp_path).frames
    assert len(frames) == 3
    assert np.allclose(frames[2].T_world_camera, opengl_from_optical(bf.frame_pose(2)), atol=1e-9)


def test_distorted_camera_info_is_undone_on_keyframes(tmp_path: Path) -> None:
    assembler = FrameAssembler(settings_from_parameters({}), KeyframeStore(tmp_path), Logs())
    msgs = bf.messages(1)
    info = msgs[0][3]
    info.d = [-0.2, 0.05, 0.0, 0.0, 0.0]
    for topic, _, _, msg in msgs:
        assembler.on_message(ROLE[topic], msg)
    frames = read_transforms(tmp_path).frames
    import cv2
    stored = cv2.imread(str(tmp_path / frames[0].file_path))[..., ::-1]
    raw, mask = bf.frame_pixels(0)
    assert stored.shape == raw.shape and not np.array_equal(stored, raw)
    inst = cv2.imread(str(tmp_path / frames[0].instance_path), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(inst)) <= set(np.unique(mask))


def test_throttled_log_keeps_kinds_apart_and_counts_suppressed() -> None:
    logs = Logs()
    log = ThrottledLog(logs, period_s=1000.0)
    for _ in range(5):
        log(LogLevel.WARN, 'a', 'first kind')
    log(LogLevel.ERROR, 'b', 'second kind')
    assert logs == [(LogLevel.WARN, 'first kind'), (LogLevel.ERROR, 'second kind')]
    log.period_s = 0.0
    log(LogLevel.WARN, 'a', 'first kind')
    assert logs[-1] == (LogLevel.WARN, 'first kind (4 similar messages suppressed)')
