"""An executor for tests that runs each submitted call at once in the calling thread and counts the calls."""

from __future__ import annotations

from concurrent.futures import Executor, Future
from typing import Any, Callable

__all__ = ['CountingExecutor']


class CountingExecutor(Executor):
    """Runs submitted calls at once in this thread and counts them."""

    def __init__(self) -> None:
        self.submitted = 0

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        self.submitted += 1
        future: Future = Future()
        future.set_result(fn(*args, **kwargs))
        return future
