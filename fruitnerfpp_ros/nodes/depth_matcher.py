"""Optional depth for the synchronised frames: the depth image whose stamp matches a frame's (the mask's rule: within
``sync_slop_s``), without ever holding the frames up when the depth topic is silent.

A frame waits for its depth as long as the depth stream is alive and the frame is younger than
``pending_timeout_s`` (stamp time, like a frame waiting for camera_info or TF); it goes on **without depth** when
the depth stream has passed its stamp (that depth image was lost), when no depth arrived for ``pending_timeout_s``
(a silent or absent depth topic), when it grew too old, or at the end of a bag. Training uses depth where a
keyframe has it.
"""

from __future__ import annotations

import bisect
from typing import Any

from fruitnerfpp_ros.errors import ConversionError

__all__ = ['DepthMatcher', 'DepthWait']


class DepthWait(ConversionError):
    """The frame's depth image may still arrive (the frame waits)."""


class DepthMatcher:
    """Depth images by stamp, matched to frames.

    Args:
        slop_ns: largest stamp difference between a frame and its depth image, nanoseconds.
        timeout_ns: how long (stamp time) a frame waits for depth, and how long without depth makes the topic
            silent, nanoseconds.
        queue_size: depth images kept (the oldest is dropped when full).

    Attributes:
        matched: frames that got a depth image.
        missing: frames that went on without one.
    """

    def __init__(self, slop_ns: int, timeout_ns: int, queue_size: int) -> None:
        self.slop_ns, self.timeout_ns, self.queue_size = int(slop_ns), int(timeout_ns), int(queue_size)
        self._queue: list[tuple[int, int, Any]] = []
        self._seq = 0
        self._newest_depth_ns: int | None = None
        self._first_stamp_ns: int | None = None
        self.matched = 0
        self.missing = 0

    def reset(self) -> None:
        """Forget the queued depth images and the stream's history (a new time line)."""
        self._queue = []
        self._newest_depth_ns = self._first_stamp_ns = None

    def saw_stamp(self, stamp_ns: int) -> None:
        """Any input's stamp: the depth stream counts as silent from the first one on."""
        if self._first_stamp_ns is None:
            self._first_stamp_ns = int(stamp_ns)

    def add(self, stamp_ns: int, msg: Any) -> None:
        """Queue a depth image."""
        self.saw_stamp(stamp_ns)
        self._seq += 1
        bisect.insort(self._queue, (int(stamp_ns), self._seq, msg), key=lambda e: (e[0], e[1]))
        if len(self._queue) > self.queue_size:
            self._queue.pop(0)
        self._newest_depth_ns = max(int(stamp_ns), self._newest_depth_ns or int(stamp_ns))

    def silent_ns(self, newest_ns: int) -> int:
        """Stamp time since the last depth image (since the first input when none came), nanoseconds."""
        since = self._newest_depth_ns if self._newest_depth_ns is not None else self._first_stamp_ns
        return 0 if since is None else max(0, int(newest_ns) - since)

    def take(self, stamp_ns: int, newest_ns: int, *, final: bool = False) -> Any | None:
        """The depth image of the frame at ``stamp_ns`` (removed from the queue), or None when the frame goes on
        without one; ``newest_ns`` is the newest stamp of any input.

        Raises:
            DepthWait: the depth image may still arrive.
        """
        if self._queue:
            nearest = min(range(len(self._queue)), key=lambda i: abs(self._queue[i][0] - stamp_ns))
            if abs(self._queue[nearest][0] - stamp_ns) <= self.slop_ns:
                self.matched += 1
                return self._queue.pop(nearest)[2]
        passed = self._newest_depth_ns is not None and self._newest_depth_ns > stamp_ns + self.slop_ns
        too_old = newest_ns - stamp_ns > self.timeout_ns
        if final or passed or too_old or self.silent_ns(newest_ns) > self.timeout_ns:
            self.missing += 1
            return None
        raise DepthWait(f'no depth image within {self.slop_ns / 1e9:g} s of {stamp_ns} ns yet')
