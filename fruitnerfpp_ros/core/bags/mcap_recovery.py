"""Read a damaged MCAP file record by record, up to its last whole message.

A recorder that loses power leaves an MCAP without its footer and summary (``File end magic is invalid`` for
readers that start at the end), often in the middle of a chunk. This reader walks the data section from the
start (the MCAP records are length-prefixed: opcode u8, length u64, content), keeps every schema and channel it
meets, and yields the messages of every readable chunk, including the whole messages at the start of a chunk cut
short (uncompressed, zstd or lz4: decompressed as far as the data goes). A chunk that fails its CRC or does not
decompress is skipped and counted; a record whose length runs past the end of the file ends the walk.

Format: https://mcap.dev/spec (little-endian; strings are u32 length + UTF-8).
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

from fruitnerfpp_ros.core.bags.records import BagMessage, BagTopic, FileRecovery
from fruitnerfpp_ros.errors import BagError

__all__ = ['McapRecovery', 'MCAP_MAGIC']

MCAP_MAGIC = b'\x89MCAP0\r\n'
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END, _FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0F, 0x02
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')
_MESSAGE_HEAD = struct.Struct('<HIQQ')


class _Truncated(Exception):
    """A record runs past the end of the available bytes."""


class _Cursor:
    """Reads little-endian fields from a bytes-like buffer; raises :class:`_Truncated` past its end."""

    def __init__(self, buf: bytes | memoryview, pos: int = 0, end: int | None = None) -> None:
        self.buf, self.pos, self.end = buf, pos, len(buf) if end is None else end

    def take(self, n: int) -> memoryview:
        if n < 0 or self.pos + n > self.end:
            raise _Truncated()
        view = memoryview(self.buf)[self.pos:self.pos + n]
        self.pos += n
        return view

    def u16(self) -> int:
        return _U16.unpack(self.take(2))[0]

    def u32(self) -> int:
        return _U32.unpack(self.take(4))[0]

    def u64(self) -> int:
        return _U64.unpack(self.take(8))[0]

    def string(self) -> str:
        return bytes(self.take(self.u32())).decode('utf-8', errors='replace')


class _Channel(NamedTuple):
    topic: str
    schema_id: int


def _decompress_partial(data: memoryview, compression: str, size: int) -> bytes:
    """As much of a (possibly cut) chunk's records as decompresses."""
    if compression == '':
        return bytes(data)
    if compression == 'zstd':
        try:
            from compression import zstd  # Python 3.14 / backports.zstd
        except ImportError:  # pragma: no cover - rosbags depends on backports.zstd
            from backports import zstd
        return zstd.ZstdDecompressor().decompress(bytes(data), max_length=size)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.LZ4FrameDecompressor().decompress(bytes(data), max_length=size)
    raise BagError(f'unsupported MCAP chunk compression {compression!r}')


