"""A counted fruit the training views' masks show as two touching fruits: split in two.

Two touching fruits whose surfaces the field joined are one cluster, centred between them. The masks tell them
apart: in the views that show them side by side, the one counted fruit's disc (``mask_fruits.fruit_discs``, the
disc a counted fruit explains masks with) covers most of *two* instance masks, which no other counted fruit covers. A
fruit counted right covers two masks only where a neighbour's mask reaches into its disc and that neighbour was not
counted.

So in every training view each mask goes to the counted fruit whose disc covers the largest share of it (at least
``explained_share``), and a fruit that gets two or more masks in at least ``split_min_views`` views, and in at least
``split_view_share`` of the views in which it gets any, is cut in two along the main axis of its points (moved to
their fruits' centres, as the centres are; two 1-D means). Both halves must keep the clustering's smallest fruit
(``min_fruit_points``) and their centres lie ``split_min_separation_diameters`` apart, or the fruit stays whole: a
piece or a small fruit has too few points for two fruits.

Measured on the trained fields of the suites and the rows (docs/results/orchard_rows.md, session 38).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit, fruit_diameter
from fruitnerfpp_ros.core.clustering.mask_fruits import fruit_discs
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews, pinhole_view

__all__ = ['masks_owned', 'split_mask_merges']


def masks_owned(views: MaskViews, centers: np.ndarray, fruit_diameter_m: float,
                config: MaskFruitConfig) -> tuple[np.ndarray, np.ndarray]:
    """([K] views in which each fruit at ``centers`` [K, 3] gets exactly one mask, [K] views in which it gets two or
    more): each mask of a view goes to the fruit whose disc covers the largest share of its pixels, when that share
    is at least ``explained_share``."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    one, more = np.zeros(len(centers), np.int64), np.zeros(len(centers), np.int64)
    for view in np.asarray(views.views, np.int64):
        mask = np.asarray(views.instance_masks[view])
        rows, cols = np.nonzero(mask)
        if not len(rows):
            continue
        ids, pixel_mask = np.unique(mask[rows, cols], return_inverse=True)
        uv, radius, front = fruit_discs(pinhole_view(views, view), centers, fruit_diameter_m, config)
        seen = np.flatnonzero(front)
        if not len(seen):
            continue
        hits = cKDTree(np.c_[cols, rows]).query_ball_point(uv[seen], radius[seen])
        sizes = np.array([len(h) for h in hits], np.int64)
        if not sizes.sum():
            continue
        pixels = np.concatenate([np.asarray(h, np.int64) for h in hits])
        fruit = np.repeat(seen, sizes)
        covered = np.bincount(pixel_mask[pixels] * len(centers) + fruit,
                              minlength=len(ids) * len(centers)).reshape(len(ids), len(centers))
        share = covered / np.bincount(pixel_mask, minlength=len(ids))[:, None]
        owner = np.where(share.max(axis=1) >= config.explained_share, share.argmax(axis=1), -1)
        owned = np.bincount(owner[owner >= 0], minlength=len(centers))
        one += owned == 1
        more += owned >= 2
    return one, more


def _halves(points: np.ndarray, iterations: int = 10) -> np.ndarray:
    """[n] bool: the points on one side of the cut along their main axis (two 1-D means)."""
    centred = points - points.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    t = centred @ axis
    cut = float(np.median(t))
    for _ in range(iterations):
        side = t > cut
        if side.all() or not side.any():
            break
        cut = 0.5 * (t[side].mean() + t[~side].mean())
    return t > cut


def split_mask_merges(count: CountResult, views: MaskViews, xyz: np.ndarray, centre_xyz: np.ndarray,
                      fruit_diameter_m: float, config: MaskFruitConfig) -> CountResult:
    """``count`` with each fruit the masks show as two touching fruits cut in two (module doc).

    ``xyz``, ``centre_xyz``: [N, 3] the cloud's points and the same moved to their fruits' centres (the count's
    labels index them). The second half gets the next free id. ``stats['mask_merges']`` says how many were split."""
    if not config.split_merges or count.count == 0 or not fruit_diameter_m > 0:
        return count
    one, more = masks_owned(views, count.centers(), fruit_diameter_m, config)
    flagged = (more >= config.split_min_views) & (more >= config.split_view_share * (one + more))
    min_points = max(1, int(count.stats.get('min_fruit_points') or 1))
    labels, fruits = count.labels.copy(), list(count.fruits)
    next_id = max((f.id for f in fruits), default=0) + 1
    split = 0
    for k in np.flatnonzero(flagged):
        fruit = fruits[k]
        members = np.flatnonzero(labels == fruit.id)
        if fruit.source != 'cloud' or len(members) < 2 * min_points:
            continue
        side = _halves(centre_xyz[members])
        a, b = members[~side], members[side]
        if min(len(a), len(b)) < min_points:
            continue
        ca, cb = np.median(centre_xyz[a], axis=0), np.median(centre_xyz[b], axis=0)
        if np.linalg.norm(ca - cb) < config.split_min_separation_diameters * fruit_diameter_m:
            continue
        labels[b] = next_id
        # sizes as the clustering measures them (counter.fruits_from_labels, centres from moved points)
        extent = [np.subtract(*np.percentile(xyz[m], [98.0, 2.0], axis=0)) for m in (a, b)]
        size = [fruit_diameter(xyz[m].astype(np.float64), c, 50.0) for m, c in ((a, ca), (b, cb))]
        fruits[k] = Fruit(fruit.id, ca, size[0], extent[0], len(a), 'cloud')
        fruits.append(Fruit(next_id, cb, size[1], extent[1], len(b), 'cloud'))
        next_id += 1
        split += 1
    stats = {**count.stats, 'mask_merges': {'split': split, 'flagged': int(flagged.sum())}}
    return dataclasses.replace(count, labels=labels, fruits=fruits, stats=stats)
