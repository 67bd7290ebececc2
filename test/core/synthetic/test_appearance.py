"""appearance_variation: off by default (the fixed look); on, the seed varies lighting and colours, never geometry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.synthetic import DEFAULT_APPEARANCE, SynthConfig, build_scene, generate_orchard
from fruitnerfpp_ros.core.synthetic.appearance import sample_appearance, vary_scene_colours, white_balance_rgb


def test_no_variation_is_the_fixed_look() -> None:
    assert sample_appearance(3, 0.0) is DEFAULT_APPEARANCE
    scene = build_scene(SynthConfig(count=5))
    assert vary_scene_colours(scene, 3, 0.0) is scene
    assert white_balance_rgb(5500.0) == pytest.approx((1.0, 1.0, 1.0))
    warm, cold = white_balance_rgb(3500.0), white_balance_rgb(8500.0)
    assert warm[0] > 1.0 > warm[2] and cold[2] > 1.0 > cold[0]


def test_each_seed_draws_its_own_light_within_the_ranges() -> None:
    looks = [sample_appearance(seed, 1.0) for seed in range(8)]
    elevations = [np.degrees(np.arcsin(a.sun_direction[2])) for a in looks]
    assert all(24.9 < e < 70.1 for e in elevations) and np.ptp(elevations) > 10
    assert all(abs(np.linalg.norm(a.sun_direction) - 1.0) < 1e-12 for a in looks)
    assert len({a.white_balance for a in looks}) == 8 and len({a.ground_noise_seed for a in looks}) > 1
    assert sample_appearance(3, 1.0) == sample_appearance(3, 1.0)
    half = sample_appearance(3, 0.5)  # the same draws, half the change
    assert abs(half.sun_strength - 0.62) == pytest.approx(0.5 * abs(looks[3].sun_strength - 0.62))


def test_variation_changes_colours_not_geometry(tmp_path: Path) -> None:
    base = SynthConfig(fruit='mixed', count=12, views=3, resolution=(48, 36), seed=1, sparse_points=0)
    varied = dataclasses.replace(base, appearance_variation=1.0)
    generate_orchard(base, tmp_path / 'base')
    generate_orchard(varied, tmp_path / 'varied')

    def read(run: str, name: str) -> bytes:
        return (tmp_path / run / name).read_bytes()

    for i in range(3):
        assert read('base', f'instances/{i:04d}.png') == read('varied', f'instances/{i:04d}.png')
        assert read('base', f'images/{i:04d}.png') != read('varied', f'images/{i:04d}.png')
    assert read('base', 'gt_fruits.json') == read('varied', 'gt_fruits.json')
    a, b = build_scene(base), vary_scene_colours(build_scene(base), 1, 1.0)
    assert np.array_equal(a.ellipsoids.center, b.ellipsoids.center)
    # Body and neck of a fruit (one id) keep one colour; fruits of one type no longer share the same tint spread.
    fruit = b.ellipsoids.instance > 0
    ratio = b.ellipsoids.albedo[fruit] / np.maximum(a.ellipsoids.albedo[fruit], 1e-9)
    assert np.std(ratio) > 0.03
