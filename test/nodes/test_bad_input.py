"""Bad input into the shared collector: every fault is a logged skip with a counter, never an exception.

The rows of docs/results/robustness.md ("bad input"): each case feeds 8 frames with one kind of fault through the
FrameAssembler that the live node and the bag replay share, and checks what was kept and what was counted.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from fruitnerfpp_ros.nodes.status import AssemblerStatus
from test.nodes import bag_factory as bf

ROLE = {'/camera/image_raw': 'image', '/camera/camera_info': 'camera_info', '/camera/pose': 'pose',
        '/camera/instance_mask': 'mask', '/tf': 'tf', '/tf_static': 'tf_static'}
Messages = list[tuple[str, str, int, Any]]


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))


def _at(frame: int, topic: str, change: Callable[[Any], None]) -> Callable[[Messages], Messages]:
    def mutate(messages: Messages) -> Messages:
        out = []
        for t, ty, stamp, msg in messages:
            if t == topic and stamp == bf.START_NS + frame * bf.PERIOD_NS:
                msg = copy.deepcopy(msg)
                change(msg)
            out.append((t, ty, stamp, msg))
        return out
    return mutate


def _every(topic: str, change: Callable[[Any], None]) -> Callable[[Messages], Messages]:
    def mutate(messages: Messages) -> Messages:
        return [m for frame in range(8) for m in _at(frame, topic, change)([x for x in messages if
                                                                           x[2] == bf.START_NS + frame * bf.PERIOD_NS])]
    return mutate


def _set(**fields: Any) -> Callable[[Any], None]:
    def change(msg: Any) -> None:
        for name, value in fields.items():
            target = msg
            *path, last = name.split('__')
            for part in path:
                target = getattr(target, part)
            setattr(target, last, value)
    return change


def _repeat_frame(frame: int) -> Callable[[Messages], Messages]:
    return lambda messages: messages + [m for m in messages if m[2] == bf.START_NS + frame * bf.PERIOD_NS]


def _fill_mask(value: int) -> Callable[[Any], None]:
    def change(msg: Any) -> None:
        msg.data = np.full(msg.height * msg.width, value, np.uint16).tobytes()
    return change


ALL = set(range(8))
CASES = {  # name: (fault, frames kept, counter that must grow)
    'image encoding yuv422': (_at(2, '/camera/image_raw', _set(encoding='yuv422')), ALL - {2}, 'frame'),
    'mask encoding rgb8': (_at(3, '/camera/instance_mask', _set(encoding='rgb8')), ALL - {3}, 'frame'),
    'mask of the wrong size': (_at(4, '/camera/instance_mask', _set(height=12, width=16, step=32,
                                                                    data=bytes(12 * 32))), ALL - {4}, 'frame'),
    'image of zero size': (_at(5, '/camera/image_raw', _set(height=0, width=0, step=0, data=b'')), ALL - {5},
                           'frame'),
    'image data too short': (_at(6, '/camera/image_raw', _set(data=bytes(10))), ALL - {6}, 'frame'),
    'NaN position': (_at(1, '/camera/pose', _set(pose__position__x=float('nan'))), ALL - {1}, 'pose'),
    'Inf orientation': (_at(2, '/camera/pose', _set(pose__orientation__z=float('inf'))), ALL - {2}, 'pose'),
    'non-unit quaternion': (_at(3, '/camera/pose', _set(pose__orientation__w=2.0)), ALL - {3}, 'pose'),
    'zero quaternion': (_at(4, '/camera/pose', _set(pose__orientation__w=0.0)), ALL - {4}, 'pose'),
    'camera_info with zero focal length': (_every('/camera/camera_info', _set(k=[0.0] * 9)), set(), 'camera_info'),
    'camera_info with 6 plumb_bob coefficients': (_every('/camera/camera_info', _set(d=[0.1, 0, 0, 0, 0, 0.1])),
                                                  set(), 'camera_info'),
    'duplicate stamps (a frame sent twice)': (_repeat_frame(3), ALL, 'rejected/duplicate_stamp'),
    'all-fruit masks': (_every('/camera/instance_mask', _fill_mask(1)), ALL, None),
    'no-fruit masks': (_every('/camera/instance_mask', _fill_mask(0)), ALL, None),
}


def _feed(messages: Messages, tmp_path: Path, **params: Any) -> tuple[FrameAssembler, Logs]:
    logs = Logs()
    assembler = FrameAssembler(settings_from_parameters({'min_translation_m': 0.1, **params}),
                               KeyframeStore(tmp_path / 'kf'), logs)
    for topic, _, _, msg in messages:
        assert assembler.on_message(ROLE[topic], msg) is not None  # never raises
    assembler.flush()
    return assembler, logs


def _counter(status: AssemblerStatus, key: str) -> int:
    if key.startswith('rejected/'):
        return status.rejected.get(key.split('/')[1], 0)
    return status.errors.get(key, 0)


@pytest.mark.parametrize('case', list(CASES))
def test_bad_input_is_skipped_and_counted(case: str, tmp_path: Path) -> None:
    fault, kept, counter = CASES[case]
    assembler, logs = _feed(fault(bf.messages(8)), tmp_path)
    stamps = [f.stamp_ns for f in assembler.store.frames]
    assert stamps == [bf.START_NS + k * bf.PERIOD_NS for k in sorted(kept)]
    if counter is not None:
        assert _counter(assembler.status(), counter) >= 1, assembler.status()
        assert any(level is not LogLevel.INFO for level, _ in logs)


def _tf_messages(frames: range, shift_ns: int) -> Messages:
    """/tf map -> base_link (rosbags-decoded messages) for ``frames``, stamps moved by ``shift_ns``."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    static = bf._tf_msg(typestore, 'base_link', 'camera_optical', bf.T_BASE_CAMERA, bf.START_NS)
    out = [('/tf_static', '', bf.START_NS, static)]
    for k in frames:
        stamp = bf.START_NS + k * bf.PERIOD_NS + shift_ns
        T_world_base = bf.frame_pose(k) @ np.linalg.inv(bf.T_BASE_CAMERA)
        out.append(('/tf', '', stamp, bf._tf_msg(typestore, 'map', 'base_link', T_world_base, stamp)))
    return out


