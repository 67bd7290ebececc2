"""Fruit the training views' masks agree on where the cloud's count has none (core/clustering/mask_fruits.py).

The views are rendered independently of the module (mask_scene.py): spheres ray-cast into pinhole cameras on a
circle, so the masks are what a camera shows, occlusions included.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.config import ClusterConfig, MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.clustering.mask_check import count_with_masks
from fruitnerfpp_ros.core.clustering.mask_fruits import MaskViews, add_mask_fruits, mask_pixel_floor
from fruitnerfpp_ros.errors import ConfigError
from test.core.clustering.mask_scene import DIAMETER, FRUITS, circle_views


@pytest.fixture(scope='module')
def views() -> MaskViews:
    return circle_views()


def _count(centers: np.ndarray) -> CountResult:
    fruits = [Fruit(i + 1, c, DIAMETER, np.full(3, DIAMETER), 100) for i, c in enumerate(centers)]
    return CountResult(np.zeros(0, np.int32), fruits, {})


def test_the_masks_are_fruit_of_a_few_dozen_pixels(views: MaskViews) -> None:
    ids, pixels = np.unique(views.instance_masks[views.instance_masks > 0], return_counts=True)
    assert ids.tolist() == [1, 2, 3, 4, 5]
    assert 20 < np.median(pixels) / len(views.views) < 60     # ~3.5 px radius, some hidden behind others


def test_fruit_the_count_lacks_are_added_where_they_hang(views: MaskViews) -> None:
    rng = np.random.default_rng(0)
    counted = FRUITS[:3] + rng.normal(0, 0.01, (3, 3))                    # the cloud's clusters, 1 cm off
    result = add_mask_fruits(_count(counted), views, DIAMETER, None, MaskFruitConfig())
    added = [f for f in result.fruits if f.source == 'masks']
    assert len(added) == 2, result.stats
    assert [f.id for f in added] == [4, 5] and all(f.n_points == 0 for f in added)
    found = np.array([f.center for f in added])
    error = np.linalg.norm(found[:, None] - FRUITS[None, 3:], axis=-1).min(0)   # each missing fruit, its nearest
    assert np.all(error < 0.25 * DIAMETER), error
    assert result.stats['mask_fruits']['added'] == 2
    assert np.array_equal(result.centers()[:3], counted) and [f.source for f in result.fruits[:3]] == ['cloud'] * 3


def test_a_complete_count_gets_nothing_added(views: MaskViews) -> None:
    result = add_mask_fruits(_count(FRUITS + 0.005), views, DIAMETER, None, MaskFruitConfig())
    assert result.count == len(FRUITS), [f.center for f in result.fruits[len(FRUITS):]]


def test_an_empty_count_is_completed_from_the_masks_alone(views: MaskViews) -> None:
    result = add_mask_fruits(_count(np.zeros((0, 3))), views, DIAMETER, None, MaskFruitConfig())
    assert result.count == len(FRUITS)


def test_fruit_a_few_pixels_across_are_found_where_the_whole_scene_is_that_small() -> None:
    far = circle_views(radius_m=3.4)                                          # 2-3 px across, 4-5 px masks
    areas = np.unique(far.instance_masks[far.instance_masks > 0], return_counts=True)[1] / len(far.views)
    assert np.all(areas < 6), areas
    result = add_mask_fruits(_count(FRUITS[:3]), far, DIAMETER, None, MaskFruitConfig())
    assert result.count == 5 and result.stats['mask_fruits']['min_mask_pixels'] == 3, result.stats
    error = np.linalg.norm(result.centers()[3:, None] - FRUITS[None, 3:], axis=-1).min(0)
    assert np.all(error < 0.5 * DIAMETER), error
    fixed = MaskFruitConfig(smallest_mask_pixels=6)                           # a 6 px floor whatever the scene
    assert add_mask_fruits(_count(FRUITS[:3]), far, DIAMETER, None, fixed).count == 3


@pytest.mark.parametrize('whole_px, floor', [(50, 6), (40, 6), (30, 5), (20, 3), (15, 3), (4, 3)])
def test_the_mask_floor_is_a_share_of_a_whole_fruit_between_3_and_6_pixels(whole_px: int, floor: int) -> None:
    areas = np.concatenate([np.full(80, 2), np.full(20, whole_px)])       # the largest fifth: whole fruit
    assert mask_pixel_floor(areas, MaskFruitConfig()) == floor
    assert mask_pixel_floor(np.zeros(0), MaskFruitConfig()) == 6


def test_fruit_too_few_views_agree_on_are_not_added(views: MaskViews) -> None:
    two = dataclasses.replace(views, views=np.array([0, 3]))                 # two views, 90 degrees apart
    assert add_mask_fruits(_count(FRUITS[:3]), two, DIAMETER, None, MaskFruitConfig()).count == 3
    three = dataclasses.replace(views, views=np.array([0, 3, 6]))
    assert add_mask_fruits(_count(FRUITS[:3]), three, DIAMETER, None, MaskFruitConfig()).count == 5


def test_outside_the_scene_box_nothing_is_added(views: MaskViews) -> None:
    box = np.array([[-0.3, -0.3, -0.1], [0.3, 0.3, 0.3]])                   # holds fruit 3 (z 0.15), not 4 (z -0.2)
    result = add_mask_fruits(_count(FRUITS[:3]), views, DIAMETER, box, MaskFruitConfig())
    assert result.count == 4
    assert np.linalg.norm(result.fruits[-1].center - FRUITS[3]) < 0.25 * DIAMETER


def test_off_leaves_the_count_alone(views: MaskViews) -> None:
    count = _count(FRUITS[:3])
    assert add_mask_fruits(count, views, DIAMETER, None, MaskFruitConfig(enabled=False)) is count


@pytest.mark.parametrize('source, added', [(None, 2), ('topic', 2), ('ground_truth', 2), ('fallback', 0),
                                           ('fallback+topic', 0), ('sam', 2)])
def test_masks_of_the_colour_fallback_add_nothing(views: MaskViews, source: str | None, added: int) -> None:
    result = count_with_masks(_count(FRUITS[:3]), dataclasses.replace(views, mask_source=source), DIAMETER, None,
                              MaskFruitConfig())
    assert result.count == 3 + added
    assert result.stats['mask_fruits']['added'] == added
    assert ('skipped_mask_source' in result.stats['mask_fruits']) == (added == 0)


def test_the_skipped_sources_are_a_setting(views: MaskViews) -> None:
    fallback = dataclasses.replace(views, mask_source='fallback')
    assert count_with_masks(_count(FRUITS[:3]), fallback, DIAMETER, None,
                            MaskFruitConfig(skip_mask_sources=())).count == 5
    sam = dataclasses.replace(views, mask_source='sam')
    assert count_with_masks(_count(FRUITS[:3]), sam, DIAMETER, None,
                            MaskFruitConfig(skip_mask_sources=('sam',))).count == 3


def test_the_settings_are_checked_and_nested_in_the_clustering_config() -> None:
    with pytest.raises(ConfigError):
        MaskFruitConfig(min_views=1)
    with pytest.raises(ConfigError):
        MaskFruitConfig(explained_share=0.0)
    with pytest.raises(ConfigError):
        MaskFruitConfig(smallest_mask_pixels=8)                               # above min_mask_pixels
    assert ClusterConfig().masks == MaskFruitConfig()


def test_rays_paired_a_block_at_a_time_meet_where_all_at_once_do(views: MaskViews) -> None:
    from fruitnerfpp_ros.core.clustering.mask_fruits import _pair_points, unexplained_mask_rays
    rays = unexplained_mask_rays(views, FRUITS[:3], DIAMETER, MaskFruitConfig())
    assert len(rays) >= 10
    whole = _pair_points(rays, 0.5 * DIAMETER, 0.1, chunk_pairs=10 ** 8)
    assert len(whole) >= 10 and np.array_equal(_pair_points(rays, 0.5 * DIAMETER, 0.1, chunk_pairs=5), whole)


@pytest.mark.parametrize('units', [0.02, 1.0, 50.0])
def test_the_masks_fruit_are_found_alike_whatever_the_poses_units(views: MaskViews, units: float) -> None:
    """The same scene with its poses in units of 50 m / 1 m / 2 cm (the masks are the same pictures): the count of a
    run in those units (``RunViews.units_per_metre``) completes an empty cloud's count with all five fruits where
    they hang. Without the conversion the 0.1 m camera distance is 5 pose units away (nothing found at 0.02) and
    the run's fruit size is all that scales."""
    from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
    from fruitnerfpp_ros.core.pipeline import RunViews, count_with_views

    poses = views.T_world_camera.copy()
    poses[:, :3, 3] *= units
    scaled = dataclasses.replace(views, T_world_camera=poses)
    cloud = FruitPointCloud.empty(8, fruit_diameter_m=DIAMETER * units)
    run = RunViews(scaled, DIAMETER * units, np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]) * units,
                   units_per_metre=units * DIAMETER / 0.07)
    result = count_with_views(cloud, ClusterConfig(), run)
    assert result.count == len(FRUITS), result.stats
    error = np.linalg.norm(result.centers()[:, None] / units - FRUITS[None], axis=-1).min(1)
    assert np.all(error < 0.25 * DIAMETER), error
    if units < 1:
        unconverted = count_with_views(cloud, ClusterConfig(), dataclasses.replace(run, units_per_metre=1.0))
        assert unconverted.count == 0
