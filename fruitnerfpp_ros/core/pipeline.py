"""The one path from a dataset to a fruit count: train -> export -> count (-> evaluate).

Used by the ``fruitnerfpp run`` CLI, the ROS node and the bag replay alike. Outputs go into the run directory:
``cloud.ply`` / ``cloud.npz`` (fruit points with their cluster ids), ``counts.json``, ``export.json`` (what each
export threshold kept) and, when the dataset has ``gt_fruits.json``, ``eval.json``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
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
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews
from fruitnerfpp_ros.core.config_io import config_to_mapping
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, load_predicted_centers
from fruitnerfpp_ros.core.evaluation.metrics import EvalMetrics, evaluate_counts
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.exporter import ExportReport, ExportResult, export_fruit_cloud
from fruitnerfpp_ros.core.export.surface import SurfaceExportReport
from fruitnerfpp_ros.core.export.npz_io import read_cloud, write_npz
from fruitnerfpp_ros.core.export.ply import write_ply
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.progress import PipelineStage, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.errors import CheckpointError, DatasetError, ExportError

__all__ = ['PipelineResult', 'PipelineOutputs', 'RunViews', 'load_run_views', 'run_pipeline',
           'export_run', 'count_run', 'count_cloud', 'count_with_views',
           'evaluate_run', 'training_views', 'counts_to_json', 'write_counts', 'COUNTS_FORMAT_VERSION', 'CLOUD_PLY',
           'CLOUD_NPZ', 'COUNTS_JSON', 'EVAL_JSON', 'EXPORT_JSON', 'GT_JSON']

COUNTS_FORMAT_VERSION = 1
CLOUD_PLY, CLOUD_NPZ, COUNTS_JSON, EVAL_JSON, EXPORT_JSON = 'cloud.ply', 'cloud.npz', 'counts.json', 'eval.json', \
    'export.json'
GT_JSON = 'gt_fruits.json'
_LOG = logging.getLogger(__name__)


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
    export_report: ExportReport | SurfaceExportReport | None
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
               stop_event: threading.Event | None = None, write_cloud: bool = True,
               dataset_dir: str | Path | None = None, dataset: Any = None, scene: Any = None) -> ExportResult:
    """Export the fruit point cloud of a trained run to ``out`` (default ``RUN_DIR/cloud.ply``) plus ``.npz``.

    Also writes ``export.json`` (the export report) next to the cloud. ``write_cloud=False`` leaves the cloud
    files to the caller (:func:`run_pipeline` writes them once, with the cluster ids). The surface export renders
    the training views of ``dataset_dir`` (default: the dataset the run was trained on), or of ``dataset`` when the
    caller has loaded it (a ``SceneDataset``). ``scene``: the run's ``TrainedScene`` when the caller has loaded it.

    Raises:
        CheckpointError: ``run_dir`` is not a trained run.
        DatasetError: the surface export cannot read the run's dataset.
        ExportError: the export failed (see the message for thresholds).
    """
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.export.surface import export_surface_cloud
    from fruitnerfpp_ros.core.training import load_trained_scene

    run_dir = Path(run_dir)
    scene = scene if scene is not None else load_trained_scene(run_dir, device=device)
    config = export_config or ExportConfig()
    diameter = scene.fruit_diameter_m
    if config.method == 'surface':
        if dataset is None:
            dataset = load_dataset(dataset_dir or scene.dataset_dir, eval_every=scene.config.data.eval_every)
        cloud, report = export_surface_cloud(scene.field, scene.occupancy, scene.render_settings, dataset,
                                             scene.poses(dataset.T_world_camera), diameter, config,
                                             progress=progress, stop_event=stop_event)
        result = ExportResult(cloud, report)
    else:
        result = export_fruit_cloud(scene.field, scene.aabb, config, surface_density=scene.surface_density,
                                    default_voxel_m=config.voxel_fruit_fraction * diameter, progress=progress,
                                    stop_event=stop_event)
    cloud = dataclasses.replace(result.cloud, fruit_diameter_m=diameter)
    if scene.config.instance.iterations == 0:  # an untrained instance head: its embeddings tell nothing apart
        cloud = cloud.one_embedding()
    result = ExportResult(cloud, result.report)
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


@dataclass(frozen=True)
class RunViews:
    """A trained run's training views as the count checks them: masks, intrinsics, the poses it trained with."""

    masks: MaskViews
    fruit_diameter_m: float
    aabb: np.ndarray
    units_per_metre: float = 1.0     # the poses' units in a metre (``SceneScale.units_per_metre``)


