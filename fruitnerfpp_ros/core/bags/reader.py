"""Open a rosbag2 recording, whole or damaged: rosbags when it can, record / page recovery when it cannot.

:func:`open_bag` reads a rosbag2 directory (sqlite3 or MCAP) or a single ``.mcap`` / ``.db3`` file:

1. A directory whose ``metadata.yaml`` lists exactly the storage files present is read with rosbags'
   ``AnyReader`` (messages in time order across split files).
2. A missing, unreadable or stale ``metadata.yaml`` (a recorder stopped before writing it, or split files it does
   not list) does not stop the read: each storage file is opened on its own (rosbags reads single files without
   metadata).
3. A storage file rosbags refuses (an MCAP without footer, a sqlite3 file with missing pages), or one that fails
   in the middle of the read, is read by :class:`~fruitnerfpp_ros.core.bags.mcap_recovery.McapRecovery` /
   :class:`~fruitnerfpp_ros.core.bags.sqlite_recovery.SqliteRecovery` up to its last whole message; each
   recovery is reported (:attr:`BagSource.recoveries`), and messages already read are not read twice.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

from fruitnerfpp_ros.core.bags.mcap_recovery import McapRecovery
from fruitnerfpp_ros.core.bags.records import BagMessage, BagTopic, FileRecovery
from fruitnerfpp_ros.core.bags.sqlite_recovery import SqliteRecovery
from fruitnerfpp_ros.errors import BagError

__all__ = ['BagSource', 'open_bag', 'storage_files']

_STORAGE_SUFFIXES = ('.mcap', '.db3')


def storage_files(directory: Path) -> list[Path]:
    """The ``.mcap`` / ``.db3`` files of a bag directory in split order (``name_0``, ``name_1``, ... ``name_10``)."""
    def split_key(path: Path) -> tuple[str, int, str]:
        match = re.match(r'(.*?)(\d+)$', path.stem)
        return (match.group(1), int(match.group(2)), path.name) if match else (path.stem, -1, path.name)
    return sorted((p for p in directory.iterdir() if p.suffix in _STORAGE_SUFFIXES and p.is_file()), key=split_key)


def _metadata_problem(directory: Path, files: list[Path]) -> str:
    """'' when metadata.yaml lists exactly ``files``, else what is wrong with it."""
    path = directory / 'metadata.yaml'
    if not path.is_file():
        return 'no metadata.yaml'
    try:
        info = yaml.safe_load(path.read_text())['rosbag2_bagfile_information']
        listed = {Path(p).name for p in info['relative_file_paths']}
    except Exception as err:  # noqa: BLE001 - any malformed file is "unreadable"
        return f'metadata.yaml unreadable ({type(err).__name__})'
    present = {p.name for p in files}
    if listed != present:
        return (f'metadata.yaml is stale (lists {", ".join(sorted(listed)) or "no file"}; present '
                f'{", ".join(sorted(present)) or "none"})')
    return ''


def _describe(err: BaseException) -> str:
    return f'{type(err).__name__}: {err}'.strip()


def _recover(path: Path, reason: str) -> McapRecovery | SqliteRecovery:
    recovery = McapRecovery if path.suffix == '.mcap' else SqliteRecovery
    return recovery(path, reason)


class _RosbagsPart:
    """Storage read by rosbags' AnyReader (a directory with good metadata, or one file)."""

    def __init__(self, path: Path, files: list[Path]) -> None:
        from rosbags.highlevel import AnyReader
        self.path, self.files = path, files
        self.reader = AnyReader([path])
        self.reader.open()

    @property
    def topics(self) -> list[BagTopic]:
        return [BagTopic(c.topic, c.msgtype) for c in self.reader.connections]

    def messages(self, topics: set[str]) -> Iterator[BagMessage]:
        connections = [c for c in self.reader.connections if c.topic in topics]
        if not connections:  # rosbags reads every connection when given none
            return
        for connection, stamp, raw in self.reader.messages(connections=connections):
            yield BagMessage(connection.topic, connection.msgtype, int(stamp), bytes(raw))

    def close(self) -> None:
        try:
            self.reader.close()
        except Exception:  # noqa: BLE001 - closing a damaged file may fail again; nothing is lost
            pass


