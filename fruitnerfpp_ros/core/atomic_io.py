"""Atomic file writes: a crash or a kill leaves either the previous file or the new one, never half of one.

Appended logs (one JSON record per line) cannot be replaced atomically; :func:`trim_torn_line` cuts the last
line off such a file when a kill or a full disk left it without its newline, before the file is read again.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

__all__ = ['atomic_path', 'atomic_write_bytes', 'atomic_write_text', 'trim_torn_line']


@contextlib.contextmanager
def atomic_path(path: str | Path, *, suffix: str = '.tmp') -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (parent folders created); on success it replaces ``path``.

    ``suffix`` ends the temporary name (e.g. ``.tmp.npz`` for writers that insist on an extension). On an
    exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes, *, fsync: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; ``fsync`` also flushes it to the disk before the rename."""
    with atomic_path(path) as tmp, open(tmp, 'wb') as f:
        f.write(data)
        if fsync:
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_text(path: str | Path, text: str, *, fsync: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode('utf-8'), fsync=fsync)


def trim_torn_line(path: str | Path) -> int:
    """Cut a last line without its newline off a line-per-record file (``metrics.jsonl``); returns the bytes cut.

    A missing file or one ending with a newline is left as it is.
    """
    path = Path(path)
    if not path.is_file():
        return 0
    with open(path, 'rb+') as f:
        size = f.seek(0, os.SEEK_END)
        if size == 0:
            return 0
        f.seek(size - 1)
        if f.read(1) == b'\n':
            return 0
        f.seek(0)
        keep = f.read().rfind(b'\n') + 1
        f.truncate(keep)
        return size - keep
