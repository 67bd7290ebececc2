"""The row trajectory drives like a robot: both sides of the row at the set standoff, height and pitch, views evenly
spaced along a drive that starts and ends with the tree out of view, ground and sky in every view."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import T_OPENGL_OPTICAL
from fruitnerfpp_ros.core.synthetic import (Renderer, SynthConfig, build_scene, generate_orchard, make_intrinsics,
                                            make_poses, row_drive)
from fruitnerfpp_ros.core.synthetic.cameras import ROW_JITTER_STD

#: A perfect drive (no jitter): the geometry is exact.
EXACT = SynthConfig(fruit='apple', count=30, views=12, resolution=(64, 48), trajectory='row', seed=4,
                    sparse_points=0, row_standoff_m=1.8, camera_height_m=1.0, camera_pitch_deg=4.0, row_jitter=0.0)


def _angles_deg(T: np.ndarray) -> tuple[float, float, float]:
    """(pitch above the horizon, yaw of the viewing direction, roll) of an OpenGL camera-to-world pose."""
    forward, right = -T[:3, 2], T[:3, 0]
    pitch = np.degrees(np.arcsin(forward[2]))
    yaw = np.degrees(np.arctan2(forward[1], forward[0]))
    roll = np.degrees(np.arcsin(right[2]))
    return float(pitch), float(yaw), float(roll)


@pytest.fixture(scope='module')
def exact_row(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('row_exact')
    generate_orchard(EXACT, out)
    return out


def test_exact_drive_geometry(exact_row: Path) -> None:
    poses = np.array([f.T_world_camera for f in read_transforms(exact_row).frames])
    eyes = poses[:, :3, 3]
    out, back = slice(0, 6), slice(6, 12)
    assert np.all(eyes[out, 1] == -1.8) and np.all(eyes[back, 1] == 1.8)           # both sides, at the standoff
    np.testing.assert_allclose(eyes[:, 2], 1.0)                                       # camera height
    assert np.all(np.diff(eyes[out, 0]) > 0) and np.all(np.diff(eyes[back, 0]) < 0)  # out along +x, back along -x
    np.testing.assert_allclose(np.diff(eyes[out, 0]), np.diff(eyes[out, 0])[0])     # evenly spaced
    np.testing.assert_allclose(eyes[back, 0], eyes[out, 0][::-1])                   # the same stretch of row
    drive = row_drive(build_scene(EXACT), EXACT)
    np.testing.assert_allclose([eyes[0, 0], eyes[5, 0]], [-drive.length_m / 2, drive.length_m / 2])
    for T, eye in zip(poses, eyes):
        pitch, yaw, roll = _angles_deg(T)
        assert pitch == pytest.approx(4.0) and roll == pytest.approx(0.0, abs=1e-9)
        assert yaw == pytest.approx(90.0 if eye[1] < 0 else -90.0)                   # facing the row centre line
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)


def test_tree_enters_and_leaves_the_view(exact_row: Path) -> None:
    fruits = json.loads((exact_row / 'gt_fruits.json').read_text())['fruits']
    seen_per_view = np.zeros(12, int)
    for fruit in fruits:
        seen_per_view[fruit['views_visible']] += 1
    # The first and last view of each pass show no fruit, the middle ones many.
    assert seen_per_view[[0, 5, 6, 11]].tolist() == [0, 0, 0, 0]
    assert seen_per_view[[2, 3, 8, 9]].min() >= 5


def test_ground_and_sky_in_every_view_and_nothing_else_at_the_ends() -> None:
    scene = build_scene(EXACT)
    K = make_intrinsics(EXACT)
    renderer = Renderer(scene, torch.device('cpu'))
    v, u = np.mgrid[0:K.h, 0:K.w]
    rays = np.stack([(u + 0.5 - K.cx) / K.fl_x, (v + 0.5 - K.cy) / K.fl_y, np.ones(u.shape)], axis=-1)
    for i, T in enumerate(make_poses(scene, EXACT)):
        depth = renderer.render(T, K).depth.astype(np.float64)
        T_opt = T @ T_OPENGL_OPTICAL
        z_world = T_opt[2, 3] + depth * (rays @ T_opt[2, :3])
        sky = ~np.isfinite(depth)
        ground = np.isfinite(depth) & (np.abs(np.where(sky, 0.0, z_world)) < 1e-3)
        assert sky.mean() > 0.2 and ground.mean() > 0.2, f'view {i}'
        assert np.all(sky[0]), f'view {i}: the top row is sky'
        if i in (0, 5, 6, 11):
            assert np.all(sky | ground) and np.all(ground[-1]), f'view {i} should not see the tree'
        else:
            assert not np.all(sky | ground), f'view {i} should see the tree'


def test_default_drive_jitters_within_its_tolerances(tmp_path: Path) -> None:
    config = SynthConfig(fruit='apple', count=30, views=24, resolution=(16, 12), trajectory='row', seed=5,
                         sparse_points=0)
    assert (config.row_standoff_m, config.camera_height_m, config.camera_pitch_deg) == (2.0, 1.2, 5.0)
    poses = make_poses(build_scene(config), config)
    eyes = poses[:, :3, 3]
    angles = np.array([_angles_deg(T) for T in poses])
    nominal_yaw = np.where(eyes[:, 1] < 0, 90.0, -90.0)
    h_std, d_std, yaw_std, pitch_std, roll_std = ROW_JITTER_STD
    deviations = {'height': (eyes[:, 2] - 1.2, h_std), 'standoff': (np.abs(eyes[:, 1]) - 2.0, d_std),
                  'yaw': (angles[:, 1] - nominal_yaw, yaw_std), 'pitch': (angles[:, 0] - 5.0, pitch_std),
                  'roll': (angles[:, 2], roll_std)}
    for name, (deviation, std) in deviations.items():
        assert 0.05 * std < np.std(deviation) and np.abs(deviation).max() < 4.0 * std, name
    # Smooth along the drive: neighbouring views differ by less than the spread over the whole pass.
    assert np.abs(np.diff(eyes[:12, 2])).max() < np.ptp(eyes[:12, 2])
