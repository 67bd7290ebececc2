"""Fixtures of the synthetic-generator tests: one small scene with an mcap bag, built once per module user."""

from __future__ import annotations

from typing import NamedTuple

import pytest

from fruitnerfpp_ros.core.synthetic import SynthConfig, SynthResult, generate_orchard

#: The scene the geometry and bag tests check (small, fast, with touching fruits and leaf occlusion).
SMALL_CONFIG = SynthConfig(fruit='apple', count=20, views=10, resolution=(96, 80), trajectory='hemisphere', seed=3,
                           device='cpu')


class SmallScene(NamedTuple):
    config: SynthConfig
    result: SynthResult


@pytest.fixture(scope='session')
def small_scene(tmp_path_factory: pytest.TempPathFactory) -> SmallScene:
    """SMALL_CONFIG rendered with an mcap bag and a preview."""
    out = tmp_path_factory.mktemp('synth_small')
    result = generate_orchard(SMALL_CONFIG, out / 'dataset', bag=out / 'bag', preview=out / 'preview.png')
    return SmallScene(SMALL_CONFIG, result)