def load_run_views(run_dir: str | Path, dataset_dir: str | Path | None = None, *, device: str = 'cpu',
                   dataset: Any = None, scene: Any = None) -> RunViews:
    """The training views of the run in ``run_dir`` (its dataset, or ``dataset_dir``, or the ``SceneDataset`` the
    caller has loaded), with the poses it trained with (refined ones when pose refinement ran). ``scene``: the run's
    ``TrainedScene`` when the caller has loaded it.

    Raises:
        CheckpointError: ``run_dir`` is not a trained run.
        DatasetError: its dataset cannot be read.
    """
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.training import load_trained_scene

    scene = scene if scene is not None else load_trained_scene(run_dir, device=device)
    if dataset is None:
        dataset = load_dataset(dataset_dir or scene.dataset_dir, eval_every=scene.config.data.eval_every)
    poses = scene.poses(dataset.T_world_camera).detach().cpu().double().numpy()
    masks = MaskViews(dataset.instance_masks.numpy(), dataset.intrinsics.double().numpy(), poses,
                      dataset.train_indices.numpy(), dataset.mask_source)
    return RunViews(masks, scene.fruit_diameter_m, np.asarray(scene.aabb, np.float64), scene.scale.units_per_metre)


def count_run(source: str | Path, cluster_config: ClusterConfig | None = None, *, out: str | Path | None = None,
              executor: Executor | None = None, progress: ProgressCallback | None = None,
              dataset_dir: str | Path | None = None) -> tuple[CountResult, FruitPointCloud, Path]:
    """Count the fruits of a run directory's cloud (``cloud.npz`` / ``cloud.ply``) or of a cloud file.

    Writes ``counts.json`` (to ``out``, default next to the cloud) and rewrites the cloud's ``.ply`` and ``.npz``
    with the cluster ids, so cloud and counts carry the same ids. ``executor``: where the clustering partitions
    run (see :func:`~fruitnerfpp_ros.core.clustering.counter.count_fruits`; None: in this process). A trained run
    directory's count also holds the fruit its training views' masks agree on (``cluster_config.masks``), as
    :func:`run_pipeline`'s does; a cloud file alone has no views to check, nor a run whose dataset is gone or whose
    checkpoint this release cannot read (logged). ``dataset_dir``: the run's dataset where it was moved (default:
    the one its checkpoint names, or found beside the run).

    Returns:
        (the count, the cloud, the counts.json path).

    Raises:
        ExportError: no cloud found / unreadable cloud.
    """
    from fruitnerfpp_ros.core.training import RunDir

    cloud_path = _cloud_source(Path(source))
    cloud, _ = read_cloud(cloud_path)
    counts_path = Path(out) if out is not None else cloud_path.with_name(COUNTS_JSON)
    views = None
    if Path(source).is_dir() and (cluster_config or ClusterConfig()).masks.enabled and \
            RunDir(source).latest_checkpoint.is_file():
        try:
            views = load_run_views(source, dataset_dir)
        except (CheckpointError, DatasetError) as err:   # an older run, or its dataset moved: count the cloud
            _LOG.warning('%s: counting the cloud alone, without the masks\' fruit: %s', source, err)
    count = count_cloud(cloud, cluster_config, cloud_path=cloud_path, counts_path=counts_path, executor=executor,
                        progress=progress, views=views)
    return count, cloud, counts_path


def count_with_views(cloud: FruitPointCloud, config: ClusterConfig, views: RunViews | None, *,
                     executor: Executor | None = None, progress: ProgressCallback | None = None) -> CountResult:
    """The clusters of ``cloud``, checked against the run's training views' masks when ``views`` are given
    (``config.masks``: fruit they agree on added, pieces of one fruit joined). Writes nothing."""
    count = count_fruits(cloud, config, executor=executor, progress=progress)
    if views is None or not config.masks.enabled:
        return count
    from fruitnerfpp_ros.core.clustering.counter import centre_positions
    from fruitnerfpp_ros.core.clustering.mask_check import count_with_masks

    points = None
    if config.masks.split_merges:  # the cut needs the points and the same moved to their fruits' centres
        points = (np.asarray(cloud.xyz, np.float64), np.asarray(centre_positions(cloud, config), np.float64))
    masks = dataclasses.replace(  # its camera distance in metres, in the poses' units
        config.masks, min_camera_distance_m=config.masks.min_camera_distance_m * views.units_per_metre)
    return count_with_masks(count, views.masks, views.fruit_diameter_m, views.aabb, masks, points)