class McapRecovery:
    """Messages of a damaged MCAP file (see the module docstring).

    Args:
        path: the ``.mcap`` file.
        reason: why the normal reader refused it (kept for the report).

    Raises:
        BagError: the file does not start with the MCAP magic or holds no readable channel.
    """

    def __init__(self, path: str | Path, reason: str = '') -> None:
        self.path = Path(path)
        self.reason = reason
        self._schemas: dict[int, str] = {}
        self._channels: dict[int, _Channel] = {}
        self.lost_records = 0
        self.bytes_read = len(MCAP_MAGIC)
        self.bytes_total = self.path.stat().st_size
        self.n_messages = 0
        with open(self.path, 'rb') as f:
            if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise BagError(f'{self.path}: not an MCAP file (no MCAP magic at its start)')
        for _ in self._walk(yield_messages=False):
            pass
        self.n_messages, self._counted = self._counted, 0
        if not self._channels:
            raise BagError(f'{self.path}: no readable channel in the damaged MCAP file (readable up to byte '
                           f'{self.bytes_read} of {self.bytes_total})')

    @property
    def topics(self) -> list[BagTopic]:
        """Every channel found, with its schema's type name."""
        return [BagTopic(c.topic, self._schemas.get(c.schema_id, '')) for c in self._channels.values()]

    def report(self) -> FileRecovery:
        """How much of the file was read back."""
        return FileRecovery(str(self.path), self.reason, self.n_messages, self.bytes_read, self.bytes_total,
                            self.lost_records)

    def messages(self, topics: set[str] | None = None) -> Iterator[BagMessage]:
        """Every recovered message (file order), optionally only those of ``topics``."""
        self._counted = 0
        for message in self._walk(yield_messages=True):
            if topics is None or message.topic in topics:
                yield message

    # ------------------------------------------------------------------ walking
    def _walk(self, *, yield_messages: bool) -> Iterator[BagMessage]:
        self._counted = 0
        lost = 0
        with open(self.path, 'rb') as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            cursor = _Cursor(buf, len(MCAP_MAGIC))
            while True:
                start = cursor.pos
                try:
                    opcode = cursor.take(1)[0]
                    length = cursor.u64()
                except _Truncated:
                    break
                content_start = cursor.pos
                available = min(length, cursor.end - content_start)
                if opcode == _CHUNK:
                    chunk_lost, whole = yield from self._chunk(buf, content_start, available, length,
                                                               yield_messages)
                    lost += chunk_lost
                    if not whole:
                        self.bytes_read = max(self.bytes_read, start)
                        break
                elif available < length:  # a record cut by the end of the file
                    break
                elif opcode in (_DATA_END, _FOOTER):
                    self.bytes_read = content_start + length
                    break
                else:
                    yield from self._record(opcode, _Cursor(buf, content_start, content_start + length),
                                            yield_messages)
                cursor.pos = content_start + length
                self.bytes_read = cursor.pos
            self.lost_records = lost

    def _chunk(self, buf: mmap.mmap, start: int, available: int, length: int,
               yield_messages: bool) -> Iterator[BagMessage]:
        """Yield a chunk's messages; returns (lost records, whether the chunk record was whole)."""
        cursor = _Cursor(buf, start, start + available)
        try:
            cursor.u64(), cursor.u64()
            size, crc = cursor.u64(), cursor.u32()
            compression = cursor.string()
            declared = cursor.u64()
        except _Truncated:
            return 0, False
        data_start = cursor.pos
        data = cursor.take(min(declared, cursor.end - cursor.pos))
        whole = available == length and len(data) == declared
        try:
            records = _decompress_partial(data, compression, size)
        except Exception:  # noqa: BLE001 - corrupt compressed data: this chunk is lost, the next may be fine
            return 1, whole
        if whole and crc and zlib.crc32(records) != crc:
            return 1, whole
        inner = _Cursor(records)
        while inner.pos < inner.end:
            try:
                opcode = inner.take(1)[0]
                rec_length = inner.u64()
                content = _Cursor(records, inner.pos, inner.pos + rec_length)
                if content.end > inner.end:
                    raise _Truncated()
            except _Truncated:
                return (1 if whole else 0), whole  # a whole chunk must parse to its end
            inner.pos = content.end
            if not compression:  # file offset of the end of the last whole record
                self.bytes_read = max(self.bytes_read, data_start + inner.pos)
            yield from self._record(opcode, content, yield_messages)
        return 0, whole

    def _record(self, opcode: int, cursor: _Cursor, yield_messages: bool) -> Iterator[BagMessage]:
        try:
            if opcode == _SCHEMA:
                schema_id = cursor.u16()
                self._schemas[schema_id] = cursor.string()
            elif opcode == _CHANNEL:
                channel_id, schema_id = cursor.u16(), cursor.u16()
                self._channels[channel_id] = _Channel(cursor.string(), schema_id)
            elif opcode == _MESSAGE:
                channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack(cursor.take(_MESSAGE_HEAD.size))
                channel = self._channels.get(channel_id)
                if channel is None:
                    return
                self._counted += 1
                if yield_messages:
                    data = bytes(cursor.take(cursor.end - cursor.pos))
                    yield BagMessage(channel.topic, self._schemas.get(channel.schema_id, ''), log_time, data)
        except _Truncated:
            return
