"""Log levels and the ``log(level, message)`` function shared by the node, the frame assembler and bag replay."""

from __future__ import annotations

import time
from collections import Counter
from enum import StrEnum
from typing import Callable

__all__ = ['LogLevel', 'LogFunction', 'ThrottledLog']


class LogLevel(StrEnum):
    """Severity of a log line (the node maps it onto its rclpy logger; bag replay prints it)."""

    INFO = 'info'
    WARN = 'warn'
    ERROR = 'error'


#: ``log(level, message)``.
LogFunction = Callable[[LogLevel, str], None]


class ThrottledLog:
    """Logs the first message of each kind at once, then at most one per ``period_s`` with a suppressed count."""

    def __init__(self, log: LogFunction, period_s: float = 5.0) -> None:
        self._log = log
        self.period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()

    def __call__(self, level: LogLevel, kind: str, message: str) -> None:
        now = time.monotonic()
        if now - self._last.get(kind, -1e18) < self.period_s:
            self._suppressed[kind] += 1
            return
        suppressed = self._suppressed.pop(kind, 0)
        self._last[kind] = now
        self._log(level, message + (f' ({suppressed} similar messages suppressed)' if suppressed else ''))
