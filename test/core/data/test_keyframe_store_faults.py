"""Keyframe store under faults: a full disk, kills between writes, torn journal lines, repeated stamps, long drives."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fruitnerfpp_ros.core.data.keyframe_store as keyframe_store
from fruitnerfpp_ros.core.data.keyframe_journal import JOURNAL_NAME
from fruitnerfpp_ros.core.data.keyframe_store import Keyframe, KeyframeConfig, KeyframeDecision, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, read_transforms
from fruitnerfpp_ros.errors import DatasetError

INTR = CameraIntrinsics(10.0, 10.0, 4.0, 4.0, 8, 8)


def _kf(i: int, stamp: int | None = None) -> Keyframe:
    T = np.eye(4)
    T[0, 3] = float(i)
    rgb = np.random.default_rng(i).integers(0, 255, (8, 8, 3), dtype=np.uint8)
    return Keyframe(i if stamp is None else stamp, rgb, np.ones((8, 8), np.uint16), T, INTR)


def test_a_failed_write_stores_nothing_and_keeps_what_was_stored(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: the frame joined the store's list before transforms.json was written, and an OSError escaped."""
    store = KeyframeStore(tmp_path / 'kf')
    for i in range(3):
        store.offer(_kf(i))
    real_append = keyframe_store.append_entry

    def disk_full(*args: object) -> None:
        raise OSError(errno.ENOSPC, 'No space left on device')
    monkeypatch.setattr(keyframe_store, 'append_entry', disk_full)
    with pytest.raises(DatasetError, match=r'keyframe 3 not stored \(No space left on device; \d+ KiB free on '
                                           r'its disk\); the 3 keyframe'):
        store.offer(_kf(3))
    assert len(store) == 3 and store.write_errors == 1
    assert not list((tmp_path / 'kf').glob('*/000003.png'))  # no orphan files of the lost frame
    monkeypatch.setattr(keyframe_store, 'append_entry', real_append)  # space again
    assert store.offer(_kf(3)) is KeyframeDecision.ACCEPTED
    assert [f.stamp_ns for f in KeyframeStore(tmp_path / 'kf').frames] == [0, 1, 2, 3]


