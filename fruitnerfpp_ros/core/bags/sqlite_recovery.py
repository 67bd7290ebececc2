"""Read the messages a damaged rosbag2 sqlite3 file still holds, page by page.

A truncated or half-written ``.db3`` (a recorder that lost power in the middle of a transaction) is refused by
SQLite as soon as a query touches a missing page, which is usually the root or an interior page of the
``messages`` table: a plain ``SELECT`` then gives nothing at all. The rows themselves live in the table's leaf
pages, which this reader scans directly (the file format is public: https://sqlite.org/fileformat2.html):
every table-leaf page is parsed, its cells classified by shape (``messages``: rowid, topic id, timestamp, data;
``topics``: rowid, name, type, serialization format, ...), large payloads followed through their overflow pages.
A row whose payload cannot be read whole (an overflow page past the end or not written) is skipped and counted.
Rows are yielded in timestamp order, read from the file one at a time.
"""

from __future__ import annotations

import mmap
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

from fruitnerfpp_ros.core.bags.records import BagMessage, BagTopic, FileRecovery
from fruitnerfpp_ros.errors import BagError

__all__ = ['SqliteRecovery', 'SQLITE_MAGIC']

SQLITE_MAGIC = b'SQLite format 3\x00'
_TABLE_LEAF = 0x0D
_U16, _U32 = struct.Struct('>H'), struct.Struct('>I')


class _Damaged(Exception):
    """A cell or payload cannot be read."""


def _varint(buf: bytes | mmap.mmap, pos: int) -> tuple[int, int]:
    """SQLite varint at ``pos``: (value, position after it)."""
    value = 0
    for i in range(9):
        byte = buf[pos + i]
        if i == 8:
            return (value << 8) | byte, pos + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    raise _Damaged()  # pragma: no cover - the loop always returns


def _serial_size(serial: int) -> int:
    if serial < 12:
        return (0, 1, 2, 3, 4, 6, 8, 8, 0, 0, 0, 0)[serial]
    return (serial - 12) // 2 if serial % 2 == 0 else (serial - 13) // 2


class _Cell(NamedTuple):
    rowid: int
    local_start: int
    local_size: int
    payload_size: int
    overflow: int


class _Row(NamedTuple):
    timestamp: int
    rowid: int
    topic_id: int
    cell: _Cell
    data_offset: int  # offset of the data column in the payload
    data_size: int


