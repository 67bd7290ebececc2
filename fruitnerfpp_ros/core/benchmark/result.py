"""Typed records of an accuracy suite run: one :class:`SceneResult` per scene, one :class:`SuiteResult` per run.

Both round-trip through JSON (``accuracy.json``): :meth:`SuiteResult.to_json` / :meth:`SuiteResult.from_json`.
Missing figures are NaN (floats) or None; a failed scene has ``error`` set and keeps what it measured before.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

__all__ = ['CounterScore', 'SceneResult', 'SuiteResult', 'ACCURACY_FORMAT_VERSION', 'TIME_KEYS']

ACCURACY_FORMAT_VERSION = 1
#: Keys of :attr:`SceneResult.times_s`, in report order: scene generation (and bag writing), fallback masks, bag
#: replay's keyframe collection, training's preparation (dataset read, pose alignment, scene measurement, model),
#: the three training stages, the held-out evaluations and checkpoint writes between them, export, clustering, our
#: whole count from the data (``ours``: the pipeline, or the bag replay with its keyframe collection; what a user
#: waits for), the tracking peer, the whole scene (scene generation and the peer included).
TIME_KEYS = ('synth', 'segment', 'keyframes', 'prepare', 'geometry', 'semantic', 'instance', 'evaluate',
             'checkpoint', 'export', 'count', 'ours', 'tracking', 'total')


@dataclass(frozen=True)
class CounterScore:
    """One counter's count on one scene, scored against the ground truth (Hungarian matching, one GT diameter).

    Attributes:
        count: fruits counted.
        tp: counted fruits matched to a ground-truth fruit.
        precision: tp / count.
        recall: matched seen fruits / fruits seen by a training view.
        f1: harmonic mean of precision and recall.
    """

    count: int
    tp: int
    precision: float
    recall: float
    f1: float

    @classmethod
    def from_metrics(cls, metrics: Any) -> 'CounterScore':
        """From :class:`~fruitnerfpp_ros.core.evaluation.metrics.EvalMetrics` (its Hungarian figures)."""
        return cls(int(metrics.count), int(metrics.hungarian.tp), float(metrics.precision), float(metrics.recall),
                   float(metrics.f1))


def _nan() -> float:
    return float('nan')


@dataclass(frozen=True)
class SceneResult:
    """Everything measured on one scene.

    Attributes:
        name: the scene's name.
        covers: the axes the scene covers (from its suite definition).
        via_bag: counted through a rosbag2 and the bag replay.
        error: ``''`` when every step ran, else ``Type: message`` of each failure (``; ``-joined).
        gt_count: ground-truth fruits on the tree.
        gt_seen: of them, fruits seen by at least one training view (the recall denominator).
        n_views: views the counters saw (dataset frames, or keyframes collected from the bag).
        ours: the pipeline's score (None when it failed).
        peer: the tracking counter's score on the same masks (None when it failed).
        psnr_db: held-out PSNR after the last training stage (dB).
        semantic_iou: held-out fruit IoU after the last stage.
        instance_acc: held-out instance assignment accuracy after the last stage.
        box_size_m: (x, y, z) extent of the scene box (m), or None.
        voxel_mm: export voxel edge (mm).
        diameter_m: fruit diameter the training measured (m).
        gt_diameter_m: median ground-truth fruit diameter (m).
        times_s: wall seconds per step (keys from :data:`TIME_KEYS`; absent: the step did not run).
        peak_rss_mb: peak resident memory of the process that ran the scene (MiB).
        cuda_max_allocated_mb: torch's CUDA peak allocation (MiB), or None off the GPU.
        picture: the count picture, relative to the suite's output directory, or None.
    """

    name: str
    covers: str = ''
    via_bag: bool = False
    error: str = ''
    gt_count: int = 0
    gt_seen: int = 0
    n_views: int = 0
    ours: CounterScore | None = None
    peer: CounterScore | None = None
    psnr_db: float = field(default_factory=_nan)
    semantic_iou: float = field(default_factory=_nan)
    instance_acc: float = field(default_factory=_nan)
    box_size_m: tuple[float, float, float] | None = None
    voxel_mm: float = field(default_factory=_nan)
    diameter_m: float = field(default_factory=_nan)
    gt_diameter_m: float = field(default_factory=_nan)
    times_s: dict[str, float] = field(default_factory=dict)
    peak_rss_mb: float = field(default_factory=_nan)
    cuda_max_allocated_mb: float | None = None
    picture: str | None = None

    @property
    def ok(self) -> bool:
        """Every step ran without an error."""
        return not self.error

    @property
    def f1_delta(self) -> float:
        """Our F1 minus the peer's (NaN when either is missing)."""
        if self.ours is None or self.peer is None:
            return float('nan')
        return self.ours.f1 - self.peer.f1

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping (NaN written as null)."""
        return _null_nans(asdict(self))

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> 'SceneResult':
        """Inverse of :meth:`to_json` (unknown keys ignored, null floats back to NaN)."""
        values = {f.name: data[f.name] for f in fields(cls) if f.name in data}
        for name in ('ours', 'peer'):
            if values.get(name) is not None:
                values[name] = CounterScore(**values[name])
        for f in fields(cls):
            if f.name in values and values[f.name] is None and f.type == 'float':
                values[f.name] = float('nan')
        if values.get('box_size_m') is not None:
            values['box_size_m'] = tuple(values['box_size_m'])
        return cls(**values)


def _null_nans(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _null_nans(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_null_nans(v) for v in value]
    return value


def _finite(values: list[float]) -> list[float]:
    return [v for v in values if math.isfinite(v)]


@dataclass(frozen=True)
class SuiteResult:
    """One run of a suite.

    Attributes:
        suite: the suite's name.
        scenes: per scene, in suite order.
        preset: training preset.
        masks: ``gt`` (the dataset's instance masks), ``fallback`` (the built-in segmenter's), ``semantic``
            (blobs of the dataset's fruit masks) or ``noisy`` (the dataset's, degraded as a segmenter's).
        device: torch device asked for.
        jobs: scenes run at once.
        config_file: the ``--config`` file, or ``''``.
        started_utc: start time, ISO 8601 UTC.
        total_s: wall seconds of the whole suite.
        command: the command line that ran it.
        git_commit: ``git rev-parse --short HEAD`` of the code (``+dirty`` when tracked files differ), or ``''``.
        pending: scenes not finished yet (a report written while the suite runs); empty once it has ended.
    """

    suite: str
    scenes: tuple[SceneResult, ...]
    preset: str
    masks: str
    device: str
    jobs: int
    config_file: str = ''
    started_utc: str = ''
    total_s: float = field(default_factory=_nan)
    command: str = ''
    git_commit: str = ''
    pending: tuple[str, ...] = ()

    def f1s(self, who: str) -> list[float]:
        """F1 of ``who`` (``ours`` or ``peer``) on every scene it scored."""
        scores = [getattr(s, who) for s in self.scenes]
        return _finite([s.f1 for s in scores if s is not None])

    def mean_f1(self, who: str) -> float:
        """Mean F1 of ``who`` over the scenes it scored (NaN when none)."""
        values = self.f1s(who)
        return sum(values) / len(values) if values else float('nan')

    def worst(self, who: str) -> tuple[float, str]:
        """(lowest F1, scene name) of ``who`` over the scenes it scored; (NaN, '') when none."""
        scored = [(getattr(s, who).f1, s.name) for s in self.scenes
                  if getattr(s, who) is not None and math.isfinite(getattr(s, who).f1)]
        return min(scored) if scored else (float('nan'), '')

    @property
    def failed(self) -> tuple[SceneResult, ...]:
        """Scenes with an error."""
        return tuple(s for s in self.scenes if not s.ok)

    def to_json(self) -> dict[str, Any]:
        """The ``accuracy.json`` document: the run's settings, per scene figures, and the summary."""
        data = _null_nans({k: v for k, v in asdict(self).items() if k != 'scenes'})
        worst_ours, worst_peer = self.worst('ours'), self.worst('peer')
        summary = {'mean_f1': self.mean_f1('ours'), 'worst_f1': worst_ours[0], 'worst_scene': worst_ours[1],
                   'peer_mean_f1': self.mean_f1('peer'), 'peer_worst_f1': worst_peer[0],
                   'peer_worst_scene': worst_peer[1], 'failed': [s.name for s in self.failed]}
        return {'version': ACCURACY_FORMAT_VERSION, **data, 'summary': _null_nans(summary),
                'scenes': [s.to_json() for s in self.scenes]}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> 'SuiteResult':
        """Inverse of :meth:`to_json` (the summary is recomputed)."""
        values = {f.name: data[f.name] for f in fields(cls) if f.name in data and f.name != 'scenes'}
        if values.get('total_s') is None:
            values['total_s'] = float('nan')
        values['pending'] = tuple(values.get('pending', ()))
        return cls(scenes=tuple(SceneResult.from_json(s) for s in data.get('scenes', [])), **values)