class BagSource:
    """A bag opened for reading (use :func:`open_bag`): its topics, its raw messages, and what was recovered.

    Attributes:
        path: the bag directory or file.
        topics: every topic found (name, rosbags type name).
        recoveries: one record per damaged storage file read by recovery (empty for a sound bag).
        notes: other things worth a log line (missing / stale metadata.yaml).
    """

    def __init__(self, path: Path, parts: list[Any], notes: list[str]) -> None:
        self.path = path
        self._parts = parts
        self.notes = notes
        self.recoveries: list[FileRecovery] = [p.report() for p in parts if not isinstance(p, _RosbagsPart)]
        self.on_recovery: Callable[[FileRecovery], None] | None = None
        seen: dict[str, BagTopic] = {}
        for part in parts:
            for topic in part.topics:
                seen.setdefault(topic.topic, topic)
        self.topics = sorted(seen.values())

    def messages(self, topics: set[str]) -> Iterator[BagMessage]:
        """The messages of ``topics``, part after part (time order within a sound part, file order in a
        recovered one). A part that breaks in the middle of the read is read again by recovery, skipping the
        messages already given. Read once: a part that broke is closed."""
        for part in self._parts:
            given: set[tuple[str, int, int]] = set()
            try:
                for message in part.messages(topics):
                    if isinstance(part, _RosbagsPart):
                        given.add((message.topic, message.log_time_ns, len(message.data)))
                    yield message
            except BagError:
                raise
            except Exception as err:  # noqa: BLE001 - rosbags raises many types for damaged files
                if not isinstance(part, _RosbagsPart):
                    raise BagError(f'{self.path}: cannot read the recovered messages: {_describe(err)}') from err
                part.close()
                yield from self._recover_rest(part, given, _describe(err), topics)

    def _recover_rest(self, part: _RosbagsPart, given: set[tuple[str, int, int]], reason: str,
                      topics: set[str]) -> Iterator[BagMessage]:
        for path in part.files:
            try:
                recovery = _recover(path, f'failed while reading: {reason}')
            except BagError:
                continue
            report = recovery.report()
            self.recoveries.append(report)
            if self.on_recovery is not None:
                self.on_recovery(report)
            for message in recovery.messages(topics):
                if (message.topic, message.log_time_ns, len(message.data)) not in given:
                    yield message

    def close(self) -> None:
        """Close every storage file."""
        for part in self._parts:
            if isinstance(part, _RosbagsPart):
                part.close()


def open_bag(path: str | Path) -> BagSource:
    """Open a rosbag2 directory or a single ``.mcap`` / ``.db3`` file (see the module docstring).

    Raises:
        BagError: the path does not exist, holds no storage file, or no storage file could be read at all.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag (a rosbag2 directory or an .mcap / .db3 file)')
    notes: list[str] = []
    if path.is_dir():
        files = storage_files(path)
        if not files:
            raise BagError(f'{path}: no .mcap or .db3 storage file in the bag directory')
        problem = _metadata_problem(path, files)
        if not problem:
            try:
                return BagSource(path, [_RosbagsPart(path, files)], notes)
            except Exception as err:  # noqa: BLE001 - fall back to the files one by one
                notes.append(f'{path}: rosbags cannot open the bag ({_describe(err)}); reading its files one by one')
        else:
            notes.append(f'{path}: {problem}; reading its storage files directly')
    elif path.suffix in _STORAGE_SUFFIXES:
        files = [path]
    else:
        raise BagError(f'{path}: not a rosbag2 directory or an .mcap / .db3 file')
    parts: list[Any] = []
    errors = []
    for file in files:
        try:
            parts.append(_RosbagsPart(file, [file]))
            continue
        except Exception as err:  # noqa: BLE001 - rosbags raises many types for damaged files
            reason = _describe(err)
        try:
            parts.append(_recover(file, reason))
        except BagError as err:
            errors.append(f'{file.name}: {reason}; recovery: {err}')
        except OSError as err:
            errors.append(f'{file.name}: {reason}; recovery: {_describe(err)}')
    if not parts:
        raise BagError(f'{path}: cannot open as a rosbag2 (sqlite3 or MCAP), and nothing could be recovered: '
                       + ' | '.join(errors))
    notes += [f'{path}: skipped unreadable storage file {e}' for e in errors]
    return BagSource(path, parts, notes)
