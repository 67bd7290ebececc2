"""Bag replay without training: topics, storages, bad input (every fault logged, good frames kept on disk)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import opengl_from_optical
from fruitnerfpp_ros.errors import BagError
from fruitnerfpp_ros.nodes.bag_replay import collect_keyframes, replay_bag
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.nodes import bag_factory as bf

SETTINGS = settings_from_parameters({'min_translation_m': 0.1})


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))

    def text(self) -> str:
        return '\n'.join(m for _, m in self)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_clean_bag_gives_every_frame_with_exact_pose(tmp_path: Path, storage: str) -> None:
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(6), storage)
    assembler = collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=Logs())
    data = read_transforms(tmp_path / 'kf')
    assert [f.stamp_ns for f in data.frames] == [bf.START_NS + k * bf.PERIOD_NS for k in range(6)]
    assert np.allclose(data.frames[3].T_world_camera, opengl_from_optical(bf.frame_pose(3)))
    assert (data.intrinsics.cx, data.intrinsics.fl_x) == (bf.INTRINSICS.cx, bf.INTRINSICS.fl_x)
    assert assembler.status().errors == {}
    assert data.mask_source == 'topic'                 # the count's masks step reads where the masks came from


def test_tf_pose_source_reads_tf_from_the_bag(tmp_path: Path) -> None:
    msgs = [m for m in bf.messages(5) if m[0] != '/camera/pose']
    bag = bf.write_bag(tmp_path / 'bag', msgs, tf_frames=5)
    settings = settings_from_parameters({'pose_source': 'tf', 'min_translation_m': 0.1})
    collect_keyframes(bag, tmp_path / 'kf', settings, log=Logs())
    frames = read_transforms(tmp_path / 'kf').frames
    assert len(frames) == 5
    assert np.allclose(frames[4].T_world_camera, opengl_from_optical(bf.frame_pose(4)), atol=1e-9)


def test_faulty_frames_are_logged_and_skipped_good_ones_stay(tmp_path: Path) -> None:
    msgs = bf.messages(8, bad_encoding_at=(1,), nan_pose_at=(3,), small_mask_at=(5,))
    bag = bf.write_bag(tmp_path / 'bag', msgs)
    logs = Logs()
    assembler = collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=logs)
    text = logs.text()
    assert "/camera/image_raw: unsupported image encoding 'yuv422'" in text
    assert '/camera/pose: pose is not finite' in text
    assert '/camera/instance_mask: mask is 16x12 but the image is 32x24' in text
    stamps = [f.stamp_ns for f in read_transforms(tmp_path / 'kf').frames]
    assert stamps == [bf.START_NS + k * bf.PERIOD_NS for k in (0, 2, 4, 6, 7)]
    assert assembler.status().total_errors >= 3


def test_stamps_that_never_sync(tmp_path: Path) -> None:
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(5, mask_offset_ns=50_000_000))
    logs = Logs()
    with pytest.raises(BagError, match='no keyframe could be made'):
        replay_bag(bag, tmp_path / 'run', SETTINGS, log=logs)
    assert 'stamps do not match within sync_slop_s=0.02 s' in logs.text()


def test_missing_camera_info_topic_lists_the_bag_topics(tmp_path: Path) -> None:
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(3, camera_info=False))
    with pytest.raises(BagError, match=r'no topic /camera/camera_info \(camera_info\).*topics in the bag: '
                                       r'/camera/image_raw \[sensor_msgs/msg/Image\]'):
        collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=Logs())


def test_renamed_topic_via_params_file(tmp_path: Path) -> None:
    msgs = [(('/cam/rgb' if t == '/camera/image_raw' else t), ty, s, m) for t, ty, s, m in bf.messages(3)]
    bag = bf.write_bag(tmp_path / 'bag', msgs)
    with pytest.raises(BagError, match='no topic /camera/image_raw'):
        collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=Logs())
    settings = settings_from_parameters({'image_topic': '/cam/rgb', 'min_translation_m': 0.1})
    assert len(collect_keyframes(bag, tmp_path / 'kf2', settings, log=Logs()).store) == 3


def test_a_bag_with_only_the_compressed_stream_is_read_from_it(tmp_path: Path) -> None:
    """image_transport records ``/camera/image_raw/compressed``; the default ``image_topic`` finds it."""
    import cv2
    from sensor_msgs.msg import CompressedImage

    msgs = []
    for topic, msgtype, stamp, msg in bf.messages(4):
        if topic == '/camera/image_raw':   # the same pixels as PNG (lossless), as compressed_image_transport sends
            rgb = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, 3)
            png = cv2.imencode('.png', rgb[..., ::-1])[1].tobytes()
            topic, msgtype = '/camera/image_raw/compressed', 'sensor_msgs/msg/CompressedImage'
            msg = CompressedImage(header=msg.header, format='rgb8; png compressed bgr8', data=png)
        msgs.append((topic, msgtype, stamp, msg))
    bag = bf.write_bag(tmp_path / 'bag', msgs)
    logs = Logs()
    assembler = collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=logs)
    assert 'reading its compressed stream /camera/image_raw/compressed' in logs.text()
    data = read_transforms(tmp_path / 'kf')
    assert len(data.frames) == 4 and assembler.status().errors == {}
    stored = cv2.imread(str(tmp_path / 'kf' / data.frames[2].file_path))[..., ::-1]
    assert np.array_equal(stored, bf.frame_pixels(2)[0])


def test_poses_in_another_frame_than_world_frame_are_warned_once(tmp_path: Path) -> None:
    msgs = bf.messages(4)
    for topic, _, _, msg in msgs:
        if topic == '/camera/pose':
            msg.header.frame_id = 'odom'
    bag = bf.write_bag(tmp_path / 'bag', msgs)
    logs = Logs()
    collect_keyframes(bag, tmp_path / 'kf', SETTINGS, log=logs)   # world_frame: map (the default)
    warned = [m for level, m in logs if "poses in frame 'odom'" in m]
    assert len(warned) == 1 and level_of(logs, warned[0]) is LogLevel.WARN
    assert "set world_frame:=odom" in warned[0]
    assert len(read_transforms(tmp_path / 'kf').frames) == 4                  # the poses are used as they are
    quiet = Logs()
    odom = settings_from_parameters({'min_translation_m': 0.1, 'world_frame': 'odom'})
    collect_keyframes(bag, tmp_path / 'kf2', odom, log=quiet)
    assert 'poses in frame' not in quiet.text()


def level_of(logs: Logs, message: str) -> LogLevel:
    return next(level for level, m in logs if m == message)


def test_missing_and_unreadable_bags(tmp_path: Path) -> None:
    """Nothing to recover is a one-line BagError (truncated bags: test_bag_recovery.py)."""
    with pytest.raises(BagError, match='no such bag'):
        collect_keyframes(tmp_path / 'nope', tmp_path / 'kf', SETTINGS, log=Logs())
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(6))
    mcap_file = next(bag.glob('*.mcap'))
    mcap_file.write_bytes(b'\x89MCAP0\r\n' + bytes(range(256)) * 4)
    with pytest.raises(BagError, match='cannot open as a rosbag2 .*nothing could be recovered'):
        collect_keyframes(bag, tmp_path / 'kf3', SETTINGS, log=Logs())
    sqlite_bag = bf.write_bag(tmp_path / 'bag_sqlite', bf.messages(6), 'sqlite3')
    db = next(sqlite_bag.glob('*.db3'))
    db.write_bytes(db.read_bytes()[:1000])
    with pytest.raises(BagError, match='nothing could be recovered.*no readable topics table'):
        collect_keyframes(sqlite_bag, tmp_path / 'kf4', SETTINGS, log=Logs())


def test_replay_into_an_existing_run_dir(tmp_path: Path) -> None:
    from fruitnerfpp_ros.errors import ConfigError
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(6))
    run = tmp_path / 'run'
    (run / 'checkpoints').mkdir(parents=True)
    with pytest.raises(ConfigError, match='already holds a training run; continue it with --resume'):
        replay_bag(bag, run, SETTINGS, log=Logs())
    for _ in range(2):  # collecting twice does not mix the keyframes of both replays
        assert replay_bag(bag, run, SETTINGS, log=Logs(), train=False).n_keyframes == 6
    assert len(read_transforms(run / 'keyframes').frames) == 6
    assert len(list(run.glob('keyframes_previous_*'))) == 1
