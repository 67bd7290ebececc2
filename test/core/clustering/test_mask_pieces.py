"""Counted fruits the training views' masks show as pieces of one fruit are joined (core/clustering/mask_pieces.py).

The masks are ray-cast spheres (mask_scene.py); the counts are made here: the true fruits, plus pieces placed where
a clustering leaves them (a cap's centre, half a diameter off the fruit's centre, with fewer points).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.clustering.mask_check import count_with_masks
from fruitnerfpp_ros.core.clustering.mask_pieces import join_mask_pieces, mask_ids_at
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews
from test.core.clustering.mask_scene import DIAMETER, FRUITS, circle_views

#: fruit 0 and a sixth fruit touching it (centres one diameter apart, side by side as the cameras circle them)
TOUCHING = np.vstack([FRUITS, FRUITS[0] + [0.0, 0.0, DIAMETER]])


@pytest.fixture(scope='module')
def views() -> MaskViews:
    return circle_views()


def _count(centers: np.ndarray, points: list[int]) -> CountResult:
    """A count of fruits at ``centers`` with ``points[i]`` cloud points each (labels: fruit ids, in order)."""
    fruits = [Fruit(i + 1, c, DIAMETER, np.full(3, DIAMETER), n, 'cloud' if n else 'masks')
              for i, (c, n) in enumerate(zip(centers, points))]
    labels = np.concatenate([np.zeros(7, np.int32)] + [np.full(n, i + 1, np.int32) for i, n in enumerate(points)])
    return CountResult(labels, fruits, {})


def test_a_centre_falls_on_its_own_fruits_mask(views: MaskViews) -> None:
    ids = mask_ids_at(views, FRUITS)
    own = ids == np.arange(1, 6)[None]
    assert own.sum(axis=0).min() >= 7                    # each fruit is seen in most of the 12 views
    far = np.array([[5.0, 0.0, 0.0]])                    # behind the cameras on one side, off the image elsewhere
    assert not mask_ids_at(views, far).any()


def test_a_fruit_cut_in_two_is_counted_once(views: MaskViews) -> None:
    piece = FRUITS[0] + [0.5 * DIAMETER * 0.6, 0.0, 0.5 * DIAMETER * 0.5]     # a cap, off the centre
    count = _count(np.vstack([FRUITS[:2], piece, FRUITS[2:]]), [90, 80, 20, 70, 60, 50])
    result = join_mask_pieces(count, views, DIAMETER, MaskFruitConfig())
    assert result.count == 5 and result.stats['mask_pieces'] == {'joined': 1}
    assert [f.id for f in result.fruits] == [1, 2, 3, 4, 5]
    assert np.array_equal(result.centers(), FRUITS)                         # the kept fruits are untouched
    assert result.fruits[0].n_points == 110
    labels = result.labels
    assert (labels == 1).sum() == 110 and (labels == 0).sum() == 7              # the piece's points joined fruit 1
    assert [(labels == k).sum() for k in (2, 3, 4, 5)] == [80, 70, 60, 50]


def test_two_touching_fruits_stay_two() -> None:
    views = circle_views(TOUCHING)
    count = _count(TOUCHING, [90, 80, 70, 60, 50, 40])
    result = join_mask_pieces(count, views, DIAMETER, MaskFruitConfig())
    assert result.count == 6, result.stats
    ids = mask_ids_at(views, TOUCHING[[0, 5]])
    assert ((ids[:, 0] > 0) & (ids[:, 1] > 0) & (ids[:, 0] != ids[:, 1])).sum() >= 3   # the masks separate them


def test_a_triangulated_fruit_on_a_counted_ones_mask_joins_it(views: MaskViews) -> None:
    cap, triangulated = FRUITS[3] + [0.4 * DIAMETER, 0, 0], FRUITS[3] - [0.4 * DIAMETER, 0, 0]   # both inside fruit 4
    count = _count(np.vstack([FRUITS[:3], cap, FRUITS[4:], triangulated]), [90, 80, 70, 60, 50, 0])
    result = join_mask_pieces(count, views, DIAMETER, MaskFruitConfig())
    assert result.count == 5 and all(f.source == 'cloud' for f in result.fruits)
    assert np.array_equal(result.fruits[3].center, cap)


def test_far_apart_or_off_nothing_is_joined(views: MaskViews) -> None:
    piece = FRUITS[0] + [0.3 * DIAMETER, 0.0, 0.0]
    count = _count(np.vstack([FRUITS, piece]), [90, 80, 70, 60, 50, 20])
    assert join_mask_pieces(count, views, DIAMETER, MaskFruitConfig(join_pieces=False)) is count
    near = MaskFruitConfig(join_within_diameters=0.2)
    assert join_mask_pieces(count, views, DIAMETER, near).count == 6
    assert join_mask_pieces(count, views, DIAMETER, MaskFruitConfig(join_min_shared_views=13)).count == 6
    assert join_mask_pieces(count, views, DIAMETER, MaskFruitConfig()).count == 5


def test_the_masks_step_joins_after_adding_and_skips_the_fallbacks_masks(views: MaskViews) -> None:
    piece = FRUITS[0] + [0.3 * DIAMETER, 0.0, 0.0]
    count = _count(np.vstack([FRUITS[:4], piece]), [90, 80, 70, 60, 20])
    result = count_with_masks(count, views, DIAMETER, None, MaskFruitConfig())
    assert result.count == 5                               # fruit 5 added from the masks, the piece joined
    assert result.stats['mask_fruits']['added'] == 1 and result.stats['mask_pieces'] == {'joined': 1}
    fallback = count_with_masks(count, dataclasses.replace(views, mask_source='fallback'), DIAMETER, None,
                                MaskFruitConfig())
    assert [f.n_points for f in fallback.fruits] == [90, 80, 70, 60, 20] and 'mask_pieces' not in fallback.stats
