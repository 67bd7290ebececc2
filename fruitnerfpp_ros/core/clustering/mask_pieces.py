"""Two counted fruits the training views' masks show as one: pieces of one fruit, joined.

The clustering sometimes cuts one fruit's points in two: a cap seen from one side and the rest, or two surface
patches of a fruit half hidden by leaves. Both pieces then count. Their centres lie within a couple of fruit
diameters, like those of two touching fruits; the masks tell the two cases apart:

- two touching fruits are two instance masks in the views that see them side by side (the masks separate them),
  and one mask only where one hides the other;
- two pieces of one fruit fall on the same mask in every view that shows the fruit.

So two counted fruits closer than ``join_within_diameters`` fruit diameters are one when their centres project
onto the same instance mask in at least ``join_min_shared_views`` training views and onto two different masks in
none (``join_max_split_views``). A view in which either centre falls off every mask (hidden by leaves, out of the
image, behind the camera) says nothing. Pairs are joined nearest first; the fruit with fewer cloud points joins
the other (its points take the other's id; a fruit triangulated from the masks, with none, joins a cluster), and
the kept fruit's centre and size stay as the clustering measured them.

The masks cannot tell two touching fruits apart where every view that sees both shows one behind the other: a
row drive sees a fruit deep in the crown through a few gaps, from two directions. Such pairs are joined too.
Requiring views that show the centres apart (a front fruit cannot hide a fruit shown beside it) avoided that, but
also left out nearly every true piece: the caps a clustering cuts a fruit into lie one behind the other along the
views that made them. Measured on the trained fields of the ``cpu``, ``quick`` and ``holdout`` suites and the
5-tree rows (docs/results/accuracy_suite.md, session 32): 20 joins on 23 scenes, F1 up on 10 and down on one
(a true fruit lost); the rows: one double across cuts gone, two true fruits lost on another row.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews, pinhole_view

__all__ = ['mask_ids_at', 'shared_and_split_views', 'join_mask_pieces']


def mask_ids_at(views: MaskViews, centers: np.ndarray) -> np.ndarray:
    """[V, K] instance id under each of the [K, 3] ``centers`` in each of the ``views.views`` (0: no mask there,
    outside the image or behind the camera)."""
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    ids = np.zeros((len(views.views), len(centers)), np.int64)
    for row, view in enumerate(np.asarray(views.views, np.int64)):
        camera = pinhole_view(views, view)
        uv, depth = camera.project(centers)                 # NaN behind the camera
        with np.errstate(invalid='ignore'):
            col, line = np.floor(uv[:, 0]), np.floor(uv[:, 1])
            inside = (depth > 0) & (col >= 0) & (col < camera.width) & (line >= 0) & (line < camera.height)
        ids[row, inside] = views.instance_masks[view, line[inside].astype(np.int64), col[inside].astype(np.int64)]
    return ids


def shared_and_split_views(ids: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """([P] views in which both centres of each pair fall on one mask, [P] views in which they fall on two), from
    the [V, K] ``ids`` of :func:`mask_ids_at` and [P, 2] ``pairs`` of fruit indices."""
    a, b = ids[:, pairs[:, 0]], ids[:, pairs[:, 1]]
    both = (a > 0) & (b > 0)
    return (both & (a == b)).sum(axis=0), (both & (a != b)).sum(axis=0)


def _pieces(views: MaskViews, centers: np.ndarray, fruit_diameter_m: float,
            config: MaskFruitConfig) -> list[tuple[int, int]]:
    """Pairs (a, b), nearest first, of fruits within the reach whose centres the masks show as one fruit."""
    pairs = cKDTree(centers).query_pairs(config.join_within_diameters * fruit_diameter_m, output_type='ndarray')
    if not len(pairs):
        return []
    shared, split = shared_and_split_views(mask_ids_at(views, centers), pairs)
    keep = (shared >= config.join_min_shared_views) & (split <= config.join_max_split_views)
    pairs = pairs[keep]
    order = np.argsort(np.linalg.norm(centers[pairs[:, 0]] - centers[pairs[:, 1]], axis=1), kind='stable')
    return [(int(i), int(j)) for i, j in pairs[order]]


def join_mask_pieces(count: CountResult, views: MaskViews, fruit_diameter_m: float,
                     config: MaskFruitConfig) -> CountResult:
    """``count`` with the fruits the masks show as pieces of one joined (module doc); ids stay 1..count in order and
    the cloud labels follow. ``stats['mask_pieces']`` says how many were joined."""
    if not config.join_pieces or count.count < 2 or not fruit_diameter_m > 0:
        return count
    centers = count.centers()
    into = np.arange(count.count)                           # fruit i joins fruit into[i]
    for i, j in _pieces(views, centers, fruit_diameter_m, config):
        if into[i] != i or into[j] != j:                    # one of them already joined another
            continue
        small, large = (i, j) if count.fruits[i].n_points < count.fruits[j].n_points else (j, i)
        into[small] = large
    joined = int((into != np.arange(count.count)).sum())
    stats = {**count.stats, 'mask_pieces': {'joined': joined}}
    if not joined:
        return dataclasses.replace(count, stats=stats)
    kept = np.flatnonzero(into == np.arange(count.count))
    new_id = np.zeros(count.count, np.int64)
    new_id[kept] = np.arange(1, len(kept) + 1)
    old_ids = np.array([f.id for f in count.fruits], np.int64)
    lookup = np.zeros(int(max(old_ids.max(), count.labels.max(initial=0))) + 1, np.int64)
    lookup[old_ids] = new_id[into]                          # a piece's points take the id of the fruit it joined
    points = np.bincount(into, weights=[f.n_points for f in count.fruits], minlength=count.count)
    fruits = [Fruit(int(new_id[k]), f.center, f.diameter_m, f.extent_m, int(points[k]), f.source)
              for k, f in ((k, count.fruits[k]) for k in kept)]
    labels = np.where(count.labels > 0, lookup[np.maximum(count.labels, 0)], 0).astype(count.labels.dtype)
    return CountResult(labels, fruits, stats)
