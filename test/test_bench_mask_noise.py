"""bench/mask_noise.py: the masks a learned segmenter would give (missed fruit, false detections), seeded."""

from __future__ import annotations

import dataclasses

import numpy as np

from test.bench_scripts import load_bench_script
from test.core.clustering.mask_scene import circle_views


def test_masks_are_missed_and_false_ones_added_in_the_training_views_only() -> None:
    noisy_masks = load_bench_script('mask_noise').noisy_masks
    views = dataclasses.replace(circle_views(), views=np.arange(0, 12, 2))      # the odd views are held out
    same = noisy_masks(views, 0.0, 0.0)
    assert np.array_equal(same.instance_masks, views.instance_masks)
    assert not noisy_masks(views, 1.0, 0.0).instance_masks[views.views].any()  # every fruit missed
    noisy = noisy_masks(views, 0.0, 1.0, seed=3)
    held_out = np.arange(1, 12, 2)
    assert np.array_equal(noisy.instance_masks[held_out], views.instance_masks[held_out])
    for view in views.views:
        real = views.instance_masks[view]
        assert np.array_equal(noisy.instance_masks[view][real > 0], real[real > 0])  # real masks kept on top
        false_ids = np.setdiff1d(np.unique(noisy.instance_masks[view]), np.unique(real))
        assert len(false_ids) >= 1 and false_ids.min() > real.max()
    assert np.array_equal(noisy_masks(views, 0.0, 1.0, seed=3).instance_masks, noisy.instance_masks)
    assert not np.array_equal(noisy_masks(views, 0.0, 1.0, seed=4).instance_masks, noisy.instance_masks)
