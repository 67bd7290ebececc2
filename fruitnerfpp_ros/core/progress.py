"""Progress events passed from long-running core work to whoever shows them (tqdm, ROS diagnostics).

Phases are a closed set (:class:`Phase`); each belongs to one :class:`PipelineStage`, so a consumer asks
``event.phase.stage`` instead of parsing strings.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Callable, NamedTuple

__all__ = ['PipelineStage', 'Phase', 'ProgressEvent', 'ProgressCallback', 'ignore_progress']


class PipelineStage(StrEnum):
    """The coarse steps of the work a progress event belongs to."""

    SYNTH = 'synth'
    SEGMENT = 'segment'
    TRAIN = 'train'
    EXPORT = 'export'
    COUNT = 'count'


class Phase(StrEnum):
    """What runs. The value is the name shown to users (tqdm bar, diagnostics)."""

    SYNTH_RENDER = 'synth:render'
    SEGMENT = 'segment'
    TRAIN_GEOMETRY = 'train:geometry'
    TRAIN_SEMANTIC = 'train:semantic'
    TRAIN_INSTANCE = 'train:instance'
    EXPORT_COARSE = 'export:coarse'
    EXPORT = 'export'
    CLUSTER = 'cluster'

    @property
    def stage(self) -> PipelineStage:
        """The pipeline stage this phase is part of."""
        return _STAGE_OF[self]

    @classmethod
    def training(cls, stage_name: str) -> 'Phase':
        """The phase of the training stage ``geometry``, ``semantic`` or ``instance``."""
        return cls(f'train:{stage_name}')


_STAGE_OF = {
    Phase.SYNTH_RENDER: PipelineStage.SYNTH, Phase.SEGMENT: PipelineStage.SEGMENT,
    Phase.TRAIN_GEOMETRY: PipelineStage.TRAIN, Phase.TRAIN_SEMANTIC: PipelineStage.TRAIN,
    Phase.TRAIN_INSTANCE: PipelineStage.TRAIN, Phase.EXPORT_COARSE: PipelineStage.EXPORT,
    Phase.EXPORT: PipelineStage.EXPORT, Phase.CLUSTER: PipelineStage.COUNT,
}


class ProgressEvent(NamedTuple):
    """One progress report.

    Attributes:
        phase: what runs.
        step: steps done in this phase.
        total: steps in this phase (0 when unknown).
        message: short human-readable status, e.g. ``loss 0.012 psnr 24.1``.
    """

    phase: Phase
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
