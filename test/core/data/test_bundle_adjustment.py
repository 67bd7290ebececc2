"""The pose alignment's bundle adjustment: analytic Jacobians, and the solve on a problem with a known answer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.data.bundle_adjustment import BundleProblem, adjust, project_with_jacobians

SIGMA = np.r_[np.full(3, np.deg2rad(0.5)), np.full(3, 0.02)]


def _ring(views: int = 12, points: int = 80, seed: int = 0) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
    """Cameras on a 3 m ring looking at a 1 m cloud of points, every point seen by every view; returns the problem
    with exact pixels, the true corrections of the recorded poses [V, 6] (zero: the recorded poses are the truth)
    and the points [P, 3]."""
    rng = np.random.default_rng(seed)
    angle = np.linspace(0.0, 2.0 * np.pi, views, endpoint=False)
    centre = np.c_[3.0 * np.cos(angle), 3.0 * np.sin(angle), np.full(views, 0.3)]
    back = centre / np.linalg.norm(centre, axis=1, keepdims=True)               # camera +z points away from the cloud
    up = np.tile([0.0, 0.0, 1.0], (views, 1))
    right = np.cross(up, back)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    R = np.stack([right, np.cross(back, right), back], axis=2)
    X = rng.uniform(-0.5, 0.5, (points, 3))
    track, view = np.repeat(np.arange(points), views), np.tile(np.arange(views), points)
    K = np.tile([300.0, 300.0, 160.0, 120.0], (views, 1))
    problem = BundleProblem(R, centre, K, track, view, np.zeros((len(view), 2)), SIGMA)
    error, in_front, _, _ = project_with_jacobians(problem, np.zeros((views, 6)), X, jacobians=False)
    assert in_front.all()
    return BundleProblem(R, centre, K, track, view, error, SIGMA), np.zeros((views, 6)), X


def test_the_jacobians_are_the_derivatives_of_the_projection() -> None:
    problem, _, X = _ring(views=5, points=10)
    rng = np.random.default_rng(1)
    correction = rng.normal(scale=0.05, size=(5, 6))                          # away from zero: J_r matters
    _, _, J_c, J_x = project_with_jacobians(problem, correction, X)
    h = 1e-6
    for v, i in [(0, 0), (1, 2), (2, 1), (3, 3), (4, 5)]:
        step = np.zeros_like(correction)
        step[v, i] = h
        numeric = (project_with_jacobians(problem, correction + step, X, False)[0]
                   - project_with_jacobians(problem, correction - step, X, False)[0]) / (2 * h)
        np.testing.assert_allclose(J_c[problem.view == v, :, i], numeric[problem.view == v], rtol=1e-5, atol=1e-4)
    for p, i in [(0, 0), (4, 1), (9, 2)]:
        step = np.zeros_like(X)
        step[p, i] = h
        numeric = (project_with_jacobians(problem, correction, X + step, False)[0]
                   - project_with_jacobians(problem, correction, X - step, False)[0]) / (2 * h)
        np.testing.assert_allclose(J_x[problem.track == p, :, i], numeric[problem.track == p], rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize('seed', [0, 1])
def test_the_adjustment_undoes_pose_noise(seed: int) -> None:
    """Recorded poses off by 1 deg / 2 cm, points triangulated off by 2 cm: the adjustment brings the reprojection
    from pixels to a small fraction of a pixel, and the views' rotations relative to one another (free of the gauge
    the priors choose) back to the truth."""
    exact, _, X = _ring(seed=seed)
    rng = np.random.default_rng(seed + 10)
    V = exact.n_views
    noise = np.c_[rng.normal(scale=np.deg2rad(1.0), size=(V, 3)), rng.normal(scale=0.02, size=(V, 3))]
    R_noisy = exact.R0 @ Rotation.from_rotvec(noise[:, :3]).as_matrix()
    problem = BundleProblem(R_noisy, exact.t0 + noise[:, 3:], exact.K, exact.track, exact.view, exact.uv, SIGMA)
    X0 = X + rng.normal(scale=0.02, size=X.shape)
    before = np.median(np.linalg.norm(project_with_jacobians(problem, np.zeros((V, 6)), X0, False)[0], axis=1))
    correction, X1 = adjust(problem, np.zeros((V, 6)), X0, np.ones(len(exact.view)), 100)
    after = np.median(np.linalg.norm(project_with_jacobians(problem, correction, X1, False)[0], axis=1))
    assert before > 5.0 and after < 0.03 * before, (before, after)

    def relative_error_deg(R: np.ndarray) -> float:
        i, j = np.triu_indices(V, 1)
        relative = np.transpose(R[i], (0, 2, 1)) @ R[j]
        true = np.transpose(exact.R0[i], (0, 2, 1)) @ exact.R0[j]
        return float(np.median(np.degrees(Rotation.from_matrix(np.transpose(true, (0, 2, 1)) @ relative).magnitude())))

    fixed = R_noisy @ Rotation.from_rotvec(correction[:, :3]).as_matrix()
    # a compact cloud seen from 3 m trades a rotation for a translation; the priors split the two: 1.9 -> 0.3 deg
    assert relative_error_deg(R_noisy) > 1.0 and relative_error_deg(fixed) < 0.3 * relative_error_deg(R_noisy), (
        relative_error_deg(R_noisy), relative_error_deg(fixed))


def test_the_minimum_is_the_one_a_general_solver_finds() -> None:
    """The same objective (weighted reprojection plus the priors) minimised by scipy's least_squares with a
    finite-difference Jacobian: the same cost and the same corrections."""
    exact, _, X = _ring(views=6, points=25, seed=3)
    rng = np.random.default_rng(4)
    V, M = exact.n_views, len(exact.view)
    noise = np.c_[rng.normal(scale=np.deg2rad(1.0), size=(V, 3)), rng.normal(scale=0.02, size=(V, 3))]
    uv = exact.uv + rng.normal(scale=0.5, size=exact.uv.shape)                  # pixel noise: a non-zero minimum
    problem = BundleProblem(exact.R0 @ Rotation.from_rotvec(noise[:, :3]).as_matrix(), exact.t0 + noise[:, 3:],
                            exact.K, exact.track, exact.view, uv, SIGMA)
    weight = rng.uniform(0.5, 1.0, M)
    X0 = X + rng.normal(scale=0.01, size=X.shape)

    def residuals(x: np.ndarray) -> np.ndarray:
        c, points = x[:6 * V].reshape(V, 6), x[6 * V:].reshape(-1, 3)
        error = project_with_jacobians(problem, c, points, False)[0]
        return np.r_[(weight[:, None] * error).ravel(), (c / SIGMA).ravel()]

    reference = least_squares(residuals, np.r_[np.zeros(6 * V), X0.ravel()], xtol=1e-12, ftol=1e-12, gtol=1e-12)
    correction, X1 = adjust(problem, np.zeros((V, 6)), X0, weight, 200, tolerance=1e-12)
    cost = float((residuals(np.r_[correction.ravel(), X1.ravel()]) ** 2).sum())
    assert cost == pytest.approx(2.0 * reference.cost, rel=1e-6)             # least_squares reports half the sum
    np.testing.assert_allclose(correction, reference.x[:6 * V].reshape(V, 6), atol=1e-5)


def test_a_start_with_a_point_behind_a_camera_is_returned_unchanged() -> None:
    problem, correction, X = _ring(views=4, points=6)
    weight = np.ones(len(problem.view))
    behind = X.copy()
    behind[0] = problem.t0[0] + 0.5 * problem.R0[0][:, 2]                     # behind view 0 (it looks along -z)
    assert not project_with_jacobians(problem, correction, behind, False)[1].all()
    # from such a start no finite cost exists: the adjustment returns what it was given
    same_c, same_x = adjust(problem, correction, behind, weight, 10)
    np.testing.assert_array_equal(same_x, behind)
    np.testing.assert_array_equal(same_c, correction)


def test_a_view_no_track_reaches_keeps_its_recorded_pose() -> None:
    exact, _, X = _ring(views=6, points=30, seed=5)
    rng = np.random.default_rng(6)
    keep = exact.view != 2                                                     # view 2 sees nothing
    problem = BundleProblem(exact.R0, exact.t0 + rng.normal(scale=0.01, size=exact.t0.shape), exact.K,
                            exact.track[keep], exact.view[keep], exact.uv[keep], SIGMA)
    correction, X1 = adjust(problem, np.zeros((6, 6)), X, np.ones(int(keep.sum())), 50)
    after = np.linalg.norm(project_with_jacobians(problem, correction, X1, False)[0], axis=1)
    assert np.all(np.isfinite(correction)) and np.abs(correction[2]).max() < 1e-9
    assert np.abs(correction[[0, 1, 3, 4, 5]]).max() > 1e-4 and np.median(after) < 0.1
