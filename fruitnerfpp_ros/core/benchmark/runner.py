"""Run the scenes of an accuracy suite, one process per scene, and write ``accuracy.json`` / ``accuracy.md``.

Each scene runs in a fresh spawned process (a ``ProcessPoolExecutor`` of one worker, ``max_tasks_per_child=1``),
``jobs`` of them at once: its peak memory is its own, and a crash (segfault, out of memory) kills only its pool.
One shared pool would not do: when any worker dies, the executor is broken and fails every pending scene too.
"""

from __future__ import annotations

import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.benchmark.report import git_commit, render_markdown
from fruitnerfpp_ros.core.benchmark.result import SceneResult, SuiteResult
from fruitnerfpp_ros.core.benchmark.scene_run import BagRunner, SceneJob, run_scene
from fruitnerfpp_ros.core.benchmark.suites import SuiteScene
from fruitnerfpp_ros.errors import ConfigError

if TYPE_CHECKING:  # torch stays unimported until a scene runs
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig
    from fruitnerfpp_ros.core.training import TrainConfig

__all__ = ['SuiteOptions', 'run_suite', 'ACCURACY_JSON', 'ACCURACY_MD', 'MASK_SOURCES']

ACCURACY_JSON, ACCURACY_MD = 'accuracy.json', 'accuracy.md'
#: Where the instance masks of both counters come from.
MASK_SOURCES = ('gt', 'fallback', 'semantic', 'noisy')


@dataclass(frozen=True)
class SuiteOptions:
    """How every scene of a run is counted."""

    preset: str
    """Training preset name (recorded, and the bag replay's ``preset`` parameter)."""
    train_config: TrainConfig
    """The resolved TrainConfig (the preset plus the ``--config`` file's train section)."""
    export_config: ExportConfig
    """The ExportConfig."""
    cluster_config: ClusterConfig
    """The ClusterConfig."""
    masks: str = 'gt'
    """``gt``: the datasets' instance masks; ``fallback``: the built-in segmenter's (bag replay: ``mask_source``);
    ``semantic``: blobs of the datasets' fruit masks, as ``fruitnerfpp segment --method semantic`` makes them (bag
    replay: ``mask_source: semantic_topic``); ``noisy``: the datasets' and bags' instance masks degraded as a learned
    segmenter's (``scene_run.NOISY_MASKS``: missed fruit, false detections, boundaries a pixel off)."""
    device: str = 'auto'
    """Torch device: auto, cpu, cuda, cuda:N."""
    jobs: int = 1
    """Scenes run at once, each in its own process."""
    config_file: str = ''
    """The pipeline config file the configs came from ('' = none); bag replays read it as ``config_file``."""
    peer_beside_ours: bool | None = None
    """The tracking peer in a process of its own while ours trains; None: on a CUDA device (``SceneJob``)."""

    def __post_init__(self) -> None:
        if self.masks not in MASK_SOURCES:
            raise ConfigError(f'masks must be one of {", ".join(MASK_SOURCES)}, got {self.masks!r}')
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, int) or self.jobs < 1:
            raise ConfigError(f'jobs must be a positive integer, got {self.jobs!r}')


def _in_own_process(scene_fn: Callable[[SceneJob], SceneResult], job: SceneJob) -> SceneResult:
    """``scene_fn(job)`` in a fresh spawned process; a dead process becomes a failed scene."""
    started = time.perf_counter()
    context = multiprocessing.get_context('spawn')
    try:
        with ProcessPoolExecutor(max_workers=1, mp_context=context, max_tasks_per_child=1) as pool:
            return pool.submit(scene_fn, job).result()
    except Exception as err:  # noqa: BLE001 - BrokenProcessPool, unpicklable results...: the suite goes on
        return SceneResult(job.scene.name, job.scene.covers, job.scene.via_bag,
                           f'scene process: {type(err).__name__}: {err}',
                           times_s={'total': time.perf_counter() - started})


def _check(scenes: Sequence[SuiteScene], bag_runner: BagRunner | None) -> None:
    names = [s.name for s in scenes]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ConfigError(f'scene names must be unique; repeated: {", ".join(duplicates)}')
    if not scenes:
        raise ConfigError('no scene to run')
    if bag_runner is None and any(s.via_bag for s in scenes):
        raise ConfigError('bag scenes ' + ', '.join(s.name for s in scenes if s.via_bag) + ' need the bag replay '
                          '(run them through `fruitnerfpp bench accuracy`)')


def run_suite(suite: str, scenes: Sequence[SuiteScene], out_dir: str | Path, options: SuiteOptions, *,
              bag_runner: BagRunner | None = None, on_scene_done: Callable[[SceneResult], None] | None = None,
              command: str = '', scene_fn: Callable[[SceneJob], SceneResult] = run_scene) -> SuiteResult:
    """Run ``scenes`` (``options.jobs`` at once, each in its own process) and write the suite's reports.

    Args:
        suite: the suite's name (recorded).
        scenes: the scenes to run, in report order.
        out_dir: output directory: ``<scene>/`` per scene (replaced), ``accuracy.json``, ``accuracy.md``.
        options: preset, configs, masks, device, jobs.
        bag_runner: runs a bag replay (module-level function: it crosses into the scene processes); required
            when a scene is ``via_bag``.
        on_scene_done: called in this process with each scene's result as it finishes.
        command: the command line, for the reports.
        scene_fn: what runs in each scene process (tests substitute it).

    Returns:
        the :class:`SuiteResult`; failed scenes are in it with their error, never raised.

    Raises:
        ConfigError: duplicate scene names, no scene, or bag scenes without a ``bag_runner``.
    """
    _check(scenes, bag_runner)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    started_utc = datetime.now(timezone.utc).strftime('%Y-%m-%dT%H:%M:%SZ')
    started = time.perf_counter()
    jobs = [SceneJob(scene, out_dir, options.masks, options.device, options.preset, options.train_config,
                     options.export_config, options.cluster_config, options.config_file, bag_runner,
                     options.peer_beside_ours, cpu_share=max(1, min(options.jobs, len(scenes))))
            for scene in scenes]
    done: dict[str, SceneResult] = {}
    commit = git_commit()

    def report() -> SuiteResult:
        """The suite's result so far, written to the reports (an interrupted run keeps its finished scenes)."""
        result = SuiteResult(suite, tuple(done[s.name] for s in scenes if s.name in done), options.preset,
                             options.masks, options.device, options.jobs, options.config_file, started_utc,
                             time.perf_counter() - started, command, commit,
                             pending=tuple(s.name for s in scenes if s.name not in done))
        atomic_write_text(out_dir / ACCURACY_JSON, json.dumps(result.to_json(), indent=1))
        atomic_write_text(out_dir / ACCURACY_MD, render_markdown(result))
        return result

    with ThreadPoolExecutor(max_workers=min(options.jobs, len(jobs)), thread_name_prefix='scene') as threads:
        futures = {threads.submit(_in_own_process, scene_fn, job): job.scene.name for job in jobs}
        for future in as_completed(futures):
            done[futures[future]] = future.result()
            if len(done) < len(jobs):
                report()
            if on_scene_done is not None:
                on_scene_done(done[futures[future]])
    return report()
