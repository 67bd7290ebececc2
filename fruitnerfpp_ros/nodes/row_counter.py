"""fruit_counter's row mode: segments trained in the background as the robot passes them, counts per tree.

The tick hands new keyframes to :class:`~fruitnerfpp_ros.core.orchard.live.LiveRow` and queues the segments it
finds passed; one worker thread trains them one after the other (a newer request of a segment, e.g. with the way
back's keyframes, replaces the one still waiting, in its place) with
:func:`~fruitnerfpp_ros.core.orchard.jobs.train_segment`, so the collection never waits. After the drive has
ended, each finished segment is asked again for the keyframes that came while it trained. After each segment the
row's count is joined again and published: ``~/tree_counts`` (report JSON, schema version 2), ``~/fruit_count``
(the row total so far), ``~/fruit_cloud``, ``~/fruit_centers``, ``~/fruit_markers`` and ``~/tree_markers``.
``RUN_DIR/row/`` holds the segments (``cell_+NNN_vV/``), the row's files (trees.csv, trees.geojson,
fruits.geojson, row_report.json) and ``events.jsonl`` (keyframes, segments queued / training / trained and
publications with their wall time: the latency from passing a tree to its count, bench/row_latency.py).
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeStore
from fruitnerfpp_ros.core.orchard.georef import WorldGeoref, fit_georef_to_drive, georef_from_datum, parse_datum
from fruitnerfpp_ros.core.orchard.gnss import GnssFix
from fruitnerfpp_ros.core.orchard.jobs import SegmentJob, SegmentOutcome, train_segment
from fruitnerfpp_ros.core.orchard.live import LiveRow, SegmentRequest
from fruitnerfpp_ros.core.orchard.segments import write_segment_dataset
from fruitnerfpp_ros.core.orchard.trees import read_planting_map
from fruitnerfpp_ros.core.data.transforms_format import TransformsFile
from fruitnerfpp_ros.errors import FruitNerfError
from fruitnerfpp_ros.nodes.log import LogFunction, LogLevel
from fruitnerfpp_ros.nodes.params import CounterSettings, pipeline_configs, use_node_cpu_threads
from fruitnerfpp_ros.nodes.row_params import RowSettings, orchard_config
from fruitnerfpp_ros.nodes.row_results import row_messages

__all__ = ['RowCounter', 'ROW_DIR']

ROW_DIR = 'row'


class RowCounter:
    """The row mode of one fruit_counter (see the module docstring).

    Args:
        run_dir: the node's output directory; store: its keyframe store.
        settings / row: the node's and the row's parameters.
        log: ``log(level, message)``; publish: receives the messages (private topic name -> rclpy message).
    """

    def __init__(self, run_dir: Path, store: KeyframeStore, settings: CounterSettings, row: RowSettings,
                 log: LogFunction, publish: Callable[[dict[str, Any]], None]) -> None:
        self.dir = run_dir / ROW_DIR
        self.dir.mkdir(parents=True, exist_ok=True)
        self.store, self.settings, self.row, self._log, self._publish = store, settings, row, log, publish
        self.configs = pipeline_configs(settings)
        self.orchard = orchard_config(row)
        self._given = None
        if self.orchard.geo.datum is not None:
            datum, yaw = parse_datum(list(self.orchard.geo.datum))
            self._given = georef_from_datum(datum, yaw)
        trees = read_planting_map(row.planting_map, self._given) if row.planting_map else None
        self.live = LiveRow(self.orchard, store.directory, trees=trees, retrain_on_return=row.retrain_on_return)
        self.fixes: list[GnssFix] = []
        self._lock = threading.Lock()               # LiveRow, the fixes and the queue
        self._wake = threading.Condition(self._lock)
        self._queue: OrderedDict[int, SegmentRequest] = OrderedDict()
        self._seen = 0
        self._last_keyframe = time.monotonic()
        self._flushed = False
        self._stop = threading.Event()
        self.last_report: str | None = None
        self.published = 0
        self._events = (self.dir / 'events.jsonl').open('a')
        self._worker = threading.Thread(target=self._work, name='fruit_counter_row', daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------ inputs
    def on_fix(self, fix: GnssFix) -> None:
        """A GNSS fix (NavSatFix converted)."""
        with self._lock:
            self.fixes.append(fix)

    def _event(self, **record: Any) -> None:
        self._events.write(json.dumps({'time_unix_s': round(time.time(), 3), **record}) + '\n')
        self._events.flush()

    def tick(self) -> None:
        """Take new keyframes, queue the segments passed (cheap: called from the node's tick)."""
        n = len(self.store)
        now = time.monotonic()
        if n > self._seen:
            frames = self.store.frames[self._seen:n]
            shared = self.store.intrinsics
            with self._lock:
                self.live.add(frames, [f.intrinsics or shared for f in frames])
                s = self.live.frame.along(np.array([f.T_world_camera[:2, 3] for f in frames])) \
                    if self.live.frame is not None else [None] * len(frames)
                for f, along in zip(frames, s):
                    self._event(event='keyframe', stamp_ns=f.stamp_ns,
                                s=None if along is None else round(float(along), 4),
                                xy=[round(float(v), 4) for v in f.T_world_camera[:2, 3]])
                self._enqueue(self.live.due())
            self._seen, self._last_keyframe, self._flushed = n, now, False
        elif not self._flushed and self._seen and now - self._last_keyframe > self.row.row_flush_after_s:
            self.flush()

    def flush(self) -> tuple[bool, str]:
        """Queue every segment with keyframes not trained on yet (end of the drive, ``~/train``)."""
        with self._lock:
            requests = self.live.flush()
            self._enqueue(requests)
            self._flushed = True
            pending = len(self._queue)
        return True, f'row: {len(requests)} more segment(s) queued, {pending} waiting'

    def _enqueue(self, requests: list[SegmentRequest]) -> None:
        for request in requests:  # under self._lock; a waiting request of the segment is replaced in its place
            self._queue[request.segment.index] = request
            self._event(event='queued', segment=request.segment.index, version=request.version,
                        keyframes=len(request.frames))
            self._log(LogLevel.INFO, f'row: segment {request.segment.index} (s {request.segment.core[0]:.2f}..'
                      f'{request.segment.core[1]:.2f} m, {len(request.frames)} keyframes, version '
                      f'{request.version}) queued')
        if requests:
            self._wake.notify()

    # ------------------------------------------------------------------ the worker
    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the worker (a running segment stops at its next checkpoint)."""
        self._stop.set()
        with self._lock:
            self._wake.notify()
        self._worker.join(timeout_s)
        self._events.close()

    def _work(self) -> None:
        use_node_cpu_threads(self.configs, self.settings.device)  # the node owns its process
        while not self._stop.is_set():
            with self._lock:
                while not self._queue and not self._stop.is_set():
                    self._wake.wait(1.0)
                if self._stop.is_set():
                    return
                _, request = self._queue.popitem(last=False)
                self.live.started(request.segment.index)
            self._event(event='training', segment=request.segment.index, version=request.version)
            outcome = self._train(request)
            self._event(event='trained', segment=request.segment.index, version=request.version, ok=outcome.ok,
                        seconds=round(outcome.seconds, 2))
            with self._lock:
                self.live.record(request, outcome)
                if self._flushed:  # the drive has ended: keyframes that came while this segment trained
                    self._enqueue(self.live.flush())
            if not outcome.ok:
                self._log(LogLevel.ERROR, f'row: segment {request.segment.index} failed: {outcome.error}')
            self._publish_row()

    def _cell_dir(self, index: int, version: int) -> Path:
        return self.dir / f'cell_{index:+04d}_v{version}'

    def _train(self, request: SegmentRequest) -> SegmentOutcome:
        seg = request.segment
        seg_dir = self._cell_dir(seg.index, request.version)
        started = time.perf_counter()
        try:
            shared = self.store.intrinsics
            transforms = TransformsFile(shared, list(request.frames))
            write_segment_dataset(transforms, self.store.directory, range(len(request.frames)), seg_dir / 'dataset',
                                  seg._replace(frames=tuple(range(len(request.frames)))).to_json())
            job = SegmentJob(seg.index, str(seg_dir / 'dataset'), str(seg_dir), self.configs.train,
                             self.configs.export, self.configs.cluster, self.settings.device,
                             tuple(float(v) for v in request.box.reshape(-1)))
            fruits = train_segment(job, stop_event=self._stop)
            return SegmentOutcome(seg.index, fruits, '', 1, time.perf_counter() - started)
        except Exception as err:  # noqa: BLE001 - a failed segment must not stop the row
            message = str(err) if isinstance(err, FruitNerfError) else f'{type(err).__name__}: {err}'
            return SegmentOutcome(seg.index, None, message, 1, time.perf_counter() - started)

    # ------------------------------------------------------------------ results
    def georef(self) -> WorldGeoref | None:
        """The given datum, else a fit to the fixes so far (None while they do not span enough)."""
        if self._given is not None:
            return self._given
        with self._lock:
            fixes, frames = list(self.fixes), list(self.live.frames)
        if len(fixes) < 3 or len(frames) < 2:
            return None
        try:
            return fit_georef_to_drive([f.stamp_ns or 0 for f in frames],
                                       np.stack([f.T_world_camera for f in frames]), fixes, self.orchard.geo)
        except FruitNerfError:
            return None

    def _publish_row(self) -> None:
        georef = self.georef()
        with self._lock:
            result = self.live.result(self.dir, georef, frame_id=self.settings.world_frame,
                                      run_id=f'{self.dir.parent.name}/{ROW_DIR}',
                                      extra={'keyframes': len(self.live.frames), 'preset': self.configs.preset,
                                             'state': self.live.counts()})
            dirs = {c.index: self._cell_dir(c.index, c.done_version) for c in self.live.cells.values() if c.done}
        if result is None:
            return
        messages = row_messages(result, self.settings.world_frame, dirs)
        self._publish(messages)
        self.last_report = messages['tree_counts'].data
        self.published += 1
        self._event(event='published', total=len(result.fruits),
                    trees=[{'id': t.id, 'count': t.count, 'complete': t.complete,
                            'position': [round(float(v), 4) for v in t.position[:2]], 's': round(t.along_m, 4)}
                           for t in result.tree_counts],
                    segments={str(k): v for k, v in self.live.counts().items()})
        self._log(LogLevel.INFO, f'row: {len(result.fruits)} fruits on {len(result.tree_counts)} tree(s) so far '
                  f'({self.live.counts()["done"]} segment(s) done); published on ~/tree_counts')

    def diagnostics(self) -> dict[str, Any]:
        """/diagnostics values: segments per state, the row total, trees, GNSS fixes."""
        with self._lock:
            counts = self.live.counts()
            waiting = len(self._queue)
            fixes = len(self.fixes)
        values = {f'row/segments_{k}': v for k, v in counts.items()}
        values['row/segments_queued'] = waiting
        values['row/fixes'] = fixes
        values['row/published'] = self.published
        values['row/frame_known'] = self.live.frame is not None
        return values
