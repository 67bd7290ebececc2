"""One segment as a job (train -> export -> count with :func:`~fruitnerfpp_ros.core.pipeline.run_pipeline`) and the
two ways to run a row's jobs: in this process one after the other, or as Ray tasks.

A job is plain data (:class:`SegmentJob`, picklable) and :func:`train_segment` a module-level function, so a Ray
worker on any machine with the package installed can run it. Each attempt appends a line to
``SEGMENT_DIR/attempts.jsonl``; a finished segment writes ``SEGMENT_DIR/result.json`` and is not trained again
(a rerun of the row, or a retry after the result was written, reuses it). A failing job is retried once (Ray:
``max_retries=1, retry_exceptions=True``), then reported with its error; the other segments are still counted.

Nothing here starts Ray: :class:`RayRunner` takes the ``ray`` module the caller initialised.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import socket
import sys
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple, Protocol, Sequence

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.orchard.merge import SegmentFruits, cloud_support
from fruitnerfpp_ros.errors import FruitNerfError

if TYPE_CHECKING:
    from fruitnerfpp_ros.core.clustering.count_result import CountResult
    from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud

__all__ = ['SegmentJob', 'SegmentOutcome', 'JobFunction', 'train_segment', 'run_attempt', 'read_segment_result',
           'segment_fruits', 'support_voxel_m', 'write_segment_result',
           'SegmentRunner', 'InProcessRunner', 'RayRunner', 'RESULT_NAME', 'ATTEMPTS_NAME']

RESULT_NAME = 'result.json'
ATTEMPTS_NAME = 'attempts.jsonl'
#: a segment's support (where its fruit cloud has points, for the merge) is kept on voxels of this many fruit
#: diameters: a fifth, so that "no support within 0.35 diameters" is "no cloud point within 0.18-0.52 diameters"
SUPPORT_VOXEL_DIAMETERS = 0.2


class SegmentJob(NamedTuple):
    """Everything a worker needs to count one segment.

    Attributes:
        index: the segment's index.
        dataset_dir: its transforms.json dataset.
        segment_dir: where its run (``run/``), ``result.json`` and ``attempts.jsonl`` go.
        train_config / export_config / cluster_config: the core's configs (None: defaults).
        device: ``auto``, ``cpu``, ``cuda[:N]`` (in a Ray task with a GPU, ``auto`` is that GPU).
        search_box: [xmin, ymin, zmin, xmax, ymax, zmax] where the segment's fruit can be (m), or None: the
            pipeline's own box (:func:`~.segments.search_box`).
    """

    index: int
    dataset_dir: str
    segment_dir: str
    train_config: Any = None
    export_config: Any = None
    cluster_config: Any = None
    device: str = 'auto'
    search_box: tuple[float, ...] | None = None


class SegmentOutcome(NamedTuple):
    """What became of one job.

    Attributes:
        index: the segment; fruits: its count (None when it failed); error: why it failed ('' when it did not);
        attempts: how many times it ran; seconds: wall time of the last attempt; worker: host:pid of the last
        attempt; peak_rss_mib: peak resident memory of that worker process.
    """

    index: int
    fruits: SegmentFruits | None
    error: str = ''
    attempts: int = 1
    seconds: float = 0.0
    worker: str = ''
    peak_rss_mib: float = 0.0

    @property
    def ok(self) -> bool:
        return self.fruits is not None


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _attempts(segment_dir: Path) -> list[dict[str, Any]]:
    try:
        return [json.loads(line) for line in (segment_dir / ATTEMPTS_NAME).read_text().splitlines() if line.strip()]
    except (OSError, ValueError):
        return []


def _support_from_record(record: Any) -> np.ndarray | None:
    """The support points of ``result.json``'s ``support`` (flat x, y, z, ...); None when the result has none
    (written before it was kept) or an unreadable one: the fruits still count, nothing is judged by it."""
    try:
        return None if record is None else np.asarray(record, np.float64).reshape(-1, 3)
    except (ValueError, TypeError):
        return None


def read_segment_result(segment_dir: str | Path) -> tuple[SegmentFruits, dict[str, Any]] | None:
    """(fruits, the whole record) of a finished segment, None when it has no readable result."""
    try:
        data = json.loads((Path(segment_dir) / RESULT_NAME).read_text())
        fruits = data['fruits']
        return SegmentFruits(int(data['segment']), np.array([f['center'] for f in fruits], np.float64).reshape(-1, 3),
                             np.array([f['diameter'] for f in fruits], np.float64),
                             np.array([f['n_points'] for f in fruits], np.int64),
                             np.array([f['id'] for f in fruits], np.int64),
                             _support_from_record(data.get('support'))), data
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _boxed_config(job: SegmentJob) -> Any:
    """The job's TrainConfig with the scene box and fruit diameter measured in its search box: the pipeline's
    scale measurement (core/data/scene_scale.py) on the segment's box; the scene box is that box grown to hold the
    segment's cameras, then cut to the fruit region and the cameras as the pipeline cuts its own
    (core/training/scene_box.py: a box that stops between the tree and the cameras paints what lies beyond on its
    far faces, in front of the other side's views)."""
    from fruitnerfpp_ros.core.config_io import replace_nested
    from fruitnerfpp_ros.core.data.dataset import load_dataset
    from fruitnerfpp_ros.core.data.scene_scale import estimate_scene_scale
    from fruitnerfpp_ros.core.device import resolve_device
    from fruitnerfpp_ros.core.training import TrainConfig
    from fruitnerfpp_ros.core.training.scene_box import build_scene_box

    config = job.train_config or TrainConfig()
    if config.data.aabb is not None:
        return config
    box = np.asarray(job.search_box, np.float64).reshape(2, 3)
    dataset = load_dataset(job.dataset_dir, eval_every=config.data.eval_every)
    scale = estimate_scene_scale(dataset, box, config.scale, device=resolve_device(job.device))
    centres = dataset.T_world_camera[:, :3, 3].double().numpy()
    reach = config.data.box_margin_m or 0.0
    grown = box.copy()
    grown[0, :2] = np.minimum(box[0, :2], centres[:, :2].min(0) - reach)
    grown[1, :2] = np.maximum(box[1, :2], centres[:, :2].max(0) + reach)
    cut = build_scene_box(config, grown, scale, centres)
    del dataset
    return replace_nested(config, {'data': {'aabb': [float(v) for v in cut.reshape(-1)]},
                                   'scale': {'fruit_diameter_m': float(scale.fruit_diameter_m)}})


def train_segment(job: SegmentJob, stop_event: Any = None) -> SegmentFruits:
    """Train, export and count one segment (or reuse its finished result); ``stop_event`` (a threading.Event, live
    use) stops it early.

    Raises:
        FruitNerfError (or anything else the pipeline raises): the job failed; the runner retries / reports it.
    """
    from fruitnerfpp_ros.core.pipeline import run_pipeline

    segment_dir = Path(job.segment_dir)
    segment_dir.mkdir(parents=True, exist_ok=True)
    done = read_segment_result(segment_dir)
    if done is not None:
        return done[0]
    started = time.perf_counter()
    run_dir = segment_dir / 'run'
    resume = (run_dir / 'checkpoints' / 'latest.pt').is_file()
    if run_dir.exists() and not resume:  # an attempt that died before its first checkpoint: start over
        shutil.rmtree(run_dir)
    train_config = job.train_config
    if job.search_box is not None and not resume:
        train_config = _boxed_config(job)
    result = run_pipeline(job.dataset_dir, run_dir, train_config=train_config, export_config=job.export_config,
                          cluster_config=job.cluster_config, device=job.device, resume=resume,
                          stop_event=stop_event)
    if result.stopped:
        raise FruitNerfError(f'segment {job.index}: the pipeline stopped before the count')
    fruits = segment_fruits(job.index, result.count, result.cloud)
    write_segment_result(segment_dir, fruits, seconds=round(time.perf_counter() - started, 2), worker=_worker(),
                         peak_rss_mib=round(_peak_rss_mib(), 1))
    return fruits


def support_voxel_m(cloud: FruitPointCloud) -> float:
    """The voxel of a segment's support (:func:`~.merge.cloud_support`): :data:`SUPPORT_VOXEL_DIAMETERS` of the
    scene's fruit diameter, at least the cloud's own spacing (a cloud of unknown scale: 1 cm)."""
    diameter = cloud.fruit_diameter_m or 0.05
    return max(SUPPORT_VOXEL_DIAMETERS * diameter, cloud.spacing_m or 0.0, 1e-3)


def segment_fruits(index: int, count: CountResult, cloud: FruitPointCloud | None = None) -> SegmentFruits:
    """Segment ``index``'s fruits from its pipeline count (and, given its fruit cloud, where that cloud has
    points: ``support``)."""
    support = None if cloud is None else cloud_support(cloud.xyz, support_voxel_m(cloud))
    return SegmentFruits(index, count.centers(), np.array([f.diameter_m for f in count.fruits], np.float64),
                         np.array([f.n_points for f in count.fruits], np.int64),
                         np.array([f.id for f in count.fruits], np.int64), support)


def write_segment_result(segment_dir: str | Path, fruits: SegmentFruits, **info: Any) -> None:
    """Write ``SEGMENT_DIR/result.json`` (what :func:`read_segment_result` reads): ``info`` (seconds, worker,
    peak_rss_mib), the fruits and, when known, their support (a few thousand points, 0.1 mm)."""
    record = {'segment': int(fruits.segment), **info,
              'fruits': [{'id': int(i), 'center': [float(v) for v in c], 'diameter': float(d), 'n_points': int(n)}
                         for i, c, d, n in zip(fruits.ids, fruits.centers, fruits.diameters, fruits.n_points)]}
    text = json.dumps(record, indent=1)
    if fruits.support is not None:  # thousands of coordinates (0.1 mm) on one line, not one per line
        flat = np.round(np.asarray(fruits.support, np.float64), 4).reshape(-1).tolist()
        text = text.removesuffix('\n}') + f',\n "support": {json.dumps(flat)}\n}}'
    atomic_write_text(Path(segment_dir) / RESULT_NAME, text)


JobFunction = Callable[[SegmentJob], SegmentFruits]


def _worker() -> str:
    return f'{socket.gethostname()}:{os.getpid()}'


def run_attempt(job: SegmentJob, function: JobFunction = train_segment) -> SegmentFruits:
    """One attempt at a job: a line in ``SEGMENT_DIR/attempts.jsonl`` (time, worker), then ``function(job)``."""
    segment_dir = Path(job.segment_dir)
    segment_dir.mkdir(parents=True, exist_ok=True)
    with (segment_dir / ATTEMPTS_NAME).open('a') as log:
        log.write(json.dumps({'time_unix_s': time.time(), 'worker': _worker()}) + '\n')
    return function(job)


def _outcome(job: SegmentJob, fruits: SegmentFruits | None, error: str, seconds: float) -> SegmentOutcome:
    segment_dir = Path(job.segment_dir)
    attempts = _attempts(segment_dir)
    record = read_segment_result(segment_dir)
    peak = float(record[1].get('peak_rss_mib', 0.0)) if record else 0.0
    return SegmentOutcome(job.index, fruits, error, max(1, len(attempts)), seconds,
                          attempts[-1]['worker'] if attempts else '', peak)


def _describe(err: BaseException) -> str:
    return str(err) if isinstance(err, FruitNerfError) else f'{type(err).__name__}: {err}'


OnDone = Callable[[SegmentOutcome], None]


class SegmentRunner(Protocol):
    """Runs segment jobs; calls ``on_done`` as each finishes (in the caller's thread) and returns all outcomes in
    job order."""

    def run(self, jobs: Sequence[SegmentJob], on_done: OnDone | None = None) -> list[SegmentOutcome]:
        ...


class InProcessRunner:
    """Jobs one after the other in this process, each retried once when it fails.

    Args:
        retries: further attempts of a failing job.
        job: the job function (tests swap in a failing one).
    """

    def __init__(self, retries: int = 1, job: JobFunction = train_segment) -> None:
        self.retries, self._job = retries, job

    def run(self, jobs: Sequence[SegmentJob], on_done: OnDone | None = None) -> list[SegmentOutcome]:
        outcomes = []
        for job in jobs:
            started, fruits, error = time.perf_counter(), None, ''
            for _ in range(self.retries + 1):
                started = time.perf_counter()
                try:
                    fruits, error = run_attempt(job, self._job), ''
                    break
                except Exception as err:  # noqa: BLE001 - a failed segment must not stop the row
                    error = _describe(err)
                    if not isinstance(err, FruitNerfError):
                        traceback.print_exc(file=sys.stderr)
            outcome = _outcome(job, fruits, error, time.perf_counter() - started)
            outcomes.append(outcome)
            if on_done is not None:
                on_done(outcome)
        return outcomes


def _ray_entry(job: SegmentJob, function: JobFunction) -> SegmentFruits:
    return run_attempt(job, function)


class RayRunner:
    """Jobs as Ray tasks on an initialised Ray (``ray.init`` by the caller: a local instance or a cluster).

    Each task asks for ``num_gpus`` (1 when the cluster has GPUs: one GPU per job) or ``num_cpus``; Ray places
    them, retries a failing task ``retries`` times (``retry_exceptions``), runs each attempt in a fresh worker
    process (``max_calls=1``: its peak memory is the segment's), and this runner collects the results as they
    finish (``ray.wait``).

    Args:
        ray: the ``ray`` module, initialised.
        num_cpus: CPUs per task (its torch threads: Ray sets OMP_NUM_THREADS to it).
        num_gpus: GPUs per task (0: CPU workers).
        retries: further attempts of a failing task.
        job: the job function (pickled to the workers; tests swap in a stub).
    """

    def __init__(self, ray: Any, *, num_cpus: float = 1, num_gpus: float = 0, retries: int = 1,
                 job: JobFunction = train_segment) -> None:
        self.ray, self.num_cpus, self.num_gpus, self.retries, self._job = ray, num_cpus, num_gpus, retries, job

    def run(self, jobs: Sequence[SegmentJob], on_done: OnDone | None = None) -> list[SegmentOutcome]:
        ray = self.ray
        # max_calls=1: every attempt in a fresh worker process (its memory is the segment's alone, and freed)
        task = ray.remote(max_calls=1)(_ray_entry).options(num_cpus=self.num_cpus, num_gpus=self.num_gpus,
                                                           max_retries=self.retries, retry_exceptions=True)
        started = time.perf_counter()
        pending = {task.remote(job, self._job): job for job in jobs}
        outcomes: dict[int, SegmentOutcome] = {}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                job = pending.pop(ref)
                try:
                    fruits, error = ray.get(ref), ''
                except Exception as err:  # noqa: BLE001 - RayTaskError wraps the job's own error
                    cause = getattr(err, 'cause', None)
                    fruits, error = None, _describe(cause if isinstance(cause, BaseException) else err)
                record = read_segment_result(job.segment_dir)
                seconds = float(record[1]['seconds']) if record else time.perf_counter() - started
                outcome = _outcome(job, fruits, error, seconds)
                outcomes[job.index] = outcome
                if on_done is not None:
                    on_done(outcome)
        return [outcomes[job.index] for job in jobs]
