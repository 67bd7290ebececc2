"""Approximate-time synchronisation of several inputs by header stamp (message_filters is not on PyPI).

Each input has a bounded queue ordered by stamp. A set is emitted when every input has a message and the
queue heads lie within ``slop_ns`` of each other; a head that is older than ``newest head - slop_ns`` can never
be part of a set any more and is dropped (counted in :attr:`ApproximateTimeSynchronizer.unmatched`).
"""

from __future__ import annotations

import bisect
from typing import Any, Generic, NamedTuple, Sequence, TypeVar

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['SyncedSet', 'ApproximateTimeSynchronizer']

T = TypeVar('T')


class SyncedSet(NamedTuple):
    """One synchronised set: the stamp of the first input and one item per input, in input order."""

    stamp_ns: int
    items: tuple[Any, ...]


class ApproximateTimeSynchronizer(Generic[T]):
    """Matches items of ``names`` inputs whose stamps differ by at most ``slop_ns``.

    Args:
        names: one name per input (used in statistics and messages).
        slop_ns: largest stamp difference within a set, nanoseconds.
        queue_size: items kept per input; the oldest is dropped (and counted) when full.

    Raises:
        ConfigError: no inputs, a negative ``slop_ns`` or a ``queue_size`` below 1.
    """

    def __init__(self, names: Sequence[str], slop_ns: int, queue_size: int = 30) -> None:
        if not names:
            raise ConfigError('approximate-time synchroniser: needs at least one input')
        if slop_ns < 0 or queue_size < 1:
            raise ConfigError(f'approximate-time synchroniser: slop_ns must be >= 0 and queue_size >= 1, got '
                              f'slop_ns={slop_ns}, queue_size={queue_size}')
        self.names = tuple(names)
        self.slop_ns = int(slop_ns)
        self.queue_size = int(queue_size)
        self._queues: list[list[tuple[int, int, T]]] = [[] for _ in self.names]
        self._seq = 0
        self.matched = 0
        self.unmatched = dict.fromkeys(self.names, 0)
        self.overflow = dict.fromkeys(self.names, 0)

    def reset(self) -> None:
        """Forget every queued item (statistics are kept)."""
        self._queues = [[] for _ in self.names]

    def pending(self) -> dict[str, int]:
        """Items waiting per input."""
        return {name: len(q) for name, q in zip(self.names, self._queues)}

    def add(self, index: int, stamp_ns: int, item: T) -> list[SyncedSet]:
        """Queue ``item`` of input ``index`` and return every set that became complete (oldest first)."""
        queue = self._queues[index]
        self._seq += 1
        bisect.insort(queue, (int(stamp_ns), self._seq, item), key=lambda e: (e[0], e[1]))
        if len(queue) > self.queue_size:
            queue.pop(0)
            self.overflow[self.names[index]] += 1
        return self._match()

    def _match(self) -> list[SyncedSet]:
        out: list[SyncedSet] = []
        while all(self._queues):
            pivot = max(q[0][0] for q in self._queues)
            dropped = False
            for name, queue in zip(self.names, self._queues):
                # Of the items not newer than the pivot + slop, keep the one closest to the pivot.
                while len(queue) > 1 and abs(queue[1][0] - pivot) <= abs(queue[0][0] - pivot):
                    queue.pop(0)
                    self.unmatched[name] += 1
                    dropped = True
                if queue[0][0] < pivot - self.slop_ns:
                    queue.pop(0)
                    self.unmatched[name] += 1
                    dropped = True
            if dropped and not all(self._queues):
                break
            heads = [q[0][0] for q in self._queues]
            if max(heads) - min(heads) <= self.slop_ns:
                items = tuple(q.pop(0)[2] for q in self._queues)
                self.matched += 1
                out.append(SyncedSet(heads[0], items))
            elif not dropped:
                break
        return out
