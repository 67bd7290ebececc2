"""RGB-D input: depth messages convert with their unit, join their frame by stamp (waiting while the depth stream is
alive, never for a silent one), are refused when misaligned, and a depth bag replays into keyframes with depth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import Image

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.core.synthetic.bag_writer import DEPTH_TOPIC
from fruitnerfpp_ros.errors import ConversionError
from fruitnerfpp_ros.nodes.bag_replay import collect_keyframes
from fruitnerfpp_ros.nodes.conversions import depth_from_msg, time_msg_from_ns
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.nodes import bag_factory as bf

ROLE = {'/camera/image_raw': 'image', '/camera/camera_info': 'camera_info', '/camera/pose': 'pose',
        '/camera/instance_mask': 'mask'}


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))


def _depth_m(k: int, shape: tuple[int, int] = (bf.H, bf.W)) -> np.ndarray:
    depth = np.random.default_rng(100 + k).uniform(0.5, 4.0, shape).astype(np.float32)
    depth[:2, :3] = 0.0
    return depth


def _depth_msg(k: int, encoding: str = '16UC1', *, frame_id: str = 'camera_optical', offset_ns: int = 0,
               shape: tuple[int, int] = (bf.H, bf.W)) -> Image:
    depth = _depth_m(k, shape)
    pixels = np.round(depth * 1000).astype('<u2') if encoding == '16UC1' else \
        np.where(depth > 0, depth, np.nan).astype('<f4')
    msg = Image(height=shape[0], width=shape[1], encoding=encoding, is_bigendian=0, step=int(pixels.strides[0]),
                data=pixels.tobytes())
    msg.header.stamp = time_msg_from_ns(bf.START_NS + k * bf.PERIOD_NS + offset_ns)
    msg.header.frame_id = frame_id
    return msg


def _assembler(tmp_path: Path, logs: Logs, **params: Any) -> FrameAssembler:
    settings = settings_from_parameters({'depth_topic': '/camera/depth', 'min_translation_m': 0.1, **params})
    return FrameAssembler(settings, KeyframeStore(tmp_path / 'kf'), logs)


def test_depth_messages_in_millimetres_and_metres() -> None:
    mm = depth_from_msg(_depth_msg(0, '16UC1'))
    metres = depth_from_msg(_depth_msg(0, '32FC1'))
    np.testing.assert_allclose(mm, _depth_m(0), atol=5e-4)
    np.testing.assert_allclose(metres, _depth_m(0), atol=1e-6)
    assert mm.dtype == np.float32 and mm[0, 0] == 0.0 and metres[0, 0] == 0.0  # 0 and NaN: no return
    bad = _depth_msg(0)
    bad.encoding = 'mono8'
    with pytest.raises(ConversionError, match="unsupported depth encoding 'mono8'"):
        depth_from_msg(bad)
    with pytest.raises(ConversionError, match='depth image is 32x24 but the colour image is 64x48'):
        depth_from_msg(_depth_msg(0), topic='d', expected_shape=(48, 64))


def test_depth_joins_its_frame_and_round_trips_to_the_dataset(tmp_path: Path) -> None:
    assembler = _assembler(tmp_path, Logs())
    for topic, _, _, msg in bf.messages(4):
        assembler.on_message(ROLE[topic], msg)
        if topic == '/camera/instance_mask':  # the depth of frame k arrives after its image, 5 ms off its stamp
            frame = (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec - bf.START_NS) // bf.PERIOD_NS
            assembler.on_message('depth', _depth_msg(frame, '32FC1' if frame % 2 else '16UC1', offset_ns=5_000_000))
    assert len(assembler.store) == 4 and assembler.depth is not None and assembler.depth.matched == 4
    tf = read_transforms(tmp_path / 'kf')
    assert tf.depth_unit_scale_factor == 0.001 and all(f.depth_path for f in tf.frames)
    depths = load_dataset(tmp_path / 'kf', eval_every=0).depths
    assert depths is not None
    for k in range(4):
        np.testing.assert_allclose(depths[k].numpy(), _depth_m(k), atol=5e-4)


def test_a_silent_depth_topic_never_holds_frames_up(tmp_path: Path) -> None:
    logs = Logs()
    assembler = _assembler(tmp_path, logs, pending_timeout_s=0.25)
    for topic, _, _, msg in bf.messages(6):
        assembler.on_message(ROLE[topic], msg)
    # frames wait while the depth stream may still start, then go on without depth once it has been silent
    assert len(assembler.store) >= 3
    assembler.flush()
    assert len(assembler.store) == 6 and assembler.dropped_pending == 0
    assert not any(f.depth_path for f in assembler.store.frames)
    assert any('/camera/depth: no depth image for' in m and 'without depth' in m for _, m in logs)
    assert load_dataset(tmp_path / 'kf', eval_every=0).depths is None


def test_misaligned_depth_is_refused_and_the_frame_kept(tmp_path: Path) -> None:
    logs = Logs()
    assembler = _assembler(tmp_path, logs)
    msgs = bf.messages(3)
    wrong = {0: _depth_msg(0, shape=(12, 16)), 1: _depth_msg(1, frame_id='camera_depth_optical'), 2: _depth_msg(2)}
    for topic, _, stamp, msg in msgs:
        assembler.on_message(ROLE[topic], msg)
        if topic == '/camera/instance_mask':
            assembler.on_message('depth', wrong[(stamp - bf.START_NS) // bf.PERIOD_NS])
    assert len(assembler.store) == 3 and assembler.errors['depth'] == 2
    assert [f.depth_path is not None for f in assembler.store.frames] == [False, False, True]
    text = ' '.join(m for _, m in logs)
    assert 'depth image is 16x12 but the colour image is 32x24' in text
    assert "depth is in frame 'camera_depth_optical', the image in 'camera_optical'" in text


def test_a_depth_bag_replays_into_keyframes_with_depth(tmp_path: Path) -> None:
    generate_orchard(SynthConfig(count=4, views=5, resolution=(40, 32), depth='stereo', sparse_points=0,
                                 distortion=(-0.1, 0.02, 0.0, 0.0, 0.0)), tmp_path / 'ds', bag=tmp_path / 'bag')
    settings = settings_from_parameters({'depth_topic': DEPTH_TOPIC, 'min_translation_m': 0.0,
                                         'min_rotation_deg': 0.0})
    collect_keyframes(tmp_path / 'bag', tmp_path / 'kf', settings, log=Logs())
    frames = read_transforms(tmp_path / 'kf').frames
    assert len(frames) == 5 and all(f.depth_path for f in frames)
    truth = load_dataset(tmp_path / 'ds', eval_every=0).depths  # the dataset's depth, undistorted by the loader
    replayed = load_dataset(tmp_path / 'kf', eval_every=0).depths  # undistorted by the node
    assert truth is not None and replayed is not None
    np.testing.assert_allclose(replayed.numpy(), truth.numpy(), atol=1.5e-3)
    raw = cv2.imread(str(tmp_path / 'kf' / frames[0].depth_path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.max() < 6500  # millimetres
