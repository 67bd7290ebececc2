"""A tiny synthetic row shared by the orchard tests (3 trees of ~10 apples, 36 views of 96 x 72 px, GNSS), and a
stand-in segment job for the bag-collected keyframes of such a row."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
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


def fruits_shown_by_stamps(gt_path: Path) -> Callable[..., Any]:
    """A job function (also taking the live ``stop_event``) returning the ground-truth fruits that >= 2 of a
    segment's keyframes show, its keyframes told apart by stamp (keyframes collected from the row's bag)."""
    from fruitnerfpp_ros.core.orchard.jobs import SegmentJob
    from fruitnerfpp_ros.core.orchard.merge import SegmentFruits
    from fruitnerfpp_ros.core.synthetic.bag_writer import BAG_START_NS, FRAME_PERIOD_NS

    gt = json.loads(Path(gt_path).read_text())['fruits']

    def shown(job: SegmentJob, stop_event: Any = None) -> SegmentFruits:
        frames = json.loads((Path(job.dataset_dir) / 'transforms.json').read_text())['frames']
        views = {round((f['stamp_ns'] - BAG_START_NS) / FRAME_PERIOD_NS) for f in frames}
        fruits = [f for f in gt if len(views & set(f['views_visible'])) >= 2]
        return SegmentFruits(job.index, np.array([f['center'] for f in fruits]).reshape(-1, 3),
                             np.array([f['diameter'] for f in fruits]), np.full(len(fruits), 50),
                             np.array([f['id'] for f in fruits]))
    return shown
