"""A row counted while it is driven: which segments the robot has passed, what each trains on, the running count.

:class:`LiveRow` follows the keyframes as they are stored. Once the robot has driven ``axis_after_m`` it fixes the
row frame (:func:`~.row_frame.estimate_row_frame` on the keyframes so far; the centre line ``standoff_m`` ahead of
the camera). The row is cut into cells: one per tree of a planting map, else ``length_m`` long from s = 0. A cell
is *passed* when the newest keyframe's view lies wholly beyond the cell's viewed stretch (core +- margin) in the
driving direction: no further keyframe of this pass will see it. A passed cell whose keyframes show fruit is due
(:meth:`LiveRow.due`); with ``retrain_on_return`` it is due again when the robot passes it on the way back (its
keyframes then show both sides; the new count replaces the first), also while its first request still waits for
training (the new request replaces it: a CPU that trains slower than the robot drives trains each cell once, on
both sides). :meth:`LiveRow.flush` makes every cell with keyframes not yet trained on due (the drive has ended).
Results come back through :meth:`LiveRow.record`, and :meth:`LiveRow.result` joins the finished cells into the
row's count (:func:`~.row_run.finish_row`).

ROS-free and single-threaded: the node calls it from its tick and its training worker under one lock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, FrameEntry
from fruitnerfpp_ros.core.orchard.config import OrchardConfig
from fruitnerfpp_ros.core.orchard.georef import WorldGeoref
from fruitnerfpp_ros.core.orchard.jobs import SegmentOutcome
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame, estimate_row_frame, viewed_intervals
from fruitnerfpp_ros.core.orchard.row_run import RowPlan, RowResult, finish_row
from fruitnerfpp_ros.core.orchard.segments import Segment, frames_for_range, fruit_span, search_box
from fruitnerfpp_ros.core.orchard.trees import TreeMap
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['SegmentRequest', 'LiveRow']


class SegmentRequest(NamedTuple):
    """A segment to train now.

    Attributes:
        segment: stretches and keyframe indices (into the keyframes given so far).
        version: 1 for the first training of this cell, 2... for later ones (more keyframes).
        frames: the keyframes it trains on.
        box: [2, 3] its search box (world, m).
    """

    segment: Segment
    version: int
    frames: list[FrameEntry]
    box: np.ndarray


@dataclass
class _Cell:
    index: int
    core: tuple[float, float]
    version: int = 0                       # latest requested version
    trained_on: frozenset[int] = frozenset()
    done: SegmentOutcome | None = None     # latest finished outcome
    done_version: int = 0
    done_segment: Segment | None = None
    failed: str = ''
    state: str = 'collecting'              # collecting, pending, training, done, failed
    history: list[int] = field(default_factory=list)


class LiveRow:
    """The live row (see the module docstring).

    Args:
        config: segments (length, margin, views), merge, trees, geo.
        keyframes_dir: where the keyframes' files are (instance masks are read once per keyframe).
        trees: a planting map's trees (one cell per tree), or None (cells of ``length_m``; trees found from fruit).
        axis_after_m: the row frame is fixed once the camera has moved this far.
        retrain_on_return: train a passed cell again when it is passed again with new keyframes.
        min_new_fraction: ... and at least this fraction of its keyframes are new.
    """

    def __init__(self, config: OrchardConfig, keyframes_dir: str | Path, *, trees: TreeMap | None = None,
                 axis_after_m: float = 2.0, retrain_on_return: bool = True, min_new_fraction: float = 0.3) -> None:
        self.config, self.keyframes_dir, self.trees = config, Path(keyframes_dir), trees
        self.axis_after_m, self.retrain_on_return, self.min_new_fraction = axis_after_m, retrain_on_return, \
            min_new_fraction
        self.frames: list[FrameEntry] = []
        self.intrinsics: list[CameraIntrinsics] = []
        self.frame: RowFrame | None = None
        self.intervals = np.zeros((0, 2))
        self.spans: list[tuple[float, float] | None] = []
        self.cells: dict[int, _Cell] = {}
        self._edges: np.ndarray | None = None

    # ------------------------------------------------------------------ keyframes
    def add(self, entries: Sequence[FrameEntry], intrinsics: Sequence[CameraIntrinsics]) -> None:
        """Take the newest keyframes (in the order they were stored)."""
        self.frames += list(entries)
        self.intrinsics += list(intrinsics)
        if self.frame is None:
            xy = np.array([f.T_world_camera[:2, 3] for f in self.frames])
            if len(xy) < 3 or np.linalg.norm(xy[-1] - xy[0]) < self.axis_after_m:
                return
            seg = self.config.segments
            self.frame = estimate_row_frame(np.stack([f.T_world_camera for f in self.frames]),
                                            standoff_m=seg.standoff_m or seg.default_standoff_m)
            self._edges = self._cell_edges()
            entries = self.frames
        self._measure(len(self.frames) - len(entries))

    def _cell_edges(self) -> np.ndarray | None:
        if self.trees is None or len(self.trees) == 0 or self.config.segments.length_m is not None:
            return None
        s = np.sort(self.frame.along(self.trees.positions))
        half = 0.5 * (np.diff(s).mean() if len(s) > 1 else self.config.segments.default_length_m)
        outer = half + self.config.trees.complete_margin_m + 0.05  # the end trees' crowns and then some
        return np.r_[s[0] - outer, 0.5 * (s[1:] + s[:-1]), s[-1] + outer]

    def _measure(self, first: int) -> None:
        """Viewed stretch, fruit stretch and cells of the keyframes from index ``first`` on."""
        assert self.frame is not None
        seg = self.config.segments
        new = self.frames[first:]
        K = self.intrinsics[first:]
        T = np.stack([f.T_world_camera for f in new])
        intervals = viewed_intervals(self.frame, T, np.array([k.fl_x for k in K]), np.array([k.w for k in K]),
                                     crown_half_depth_m=seg.crown_half_depth_m, max_range_m=seg.max_range_m)
        self.intervals = np.concatenate([self.intervals[:first], intervals])
        for f, k in zip(new, K):
            mask = cv2.imread(str(self.keyframes_dir / f.instance_path), cv2.IMREAD_UNCHANGED) \
                if f.instance_path else None
            span = fruit_span(mask, f.T_world_camera, k, self.frame)
            self.spans.append(span)
            if span is not None:
                for index in self._cells_between(*span):
                    self.cells.setdefault(index, _Cell(index, self._core(index)))

    def _core(self, index: int) -> tuple[float, float]:
        if self._edges is not None:
            return float(self._edges[index]), float(self._edges[index + 1])
        length = self.config.segments.length_m or self.config.segments.default_length_m
        return index * length, (index + 1) * length

    def _cells_between(self, lo: float, hi: float) -> list[int]:
        if self._edges is not None:
            first = max(0, int(np.searchsorted(self._edges, lo, side='right')) - 1)
            last = min(len(self._edges) - 2, int(np.searchsorted(self._edges, hi, side='right')) - 1)
            return list(range(first, last + 1)) if hi >= self._edges[0] and lo <= self._edges[-1] else []
        length = self.config.segments.length_m or self.config.segments.default_length_m
        return list(range(int(np.floor(lo / length)), int(np.floor(hi / length)) + 1))

    # ------------------------------------------------------------------ decisions
    @property
    def direction(self) -> int:
        """+1 / -1: the robot drives towards growing / falling s (0: not known yet)."""
        if self.frame is None or len(self.frames) < 2:
            return 0
        recent = np.array([f.T_world_camera[:2, 3] for f in self.frames[-5:]])
        ds = float(self.frame.along(recent[-1:])[0] - self.frame.along(recent[:1])[0])
        return 0 if abs(ds) < 1e-3 else (1 if ds > 0 else -1)

    def _request(self, cell: _Cell) -> SegmentRequest | None:
        seg = self.config.segments
        lo, hi = cell.core[0] - seg.margin_m, cell.core[1] + seg.margin_m
        frames = frames_for_range(self.intervals, lo, hi, seg)
        if len(frames) < seg.min_views:
            return None
        new = set(frames.tolist()) - cell.trained_on
        if cell.version and (not self.retrain_on_return or len(new) < self.min_new_fraction * len(frames)):
            return None
        t = seg.trust_fraction * seg.margin_m
        segment = Segment(cell.index, cell.core, (cell.core[0] - t, cell.core[1] + t), (lo, hi),
                          tuple(int(i) for i in frames))
        T = np.stack([f.T_world_camera for f in self.frames])
        cell.version += 1
        cell.trained_on = frozenset(frames.tolist())
        cell.state = 'pending'
        return SegmentRequest(segment, cell.version, [self.frames[i] for i in frames],
                              search_box(self.frame, segment, T, seg))

    def due(self) -> list[SegmentRequest]:
        """The cells the robot has passed since the last call, as requests."""
        direction = self.direction
        if not direction or not len(self.intervals):
            return []
        lo, hi = self.intervals[-1]
        margin = self.config.segments.margin_m
        out = []
        for cell in sorted(self.cells.values(), key=lambda c: c.index):
            passed = lo > cell.core[1] + margin if direction > 0 else hi < cell.core[0] - margin
            if passed and cell.state != 'training':  # a pending cell's newer request replaces the waiting one
                request = self._request(cell)
                if request is not None:
                    out.append(request)
        return out

    def flush(self) -> list[SegmentRequest]:
        """Every cell not training with keyframes it has not been asked for (the drive has ended); a pending
        cell's request then replaces the one waiting (same segment, a higher version)."""
        if self.frame is None:
            return []
        out = []
        for cell in sorted(self.cells.values(), key=lambda c: c.index):
            if cell.state == 'training':  # asked again by a flush after it ends (the node flushes after each)
                continue
            request = self._request(cell)
            if request is not None:
                out.append(request)
        return out

    def started(self, index: int) -> None:
        """A cell's training began."""
        self.cells[index].state = 'training'

    def record(self, request: SegmentRequest, outcome: SegmentOutcome) -> None:
        """A cell's training ended (a failed retraining keeps the earlier count)."""
        cell = self.cells[request.segment.index]
        if outcome.ok:
            cell.done, cell.done_segment, cell.failed, cell.state = outcome, request.segment, '', 'done'
            cell.done_version = request.version
        else:
            cell.failed = outcome.error
            cell.state = 'done' if cell.done is not None else 'failed'
        cell.history.append(request.version)

    # ------------------------------------------------------------------ results
    def counts(self) -> dict[str, int]:
        """Cells per state (collecting, pending, training, done, failed)."""
        out = dict.fromkeys(('collecting', 'pending', 'training', 'done', 'failed'), 0)
        for cell in self.cells.values():
            out[cell.state] += 1
        return out

    def result(self, out_dir: Path, georef: WorldGeoref | None, *, frame_id: str, run_id: str,
               extra: dict[str, Any] | None = None, write_files: bool = True) -> RowResult | None:
        """The row's count from the finished cells (None before any)."""
        done = [c for c in sorted(self.cells.values(), key=lambda c: c.index) if c.done is not None]
        if not done or self.frame is None:
            return None
        segments = [c.done_segment for c in done]
        outcomes = [c.done._replace(index=c.index) for c in done]
        stamps = [f.stamp_ns or 0 for c in done for f in (self.frames[i] for i in c.done_segment.frames)]
        spans = [s for s in self.spans if s is not None]
        extent = (min(s[0] for s in spans), max(s[1] for s in spans)) if spans else (0.0, 0.0)
        plan = RowPlan(self.frame, extent, segments, self.intervals, self.trees)
        try:
            return finish_row(plan, outcomes, out_dir, self.config, georef, frame_id=frame_id,
                              stamp_ns=max(stamps), run_id=run_id, extra=extra, write_files=write_files)
        except OrchardError:
            return None