def test_a_journal_write_that_makes_no_progress_is_an_error_not_a_hang(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``os.write`` may return fewer bytes than asked; a return of 0 made the append loop for ever."""
    import fruitnerfpp_ros.core.data.keyframe_journal as keyframe_journal
    store = KeyframeStore(tmp_path / 'kf')
    store.offer(_kf(0))
    journal = (tmp_path / 'kf' / JOURNAL_NAME).read_bytes()
    real_write = os.write

    def short_then_none(fd: int, data: bytes) -> int:
        return real_write(fd, data[:7]) if len(data) > 40 else 0
    monkeypatch.setattr(keyframe_journal.os, 'write', short_then_none)
    with pytest.raises(DatasetError, match='keyframe 1 not stored'):
        store.offer(_kf(1))
    monkeypatch.undo()
    assert (tmp_path / 'kf' / JOURNAL_NAME).read_bytes() == journal  # the partial line was cut off again
    assert store.offer(_kf(1)) is KeyframeDecision.ACCEPTED and len(KeyframeStore(tmp_path / 'kf')) == 2


def test_a_kill_between_index_writes_loses_no_keyframe(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf', index_every_frame_below=3, index_period_s=1e9)
    for i in range(5):
        store.offer(_kf(i))
    assert len(read_transforms(tmp_path / 'kf').frames) == 2  # the index lags; the journal does not
    with open(tmp_path / 'kf' / JOURNAL_NAME, 'ab') as f:  # a kill in the middle of the next line
        f.write(b'{"index": 5, "frame": {"file_pa')
    resumed = KeyframeStore(tmp_path / 'kf')
    assert [f.stamp_ns for f in resumed.frames] == [0, 1, 2, 3, 4]
    assert len(read_transforms(tmp_path / 'kf').frames) == 5  # re-indexed on opening
    assert resumed.offer(_kf(5)) is KeyframeDecision.ACCEPTED  # a line of its own after the torn one was cut
    assert len(KeyframeStore(tmp_path / 'kf')) == 6


def test_repeated_stamps_and_a_resumed_replay(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf')
    assert store.offer(_kf(0)) is KeyframeDecision.ACCEPTED
    assert store.offer(_kf(5, stamp=0)) is KeyframeDecision.DUPLICATE_STAMP
    store.offer(_kf(1))
    resumed = KeyframeStore(tmp_path / 'kf', resume_after_newest=True)
    assert [resumed.offer(_kf(i)) for i in (0, 1, 2)] == [KeyframeDecision.ALREADY_STORED] * 2 + \
        [KeyframeDecision.ACCEPTED]
    assert resumed.rejected[KeyframeDecision.ALREADY_STORED] == 2


def test_storing_costs_the_same_however_many_keyframes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: transforms.json was rewritten after every keyframe (1,000 keyframes: 24 s, 10,000: ~40 min)."""
    writes = []
    real = keyframe_store.write_transforms
    monkeypatch.setattr(keyframe_store, 'write_transforms', lambda *a: writes.append(1) or real(*a))
    store = KeyframeStore(tmp_path / 'kf', KeyframeConfig(max_keyframes=10_000), index_every_frame_below=20,
                          index_period_s=3600.0)
    for i in range(400):
        store.offer(_kf(i))
    assert len(writes) <= 21
    store.flush()
    assert len(read_transforms(tmp_path / 'kf').frames) == 400


_DISK_FULL_SCRIPT = r'''
import json, sys
from pathlib import Path
import cv2, numpy as np, torch
from fruitnerfpp_ros.core.data.keyframe_store import Keyframe, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, read_transforms
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint, save_checkpoint
from fruitnerfpp_ros.errors import CheckpointError, DatasetError
root = Path(sys.argv[1])
small = {'field': torch.arange(4000, dtype=torch.float32)}
save_checkpoint(small, root / 'run' / 'latest.pt')
(root / 'ballast').write_bytes(bytes(96 * 1024))
store, n, error = KeyframeStore(root / 'kf'), 0, ''
intr = CameraIntrinsics(50.0, 50.0, 32.0, 24.0, 64, 48)
for i in range(200):
    T = np.eye(4); T[0, 3] = i
    rgb = np.random.default_rng(i).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    try:
        store.offer(Keyframe(i, rgb, np.ones((48, 64), np.uint16), T, intr))
    except DatasetError as err:
        error = str(err); break
    n += 1
try:
    save_checkpoint({'field': torch.zeros(200_000)}, root / 'run' / 'latest.pt'); ckpt_error = ''
except CheckpointError as err:
    ckpt_error = str(err)
kept = torch.equal(load_checkpoint(root / 'run' / 'latest.pt')['field'], small['field'])
reopened = KeyframeStore(root / 'kf')
n_reopened = len(reopened)
readable = all(cv2.imread(str(root / 'kf' / f.file_path)) is not None for f in reopened.frames)
(root / 'ballast').unlink()  # space again
after = reopened.offer(Keyframe(10_000, rgb, np.ones((48, 64), np.uint16), np.eye(4), intr)).value
print(json.dumps({'n': n, 'error': error, 'ckpt_error': ckpt_error, 'ckpt_kept': kept, 'reopened': n_reopened,
                  'readable': readable, 'index': len(read_transforms(root / 'kf').frames), 'after': after,
                  'tmp_left': sorted(p.name for p in root.rglob('*.tmp*'))}))
'''


def _can_mount_tmpfs() -> bool:
    if shutil.which('unshare') is None:
        return False
    probe = subprocess.run(['unshare', '-m', 'sh', '-c', 'mount -t tmpfs -o size=64k tmpfs /mnt'],
                           capture_output=True)
    return probe.returncode == 0


@pytest.mark.skipif(not _can_mount_tmpfs(), reason='needs `unshare -m` and tmpfs mounts (root); the ENOSPC '
                    'paths are covered by test_a_failed_write_stores_nothing_and_keeps_what_was_stored')
def test_a_real_full_disk_for_keyframes_and_checkpoints(tmp_path: Path) -> None:
    """A 320 KiB tmpfs in a private mount namespace: keyframes until the disk is full, then a checkpoint."""
    mount = tmp_path / 'small_disk'
    mount.mkdir()
    command = (f'mount -t tmpfs -o size=320k tmpfs {mount} && exec {sys.executable} -c "$SCRIPT" {mount}')
    run = subprocess.run(['unshare', '-m', 'sh', '-c', command], capture_output=True, text=True, timeout=120,
                         env={**os.environ, 'SCRIPT': _DISK_FULL_SCRIPT})
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    n = result['n']
    assert 3 <= n < 200 and f'keyframe {n} not stored (' in result['error'], result
    assert 'KiB free on its disk); the' in result['error']
    assert 'cannot write checkpoint' in result['ckpt_error'] and 'previous checkpoint is kept' in result['ckpt_error']
    assert result['ckpt_kept'] and result['tmp_left'] == []
    assert result['reopened'] == n and result['readable'] and result['index'] == n + 1
    assert result['after'] == 'accepted'


def test_readers_never_wait_for_a_keyframe_being_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: offer() held the store's lock while encoding PNGs, so /diagnostics (len) and ~/save waited for the
    disk (a 1280x720 keyframe takes ~0.2 s, a slow disk far longer)."""
    import threading
    import time
    store = KeyframeStore(tmp_path / 'kf')
    store.offer(_kf(0))
    real = keyframe_store.write_rgb_png
    writing = threading.Event()

    def slow_disk(*args: object) -> None:
        writing.set()
        time.sleep(1.0)
        real(*args)
    monkeypatch.setattr(keyframe_store, 'write_rgb_png', slow_disk)
    writer = threading.Thread(target=store.offer, args=(_kf(1),))
    writer.start()
    assert writing.wait(5)
    started = time.monotonic()
    assert len(store) == 1 and len(store.frames) == 1
    assert time.monotonic() - started < 0.5
    writer.join()
    assert len(store) == 2