def test_a_time_jump_backwards_starts_a_new_time_line(tmp_path: Path) -> None:
    """A bag played again (stamps 100 s earlier): before, its /tf was dropped as older than the cache and every
    frame after the jump was lost; now the queues and the /tf history start over and the frames are kept."""
    back = -100 * 10**9
    later = [(t, ty, s + back, m) for t, ty, s, m in bf.messages(8) if s >= bf.START_NS + 4 * bf.PERIOD_NS]
    for _, _, stamp, msg in later:
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    first = [m for m in bf.messages(4) if m[0] != '/camera/pose']
    messages = _tf_messages(range(4), 0) + first + _tf_messages(range(4, 8), back)[1:] + \
        [m for m in later if m[0] != '/camera/pose']
    assembler, logs = _feed(messages, tmp_path, pose_source='tf')
    assert len(assembler.store) == 8 and assembler.status().time_jumps == 1
    assert any('stamp jumped back 99.9 s' in m for _, m in logs)


def test_a_frame_that_fails_unexpectedly_does_not_hold_up_the_others(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: a non-package exception while completing a frame escaped the drain loop, the frame stayed first in
    the waiting list and every later frame failed behind it."""
    import fruitnerfpp_ros.nodes.frame_assembler as frame_assembler
    calls = []
    real = frame_assembler.undistort_image

    def flaky(image: np.ndarray, camera: Any) -> np.ndarray:
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError('an OpenCV assertion')
        return real(image, camera)
    monkeypatch.setattr(frame_assembler, 'undistort_image', flaky)
    assembler, _ = _feed(bf.messages(6), tmp_path)
    assert len(assembler.store) == 5 and assembler.status().errors == {'frame': 1}
