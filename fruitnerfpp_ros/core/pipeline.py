"""The one path from a dataset to a fruit count: train -> export -> count (-> evaluate).

Used by the ``fruitnerfpp run`` CLI, the ROS node and the bag replay alike. Outputs go into the run directory:
``cloud.ply`` / ``cloud.npz`` (fruit points with their cluster ids), ``counts.json``, ``export.json`` (what each
export threshold kept) and, when the dataset has ``gt_fruits.json``, ``eval.json``.
"""

from __future__ import annotations

import json
import threading
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.config_io import config_to_mapping
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, load_predicted_centers
from fruitnerfpp_ros.core.evaluation.metrics import EvalMetrics, evaluate_counts
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.exporter import ExportReport, ExportResult, export_fruit_cloud
from fruitnerfpp_ros.core.export.npz_io import read_cloud, write_npz
from fruitnerfpp_ros.core.export.ply import write_ply
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.progress import PipelineStage, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.errors import ExportError

__all__ = ['PipelineResult', 'PipelineOutputs', 'run_pipeline', 'export_run', 'count_run', 'count_cloud',
           'evaluate_run', 'counts_to_json', 'write_counts', 'COUNTS_FORMAT_VERSION', 'CLOUD_PLY', 'CLOUD_NPZ',
           'COUNTS_JSON', 'EVAL_JSON', 'EXPORT_JSON', 'GT_JSON']

COUNTS_FORMAT_VERSION = 1
CLOUD_PLY, CLOUD_NPZ, COUNTS_JSON, EVAL_JSON, EXPORT_JSON = 'cloud.ply', 'cloud.npz', 'counts.json', 'eval.json', \
    'export.json'
GT_JSON = 'gt_fruits.json'


@dataclass(frozen=True)
class PipelineOutputs:
    """Files written by the pipeline (None: not written)."""

    cloud_ply: Path | None
    cloud_npz: Path | None
    counts_json: Path | None
    export_json: Path | None
    eval_json: Path | None


@dataclass(frozen=True)
class PipelineResult:
    """Everything one pipeline run produced.

    Attributes:
        run_dir: the run directory.
        cloud: the exported fruit point cloud (empty when training was stopped).
        export_report: what each export threshold kept (None when training was stopped).
        count: the clusters (ids from 1, 0 = noise) and fruits.
        eval: metrics against ``gt_fruits.json`` (None without ground truth).
        paths: the output files.
        stopped: the stop event ended the run early (training checkpointed, nothing exported).
        train_summary: what :func:`train` returned.
    """

    run_dir: Path
    cloud: FruitPointCloud
    export_report: ExportReport | None
    count: CountResult
    eval: EvalMetrics | None
    paths: PipelineOutputs
    stopped: bool = False
    train_summary: Any = None

    @property
    def labels(self) -> np.ndarray:
        """[N] cluster id per cloud point (0 = noise)."""
        return self.count.labels

    def table(self) -> str:
        """Human-readable summary: export, count and (when present) evaluation."""
        lines = []
        if self.export_report is not None:
            lines.append(self.export_report.explain())
        lines.append(f'fruits counted: {self.count.count} (cloud {len(self.cloud)} points, '
                     f'{int(np.count_nonzero(self.count.labels == 0))} noise)')
        if self.eval is not None:
            lines.append(self.eval.table())
        for name in ('cloud_ply', 'cloud_npz', 'counts_json', 'eval_json'):
            path = getattr(self.paths, name)
            if path is not None:
                lines.append(f'{name:<12} {path}')
        return '\n'.join(lines)


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return value


def _write_json(path: Path, data: Any) -> Path:
    return atomic_write_text(path, json.dumps(_json_safe(data), indent=1))


def counts_to_json(count: CountResult, config: ClusterConfig | None = None, *, source: str = '') -> dict[str, Any]:
    """The ``counts.json`` document: version, total, per fruit id / center / diameter / extent / n_points."""
    return {'version': COUNTS_FORMAT_VERSION, 'total': count.count, 'fruits': [f.to_json() for f in count.fruits],
            'source': source, 'cluster_config': config_to_mapping(config) if config is not None else None,
            'stats': count.stats}


def write_counts(path: str | Path, count: CountResult, config: ClusterConfig | None = None, *,
                 source: str = '') -> Path:
    """Write ``counts.json`` (atomic)."""
    return _write_json(Path(path), counts_to_json(count, config, source=source))


