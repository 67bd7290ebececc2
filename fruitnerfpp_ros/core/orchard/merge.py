"""One row count from the segments' counts: every fruit once, also where two segments overlap.

Each segment's fruits count within its trusted stretch (:class:`~.segments.Segment`). Two neighbours' trusted
stretches overlap around their cut; a fruit there (or within the match reach of the overlap's ends) is usually
counted by both. Such pairs are matched one-to-one by 3D distance (Hungarian; at most ``match_diameters`` fruit
diameters apart) and kept once: the copy of the segment whose own stretch holds the pair (it saw the fruit from
more central views). A fruit only one of them counted stays, unless the other segment's fruit cloud holds no
point near it (``SegmentFruits.support``): that segment's views saw the place and its field put no fruit surface
there, so the fruit is one segment's ghost. A piece of a paired fruit (a segment that split the fruit in two) does
not stay. Instance embeddings are not used for matching: each segment trains its own instance field, so the
embeddings of two segments live in unrelated spaces.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.orchard.config import MergeConfig
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame
from fruitnerfpp_ros.core.orchard.segments import Segment

__all__ = ['SegmentFruits', 'RowFruits', 'merge_segments', 'cloud_support']


class SegmentFruits(NamedTuple):
    """The fruits one segment counted (world frame).

    Attributes:
        segment: the segment's index.
        centers: [K, 3] metres; diameters: [K] metres; n_points: [K] cloud points of each fruit.
        ids: [K] the fruit ids of the segment's own count (counts.json, its cloud's instance ids).
        support: [V, 3] where the segment's fruit cloud has points (:func:`cloud_support`), or None: not known
            (a result written before it was kept, a test's stub); then no fruit is judged by it.
    """

    segment: int
    centers: np.ndarray
    diameters: np.ndarray
    n_points: np.ndarray
    ids: np.ndarray
    support: np.ndarray | None = None

    @classmethod
    def empty(cls, segment: int) -> 'SegmentFruits':
        return cls(segment, np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64))


def cloud_support(xyz: np.ndarray, voxel_m: float) -> np.ndarray:
    """[V, 3] the centres of the ``voxel_m`` voxels that hold points of a fruit cloud [N, 3]: the cloud thinned to
    what the merge asks of it (is there fruit surface near a place?), a few thousand points per segment."""
    keys = np.unique(np.floor(np.asarray(xyz, np.float64).reshape(-1, 3) / voxel_m).astype(np.int64), axis=0)
    return (keys + 0.5) * voxel_m


class RowFruits(NamedTuple):
    """The row's fruits, each once, ordered along the row (row fruit id = position + 1).

    Attributes:
        centers: [M, 3]; diameters: [M]; n_points: [M]; along: [M] s along the row (m).
        segments: [M] the segment whose copy was kept; local_ids: [M] its id in that segment's count.
        matched: [M] bool: two neighbouring segments counted it (the pair became this one fruit).
        dropped_off_row: fruits left out for lying further than ``max_lateral_m`` from the centre line.
        dropped_untrusted: fruits left out for lying outside their segment's trusted stretch.
        dropped_unsupported: fruits one segment counted in the overlap with a neighbour whose fruit cloud has no
            point near them.
    """

    centers: np.ndarray
    diameters: np.ndarray
    n_points: np.ndarray
    along: np.ndarray
    segments: np.ndarray
    local_ids: np.ndarray
    matched: np.ndarray
    dropped_off_row: int = 0
    dropped_untrusted: int = 0
    dropped_unsupported: int = 0

    def __len__(self) -> int:
        return len(self.centers)


def _distances(a: np.ndarray, da: np.ndarray, b: np.ndarray, db: np.ndarray, config: MergeConfig
               ) -> tuple[np.ndarray, np.ndarray]:
    """[A, B] distances of the centres a, b (diameters da, db) and the match reach of each pair: ``match_diameters``
    times the larger diameter (at least ``min_diameter_m``)."""
    dist = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return dist, config.match_diameters * np.maximum(np.maximum(da[:, None], db[None, :]), config.min_diameter_m)


def _pairs(a: np.ndarray, da: np.ndarray, b: np.ndarray, db: np.ndarray, config: MergeConfig) -> np.ndarray:
    """[P, 2] one-to-one index pairs (into a, b) of centres closer than the match reach."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    dist, reach = _distances(a, da, b, db, config)
    cost = np.where(dist <= reach, dist, 1e6)
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] < 1e6
    return np.stack([rows[ok], cols[ok]], axis=1)


