"""The fruit counter's training runs: numbered, one background thread at a time, resumed after a restart.

Run ``N`` of a node's output directory is ``RUN_DIR/train_NNN`` (the training run, cloud, counts,
``fruit_report.json``) trained on ``RUN_DIR/datasets/train_NNN`` (a frozen transforms.json of the keyframes).
A node killed during training (``kill -9``, power loss) finds the run without a report when it starts again and
continues it from its last checkpoint (:meth:`TrainingRuns.resume_interrupted`): on the CPU the count equals the
one an uninterrupted run gives. A run stopped by ``~/reset`` is marked abandoned (``abandoned.json``) and not
resumed. ROS-free apart from the publish callback the node passes in.
"""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple

from fruitnerfpp_ros.core.atomic_io import atomic_write_text, trim_torn_line
from fruitnerfpp_ros.core.data.keyframe_store import KeyframeSnapshot, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.errors import FruitNerfError
from fruitnerfpp_ros.nodes.log import LogFunction, LogLevel
from fruitnerfpp_ros.nodes.params import CounterSettings, pipeline_configs, use_node_cpu_threads
from fruitnerfpp_ros.nodes.results import result_messages, write_report
from fruitnerfpp_ros.nodes.status import NodeState, RunStatus

__all__ = ['RunRecord', 'TrainingRuns', 'find_runs', 'REPORT_NAME', 'ABANDONED_NAME']

REPORT_NAME = 'fruit_report.json'
ABANDONED_NAME = 'abandoned.json'


class RunRecord(NamedTuple):
    """A training run found in the output directory.

    Attributes:
        index: the run number N.
        run_dir: ``RUN_DIR/train_NNN``.
        dataset_dir: ``RUN_DIR/datasets/train_NNN`` (its frozen keyframes).
        finished: it wrote its report.
        abandoned: ``~/reset`` stopped it (never resumed).
    """

    index: int
    run_dir: Path
    dataset_dir: Path
    finished: bool
    abandoned: bool


def find_runs(run_dir: Path) -> list[RunRecord]:
    """Every training run of a node's output directory, by number (a frozen dataset counts as a run begun)."""
    names = {p.name for p in run_dir.glob('train_[0-9][0-9][0-9]') if p.is_dir()}
    names |= {p.name for p in (run_dir / 'datasets').glob('train_[0-9][0-9][0-9]') if p.is_dir()}
    runs = []
    for name in sorted(names):
        train_dir = run_dir / name
        runs.append(RunRecord(int(name[len('train_'):]), train_dir, run_dir / 'datasets' / name,
                              (train_dir / REPORT_NAME).is_file(), (train_dir / ABANDONED_NAME).is_file()))
    return runs


