"""Projection, rays, triangulation and the scene centre of the tracker's camera model."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.tracking.camera import PinholeView, triangulate
from fruitnerfpp_ros.errors import DatasetError
from test.core.tracking.scenes import INTRINSICS, look_at


def _view(distortion: dict[str, float] | None = None) -> PinholeView:
    cam = CameraIntrinsics(110.0, 100.0, 50.0, 45.0, 96, 90, distortion or {})
    return PinholeView.from_intrinsics(look_at(np.array([0.2, -1.5, 0.3]), np.array([0.0, 0.0, 0.4])), cam)


@pytest.mark.parametrize('distortion', [None, {'k1': -0.2, 'k2': 0.05, 'p1': 0.002, 'p2': -0.001}])
def test_rays_and_projection_are_inverse(distortion: dict[str, float] | None) -> None:
    view = _view(distortion)
    points = np.random.default_rng(0).uniform([-0.3, -0.3, 0.1], [0.3, 0.3, 0.7], (20, 3))
    uv, depth = view.project(points)
    assert np.all(depth > 0)
    directions, range_per_depth = view.rays(uv)
    back = view.origin + (depth * range_per_depth)[:, None] * directions
    np.testing.assert_allclose(back, points, atol=1e-5)


def test_projection_conventions() -> None:
    view = PinholeView.from_intrinsics(np.eye(4), INTRINSICS)  # at the origin, looking along -z
    uv, depth = view.project(np.array([[0.0, 0.0, -2.0], [0.2, 0.1, -2.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [48.0, 48.0])  # the principal point: the image centre (corner at 0, 0)
    np.testing.assert_allclose(uv[1], [48.0 + 10.0, 48.0 - 5.0])  # x right, y up
    np.testing.assert_allclose(depth, [2.0, 2.0, -1.0])
    assert np.all(np.isnan(uv[2]))  # behind the camera


def test_jacobian_matches_finite_differences() -> None:
    view = _view()
    point = np.array([0.05, 0.1, 0.45])
    J = view.jacobian(point)
    step = 1e-6
    numeric = np.stack([(view.project(point + step * e)[0][0] - view.project(point - step * e)[0][0]) / (2 * step)
                        for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(J, numeric, rtol=1e-5)


def test_fisheye_is_refused() -> None:
    cam = CameraIntrinsics(100.0, 100.0, 48.0, 48.0, 96, 96, {'k1': 0.1, 'k4': 0.01})
    with pytest.raises(DatasetError, match='fisheye'):
        PinholeView.from_intrinsics(np.eye(4), cam)


def test_triangulation_crosses_rays_and_falls_back_on_the_prior() -> None:
    target = np.array([0.1, 0.2, 0.3])
    origins = np.array([[0.0, -1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, 0.0, 1.0]])
    directions = target - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wrong_priors = np.full(3, 5.0)  # 5 m along each ray: far off, weak
    point, information = triangulate(origins, directions, wrong_priors, np.full(3, 1e4), np.full(3, 1e-4))
    np.testing.assert_allclose(point, target, atol=1e-3)
    assert np.all(np.linalg.eigvalsh(information) > 0)
    single, _ = triangulate(origins[:1], directions[:1], np.array([2.0]), np.array([1e4]), np.array([1.0]))
    np.testing.assert_allclose(single, origins[0] + 2.0 * directions[0])  # one ray: its prior point
