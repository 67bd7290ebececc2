"""The scene box: the cameras' box cut across to the fruit region and the cameras, its height kept."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.config_io import replace_nested
from fruitnerfpp_ros.core.data.scene_scale import SceneScale
from fruitnerfpp_ros.core.training import TrainConfig
from fruitnerfpp_ros.core.training.scene_box import build_scene_box
from fruitnerfpp_ros.errors import DatasetError

CAMERA_BOX = np.array([[-4.0, -4.0, -1.0], [4.0, 4.0, 3.0]])
REGION = np.array([[-0.5, -0.4, 0.5], [0.5, 0.4, 1.3]])
SCALE = SceneScale(0.075, 'masks', REGION, 500, 300)


def test_the_box_reaches_past_the_cameras_on_both_sides_of_a_row() -> None:
    cameras = np.array([[x, side * 2.0, 1.2] for x in np.linspace(-1.5, 1.5, 7) for side in (-1, 1)])
    box = build_scene_box(TrainConfig(), CAMERA_BOX, SCALE, cameras)
    np.testing.assert_allclose(box[:, :2], [[-2.0, -2.5], [2.0, 2.5]])       # cameras +- 0.5 m across
    np.testing.assert_allclose(box[:, 2], CAMERA_BOX[:, 2])                  # the ground stays in
    assert np.all(box[0, :2] < cameras.min(0)[:2]) and np.all(box[1, :2] > cameras.max(0)[:2])


def test_explicit_and_uncut_boxes() -> None:
    assert np.array_equal(build_scene_box(replace_nested(TrainConfig(), {'data': {'box_margin_m': None}}),
                                          CAMERA_BOX, SCALE), CAMERA_BOX)
    nothing = SceneScale(0.07, 'default', None, 0, 0)
    assert np.array_equal(build_scene_box(TrainConfig(), CAMERA_BOX, nothing), CAMERA_BOX)
    given = replace_nested(TrainConfig(), {'data': {'aabb': (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)}})
    assert np.array_equal(build_scene_box(given, CAMERA_BOX, SCALE), [[0, 0, 0], [1, 1, 1]])
    far = SceneScale(0.07, 'masks', REGION + 20.0, 10, 10)
    with pytest.raises(DatasetError, match='outside the cameras'):
        build_scene_box(TrainConfig(), CAMERA_BOX, far)