def _pieces(own: SegmentFruits, window: np.ndarray, paired: np.ndarray, other: SegmentFruits,
            partners: np.ndarray, config: MergeConfig) -> np.ndarray:
    """Indices of ``own``'s fruits in ``window`` (indices), not in ``paired``, that are a piece of a paired fruit.

    A segment that split a fruit in two counts both halves; its neighbour counts the fruit once and the one-to-one
    match pairs it with one half. The other half lies within the match reach of both copies of the pair: two
    separate fruits cannot have centres closer than a fruit diameter, so it is the same fruit (it is dropped) -
    unless the neighbour's copy is larger than one fruit (``piece_max_diameter_ratio`` median diameters): then the
    neighbour may have merged two fruits into it; or unless the neighbour counted a fruit of its own there (trusted
    or not, paired with nothing): then both saw a second fruit (a touching fruit beyond the neighbour's trusted
    stretch). ``paired[i]`` (own) and ``partners[i]`` (other) are pair i.
    """
    loose = np.setdiff1d(window, paired)
    if len(loose) == 0 or len(paired) == 0:
        return np.zeros(0, np.int64)
    piece = other.diameters[partners] <= config.piece_max_diameter_ratio * float(np.median(own.diameters))
    for centers, diameters in ((own.centers[paired], own.diameters[paired]),
                               (other.centers[partners], other.diameters[partners])):
        dist, reach = _distances(own.centers[loose], own.diameters[loose], centers, diameters, config)
        piece = piece & (dist <= reach)
    unpaired = np.setdiff1d(np.arange(len(other.centers)), partners)
    if len(unpaired):
        dist, reach = _distances(own.centers[loose], own.diameters[loose], other.centers[unpaired],
                                 other.diameters[unpaired], config)
        piece = piece & ~(dist <= reach).any(axis=1, keepdims=True)
    return loose[piece.any(axis=1)]


def _unsupported(done: dict[int, SegmentFruits], by_index: dict[int, Segment], kept: dict[int, np.ndarray],
                 along: dict[int, np.ndarray], matched: dict[int, np.ndarray], config: MergeConfig
                 ) -> dict[int, np.ndarray]:
    """Per segment, a mask of its kept fruits that no other segment counted (unpaired) although they lie in
    another segment's trusted stretch whose fruit cloud (``support``) has no point within
    ``support_radius_diameters`` of the segment's median fruit diameters of them. Fruits found from the views'
    masks where the segment's own cloud had no points (``n_points`` 0) are not judged by a cloud, nor by an empty
    cloud (a segment that found no fruit at all says more about itself than about the place)."""
    drop = {k: np.zeros(len(done[k].centers), bool) for k in done}
    if not config.support_radius_diameters:
        return drop
    trees = {j: cKDTree(c.support) for j, c in done.items() if c.support is not None and len(c.support)}
    order = sorted(done)  # only neighbours' trusted stretches overlap
    for k, j in [*zip(order, order[1:]), *zip(order[1:], order)]:
        own = done[k]
        trust = by_index[j].trust
        judged = kept[k] & ~matched[k] & (own.n_points > 0) & (along[k] >= trust[0]) & (along[k] <= trust[1])
        if j not in trees or not judged.any():
            continue
        radius = config.support_radius_diameters * float(np.median(own.diameters))
        near = trees[j].query_ball_point(own.centers[judged], radius, return_length=True) > 0
        drop[k][np.flatnonzero(judged)[~near]] = True
    return drop


