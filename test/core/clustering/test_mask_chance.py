"""The masks' fruit need more views where views agree by chance (core/clustering/mask_fruits.py, chance_min_views):
a segmenter's false detections must not become fruit. The views are rendered in mask_scene.py; the false detections
are bench/mask_noise.py's, the model the suite's noisy-mask figures use."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.clustering.mask_fruits import (MaskViews, add_mask_fruits, shuffled_rays,
                                                         unexplained_mask_rays)
from fruitnerfpp_ros.errors import ConfigError
from test.bench_scripts import load_bench_script
from test.core.clustering.mask_scene import DIAMETER, FRUITS, circle_views

EMPTY = CountResult(np.zeros(0, np.int32), [], {})


@pytest.fixture(scope='module')
def views() -> MaskViews:
    return circle_views()


def _true_fruits(result: CountResult) -> int:
    """How many of FRUITS the result holds (a centre within half a diameter)."""
    if not result.count:
        return 0
    error = np.linalg.norm(result.centers()[:, None] - FRUITS[None], axis=-1).min(0)
    return int(np.count_nonzero(error < 0.5 * DIAMETER))


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_false_detections_that_agree_by_chance_are_not_counted(views: MaskViews, seed: int) -> None:
    noisy = load_bench_script('mask_noise').noisy_masks(views, 0.0, 0.8, seed)   # ~4 false masks a view, 5 fruit
    every = add_mask_fruits(EMPTY, noisy, DIAMETER, None, MaskFruitConfig(chance_draws=0))
    assert every.count >= 7                                              # three views agree on ghosts by chance
    result = add_mask_fruits(EMPTY, noisy, DIAMETER, None, MaskFruitConfig())
    assert result.count == 5 and _true_fruits(result) == 5, result.stats
    assert result.stats['mask_fruits']['min_views'] > MaskFruitConfig().min_views


def test_with_clean_masks_every_fruit_is_found_and_the_same_on_every_run(views: MaskViews) -> None:
    result = add_mask_fruits(EMPTY, views, DIAMETER, None, MaskFruitConfig())
    assert result.count == 5 and _true_fruits(result) == 5
    again = add_mask_fruits(EMPTY, views, DIAMETER, None, MaskFruitConfig())
    assert np.array_equal(again.centers(), result.centers()) and again.stats == result.stats


def test_a_shuffle_turns_each_views_rays_together(views: MaskViews) -> None:
    config = MaskFruitConfig()
    rays = unexplained_mask_rays(views, np.zeros((0, 3)), DIAMETER, config)
    turned = shuffled_rays(rays, DIAMETER, config, np.random.default_rng(0))
    assert np.array_equal(turned.origin, rays.origin) and np.array_equal(turned.view, rays.view)
    assert np.allclose(np.linalg.norm(turned.direction, axis=1), 1.0)
    for view in np.unique(rays.view):
        mine = rays.view == view
        before, after = rays.direction[mine], turned.direction[mine]
        assert np.allclose(before @ before.T, after @ after.T)           # the view's pattern kept
        depth = rays.max_depth[mine].mean() / config.max_depth_factor
        angle = np.arccos(np.clip(np.sum(before * after, axis=1), -1, 1))
        expected = config.chance_shift_diameters * DIAMETER / depth       # about 3 diameters at the fruit's depth
        assert np.all(angle <= expected + 1e-9) and angle.max() > 0.8 * expected


def test_the_chance_settings_are_checked() -> None:
    for bad in (dict(chance_draws=-1), dict(chance_shift_diameters=0.0), dict(max_chance_share=-0.1)):
        with pytest.raises(ConfigError):
            MaskFruitConfig(**bad)
