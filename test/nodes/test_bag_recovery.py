"""Recordings cut short: an MCAP without footer and summary, a sqlite3 file with missing pages, no metadata.yaml.

Before: such a bag was refused ("File end magic is invalid", "database disk image is malformed") and the whole
drive was lost. Now the replay reads it up to its last whole message, warns how much it recovered and counts.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message

from fruitnerfpp_ros.core.bags import open_bag
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.nodes.bag_replay import replay_bag
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.nodes import bag_factory as bf

SETTINGS = settings_from_parameters({'min_translation_m': 0.1})
N_FRAMES = 8
STAMPS = [bf.START_NS + k * bf.PERIOD_NS for k in range(N_FRAMES)]


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))

    def warnings(self) -> str:
        return '\n'.join(m for level, m in self if level is LogLevel.WARN)


@pytest.fixture(scope='module')
def sound_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp('sound_bags')
    return {storage: bf.write_bag(out / storage, bf.messages(N_FRAMES), storage) for storage in ('mcap', 'sqlite3')}


def _cut_copy(bag: Path, tmp_path: Path, keep: int | float) -> tuple[Path, Path]:
    """A copy of ``bag`` whose storage file keeps ``keep`` bytes (an int) or that fraction (a float)."""
    copy = tmp_path / f'{bag.name}_cut'
    shutil.copytree(bag, copy)
    storage = next(p for p in copy.iterdir() if p.suffix in ('.mcap', '.db3'))
    data = storage.read_bytes()
    storage.write_bytes(data[:keep if isinstance(keep, int) else int(len(data) * keep)])
    (copy / 'metadata.yaml').unlink()  # a recorder that lost power wrote no metadata.yaml either
    return copy, storage


def _message_ends(storage: Path) -> list[tuple[int, int]]:
    """(end offset in the file, frame) of each frame's last message (its mask), found by its bytes."""
    data = storage.read_bytes()
    ends = []
    for topic, _, stamp, msg in bf.messages(N_FRAMES):
        if topic == '/camera/instance_mask':
            raw = serialize_message(msg)
            ends.append((data.index(raw) + len(raw), (stamp - bf.START_NS) // bf.PERIOD_NS))
    return ends


@pytest.mark.parametrize('fraction', [0.2, 0.55, 0.9, 'footer'])
def test_a_truncated_mcap_gives_every_frame_before_the_cut(sound_bags: dict[str, Path], tmp_path: Path,
                                                           fraction: float | str) -> None:
    sound = next(sound_bags['mcap'].glob('*.mcap'))
    ends = _message_ends(sound)
    cut = ends[-1][0] + 40 if fraction == 'footer' else int(sound.stat().st_size * fraction)  # 'footer': data
    bag, _ = _cut_copy(sound_bags['mcap'], tmp_path, cut)                                # whole, summary lost
    logs = Logs()
    result = replay_bag(bag, tmp_path / 'run', SETTINGS, log=logs, train=False)
    whole = [k for end, k in ends if end <= cut]
    assert [f.stamp_ns for f in read_transforms(result.keyframes_dir).frames] == [STAMPS[k] for k in whole]
    assert len(result.recoveries) == 1 and 'File end magic is invalid' in result.recoveries[0].reason
    assert f'recovered {result.recoveries[0].messages} message(s), readable up to byte' in logs.warnings()
    assert 'no metadata.yaml; reading its storage files directly' in logs.warnings()


def test_a_truncated_sqlite3_bag_gives_the_frames_its_pages_still_hold(sound_bags: dict[str, Path],
                                                                       tmp_path: Path) -> None:
    """SQLite keeps rows in leaf pages anywhere in the file: a cut loses the rows of the pages behind it."""
    found = []
    for fraction in (0.5, 0.9):
        bag, _ = _cut_copy(sound_bags['sqlite3'], tmp_path / str(fraction), fraction)
        result = replay_bag(bag, tmp_path / f'run_{fraction}', SETTINGS, log=Logs(), train=False)
        stamps = [f.stamp_ns for f in read_transforms(result.keyframes_dir).frames]
        assert set(stamps) <= set(STAMPS) and len(stamps) == len(set(stamps))
        assert 'database disk image is malformed' in result.recoveries[0].reason
        found.append(len(stamps))
    assert 1 <= found[0] <= found[1] < N_FRAMES


def test_no_or_stale_metadata_does_not_stop_a_sound_bag(sound_bags: dict[str, Path], tmp_path: Path) -> None:
    for storage, bag in sound_bags.items():
        copy = tmp_path / storage
        shutil.copytree(bag, copy)
        (copy / 'metadata.yaml').unlink()
        logs = Logs()
        assert replay_bag(copy, tmp_path / f'run_{storage}', SETTINGS, log=logs, train=False).n_keyframes == N_FRAMES
        assert 'no metadata.yaml' in logs.warnings()
    stale = tmp_path / 'stale'
    shutil.copytree(sound_bags['mcap'], stale)
    (stale / 'mcap.mcap').rename(stale / 'mcap_1.mcap')  # a split file the metadata does not list
    logs = Logs()
    assert replay_bag(stale, tmp_path / 'run_stale', SETTINGS, log=logs, train=False).n_keyframes == N_FRAMES
    assert 'metadata.yaml is stale (lists mcap.mcap; present mcap_1.mcap)' in logs.warnings()


def test_a_chunk_that_does_not_decompress_is_skipped_and_counted(tmp_path: Path) -> None:
    """A damaged compressed chunk in the middle: the chunks around it are read."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / 'zstd'
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, msgtype, stamp, msg in bf.messages(N_FRAMES):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=typestore)
            writer.write(connections[topic], stamp, serialize_message(msg))
            if topic == '/camera/instance_mask' and stamp == STAMPS[3]:
                writer.storage.close_chunk()  # frames 0-3 in one chunk, 4-7 in the next
    storage = next(bag.glob('*.mcap'))
    data = bytearray(storage.read_bytes())
    data[-200:] = b''  # no footer
    middle = data.index(b'\x28\xb5\x2f\xfd', data.index(b'\x28\xb5\x2f\xfd') + 4)  # the second zstd frame
    data[middle:middle + 8] = bytes(8)  # its frame header
    storage.write_bytes(bytes(data))
    source = open_bag(storage)
    assert source.recoveries[0].lost_records == 1
    assert 0 < source.recoveries[0].messages < 4 * N_FRAMES


def test_a_chunk_failing_its_crc_is_skipped_and_the_next_is_read(tmp_path: Path) -> None:
    """The mcap library writes chunk CRCs (rosbags writes none): a damaged chunk is recognised and left out."""
    from mcap.writer import CompressionType, Writer

    path = tmp_path / 'crc.mcap'
    with open(path, 'wb') as f:
        writer = Writer(f, chunk_size=200, compression=CompressionType.NONE)
        writer.start('ros2', 'test')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = writer.register_channel('/text', 'cdr', schema)
        for k in range(6):
            writer.add_message(channel, log_time=k, publish_time=k, data=bytes([k]) * 150)
        writer.finish()
    data = bytearray(path.read_bytes())
    data[data.index(bytes([2]) * 150) + 10] ^= 0xFF  # a flipped byte in message 2's chunk
    path.write_bytes(bytes(data[:data.index(bytes([5]) * 150) + 150]))  # cut after the last message
    source = open_bag(path)
    messages = list(source.messages({'/text'}))
    # messages 1 and 2 share a chunk (chunk_size 200 B): both are left out, the others are read
    assert [m.data[0] for m in messages] == [0, 3, 4, 5] and source.recoveries[0].lost_records == 1
