"""A counted fruit the training views' masks show as two touching fruits is cut in two
(core/clustering/mask_merges.py).

The masks are ray-cast spheres (mask_scene.py): fruit 0 and a sixth fruit touching it, side by side in every view.
The counts are made here: the clustering's mistake is one cluster holding both touching fruits' points, centred
between them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.clustering.mask_check import count_with_masks
from fruitnerfpp_ros.core.clustering.mask_merges import masks_owned, split_mask_merges
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews
from fruitnerfpp_ros.errors import ConfigError
from test.core.clustering.mask_scene import DIAMETER, FRUITS, circle_views

TOUCHING = np.vstack([FRUITS, FRUITS[0] + [0.0, 0.0, DIAMETER]])
ON = MaskFruitConfig(split_merges=True)


@pytest.fixture(scope='module')
def views() -> MaskViews:
    return circle_views(TOUCHING)


def _cloud(centers: np.ndarray, points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface points of a sphere at each of ``centers`` and the same moved to their sphere's centre (with the
    scatter a clustering's moved points keep)."""
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(len(centers) * points, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    own = np.repeat(centers, points, axis=0)
    return own + 0.5 * DIAMETER * normals, own + rng.normal(scale=0.08 * DIAMETER, size=own.shape)


def _merged_count(points_each: int = 60) -> tuple[CountResult, np.ndarray, np.ndarray]:
    """Fruits 1-4 counted right; fruit 0 and its touching neighbour counted as one fruit between them."""
    xyz, moved = _cloud(TOUCHING, points_each, seed=3)
    labels = np.repeat([1, 2, 3, 4, 5, 1], points_each).astype(np.int32)          # the sixth fruit's points in 1
    centers = [moved[labels == k].mean(axis=0) for k in range(1, 6)]
    fruits = [Fruit(k + 1, c, DIAMETER, np.full(3, DIAMETER), int((labels == k + 1).sum()))
              for k, c in enumerate(centers)]
    return CountResult(labels, fruits, {'min_fruit_points': 20}), xyz, moved


def test_a_right_count_holds_one_mask_per_fruit_and_the_merge_two(views: MaskViews) -> None:
    one, more = masks_owned(views, TOUCHING, DIAMETER, ON)
    assert one.min() >= 11 and more.max() <= 1                     # each fruit its own mask in (nearly) every view
    merged = np.vstack([FRUITS[1:], 0.5 * (TOUCHING[0] + TOUCHING[5])])
    one, more = masks_owned(views, merged, DIAMETER, ON)
    assert more[-1] >= 10 and one[-1] <= 2                         # the merge's disc holds both touching masks
    assert more[:-1].max() <= 1


def test_two_touching_fruits_counted_as_one_are_counted_as_two(views: MaskViews) -> None:
    count, xyz, moved = _merged_count()
    result = split_mask_merges(count, views, xyz, moved, DIAMETER, ON)
    assert result.count == 6 and result.stats['mask_merges']['split'] == 1
    found = result.centers()
    error = np.linalg.norm(found[:, None] - TOUCHING[None], axis=2).min(axis=0)
    assert error.max() < 0.25 * DIAMETER                            # every true fruit has a counted centre on it
    assert sorted(f.id for f in result.fruits) == [1, 2, 3, 4, 5, 6]
    assert [(result.labels == k).sum() for k in range(1, 7)] == [f.n_points for f in sorted(
        result.fruits, key=lambda f: f.id)]
    assert {(result.labels == 1).sum(), (result.labels == 6).sum()} == {60}   # each half one fruit's points
    halves = [f for f in result.fruits if f.id in (1, 6)]
    assert all(0.8 * DIAMETER < f.diameter_m < 1.25 * DIAMETER for f in halves)  # each measured as one fruit


def test_the_pipelines_masks_step_splits_when_given_the_points(views: MaskViews) -> None:
    count, xyz, moved = _merged_count()
    assert count_with_masks(count, views, DIAMETER, None, ON, (xyz, moved)).count == 6
    assert count_with_masks(count, views, DIAMETER, None, ON).count == 5                 # no points: no cut


def test_a_right_count_a_small_cluster_or_the_step_off_cut_nothing(views: MaskViews) -> None:
    xyz, moved = _cloud(TOUCHING, 40, seed=4)
    labels = np.repeat(np.arange(1, 7), 40).astype(np.int32)
    right = CountResult(labels, [Fruit(k + 1, c, DIAMETER, np.full(3, DIAMETER), 40) for k, c in enumerate(TOUCHING)],
                        {'min_fruit_points': 20})
    assert split_mask_merges(right, views, xyz, moved, DIAMETER, ON).count == 6
    count, xyz, moved = _merged_count(points_each=15)                # halves under the smallest fruit (20 points)
    assert split_mask_merges(count, views, xyz, moved, DIAMETER, ON).count == 5
    count, xyz, moved = _merged_count()
    assert split_mask_merges(count, views, xyz, moved, DIAMETER, dataclasses.replace(ON, split_merges=False)) is count
    strict = dataclasses.replace(ON, split_min_views=13)             # more views than the scene has
    assert split_mask_merges(count, views, xyz, moved, DIAMETER, strict).count == 5


def test_bad_split_settings_are_refused() -> None:
    for bad in ({'split_min_views': 0}, {'split_view_share': 1.5}, {'split_min_separation_diameters': -1.0}):
        with pytest.raises(ConfigError, match='split_'):
            MaskFruitConfig(**bad)
