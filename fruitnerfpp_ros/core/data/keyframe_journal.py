"""The keyframe store's append-only journal: one JSON line per keyframe, so storing a keyframe costs O(1).

``transforms.json`` holds every frame, so rewriting it after each keyframe costs O(n) and a long drive O(n^2)
(10,000 keyframes: gigabytes of JSON). The store appends each keyframe to ``frames.jsonl`` instead (after its
images are on disk) and rewrites ``transforms.json`` now and then; on opening, the frames of the journal that
``transforms.json`` lacks are added back. A line cut by a kill or a full disk is cut off again (a failed append)
or ignored (a torn last line), so the journal never holds half a frame that later lines would follow.

Line format: ``{"index": i, "frame": <transforms.json frame>, "intrinsics": <global intrinsics, frame 0 only>}``.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, FrameEntry, depth_path_of
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['JOURNAL_NAME', 'JournalEntry', 'append_entry', 'read_entries', 'trim_torn_tail']

JOURNAL_NAME = 'frames.jsonl'
_INTRINSIC_KEYS = ('fl_x', 'fl_y', 'cx', 'cy', 'w', 'h')


class JournalEntry(NamedTuple):
    """One journal line: the keyframe's index, its frame and (frame 0) the store's global intrinsics."""

    index: int
    frame: FrameEntry
    intrinsics: CameraIntrinsics | None


def append_entry(directory: Path, entry: JournalEntry) -> None:
    """Append one line to ``directory/frames.jsonl`` and flush it; on failure the file is cut back to its length
    before the call (no torn line stays for later lines to follow).

    Raises:
        OSError: the line could not be written (e.g. ENOSPC); the journal is unchanged.
    """
    line = json.dumps({'index': entry.index, 'frame': entry.frame.to_json(),
                       'intrinsics': None if entry.intrinsics is None else entry.intrinsics.to_json()},
                      separators=(',', ':')) + '\n'
    data = line.encode('utf-8')
    fd = os.open(directory / JOURNAL_NAME, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        start = os.lseek(fd, 0, os.SEEK_END)
        try:
            written = 0
            while written < len(data):  # unbuffered: a failed write leaves nothing queued to flush later
                step = os.write(fd, data[written:])
                if step == 0:  # no progress and no error: never loop on it
                    raise OSError(errno.EIO, 'the journal write made no progress')
                written += step
        except BaseException:
            os.ftruncate(fd, start)
            raise
    finally:
        os.close(fd)


def trim_torn_tail(directory: Path) -> int:
    """Cut a torn last line (a kill in the middle of an append) off ``directory/frames.jsonl``, so the next line
    starts on a line of its own; returns the bytes removed."""
    path = directory / JOURNAL_NAME
    if not path.is_file():
        return 0
    with open(path, 'rb+') as f:
        size = f.seek(0, 2)
        if size == 0:
            return 0
        f.seek(max(0, size - 1))
        if f.read(1) == b'\n':
            return 0
        tail = max(0, size - (1 << 20))
        f.seek(tail)
        keep = tail + f.read().rfind(b'\n') + 1  # lines are far shorter than 1 MiB
        f.truncate(keep)
        return size - keep


def _frame_from_json(raw: Any, where: str) -> FrameEntry:
    if not isinstance(raw, dict) or 'file_path' not in raw or 'transform_matrix' not in raw:
        raise DatasetError(f'{where}: needs "file_path" and "transform_matrix"')
    T = np.asarray(raw['transform_matrix'], dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DatasetError(f'{where}: transform_matrix must be a finite 4x4 matrix')
    own = CameraIntrinsics.from_json(raw, where) if any(k in raw for k in _INTRINSIC_KEYS) else None
    stamp = raw.get('stamp_ns')
    return FrameEntry(str(raw['file_path']), T, raw.get('instance_path'), raw.get('semantic_path'), own,
                      None if stamp is None else int(stamp), raw.get('mask_path'), depth_path_of(raw))


def read_entries(directory: Path) -> list[JournalEntry]:
    """Every readable line of ``directory/frames.jsonl`` in file order ([] when there is none).

    Unreadable lines (a torn last line, a line that is not a frame) are left out; callers keep the entries that
    continue their frame list (``index`` = frames so far).
    """
    path = directory / JOURNAL_NAME
    if not path.is_file():
        return []
    entries = []
    for number, line in enumerate(path.read_bytes().splitlines(), 1):
        try:
            data = json.loads(line)
            intrinsics = data.get('intrinsics')
            entries.append(JournalEntry(int(data['index']), _frame_from_json(data['frame'], f'{path}:{number}'),
                                        None if intrinsics is None else
                                        CameraIntrinsics.from_json(intrinsics, f'{path}:{number}')))
        except (ValueError, KeyError, TypeError, AttributeError, DatasetError):
            continue
    return entries