class TrainingRuns:
    """Starts, stops and resumes the node's training runs; holds their :class:`RunStatus`.

    Args:
        run_dir: the node's output directory.
        store: the keyframe store (snapshots are taken from it).
        log: ``log(level, message)``.
        publish: receives the result messages of a finished run (private topic name -> rclpy message).
    """

    def __init__(self, run_dir: Path, store: KeyframeStore, log: LogFunction,
                 publish: Callable[[dict[str, Any]], None]) -> None:
        self.run_dir, self.store, self._log, self._publish = run_dir, store, log, publish
        self._state_lock = threading.Lock()
        self._start_lock = threading.Lock()
        self._status = RunStatus()
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._active = 0
        self.index = max((r.index for r in find_runs(run_dir)), default=0)

    # ------------------------------------------------------------------ state
    @property
    def status(self) -> RunStatus:
        """State of the runs: state, phase, progress, last error, last count and report."""
        with self._state_lock:
            return self._status

    def update(self, **changes: Any) -> None:
        """Replace fields of the status."""
        with self._state_lock:
            self._status = dataclasses.replace(self._status, **changes)

    @property
    def running(self) -> bool:
        """A run's thread is alive (also while it stops)."""
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ starting
    def start(self, settings: CounterSettings) -> tuple[bool, str]:
        """Freeze the keyframes collected so far and train on them in the background; returns (started, message).

        The keyframes are frozen (a transforms.json snapshot, one small file) before answering, so the answer, the
        log and the run's report name the same keyframes however many arrive meanwhile.
        """
        with self._start_lock:  # ~/train and auto-train may ask at once
            if self.running:
                run = self.status
                what = 'stopping' if self._stop_event.is_set() else (run.phase or run.state)
                return False, f'training run {self._active} already running ({what})'
            n = len(self.store)
            if n < settings.min_keyframes:
                return False, f'only {n} keyframe(s) collected, min_keyframes is {settings.min_keyframes}'
            index = self.index + 1
            try:
                snapshot = self.store.snapshot(self.run_dir / 'datasets' / f'train_{index:03d}')
            except (FruitNerfError, OSError) as err:
                return False, f'cannot freeze the keyframes for training run {index}: {err}'
            self.index = index
            self._launch(index, snapshot, settings, resume=False)
        return True, (f'training run {index} started on {snapshot.n_keyframes} keyframes '
                      f'({self.run_dir / f"train_{index:03d}"})')

    def resume_interrupted(self, settings: CounterSettings) -> str | None:
        """Continue the newest run if a kill interrupted it (no report, not abandoned); returns what was done."""
        runs = find_runs(self.run_dir)
        if not runs or runs[-1].finished or runs[-1].abandoned:
            return None
        record = runs[-1]
        try:
            frames = read_transforms(record.dataset_dir).frames
        except FruitNerfError as err:
            self._abandon(record.index, f'its frozen keyframes are unreadable: {err}')
            return f'training run {record.index} cannot be resumed ({err}); it is abandoned'
        snapshot = KeyframeSnapshot(record.dataset_dir, len(frames), max(f.stamp_ns or 0 for f in frames))
        with self._start_lock:
            if self.running:
                return None
            self._launch(record.index, snapshot, settings, resume=True)
        return (f'training run {record.index} was interrupted: resuming it on its {len(frames)} keyframes from its '
                'last checkpoint')

    def last_finished_report(self) -> tuple[int, str] | None:
        """(count, report JSON) of the newest finished run, None when none finished."""
        for record in reversed(find_runs(self.run_dir)):
            if record.finished:
                try:
                    report = (record.run_dir / REPORT_NAME).read_text()
                    return int(json.loads(report)['total']), report
                except (OSError, ValueError, KeyError, TypeError):
                    continue
        return None

    def _launch(self, index: int, snapshot: KeyframeSnapshot, settings: CounterSettings, *, resume: bool) -> None:
        self._stop_event = threading.Event()
        self._active = index
        self.update(state=NodeState.TRAINING, phase=None, progress=0.0, last_error='')
        self._thread = threading.Thread(target=self._worker, args=(index, snapshot, settings, self._stop_event,
                                                                   resume),
                                        name=f'fruit_counter_train_{index}', daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ stopping
    def stop(self, timeout_s: float = 10.0) -> None:
        """Ask a running training to stop (it checkpoints) and wait up to ``timeout_s`` for it."""
        self._stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def abandon(self) -> int | None:
        """Stop the running training without waiting and mark it never to be resumed (``~/reset``); returns its
        number, None when none ran."""
        if not self.running:
            return None
        self._stop_event.set()
        self._abandon(self._active, 'stopped by ~/reset')
        return self._active

    def _abandon(self, index: int, reason: str) -> None:
        try:
            atomic_write_text(self.run_dir / f'train_{index:03d}' / ABANDONED_NAME,
                              json.dumps({'reason': reason, 'time_unix_s': time.time()}))
        except OSError as err:
            self._log(LogLevel.ERROR, f'training run {index}: cannot mark it abandoned: {err}')

    # ------------------------------------------------------------------ the thread
    def _on_progress(self, event: ProgressEvent, stop_event: threading.Event) -> None:
        if not stop_event.is_set():  # a run that is stopping no longer speaks for the node
            self.update(state=NodeState.during(event.phase.stage), phase=event.phase, progress=event.fraction)

    def _worker(self, index: int, snapshot: KeyframeSnapshot, settings: CounterSettings,
                stop_event: threading.Event, resume: bool) -> None:
        stamp_ns, n_keyframes = snapshot.latest_stamp_ns, snapshot.n_keyframes  # what this run trains on
        train_dir = self.run_dir / f'train_{index:03d}'
        try:
            from fruitnerfpp_ros.core.clustering.workers import partition_pool
            from fruitnerfpp_ros.core.pipeline import run_pipeline
            configs = pipeline_configs(settings)
            for note in configs.notes:
                self._log(LogLevel.INFO, note)
            use_node_cpu_threads(configs, settings.device)  # the node owns its process
            if resume:  # a kill or a full disk may have cut the last metrics line, which resuming reads again
                trim_torn_line(train_dir / 'metrics.jsonl')
            with partition_pool(configs.cluster.n_jobs) as pool:  # workers live for this run only
                result = run_pipeline(snapshot.dataset_dir, train_dir, train_config=configs.train,
                                      export_config=configs.export, cluster_config=configs.cluster,
                                      device=settings.device, stop_event=stop_event, executor=pool,
                                      progress=lambda event: self._on_progress(event, stop_event), resume=resume)
            if stop_event.is_set() or result.stopped:
                self._stopped(index, stop_event)
                return
            messages = result_messages(result.count, result.cloud, settings.world_frame, stamp_ns,
                                       f'{self.run_dir.name}/train_{index:03d}',
                                       {'keyframes': n_keyframes, 'preset': configs.preset})
            self._publish(messages)
            write_report(train_dir / REPORT_NAME, messages['fruit_report'].data)
            self.update(state=NodeState.DONE, phase=None, progress=1.0, last_count=int(result.count.count),
                        last_report=messages['fruit_report'].data)
            self._log(LogLevel.INFO, f'training run {index}: {result.count.count} fruits counted from {n_keyframes} '
                      'keyframes; published on ~/fruit_count and friends')
        except Exception as err:  # noqa: BLE001 - a failed run must not take the node down
            if stop_event.is_set():  # e.g. ~/reset moved the keyframes it was reading: it was stopping anyway
                self._stopped(index, stop_event)
                return
            message = str(err) if isinstance(err, FruitNerfError) else f'{type(err).__name__}: {err}'
            self.update(state=NodeState.ERROR, last_error=message)
            self._log(LogLevel.ERROR, f'training run {index} failed: {message}; the keyframes stay in '
                      f'{self.store.directory}')

    def _stopped(self, index: int, stop_event: threading.Event) -> None:
        if self._stop_event is stop_event:  # no newer run has started meanwhile
            self.update(state=NodeState.COLLECTING, phase=None)
        self._log(LogLevel.INFO, f'training run {index} stopped')
