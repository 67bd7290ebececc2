"""Progress events passed from long-running core work to whoever shows them (tqdm, ROS diagnostics)."""

from __future__ import annotations

from typing import Callable, NamedTuple

__all__ = ['ProgressEvent', 'ProgressCallback', 'ignore_progress']


class ProgressEvent(NamedTuple):
    """One progress report.

    Attributes:
        phase: what runs, e.g. ``train:geometry``, ``train:semantic``, ``train:instance``, ``export``, ``cluster``.
        step: steps done in this phase.
        total: steps in this phase (0 when unknown).
        message: short human-readable status, e.g. ``loss 0.012 psnr 24.1``.
    """

    phase: str
    step: int
    total: int
    message: str = ''

    @property
    def fraction(self) -> float:
        """Completed fraction of the phase in [0, 1] (0 when the total is unknown)."""
        return min(1.0, self.step / self.total) if self.total else 0.0


ProgressCallback = Callable[[ProgressEvent], None]


def ignore_progress(event: ProgressEvent) -> None:
    """A progress callback that does nothing."""
