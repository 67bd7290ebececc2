"""The scene box: the cameras' box cut to the fruit region on every axis (default), or across to the fruit region
and the cameras with its height kept (``box_around: fruit_and_cameras``)."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.config_io import replace_nested
from fruitnerfpp_ros.core.data.scene_scale import SceneScale
from fruitnerfpp_ros.core.preset_names import PRESET_NAMES
from fruitnerfpp_ros.core.training import TrainConfig
from fruitnerfpp_ros.core.training.scene_box import build_scene_box
from fruitnerfpp_ros.errors import ConfigError, DatasetError

CAMERA_BOX = np.array([[-4.0, -4.0, -1.0], [4.0, 4.0, 3.0]])
REGION = np.array([[-0.5, -0.4, 0.5], [0.5, 0.4, 1.3]])
SCALE = SceneScale(0.075, 'masks', REGION, 500, 300)


def test_a_box_around_fruit_and_cameras_reaches_past_the_cameras_on_both_sides_of_a_row() -> None:
    cameras = np.array([[x, side * 2.0, 1.2] for x in np.linspace(-1.5, 1.5, 7) for side in (-1, 1)])
    config = replace_nested(TrainConfig(), {'data': {'box_around': 'fruit_and_cameras'}})
    box = build_scene_box(config, CAMERA_BOX, SCALE, cameras)
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


def test_a_box_around_the_fruit_is_cut_on_every_axis_and_leaves_the_cameras_out() -> None:
    cameras = np.array([[x, side * 2.0, 1.2] for x in np.linspace(-1.5, 1.5, 7) for side in (-1, 1)])
    config = replace_nested(TrainConfig(), {'data': {'box_margin_m': 0.3}})      # box_around: fruit, the default
    box = build_scene_box(config, CAMERA_BOX, SCALE, cameras)
    np.testing.assert_allclose(box, [[-0.8, -0.7, 0.2], [0.8, 0.7, 1.6]])   # the fruit region +- 0.3 m
    for name in PRESET_NAMES:                                                 # every preset, the far field too
        preset = TrainConfig.preset(name)
        assert preset.data.box_around == 'fruit' and preset.field.far_field.samples > 0
    wide = SceneScale(0.075, 'masks', np.array([[-6.0, -0.4, -3.0], [0.5, 0.4, 1.3]]), 500, 300)
    np.testing.assert_allclose(build_scene_box(config, CAMERA_BOX, wide, cameras)[0], [-4.0, -0.7, -1.0])
    with pytest.raises(ConfigError, match='box_around'):
        replace_nested(TrainConfig(), {'data': {'box_around': 'trees'}})
    with pytest.raises(ConfigError, match='far_field.samples'):  # the box around the fruit needs the far field
        replace_nested(TrainConfig(), {'field': {'far_field': {'samples': 0}}})
    for legal in ({'data': {'box_around': 'fruit_and_cameras'}}, {'data': {'aabb': [0, 0, 0, 1, 1, 1]}}):
        config = replace_nested(TrainConfig(), {**legal, 'field': {'far_field': {'samples': 0}}})
        assert not config.field.far_field.enabled


def test_the_margin_given_in_metres_is_converted_to_the_poses_units() -> None:
    """Poses in units of 10 cm (``units_per_metre`` 10): the 0.5 m margin is 5 units; the marching's near plane,
    the pass registration's shifts, the distortion loss's weight (per metre) and the far field's density are
    converted with it."""
    from fruitnerfpp_ros.core.training.pose_start import lengths_in_pose_units

    in_tenths = SceneScale(0.75, 'pose_units', REGION * 10, 500, 300, units_per_metre=10.0)
    box = build_scene_box(TrainConfig(), CAMERA_BOX * 10, in_tenths)
    np.testing.assert_allclose(box, [REGION[0] * 10 - 5.0, REGION[1] * 10 + 5.0])
    config = TrainConfig()
    converted = lengths_in_pose_units(config, 10.0)
    assert converted.render.near == pytest.approx(10 * config.render.near)
    shift = config.pass_registration.max_shift_m
    np.testing.assert_allclose(converted.pass_registration.max_shift_m, np.multiply(shift, 10))
    assert converted.geometry.distortion_weight == pytest.approx(config.geometry.distortion_weight / 10)
    assert converted.field.far_field.units_per_metre == 10.0
    assert converted.data.box_margin_m == config.data.box_margin_m       # converted where the box is built
    assert lengths_in_pose_units(config, 1.0) is config