def count_cloud(cloud: FruitPointCloud, cluster_config: ClusterConfig | None, *, cloud_path: Path,
                counts_path: Path, executor: Executor | None = None,
                progress: ProgressCallback | None = None, views: RunViews | None = None) -> CountResult:
    """Count ``cloud``, write ``counts_path`` and the cloud with its cluster ids as ``cloud_path`` .ply + .npz.

    ``executor``: where the clustering partitions run (see
    :func:`~fruitnerfpp_ros.core.clustering.counter.count_fruits`; None: in this process). ``views``: the run's
    training views; with them the count is checked against their masks (``cluster_config.masks``: fruit they
    agree on added, pieces of one fruit joined).
    """
    config = cluster_config or ClusterConfig()
    count = count_with_views(cloud, config, views, executor=executor, progress=progress)
    write_counts(counts_path, count, config, source=str(cloud_path))
    write_ply(cloud_path.with_suffix('.ply'), cloud, count.labels)
    write_npz(cloud_path.with_suffix('.npz'), cloud, count.labels)
    return count


def training_views(dataset_dir: str | Path, eval_every: int, gt_json: str | Path) -> np.ndarray | None:
    """The ground truth's view indices of the frames a run of ``dataset_dir`` trained on (held-out frames left
    out), matched by stamp when the ground truth lists its views' stamps; None when they cannot be matched."""
    from fruitnerfpp_ros.core.data.dataset import split_indices
    from fruitnerfpp_ros.core.data.transforms_format import read_transforms

    frames = read_transforms(dataset_dir).frames
    train, _ = split_indices(len(frames), eval_every)
    stamps = [frames[i].stamp_ns for i in train]
    gt = load_ground_truth(gt_json)
    if gt.view_stamps_ns is None or any(s is None for s in stamps):
        return None
    return gt.views_at_stamps(stamps)


def evaluate_run(counts_json: str | Path, gt_json: str | Path, *, out: str | Path | None = None,
                 tolerance: float = 1.0, exclude_unseen: bool = True,
                 centers: np.ndarray | None = None, train_views: np.ndarray | None = None) -> EvalMetrics:
    """Score a ``counts.json`` against ``gt_fruits.json``; writes ``out`` (eval.json) when given.

    ``centers``: the count's fruit centres [K, 3] when the caller holds them (then ``counts_json`` is only named
    in eval.json, not read back). ``train_views``: the ground truth's views the run trained on (see
    :func:`training_views`); with ``exclude_unseen``, fruits none of them saw are left out of recall.

    Raises:
        EvaluationError: missing / malformed files.
    """
    pred = load_predicted_centers(counts_json) if centers is None else np.asarray(centers, np.float64).reshape(-1, 3)
    gt = load_ground_truth(gt_json, train_views=train_views)
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
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.training import load_trained_scene

    scene = load_trained_scene(run_dir, device=device)     # read once: the export and the masks' views share it
    eval_every = scene.config.data.eval_every
    masks = (cluster_config or ClusterConfig()).masks.enabled
    dataset = None   # read once: the surface export renders its views, the count checks its masks
    if masks or (export_config or ExportConfig()).method == 'surface':
        dataset = load_dataset(dataset_dir, eval_every=eval_every)
    exported = export_run(run_dir, export_config, device=device, progress=progress, stop_event=stop_event,
                          write_cloud=False, dataset=dataset, scene=scene)
    cloud, counts_path = exported.cloud, run_dir / COUNTS_JSON
    views = None
    if masks and not exported.report.stopped:
        views = load_run_views(run_dir, dataset=dataset, scene=scene)
    count = count_cloud(cloud, cluster_config, cloud_path=run_dir / CLOUD_PLY, counts_path=counts_path,
                        executor=executor, progress=progress, views=views)
    metrics = None
    eval_path = None
    gt_path = dataset_dir / GT_JSON
    if gt_path.is_file():
        eval_path = run_dir / EVAL_JSON
        metrics = evaluate_run(counts_path, gt_path, out=eval_path, centers=count.centers(),
                               train_views=training_views(dataset_dir, eval_every, gt_path))
    paths = PipelineOutputs(run_dir / CLOUD_PLY, run_dir / CLOUD_NPZ, counts_path, run_dir / EXPORT_JSON, eval_path)
    return PipelineResult(run_dir, cloud, exported.report, count, metrics, paths,
                          stopped=exported.report.stopped, train_summary=summary)
