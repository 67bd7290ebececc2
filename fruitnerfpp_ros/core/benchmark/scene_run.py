"""One scene of an accuracy suite, run in its own process: generate -> (fallback masks) -> count -> score.

:func:`run_scene` generates the scene under ``OUT/<scene>/data`` (plus ``OUT/<scene>/bag`` for a bag scene), runs
the pipeline into ``OUT/<scene>/run`` (a bag scene: the bag replay, through the caller's :data:`BagRunner`, since
the core cannot import the ROS layer), runs the tracking peer on the same instance masks, scores both against the
ground truth in one way, draws ``OUT/<scene>/count.png`` and writes ``OUT/<scene>/scene.json``. Whatever the
scene prints goes to ``OUT/<scene>/scene.log``. A failing step is recorded in the result, never raised: the
suite goes on.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import resource
import shutil
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.benchmark.result import CounterScore, SceneResult
from fruitnerfpp_ros.core.benchmark.suites import SuiteScene

if TYPE_CHECKING:  # torch stays unimported until a scene runs
    from concurrent.futures import Future

    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.evaluation.ground_truth import GroundTruth
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.pipeline import PipelineResult
    from fruitnerfpp_ros.core.synthetic import SynthConfig
    from fruitnerfpp_ros.core.training import TrainConfig

__all__ = ['BagReplayRequest', 'BagReplayOutcome', 'BagRunner', 'SceneJob', 'run_scene', 'scored_ground_truth',
           'SCENE_LOG', 'SCENE_JSON', 'PICTURE', 'NOISY_MASKS', 'scene_synth_config']

SCENE_LOG, SCENE_JSON, PICTURE, TRACK_COUNTS = 'scene.log', 'scene.json', 'count.png', 'track_counts.json'

#: ``--masks noisy``: the SynthConfig mask settings of a segmenter-like set of masks (``synthetic/mask_noise.py``):
#: 15 % of the fruit masks of a view missed, one false detection per ten fruit, boundaries moved by a pixel.
NOISY_MASKS = {'mask_missed': 0.15, 'mask_false': 0.1, 'mask_boundary_px': 1}


@dataclass(frozen=True)
class BagReplayRequest:
    """What a bag scene asks of the bag replay."""

    bag_path: Path
    """The scene's rosbag2."""
    run_dir: Path
    """The replay's run directory (keyframes land in ``run_dir/keyframes``)."""
    parameters: dict[str, Any]
    """fruit_counter / replay parameters (``config/fruit_counter.yaml`` names), as a robot user's params file."""


@dataclass(frozen=True)
class BagReplayOutcome:
    """What the bag replay produced."""

    keyframes_dir: Path
    """The transforms.json dataset of the collected keyframes."""
    pipeline: PipelineResult
    """The replay's :class:`~fruitnerfpp_ros.core.pipeline.PipelineResult`."""
    keyframes_s: float
    """Wall seconds from the replay's start to its first training event (keyframe collection)."""


#: Runs one bag replay (``fruitnerfpp replay``); a module-level function, as it crosses into the scene process.
BagRunner = Callable[[BagReplayRequest], BagReplayOutcome]


@dataclass(frozen=True)
class SceneJob:
    """Everything a scene process needs (picklable)."""

    scene: SuiteScene
    """The scene."""
    out_dir: Path
    """The suite's output directory (the scene writes into ``out_dir/<name>``, replacing what was there)."""
    masks: str
    """``gt``: the dataset's instance masks; ``fallback``: the built-in segmenter's; ``semantic``: blobs of the
    fruit masks; ``noisy``: the scene's masks degraded as a segmenter's (:data:`NOISY_MASKS`) (for both
    counters)."""
    device: str
    """Torch device for rendering and training."""
    preset: str
    """Training preset name (the bag replay's ``preset`` parameter)."""
    train_config: TrainConfig
    """The resolved TrainConfig (preset plus ``--config``'s train section)."""
    export_config: ExportConfig
    """The ExportConfig."""
    cluster_config: ClusterConfig
    """The ClusterConfig."""
    config_file: str = ''
    """The ``--config`` pipeline file, for the bag replay's ``config_file`` parameter ('' = none)."""
    bag_runner: BagRunner | None = None
    """Runs a bag replay; required by ``via_bag`` scenes."""
    peer_beside_ours: bool | None = None
    """Run the tracking peer in a process of its own while ours trains (dataset scenes); None: on a CUDA device, where
    ours leaves the CPU cores idle (on the CPU suites both would share the scene's one core and its times)."""
    cpu_share: int = 1
    """Scenes the suite runs at once: a ``cpu_threads`` of 0 (auto) gives each the cores divided among them."""


