"""Typed status records of the fruit counter: node state, frame collection counters and the diagnostics snapshot.

ROS-free (no rclpy): the node fills these records and :func:`~fruitnerfpp_ros.nodes.results.diagnostics_msg`
turns :meth:`NodeStatus.values` into ``/diagnostics`` key-value pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Mapping

from fruitnerfpp_ros.core.progress import Phase, PipelineStage

__all__ = ['NodeState', 'DiagnosticLevel', 'AssemblerStatus', 'RunStatus', 'NodeStatus']


class NodeState(StrEnum):
    """What the fruit counter is doing (the ``state`` diagnostics value)."""

    COLLECTING = 'collecting'
    TRAINING = 'training'
    EXPORTING = 'exporting'
    COUNTING = 'counting'
    DONE = 'done'
    ERROR = 'error'

    @classmethod
    def during(cls, stage: PipelineStage) -> 'NodeState':
        """The state while the pipeline runs ``stage`` (stages before training, if any, report as training)."""
        return _STATE_DURING.get(stage, cls.TRAINING)


_STATE_DURING = {PipelineStage.TRAIN: NodeState.TRAINING, PipelineStage.EXPORT: NodeState.EXPORTING,
                 PipelineStage.COUNT: NodeState.COUNTING}


class DiagnosticLevel(StrEnum):
    """Level of a ``diagnostic_msgs/DiagnosticStatus``."""

    OK = 'ok'
    WARN = 'warn'
    ERROR = 'error'


@dataclass(frozen=True)
class AssemblerStatus:
    """Counters of the frame assembler (keyframe collection), for diagnostics, reports and bag replay errors.

    Attributes:
        keyframes: keyframes in the store.
        received: messages received per role (``image``, ``mask``, ``pose``, ...).
        errors: messages or frames dropped per role or kind (``frame``, ``waiting``).
        decisions: what the keyframe store decided, per decision.
        rejected: frames the keyframe store rejected, per reason.
        sync_matched: image / mask / pose sets matched by stamp.
        sync_unmatched: messages dropped unmatched, per input.
        waiting: matched frames waiting for camera_info or TF.
        dropped_waiting: frames that waited too long and were dropped.
        write_errors: keyframes the store could not write (a full disk) and deferred index writes.
        time_jumps: stamps that jumped back in time (a bag restarted, a clock reset): queues and TF history cleared.
    """

    keyframes: int
    received: Mapping[str, int] = field(default_factory=dict)
    errors: Mapping[str, int] = field(default_factory=dict)
    decisions: Mapping[str, int] = field(default_factory=dict)
    rejected: Mapping[str, int] = field(default_factory=dict)
    sync_matched: int = 0
    sync_unmatched: Mapping[str, int] = field(default_factory=dict)
    waiting: int = 0
    dropped_waiting: int = 0
    write_errors: int = 0
    time_jumps: int = 0

    @property
    def total_errors(self) -> int:
        """Messages and frames dropped, all roles together."""
        return sum(self.errors.values())

    @property
    def total_sync_unmatched(self) -> int:
        """Messages dropped unmatched, all inputs together."""
        return sum(self.sync_unmatched.values())


@dataclass(frozen=True)
class RunStatus:
    """State of the node's training runs (replaced as a whole under the node's lock).

    Attributes:
        state: what the node is doing.
        phase: the pipeline phase running (None outside a run).
        progress: completed fraction of ``phase`` in [0, 1].
        last_error: why the last run failed ('' when it did not).
        last_count: fruits counted by the last finished run (None before the first).
        last_report: the last run's ``fruit_report`` JSON (None before the first).
    """

    state: NodeState = NodeState.COLLECTING
    phase: Phase | None = None
    progress: float = 0.0
    last_error: str = ''
    last_count: int | None = None
    last_report: str | None = None


@dataclass(frozen=True)
class NodeStatus:
    """One diagnostics snapshot of the fruit counter.

    Attributes:
        state: what the node is doing.
        phase: the pipeline phase running (None outside a run).
        progress: completed fraction of ``phase`` in [0, 1].
        last_error: why the last run failed ('' when it did not).
        fruit_count: fruits counted by the last finished run (None before the first).
        keyframes: keyframes collected.
        dropped_queue: input messages dropped from full queues.
        frame_errors: messages and frames the assembler dropped.
        sync_unmatched: messages dropped unmatched by stamp.
        run_dir: the node's output directory.
        rates_hz: input rate per topic over the last diagnostics period (Hz).
        silent_topics: required inputs silent for longer than ``silent_input_warning_s``.
        counters: messages received per topic (``received/<topic>``) and what was skipped and why
            (``skipped/<role or kind>``, ``rejected/<reason>``, ``dropped_queue/<topic>``, ``write_errors``,
            ``time_jumps``), each a count since the start.
        write_error: the last failed keyframe write when one failed since the last snapshot ('' otherwise).
    """

    state: NodeState
    phase: Phase | None
    progress: float
    last_error: str
    fruit_count: int | None
    keyframes: int
    dropped_queue: int
    frame_errors: int
    sync_unmatched: int
    run_dir: Path
    rates_hz: Mapping[str, float] = field(default_factory=dict)
    silent_topics: tuple[str, ...] = ()
    counters: Mapping[str, int] = field(default_factory=dict)
    write_error: str = ''

    @classmethod
    def from_parts(cls, run: RunStatus, frames: AssemblerStatus, *, dropped_queue: int, run_dir: Path,
                   rates_hz: Mapping[str, float], silent_topics: tuple[str, ...],
                   dropped_per_topic: Mapping[str, int] | None = None, write_error: str = '',
                   received_per_topic: Mapping[str, int] | None = None) -> 'NodeStatus':
        """The snapshot of a run status and the assembler's counters."""
        counters = {f'received/{topic}': n for topic, n in sorted((received_per_topic or {}).items())}
        counters.update({f'skipped/{kind}': n for kind, n in sorted(frames.errors.items())})
        counters.update({f'rejected/{reason}': n for reason, n in sorted(frames.rejected.items()) if n})
        counters.update({f'dropped_queue/{topic}': n for topic, n in sorted((dropped_per_topic or {}).items())})
        counters.update(write_errors=frames.write_errors, time_jumps=frames.time_jumps)
        return cls(run.state, run.phase, run.progress, run.last_error, run.last_count, frames.keyframes,
                   dropped_queue, frames.total_errors, frames.total_sync_unmatched, run_dir, dict(rates_hz),
                   tuple(silent_topics), counters, write_error)

    @property
    def level(self) -> DiagnosticLevel:
        """ERROR after a failed run or a failed keyframe write, WARN while a required input is silent, else OK."""
        if self.state is NodeState.ERROR or self.write_error:
            return DiagnosticLevel.ERROR
        return DiagnosticLevel.WARN if self.silent_topics else DiagnosticLevel.OK

    def message(self) -> str:
        """One line: state, phase and progress, silent inputs, a failed write, the last error."""
        return (f'{self.state}' + (f' {self.phase} {100 * self.progress:.0f}%' if self.phase else '')
                + (f'; silent inputs: {", ".join(self.silent_topics)}' if self.silent_topics else '')
                + (f'; {self.write_error}' if self.write_error else '')
                + (f'; {self.last_error}' if self.last_error else ''))

    def values(self) -> dict[str, str]:
        """The ``/diagnostics`` key-value pairs of this snapshot."""
        values = {'state': str(self.state), 'phase': str(self.phase or ''), 'progress': f'{self.progress:.3f}',
                  'keyframes': str(self.keyframes),
                  'fruit_count': '' if self.fruit_count is None else str(self.fruit_count),
                  'run_dir': str(self.run_dir), 'dropped_queue': str(self.dropped_queue),
                  'frame_errors': str(self.frame_errors), 'sync_unmatched': str(self.sync_unmatched)}
        values.update({f'rate_hz/{topic}': f'{hz:.1f}' for topic, hz in self.rates_hz.items()})
        values.update({key: str(n) for key, n in self.counters.items()})
        return values
