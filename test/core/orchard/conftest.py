"""A tiny synthetic row shared by the orchard tests (3 trees of ~10 apples, 36 views of 96 x 72 px, GNSS)."""

from __future__ import annotations

from pathlib import Path

import pytest

#: The tiny row: small trees seen from 1.2 m, the camera at crown height.
TINY_ROW = dict(fruit='apple', count=10, views=36, resolution=(96, 72), row_standoff_m=1.2, camera_height_m=0.6,
                camera_pitch_deg=0.0, seed=3)


@pytest.fixture(scope='session')
def row_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The :data:`TINY_ROW` row of 3 trees with GNSS fixes (dataset and bag)."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig
    from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, generate_row

    out = tmp_path_factory.mktemp('row')
    generate_row(SynthConfig(**TINY_ROW), RowSceneConfig(trees=3, gnss=True), out / 'ds', bag=out / 'bag')
    return out / 'ds'
