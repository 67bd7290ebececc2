"""Cutting a row into overlapping segments, each its own transforms.json dataset (pointing at the same images).

Segment k owns the stretch ``core = [a, b]`` of the row (cores tile the row without gaps). It trains on the
keyframes that see ``views = [a - margin, b + margin]`` (at least ``min_overlap_m`` of it), at most ``max_views``
of them, so its memory and time depend on its length, not on the row's. Its fruits count within ``trust = [a - t,
b + t]`` (``t = trust_fraction * margin``); where the trusted stretches of two neighbours overlap, their fruits are
matched (:mod:`.merge`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import (CameraIntrinsics, FrameEntry, TransformsFile,
                                                         write_transforms)
from fruitnerfpp_ros.core.orchard.config import SegmentConfig
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['Segment', 'segment_edges', 'edges_between_trees', 'plan_segments', 'frames_for_range',
           'write_segment_dataset', 'fruit_span', 'fruit_extent', 'search_box']


class Segment(NamedTuple):
    """One segment of the row (row coordinates ``s``, metres).

    Attributes:
        index: 0.. along the row.
        core: (a, b) the stretch it owns.
        trust: the stretch its fruits count in.
        views: the stretch its keyframes see.
        frames: keyframe indices (into the row's transforms.json) it trains on.
    """

    index: int
    core: tuple[float, float]
    trust: tuple[float, float]
    views: tuple[float, float]
    frames: tuple[int, ...]

    @property
    def name(self) -> str:
        """``seg_NNN``."""
        return f'seg_{self.index:03d}'

    def to_json(self) -> dict[str, Any]:
        return {'index': self.index, 'name': self.name, 'core': [round(v, 4) for v in self.core],
                'trust': [round(v, 4) for v in self.trust], 'views': [round(v, 4) for v in self.views],
                'frames': list(self.frames)}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> 'Segment':
        return cls(int(data['index']), tuple(data['core']), tuple(data['trust']), tuple(data['views']),
                   tuple(int(i) for i in data['frames']))


def segment_edges(s_min: float, s_max: float, length_m: float) -> np.ndarray:
    """Cut points [K + 1] tiling [s_min, s_max] with K = ceil(extent / length) equal segments (the outer two
    reach to +-infinity)."""
    k = max(1, int(np.ceil((s_max - s_min) / length_m - 1e-6)))
    edges = s_min + (s_max - s_min) * np.arange(k + 1) / k
    edges[0], edges[-1] = -np.inf, np.inf
    return edges


def edges_between_trees(trunk_s: np.ndarray) -> np.ndarray:
    """Cut points [T + 1] of one segment per tree: midway between neighbouring trunks (outer ones +-infinity)."""
    s = np.sort(np.asarray(trunk_s, np.float64))
    return np.r_[-np.inf, 0.5 * (s[1:] + s[:-1]), np.inf]


def frames_for_range(intervals: np.ndarray, lo: float, hi: float, config: SegmentConfig) -> np.ndarray:
    """Indices of the keyframes whose viewed stretch ([N, 2] ``intervals``) overlaps [lo, hi] by at least
    ``min_overlap_m`` (or all of it), evenly thinned to ``max_views``."""
    overlap = np.minimum(intervals[:, 1], hi) - np.maximum(intervals[:, 0], lo)
    need = min(config.min_overlap_m, hi - lo)
    idx = np.flatnonzero(overlap >= need - 1e-9)
    if len(idx) > config.max_views:
        idx = idx[np.round(np.linspace(0, len(idx) - 1, config.max_views)).astype(int)]
    return idx


def plan_segments(intervals: np.ndarray, edges: np.ndarray, config: SegmentConfig) -> list[Segment]:
    """Segments between consecutive ``edges`` (+-infinity outermost: clamped to what the cameras see).

    Args:
        intervals: [N, 2] the stretch each keyframe sees (:func:`~.row_frame.viewed_intervals`).
        edges: [K + 1] increasing cut points.
        config: margins and view limits.
    """
    seen_lo, seen_hi = float(intervals[:, 0].min()), float(intervals[:, 1].max())
    t = config.trust_fraction * config.margin_m
    segments = []
    for k in range(len(edges) - 1):
        a, b = max(float(edges[k]), seen_lo), min(float(edges[k + 1]), seen_hi)
        if b <= a:
            continue
        lo, hi = a - config.margin_m, b + config.margin_m
        frames = frames_for_range(intervals, lo, hi, config)
        core = (float(edges[k]) if np.isfinite(edges[k]) else a, float(edges[k + 1]) if np.isfinite(edges[k + 1])
                else b)
        segments.append(Segment(len(segments), core, (core[0] - t, core[1] + t), (lo, hi),
                                tuple(int(i) for i in frames)))
    if not segments:
        raise OrchardError('no segment: the cameras see no stretch of the row')
    return segments


def write_segment_dataset(transforms: TransformsFile, source_dir: str | Path, frames: Sequence[int],
                          out_dir: str | Path, info: dict[str, Any] | None = None) -> Path:
    """Write ``out_dir/transforms.json`` holding ``frames`` of the row's dataset, paths pointing at its files
    (nothing is copied; no sparse point cloud, whose extent is the row's). ``info`` goes under ``segment``.

    Raises:
        OrchardError: no frames.
    """
    if len(frames) == 0:
        raise OrchardError(f'{out_dir}: a segment without keyframes')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    prefix = Path(os.path.relpath(Path(source_dir).resolve(), out_dir.resolve()))

    def moved(path: str | None) -> str | None:
        return None if path is None else str(prefix / path)

    entries = []
    for i in frames:
        f = transforms.frames[int(i)]
        entries.append(FrameEntry(str(prefix / f.file_path), f.T_world_camera, moved(f.instance_path),
                                  moved(f.semantic_path), f.intrinsics, f.stamp_ns, moved(f.mask_path),
                                  moved(f.depth_path)))
    extra = {k: v for k, v in transforms.extra.items() if k not in ('generator',)}
    extra['segment'] = json.loads(json.dumps(info or {}))
    return write_transforms(out_dir, TransformsFile(transforms.intrinsics, entries, None, extra,
                                                    transforms.depth_unit_scale_factor))


def fruit_span(mask: np.ndarray | None, T_world_camera: np.ndarray, K: CameraIntrinsics, frame: RowFrame,
               min_pixels: int = 20) -> tuple[float, float] | None:
    """(s_min, s_max) where a view's leftmost and rightmost fruit pixel columns, cast as horizontal rays, cross the
    row's centre line; None without fruit (fewer than ``min_pixels`` fruit pixels in the instance ``mask``)."""
    if mask is None or np.count_nonzero(mask) < min_pixels:
        return None
    cols = np.flatnonzero((mask > 0).any(axis=0))
    T = np.asarray(T_world_camera, np.float64)
    ends = []
    for u in (cols[0], cols[-1]):
        ray = T[:3, :3] @ np.array([(u + 0.5 - K.cx) / K.fl_x, 0.0, -1.0])
        d_l = ray[:2] @ frame.normal
        if abs(d_l) < 1e-9:
            continue
        t = -frame.across(T[None, :2, 3])[0] / d_l
        if t > 0:
            ends.append(float(frame.along((T[:2, 3] + t * ray[:2])[None])[0]))
    return (min(ends), max(ends)) if ends else None


def fruit_extent(transforms: TransformsFile, dataset_dir: str | Path, frame: RowFrame, *,
                 min_pixels: int = 20) -> tuple[float, float] | None:
    """The stretch of the row that holds fruit, from the instance masks before any training: the views'
    :func:`fruit_span` (1st / 99th percentile of their ends). None when no view has ``min_pixels`` fruit pixels.
    Reads one mask at a time."""
    ends: list[float] = []
    dataset_dir = Path(dataset_dir)
    for i, f in enumerate(transforms.frames):
        if f.instance_path is None:
            continue
        mask = cv2.imread(str(dataset_dir / f.instance_path), cv2.IMREAD_UNCHANGED)
        span = fruit_span(mask, f.T_world_camera, transforms.intrinsics_of(i), frame, min_pixels)
        if span is not None:
            ends += span
    if len(ends) < 2:
        return None
    return float(np.percentile(ends, 1.0)), float(np.percentile(ends, 99.0))


def search_box(frame: RowFrame, segment: Segment, T_world_camera: np.ndarray, config: SegmentConfig) -> np.ndarray:
    """[2, 3] world box where a segment's fruit can be: its viewed stretch along the row, the canopy across it
    (stopping short of the cameras), from below the lowest to above the highest camera. The pipeline's scale
    measurement searches it and cuts it to the fruit region (the cameras' frustum overlap, the default search box,
    is unbounded along a row whose cameras all look across it)."""
    T = np.asarray(T_world_camera, np.float64)[list(segment.frames)]
    standoff = float(np.median(np.abs(frame.across(T[:, :3, 3]))))
    half = min(config.crown_half_depth_m + 0.3, 0.8 * standoff)
    corners = frame.world_xy(np.array([segment.views[0], segment.views[0], segment.views[1], segment.views[1]]),
                             np.array([-half, half, -half, half]))
    z = T[:, 2, 3]
    return np.array([[*corners.min(axis=0), z.min() - config.box_below_camera_m],
                     [*corners.max(axis=0), z.max() + config.box_above_camera_m]])