@dataclass
class _Record:
    """What the scene measured so far (mutable while the scene runs)."""

    errors: list[str] = field(default_factory=list)
    times: dict[str, float] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)

    def fail(self, step: str, err: BaseException) -> None:
        self.errors.append(f'{step}: {type(err).__name__}: {err}')
        traceback.print_exception(err)

    @contextlib.contextmanager
    def timed(self, key: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.times[key] = self.times.get(key, 0.0) + time.perf_counter() - start


@contextlib.contextmanager
def _output_to(path: Path) -> Iterator[None]:
    """Send this process's stdout and stderr (file descriptors 1 and 2, C libraries included) to ``path``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(path, 'a', buffering=1) as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def scored_ground_truth(gt_path: Path, counted_dir: Path, run_dir: Path, default_eval_every: int) -> GroundTruth:
    """A scene's ground truth as the suite scores it: fruits no training view of the run saw marked unseen.

    ``counted_dir``: the dataset the run trained on (a bag scene's keyframes); the held-out views are every
    ``data.eval_every``-th of the run's config.yaml, else ``default_eval_every``.
    """
    from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
    from fruitnerfpp_ros.core.evaluation.run_inputs import run_eval_every  # torch: in the scene's process only
    from fruitnerfpp_ros.core.pipeline import training_views

    eval_every = run_eval_every(run_dir, default_eval_every)
    return load_ground_truth(gt_path, train_views=training_views(counted_dir, eval_every, gt_path))


def _bag_parameters(job: SceneJob, config: SynthConfig) -> dict[str, Any]:
    """The replay parameters a robot user would write for this recording."""
    from fruitnerfpp_ros.core.synthetic import image_topic

    parameters = {'image_topic': image_topic(config.bag_image_format),
                  'compressed_image': config.bag_image_format == 'jpeg', 'world_frame': config.world_frame,
                  'pose_source': job.scene.bag.pose_source, 'preset': job.preset, 'device': job.device,
                  'config_file': job.config_file,
                  'mask_source': {'fallback': 'fallback', 'semantic': 'semantic_topic'}.get(job.masks, 'topic')}
    return {**parameters, **job.scene.bag.params}


def _count_ours(job: SceneJob, scene_dir: Path, data_dir: Path, record: _Record,
                config: SynthConfig) -> tuple[PipelineResult, Path]:
    """Our count (the pipeline, or the bag replay); returns (PipelineResult, the dataset it trained on)."""
    run_dir = scene_dir / 'run'
    if job.scene.via_bag:
        if job.bag_runner is None:
            raise RuntimeError('a via_bag scene needs a bag runner (run it through `fruitnerfpp bench`)')
        started = time.perf_counter()
        try:
            outcome = job.bag_runner(BagReplayRequest(scene_dir / 'bag', run_dir, _bag_parameters(job, config)))
        finally:
            record.times['replay'] = time.perf_counter() - started
        record.times['keyframes'] = outcome.keyframes_s
        return outcome.pipeline, outcome.keyframes_dir
    from fruitnerfpp_ros.core.clustering.workers import partition_pool
    from fruitnerfpp_ros.core.pipeline import run_pipeline

    with partition_pool(job.cluster_config.n_jobs) as pool:
        result = run_pipeline(data_dir, run_dir, train_config=job.train_config, export_config=job.export_config,
                              cluster_config=job.cluster_config, device=job.device, executor=pool)
    return result, data_dir


def _pipeline_figures(result: PipelineResult, record: _Record) -> None:
    """Held-out figures, scene box, voxel, measured diameter and step times of a PipelineResult."""
    summary = result.train_summary
    stages = tuple(getattr(summary, 'stages', ()) or ())
    for stage in stages:
        record.times[stage.name] = float(stage.wall_s)
    if summary is not None:
        record.times.update(prepare=float(summary.prepare_s), evaluate=float(summary.evaluate_s),
                            checkpoint=float(summary.checkpoint_s))
    if stages:
        last = stages[-1].eval
        record.values.update(psnr_db=float(last.psnr), semantic_iou=float(last.semantic_iou),
                             instance_acc=float(last.instance_acc))
    aabb = getattr(summary, 'aabb', None)
    if aabb is not None:
        box = np.asarray(aabb, np.float64).reshape(2, 3)
        record.values['box_size_m'] = tuple(float(v) for v in box[1] - box[0])
    diameter = getattr(getattr(summary, 'scale', None), 'fruit_diameter_m', None)
    if diameter is None:
        diameter = getattr(result.cloud, 'fruit_diameter_m', None)
    if diameter is not None:
        record.values['diameter_m'] = float(diameter)
    report = result.export_report
    if report is not None:
        record.values['voxel_mm'] = float(report.voxel_size_m) * 1e3
        record.times['export'] = float(report.time_s)
    if 'time_total_s' in result.count.stats:
        record.times['count'] = float(result.count.stats['time_total_s'])


def scene_synth_config(job: SceneJob) -> SynthConfig:
    """The SynthConfig the scene is generated with: the scene's, with a segmenter's mask errors for ``noisy``."""
    config = job.scene.synth_config(job.device)
    return dataclasses.replace(config, **NOISY_MASKS) if job.masks == 'noisy' else config


def _steps(job: SceneJob, scene_dir: Path, record: _Record) -> None:
    """Every step of the scene; raises only when nothing can be scored (no scene)."""
    from fruitnerfpp_ros.core.device import use_cpu_threads
    from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
    from fruitnerfpp_ros.core.synthetic import generate_orchard

    config = scene_synth_config(job)
    # this process is the scene's alone; its bag replay resolves an auto thread count from OMP_NUM_THREADS
    threads = use_cpu_threads(job.train_config.cpu_threads, job.device, share=job.cpu_share)
    os.environ['OMP_NUM_THREADS'] = str(threads)
    data_dir = scene_dir / 'data'
    with record.timed('synth'):
        synth = generate_orchard(config, data_dir, bag=scene_dir / 'bag' if job.scene.via_bag else None,
                                 bag_storage=job.scene.bag.storage)
    gt_all = load_ground_truth(synth.gt_path)
    record.values.update(gt_count=len(gt_all), gt_diameter_m=float(np.median(gt_all.diameters)))
    if job.masks == 'fallback' and not job.scene.via_bag:  # a bag scene's replay segments its own images
        from fruitnerfpp_ros.core.segmentation import SegmenterConfig, build_segmenter
        from fruitnerfpp_ros.core.segmentation.dataset_masks import segment_dataset
        with record.timed('segment'):
            segment_dataset(data_dir, build_segmenter(SegmenterConfig(method='fallback')), overwrite=True)
    if job.masks == 'semantic' and not job.scene.via_bag:  # a bag scene's replay splits its mask topic's blobs
        from fruitnerfpp_ros.core.segmentation.semantic_instances import instances_from_semantics
        with record.timed('segment'):
            instances_from_semantics(data_dir, overwrite=True)

    counted_dir = scene_dir / 'run' / 'keyframes' if job.scene.via_bag else data_dir
    with contextlib.ExitStack() as stack:
        peer = None
        if _peer_beside_ours(job):  # the GPU trains while a CPU process tracks (300 views of 512 px: ~2 min)
            from concurrent.futures import ProcessPoolExecutor
            from multiprocessing import get_context
            pool = stack.enter_context(ProcessPoolExecutor(max_workers=1, mp_context=get_context('spawn')))
            peer = pool.submit(_timed_tracking, data_dir)
        _score_scene(job, scene_dir, data_dir, counted_dir, record, config, synth.gt_path, peer)


def _peer_beside_ours(job: SceneJob) -> bool:
    """Whether the tracking peer runs beside ours (see ``SceneJob.peer_beside_ours``); a bag scene's peer counts the
    keyframes its replay collects, so it waits for them."""
    if job.scene.via_bag:
        return False
    if job.peer_beside_ours is not None:
        return job.peer_beside_ours
    from fruitnerfpp_ros.core.device import resolve_device
    return resolve_device(job.device).type == 'cuda'


def _timed_tracking(counted_dir: Path) -> tuple[Any, float]:
    """The tracking peer's count of a dataset and its wall time (s)."""
    from fruitnerfpp_ros.core.tracking import track_dataset
    started = time.perf_counter()
    tracked = track_dataset(counted_dir)
    return tracked, time.perf_counter() - started


def _score_scene(job: SceneJob, scene_dir: Path, data_dir: Path, counted_dir: Path, record: _Record,
                 config: SynthConfig, gt_path: Path, peer: Future[tuple[Any, float]] | None) -> None:
    """Ours, then the peer (``peer``: its future when it already runs beside ours), both scored."""
    from fruitnerfpp_ros.core.data.transforms_format import read_transforms
    from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
    pipeline = None
    try:
        with record.timed('ours'):
            pipeline, counted_dir = _count_ours(job, scene_dir, data_dir, record, config)
        _pipeline_figures(pipeline, record)
    except Exception as err:  # noqa: BLE001 - reported in the scene's row; the peer still runs
        record.fail('ours', err)
    record.values['n_views'] = len(read_transforms(counted_dir).frames)
    gt = scored_ground_truth(gt_path, counted_dir, scene_dir / 'run', job.train_config.data.eval_every)
    record.values['gt_seen'] = int(gt.seen.sum())
    if not record.values['gt_seen']:  # every count would score 1.0: the scene tells nothing, nor lifts a mean
        record.errors.append(f'scene: no training view sees any of the {len(gt.seen)} fruits (the cameras look '
                             'past the tree): not scored')
        return
    if pipeline is not None:
        metrics = evaluate_counts(pipeline.count.centers(), gt)
        record.values['ours'] = CounterScore.from_metrics(metrics)
        try:
            from fruitnerfpp_ros.core.evaluation.picture import write_count_picture
            write_count_picture(scene_dir / PICTURE, counted_dir, pipeline.count.centers(), gt, metrics)
            record.values['picture'] = f'{job.scene.name}/{PICTURE}'
        except Exception as err:  # noqa: BLE001
            record.fail('picture', err)
    try:
        from fruitnerfpp_ros.core.tracking import write_track_counts
        if peer is not None:
            tracked, record.times['tracking'] = peer.result()
        else:
            tracked, record.times['tracking'] = _timed_tracking(counted_dir)
        write_track_counts(scene_dir / TRACK_COUNTS, tracked, source=str(counted_dir))
        record.values['peer'] = CounterScore.from_metrics(evaluate_counts(tracked.centers(), gt))
    except Exception as err:  # noqa: BLE001
        record.fail('peer', err)


def _memory(record: _Record) -> None:
    record.values['peak_rss_mb'] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    torch = sys.modules.get('torch')
    if torch is not None and torch.cuda.is_available() and torch.cuda.is_initialized():
        record.values['cuda_max_allocated_mb'] = torch.cuda.max_memory_allocated() / 2.0 ** 20


def run_scene(job: SceneJob) -> SceneResult:
    """Run one scene end to end and return what it measured (failures recorded, not raised).

    Meant for a process of its own (peak memory is the process's): it sets torch's CPU threads (and
    ``OMP_NUM_THREADS`` for its bag replay: an auto count is the cores shared among ``job.cpu_share`` scenes),
    redirects the process's output to ``scene.log`` while it runs, and replaces ``out_dir/<scene>``.
    """
    started = time.perf_counter()
    scene_dir = Path(job.out_dir) / job.scene.name
    if scene_dir.exists():
        shutil.rmtree(scene_dir)
    scene_dir.mkdir(parents=True)
    record = _Record()
    with _output_to(scene_dir / SCENE_LOG):
        try:
            _steps(job, scene_dir, record)
        except Exception as err:  # noqa: BLE001 - a scene's failure is reported, the suite goes on
            record.fail('scene', err)
        record.times['total'] = time.perf_counter() - started
        _memory(record)
    result = SceneResult(job.scene.name, job.scene.covers, job.scene.via_bag, '; '.join(record.errors),
                         times_s=dict(record.times), **record.values)
    atomic_write_text(scene_dir / SCENE_JSON, json.dumps(result.to_json(), indent=1))
    return result
