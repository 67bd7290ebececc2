"""Bundle adjustment of per-view pose corrections and track points: Levenberg-Marquardt on the reduced camera system.

The problem of :mod:`pose_alignment`: per view a correction c = (w, d) of its recorded pose (a rotation vector w in
the camera's frame, R = R0 Exp(w); a translation d in the world's, t = t0 + d) with a Gaussian prior c / sigma, and
per feature track a world point X; each observation's residual is its reprojection error (px) times its weight.

Each Levenberg-Marquardt step solves the normal equations with the points eliminated (the Schur complement, as
Ceres and COLMAP solve bundle adjustments): the points' 3 x 3 blocks are inverted independently, the 6V x 6V
reduced camera system is solved sparse, and the points follow by back-substitution. The Jacobians are analytic (the
projection's, and the rotation's through the right Jacobian of SO(3)), so a step costs a few array passes over the
observations instead of a finite-difference Jacobian and an iterative solve.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, csr_matrix
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

__all__ = ['BundleProblem', 'adjust', 'project', 'project_with_jacobians']

#: Pairs of observations of one track per chunk of the reduced system's assembly (bounds its memory).
_PAIR_CHUNK = 1 << 18
#: A camera-space depth below this (m) makes a step invalid (the point went behind the camera).
_MIN_DEPTH_M = 1e-6


@dataclass(frozen=True)
class BundleProblem:
    """The fixed data of an adjustment.

    Attributes:
        R0, t0: [V, 3, 3], [V, 3] recorded camera-to-world rotations and positions (OpenGL camera axes).
        K: [V, 4] fx, fy, cx, cy (px).
        track, view: [M] the track and the view of each observation; uv: [M, 2] its pixel.
        sigma: [6] prior standard deviations of a correction (rad x 3, m x 3).
    """

    R0: np.ndarray
    t0: np.ndarray
    K: np.ndarray
    track: np.ndarray
    view: np.ndarray
    uv: np.ndarray
    sigma: np.ndarray

    @property
    def n_views(self) -> int:
        return len(self.R0)

    @functools.cached_property
    def structure(self) -> _Structure:
        """The reduced system's index arrays, built once for all the adjustments of this problem."""
        return _Structure(self)


def _skew(v: np.ndarray) -> np.ndarray:
    """[N, 3, 3] cross-product matrices of [N, 3] vectors."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def _right_jacobian(w: np.ndarray) -> np.ndarray:
    """[N, 3, 3] right Jacobians of SO(3) at rotation vectors [N, 3]: Exp(w + e) = Exp(w) Exp(J_r(w) e) to first
    order."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - np.cos(safe)) / safe ** 2)
    b = np.where(small, 1.0 / 6.0 - theta ** 2 / 120.0, (safe - np.sin(safe)) / safe ** 3)
    W = _skew(w)
    return np.eye(3)[None] - a[:, None, None] * W + b[:, None, None] * (W @ W)