class SqliteRecovery:
    """Messages of a damaged rosbag2 ``.db3`` file (see the module docstring).

    Args:
        path: the ``.db3`` file.
        reason: why the normal reader refused it (kept for the report).

    Raises:
        BagError: not an SQLite file, or no ``topics`` row could be read (nothing to name the messages by).
    """

    def __init__(self, path: str | Path, reason: str = '') -> None:
        self.path = Path(path)
        self.reason = reason
        self.bytes_total = self.path.stat().st_size
        with open(self.path, 'rb') as f:
            header = f.read(100)
        if len(header) < 100 or not header.startswith(SQLITE_MAGIC):
            raise BagError(f'{self.path}: not an SQLite database (no SQLite header)')
        page_size = _U16.unpack(header[16:18])[0]
        self.page_size = 65536 if page_size == 1 else page_size
        self.usable = self.page_size - header[20]
        if self.page_size < 512 or self.usable < 480:
            raise BagError(f'{self.path}: invalid SQLite page size {self.page_size}')
        self.n_pages = self.bytes_total // self.page_size
        self._topics: dict[int, BagTopic] = {}
        self._rows: dict[int, _Row] = {}
        self.lost_records = 0
        self.bytes_read = 0
        self._scan()
        if not self._topics:
            raise BagError(f'{self.path}: no readable topics table in the damaged sqlite3 file')
        unnamed = [r for r in self._rows.values() if r.topic_id not in self._topics]
        self.lost_records += len(unnamed)
        self._order = sorted((r for r in self._rows.values() if r.topic_id in self._topics),
                             key=lambda r: (r.timestamp, r.rowid))

    @property
    def topics(self) -> list[BagTopic]:
        """Every topic row found."""
        return list(self._topics.values())

    def report(self) -> FileRecovery:
        """How much of the file was read back."""
        return FileRecovery(str(self.path), self.reason, len(self._order), self.bytes_read, self.bytes_total,
                            self.lost_records)

    def messages(self, topics: set[str] | None = None) -> Iterator[BagMessage]:
        """Every recovered message in timestamp order, optionally only those of ``topics``."""
        with open(self.path, 'rb') as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            for row in self._order:
                topic = self._topics[row.topic_id]
                if topics is not None and topic.topic not in topics:
                    continue
                payload = self._payload(buf, row.cell)
                data = payload[row.data_offset:row.data_offset + row.data_size]
                yield BagMessage(topic.topic, topic.msgtype, row.timestamp, data)

    # ------------------------------------------------------------------ scanning
    def _scan(self) -> None:
        with open(self.path, 'rb') as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            for page in range(1, self.n_pages + 1):
                base = (page - 1) * self.page_size
                head = base + (100 if page == 1 else 0)
                if buf[head] != _TABLE_LEAF:
                    continue
                n_cells = _U16.unpack(buf[head + 3:head + 5])[0]
                if n_cells * 2 + 8 > self.page_size:
                    continue
                used = False
                for i in range(n_cells):
                    pointer = _U16.unpack(buf[head + 8 + 2 * i:head + 10 + 2 * i])[0]
                    try:
                        used |= self._cell(buf, base, base + pointer)
                    except (_Damaged, IndexError, UnicodeDecodeError, struct.error):
                        self.lost_records += 1
                if used:
                    self.bytes_read = max(self.bytes_read, base + self.page_size)

    def _cell(self, buf: mmap.mmap, base: int, pos: int) -> bool:
        if pos >= base + self.page_size:
            raise _Damaged()
        payload_size, pos = _varint(buf, pos)
        rowid, pos = _varint(buf, pos)
        local = self._local_size(payload_size)
        overflow = _U32.unpack(buf[pos + local:pos + local + 4])[0] if local < payload_size else 0
        if pos + local > base + self.page_size:
            raise _Damaged()
        cell = _Cell(rowid, pos, local, payload_size, overflow)
        header_size, p = _varint(buf, pos)
        if header_size > local:
            return False
        serials = []
        while p < pos + header_size:
            serial, p = _varint(buf, p)
            serials.append(serial)
        offsets = [pos + header_size]
        for serial in serials:
            offsets.append(offsets[-1] + _serial_size(serial))
        if offsets[-1] - pos != payload_size:
            raise _Damaged()
        ints = (1, 2, 3, 4, 5, 6, 8, 9)
        if len(serials) == 4 and serials[0] == 0 and serials[1] in ints and serials[2] in ints \
                and serials[3] >= 12 and serials[3] % 2 == 0:
            if not self._chain_ok(buf, cell):
                raise _Damaged()
            if rowid not in self._rows:
                self._rows[rowid] = _Row(self._int(buf, offsets[2], serials[2]), rowid,
                                         self._int(buf, offsets[1], serials[1]), cell, offsets[3] - pos,
                                         _serial_size(serials[3]))
            return True
        if len(serials) >= 4 and serials[0] == 0 and all(s >= 13 and s % 2 for s in serials[1:4]) \
                and offsets[4] - pos <= local:
            name, msgtype, fmt = (bytes(buf[offsets[k]:offsets[k + 1]]).decode('utf-8') for k in (1, 2, 3))
            if name.startswith('/') and '/' in msgtype and fmt == 'cdr':
                self._topics.setdefault(rowid, BagTopic(name, msgtype))
                return True
        return False

    def _local_size(self, payload_size: int) -> int:
        u = self.usable
        x = u - 35
        if payload_size <= x:
            return payload_size
        m = ((u - 12) * 32 // 255) - 23
        k = m + (payload_size - m) % (u - 4)
        return k if k <= x else m

    @staticmethod
    def _int(buf: mmap.mmap, pos: int, serial: int) -> int:
        if serial in (8, 9):
            return serial - 8
        size = _serial_size(serial)
        return int.from_bytes(buf[pos:pos + size], 'big', signed=True)

    def _chain_ok(self, buf: mmap.mmap, cell: _Cell) -> bool:
        """Whether every overflow page of the cell's payload lies in the file."""
        remaining, page = cell.payload_size - cell.local_size, cell.overflow
        while remaining > 0:
            if not 1 <= page <= self.n_pages:
                return False
            base = (page - 1) * self.page_size
            page = _U32.unpack(buf[base:base + 4])[0]
            remaining -= self.usable - 4
        return True

    def _payload(self, buf: mmap.mmap, cell: _Cell) -> bytes:
        parts = [bytes(buf[cell.local_start:cell.local_start + cell.local_size])]
        remaining = cell.payload_size - cell.local_size
        page = cell.overflow
        while remaining > 0:
            if not 1 <= page <= self.n_pages:
                raise BagError(f'{self.path}: a message runs into a missing page')
            base = (page - 1) * self.page_size
            page = _U32.unpack(buf[base:base + 4])[0]
            take = min(remaining, self.usable - 4)
            parts.append(bytes(buf[base + 4:base + 4 + take]))
            remaining -= take
        return b''.join(parts)