def _tqdm_progress(*, skip: PipelineStage = PipelineStage.TRAIN) -> Callable[[ProgressEvent], None]:
    """tqdm bars driven by progress events; phases of the stage ``skip`` are left out (the trainer draws its own
    per-step bars)."""
    from tqdm import tqdm

    bars: dict[str, Any] = {}

    def show(event: ProgressEvent) -> None:
        if event.phase.stage is skip:
            return
        bar = bars.get(event.phase)
        if bar is None:
            bar = bars[event.phase] = tqdm(total=event.total or None, desc=str(event.phase), leave=False)
        bar.n = event.step
        bar.set_postfix_str(event.message, refresh=False)
        bar.refresh()
        if event.total and event.step >= event.total:
            bar.close()
    return show


def export_run(run_dir: str | Path, export_config: ExportConfig | None = None, *, device: str = 'auto',
               out: str | Path | None = None, progress: ProgressCallback | None = None,
               stop_event: threading.Event | None = None, write_cloud: bool = True) -> ExportResult:
    """Export the fruit point cloud of a trained run to ``out`` (default ``RUN_DIR/cloud.ply``) plus ``.npz``.

    Also writes ``export.json`` (the export report) next to the cloud. ``write_cloud=False`` leaves the cloud
    files to the caller (:func:`run_pipeline` writes them once, with the cluster ids).

    Raises:
        CheckpointError: ``run_dir`` is not a trained run.
        ExportError: the export failed (see the message for thresholds).
    """
    from fruitnerfpp_ros.core.training import load_trained_scene

    run_dir = Path(run_dir)
    scene = load_trained_scene(run_dir, device=device)
    result = export_fruit_cloud(scene.field, scene.aabb, export_config or ExportConfig(),
                                surface_density=scene.surface_density, march_step=scene.march_step,
                                progress=progress, stop_event=stop_event)
    ply = Path(out) if out is not None else run_dir / CLOUD_PLY
    if write_cloud:
        write_ply(ply, result.cloud)
        write_npz(ply.with_suffix('.npz'), result.cloud)
    _write_json(ply.with_name(EXPORT_JSON), result.report.to_json())
    return result


def _cloud_source(source: Path) -> Path:
    if source.is_dir():
        for name in (CLOUD_NPZ, CLOUD_PLY):
            if (source / name).is_file():
                return source / name
        raise ExportError(f'{source}: no {CLOUD_NPZ} or {CLOUD_PLY}; run `fruitnerfpp export {source}` first')
    if not source.is_file():
        raise ExportError(f'{source}: no such run directory or point cloud file')
    return source


def count_run(source: str | Path, cluster_config: ClusterConfig | None = None, *, out: str | Path | None = None,
              executor: Executor | None = None,
              progress: ProgressCallback | None = None) -> tuple[CountResult, FruitPointCloud, Path]:
    """Count the fruits of a run directory's cloud (``cloud.npz`` / ``cloud.ply``) or of a cloud file.

    Writes ``counts.json`` (to ``out``, default next to the cloud) and rewrites the cloud's ``.ply`` and ``.npz``
    with the cluster ids, so cloud and counts carry the same ids. ``executor``: where the clustering partitions
    run (see :func:`~fruitnerfpp_ros.core.clustering.counter.count_fruits`; None: in this process).

    Returns:
        (the count, the cloud, the counts.json path).

    Raises:
        ExportError: no cloud found / unreadable cloud.
    """
    cloud_path = _cloud_source(Path(source))
    cloud, _ = read_cloud(cloud_path)
    counts_path = Path(out) if out is not None else cloud_path.with_name(COUNTS_JSON)
    count = count_cloud(cloud, cluster_config, cloud_path=cloud_path, counts_path=counts_path, executor=executor,
                        progress=progress)
    return count, cloud, counts_path


def count_cloud(cloud: FruitPointCloud, cluster_config: ClusterConfig | None, *, cloud_path: Path,
                counts_path: Path, executor: Executor | None = None,
                progress: ProgressCallback | None = None) -> CountResult:
    """Count ``cloud``, write ``counts_path`` and the cloud with its cluster ids as ``cloud_path`` .ply + .npz.

    ``executor``: where the clustering partitions run (see
    :func:`~fruitnerfpp_ros.core.clustering.counter.count_fruits`; None: in this process).
    """
    config = cluster_config or ClusterConfig()
    count = count_fruits(cloud, config, executor=executor, progress=progress)
    write_counts(counts_path, count, config, source=str(cloud_path))
    write_ply(cloud_path.with_suffix('.ply'), cloud, count.labels)
    write_npz(cloud_path.with_suffix('.npz'), cloud, count.labels)
    return count