def project(R: np.ndarray, t: np.ndarray, K: np.ndarray, X: np.ndarray, view: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels [N, 2] of world points ``X`` [N, 3] in views ``view`` (camera-to-world ``R`` [V, 3, 3], ``t`` [V, 3],
    ``K`` [V, 4] fx, fy, cx, cy; OpenGL camera axes), their camera coordinates [N, 3] and whether each lies in front
    of its camera (the pixels of the others are meaningless)."""
    p = np.einsum('nji,nj->ni', R[view], X - t[view])              # camera coordinates (looking along -z)
    z = -p[:, 2]
    in_front = z > _MIN_DEPTH_M
    zs = np.where(in_front, z, 1.0)
    k = K[view]
    return np.stack([k[:, 0] * p[:, 0] / zs + k[:, 2], -k[:, 1] * p[:, 1] / zs + k[:, 3]], 1), p, in_front


def project_with_jacobians(problem: BundleProblem, correction: np.ndarray, X: np.ndarray, jacobians: bool = True
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Reprojection of every observation under ``correction`` [V, 6] and points ``X`` [P, 3].

    Returns (uv_error [M, 2] = projected - observed, px; in_front [M] bool; d uv / d correction [M, 2, 6];
    d uv / d X [M, 2, 3]); the Jacobians are None without ``jacobians``.
    """
    view = problem.view
    w = correction[:, :3]
    R = problem.R0 @ Rotation.from_rotvec(w).as_matrix()
    uv, p, in_front = project(R, problem.t0 + correction[:, 3:], problem.K, X[problem.track], view)
    error = uv - problem.uv
    if not jacobians:
        return error, in_front, None, None
    k, zs = problem.K[view], np.where(in_front, -p[:, 2], 1.0)
    du_dp = np.zeros((len(p), 2, 3))
    du_dp[:, 0, 0] = k[:, 0] / zs
    du_dp[:, 0, 2] = k[:, 0] * p[:, 0] / zs ** 2
    du_dp[:, 1, 1] = -k[:, 1] / zs
    du_dp[:, 1, 2] = -k[:, 1] * p[:, 1] / zs ** 2
    Rt = np.transpose(R[view], (0, 2, 1))
    dp_dw = _skew(p) @ _right_jacobian(w)[view]                      # p = Exp(w)^T R0^T (X - t)
    J_c = np.concatenate([du_dp @ dp_dw, -(du_dp @ Rt)], axis=2)
    J_x = du_dp @ Rt
    return error, in_front, J_c, J_x


def _cost(problem: BundleProblem, correction: np.ndarray, X: np.ndarray, weight: np.ndarray) -> float:
    error, in_front, _, _ = project_with_jacobians(problem, correction, X, jacobians=False)
    if not in_front[weight > 0].all():
        return np.inf
    return float(((weight[:, None] * error) ** 2).sum() + ((correction / problem.sigma) ** 2).sum())


class _Structure:
    """Index arrays of the reduced camera system, fixed for a problem: sums of per-observation terms per view and per
    point (sparse indicator matrices), the pairs of observations of one track with the view-pair block each adds
    to, and the 6 x 6 blocks' places in the 6V x 6V system (the views' own blocks, then the pairs')."""

    def __init__(self, problem: BundleProblem) -> None:
        track, view, V = problem.track, problem.view, problem.n_views
        M = len(track)
        counts = np.bincount(track)
        self.n_points = len(counts)
        self.by_view = csr_matrix((np.ones(M), (view, np.arange(M))), shape=(V, M))
        self.by_track = csr_matrix((np.ones(M), (track, np.arange(M))), shape=(self.n_points, M))
        order = np.argsort(track, kind='stable')
        start = np.r_[0, np.cumsum(counts)[:-1]]
        n = counts[track]
        self.first = np.repeat(np.arange(M), n)                             # observation k of each pair
        offset = np.arange(len(self.first)) - np.repeat(np.cumsum(n) - n, n)
        self.second = order[start[track[self.first]] + offset]              # observation l, same track
        keys = view[self.first].astype(np.int64) * V + view[self.second]
        blocks, block_of_pair = np.unique(keys, return_inverse=True)
        self.by_block = csc_matrix((np.ones(len(keys)), (block_of_pair, np.arange(len(keys)))),
                                   shape=(len(blocks), len(keys)))
        a, b = np.r_[np.arange(V), blocks // V], np.r_[np.arange(V), blocks % V]
        i6 = np.arange(6)
        self.rows = (6 * a[:, None, None] + i6[None, :, None]).repeat(6, axis=2).ravel()
        self.cols = (6 * b[:, None, None] + i6[None, None, :]).repeat(6, axis=1).ravel()


def _step(problem: BundleProblem, e: np.ndarray, J_c: np.ndarray, J_x: np.ndarray, correction: np.ndarray,
          damping: float) -> tuple[np.ndarray, np.ndarray]:
    """One damped Gauss-Newton step (d correction [V, 6], d X [P, 3]) from weighted residuals and Jacobians."""
    structure = problem.structure
    V, P = problem.n_views, structure.n_points
    view, track = problem.view, problem.track
    inv_var = 1.0 / problem.sigma ** 2
    M = len(view)
    U = (structure.by_view @ np.einsum('nki,nkj->nij', J_c, J_c).reshape(M, 36)).reshape(V, 6, 6)
    U[:, np.arange(6), np.arange(6)] += inv_var
    g_c = structure.by_view @ np.einsum('nki,nk->ni', J_c, e) + correction * inv_var
    Vp = (structure.by_track @ np.einsum('nki,nkj->nij', J_x, J_x).reshape(M, 9)).reshape(P, 3, 3)
    g_x = structure.by_track @ np.einsum('nki,nk->ni', J_x, e)
    W = np.einsum('nki,nkj->nij', J_c, J_x)                                  # [M, 6, 3]
    i6, i3 = np.arange(6), np.arange(3)
    U[:, i6, i6] *= 1.0 + damping
    Vp[:, i3, i3] = Vp[:, i3, i3] * (1.0 + damping) + 1e-9
    V_inv = np.linalg.inv(Vp)
    Y = W @ V_inv[track]                                                      # [M, 6, 3]
    blocks = np.zeros((structure.by_block.shape[0], 36))
    for lo in range(0, len(structure.first), _PAIR_CHUNK):
        k, m = structure.first[lo:lo + _PAIR_CHUNK], structure.second[lo:lo + _PAIR_CHUNK]
        blocks -= structure.by_block[:, lo:lo + _PAIR_CHUNK] @ (Y[k] @ np.transpose(W[m], (0, 2, 1))).reshape(-1, 36)
    S = coo_matrix((np.r_[U.ravel(), blocks.ravel()], (structure.rows, structure.cols)),  # duplicates add up
                   shape=(6 * V, 6 * V)).tocsc()
    rhs = -g_c + structure.by_view @ np.einsum('nij,nj->ni', Y, g_x[track])
    d_c = np.asarray(spsolve(S, rhs.ravel())).reshape(V, 6)
    back = structure.by_track @ np.einsum('nji,nj->ni', W, d_c[view])
    d_x = np.einsum('pij,pj->pi', V_inv, -g_x - back)
    return d_c, d_x


def adjust(problem: BundleProblem, correction: np.ndarray, X: np.ndarray, weight: np.ndarray,
           max_iterations: int, *, tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Minimise the weighted reprojection error plus the priors from ``correction`` [V, 6] and ``X`` [P, 3] with
    observation weights ``weight`` [M]; returns the adjusted (correction, X).

    Levenberg-Marquardt (Marquardt's diagonal damping): at most ``max_iterations`` cost evaluations, stopped when a
    step lowers the cost by less than ``tolerance`` of it.
    """
    cost = _cost(problem, correction, X, weight)
    damping, evaluations = 1e-4, 0
    e = J_c = J_x = None
    while evaluations < max_iterations and np.isfinite(cost):
        if e is None:
            error, _, J_c, J_x = project_with_jacobians(problem, correction, X)
            e = weight[:, None] * error
            J_c, J_x = weight[:, None, None] * J_c, weight[:, None, None] * J_x
        d_c, d_x = _step(problem, e, J_c, J_x, correction, damping)
        trial_c, trial_x = correction + d_c, X + d_x
        trial = _cost(problem, trial_c, trial_x, weight)
        evaluations += 1
        if trial < cost:
            done = cost - trial < tolerance * cost
            correction, X, cost = trial_c, trial_x, trial
            damping, e = max(damping / 3.0, 1e-10), None
            if done:
                break
        else:
            damping *= 10.0
            if damping > 1e8:
                break
    return correction, X