def merge_segments(frame: RowFrame, segments: Sequence[Segment], counts: Sequence[SegmentFruits | None],
                   config: MergeConfig = MergeConfig()) -> RowFruits:
    """Join the segments' counts (None: the segment has no count, e.g. it failed) into the row's fruits."""
    by_index = {seg.index: seg for seg in segments}
    kept: dict[int, np.ndarray] = {}          # segment -> bool mask over its fruits
    along: dict[int, np.ndarray] = {}
    off_row = untrusted = 0
    for count in counts:
        if count is None:
            continue
        seg = by_index[count.segment]
        s = frame.along(count.centers) if len(count.centers) else np.zeros(0)
        on_row = np.abs(frame.across(count.centers)) <= config.max_lateral_m if len(count.centers) \
            else np.zeros(0, bool)
        trusted = (s >= seg.trust[0]) & (s <= seg.trust[1])
        off_row += int((~on_row).sum())
        untrusted += int((on_row & ~trusted).sum())
        kept[count.segment], along[count.segment] = on_row & trusted, s
    done = {c.segment: c for c in counts if c is not None}
    order = sorted(done)
    matched: dict[int, np.ndarray] = {k: np.zeros(len(done[k].centers), bool) for k in order}
    for k, k_next in zip(order[:-1], order[1:]):
        a_seg, b_seg = by_index[k], by_index[k_next]
        a, b = done[k], done[k_next]
        # the overlap of the trusted stretches, grown by the match reach: the two copies of a fruit at its edge
        # fall on both sides of it (2 of the 3 double counts across cuts of the 5-tree row before)
        reach = config.match_diameters * max(config.min_diameter_m, float(np.max(a.diameters, initial=0.0)),
                                             float(np.max(b.diameters, initial=0.0)))
        lo, hi = b_seg.trust[0] - reach, a_seg.trust[1] + reach
        if hi <= lo:
            continue
        ia = np.flatnonzero(kept[k] & (along[k] >= lo) & (along[k] <= hi))
        ib = np.flatnonzero(kept[k_next] & (along[k_next] >= lo) & (along[k_next] <= hi))
        pairs = _pairs(a.centers[ia], a.diameters[ia], b.centers[ib], b.diameters[ib], config)
        pa, pb = ia[pairs[:, 0]], ib[pairs[:, 1]]
        pieces_a, pieces_b = _pieces(a, ia, pa, b, pb, config), _pieces(b, ib, pb, a, pa, config)
        for i, j in zip(pa, pb):
            middle = 0.5 * (along[k][i] + along[k_next][j])
            if middle <= a_seg.core[1]:     # keep the copy of the segment whose own stretch holds the pair
                kept[k_next][j], matched[k][i] = False, True
            else:
                kept[k][i], matched[k_next][j] = False, True
        kept[k][pieces_a] = False
        kept[k_next][pieces_b] = False
    unsupported = _unsupported(done, by_index, kept, along, matched, config)
    for k in order:
        kept[k] &= ~unsupported[k]
    parts = [(k, np.flatnonzero(kept[k])) for k in order]
    centers = np.concatenate([done[k].centers[i] for k, i in parts]) if parts else np.zeros((0, 3))
    s_all = np.concatenate([along[k][i] for k, i in parts]) if parts else np.zeros(0)
    rank = np.argsort(s_all, kind='stable')

    def gather(values: dict[int, np.ndarray] | None, name: str = '') -> np.ndarray:
        if not parts:
            return np.zeros(0)
        return np.concatenate([(getattr(done[k], name) if values is None else values[k])[i] for k, i in parts])[rank]

    segs = np.concatenate([np.full(len(i), k) for k, i in parts])[rank] if parts else np.zeros(0, np.int64)
    return RowFruits(centers.reshape(-1, 3)[rank], gather(None, 'diameters'), gather(None, 'n_points'),
                     s_all[rank], segs.astype(np.int64), gather(None, 'ids').astype(np.int64),
                     gather(matched).astype(bool), off_row, untrusted,
                     sum(int(u.sum()) for u in unsupported.values()))