def evaluate_run(counts_json: str | Path, gt_json: str | Path, *, out: str | Path | None = None,
                 tolerance: float = 1.0, exclude_unseen: bool = True,
                 centers: np.ndarray | None = None) -> EvalMetrics:
    """Score a ``counts.json`` against ``gt_fruits.json``; writes ``out`` (eval.json) when given.

    ``centers``: the count's fruit centres [K, 3] when the caller holds them (then ``counts_json`` is only named
    in eval.json, not read back).

    Raises:
        EvaluationError: missing / malformed files.
    """
    pred = load_predicted_centers(counts_json) if centers is None else np.asarray(centers, np.float64).reshape(-1, 3)
    gt = load_ground_truth(gt_json)
    metrics = evaluate_counts(pred, gt, tolerance=tolerance, exclude_unseen=exclude_unseen)
    if out is not None:
        _write_json(Path(out), {**metrics.to_json(), 'counts': str(counts_json), 'ground_truth': str(gt_json)})
    return metrics


def run_pipeline(dataset_dir: str | Path, run_dir: str | Path, *, train_config: Any = None,
                 export_config: ExportConfig | None = None, cluster_config: ClusterConfig | None = None,
                 device: str = 'auto', progress: ProgressCallback | None = None,
                 stop_event: threading.Event | None = None, show_progress: bool = False,
                 resume: bool = False, skip_training: bool = False,
                 executor: Executor | None = None) -> PipelineResult:
    """Train on ``dataset_dir``, export the fruit cloud, count the fruits and evaluate when GT exists.

    Args:
        dataset_dir: a transforms.json dataset (``gt_fruits.json`` beside it enables evaluation).
        run_dir: the run directory (created).
        train_config: a ``TrainConfig`` (default preset when None).
        export_config: export grid and thresholds.
        cluster_config: clustering settings.
        device: ``auto``, ``cpu`` or ``cuda[:N]``.
        progress: receives every phase's events (train:*, export, cluster).
        stop_event: when set, training checkpoints and the pipeline returns early (``stopped``).
        show_progress: tqdm bars (CLI).
        resume: continue training from the run's last checkpoint.
        skip_training: reuse an already trained ``run_dir`` (no training call).
        executor: where the clustering partitions run (e.g. a
            :func:`~fruitnerfpp_ros.core.clustering.workers.partition_pool`, owned by the caller); None: in this
            process.

    Returns:
        The :class:`PipelineResult` (cloud, count, labels, metrics, output paths).
    """
    from fruitnerfpp_ros.core.training import train

    dataset_dir, run_dir = Path(dataset_dir), Path(run_dir)
    if progress is None:
        progress = _tqdm_progress() if show_progress else ignore_progress
    summary = None
    if not skip_training:
        summary = train(dataset_dir, run_dir, train_config, device=device, resume=resume, progress=progress,
                        stop_event=stop_event, show_progress=show_progress)
        if getattr(summary, 'stopped', False):
            empty = FruitPointCloud.empty(0)
            return PipelineResult(run_dir, empty, None, CountResult(np.zeros(0, np.int32), [], {}), None,
                                  PipelineOutputs(None, None, None, None, None), stopped=True, train_summary=summary)
    exported = export_run(run_dir, export_config, device=device, progress=progress, stop_event=stop_event,
                          write_cloud=False)
    cloud, counts_path = exported.cloud, run_dir / COUNTS_JSON
    count = count_cloud(cloud, cluster_config, cloud_path=run_dir / CLOUD_PLY, counts_path=counts_path,
                        executor=executor, progress=progress)
    metrics = None
    eval_path = None
    gt_path = dataset_dir / GT_JSON
    if gt_path.is_file():
        eval_path = run_dir / EVAL_JSON
        metrics = evaluate_run(counts_path, gt_path, out=eval_path, centers=count.centers())
    paths = PipelineOutputs(run_dir / CLOUD_PLY, run_dir / CLOUD_NPZ, counts_path, run_dir / EXPORT_JSON, eval_path)
    return PipelineResult(run_dir, cloud, exported.report, count, metrics, paths,
                          stopped=exported.report.stopped, train_summary=summary)
