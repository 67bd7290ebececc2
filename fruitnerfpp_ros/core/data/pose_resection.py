"""Held-out views posed on the aligned training views' feature tracks (a resection per view).

The pose alignment (:mod:`pose_alignment`) corrects the training views only: the held-out views must not shape the
tracks the training poses are adjusted on. Left at their recorded poses, though, they are rendered from where the
odometry put them, and their PSNR, semantic IoU and instance accuracy measure the odometry's error as much as the
fields (a mango row with 1.8 cm / 0.7 deg of noise: held-out IoU 0.15). As a NeRF benchmark poses its test views
with the same structure from motion as its training views, each held-out view is posed here on the adjusted
tracks, with the training views' poses and the tracks' points held fixed:

1. each track projected with the view's recorded pose and matched with the view's features near it (guided
   matching: the track described by its observation in the nearest training view; ratio test, mutual nearest),
   each match a 2D-3D correspondence;
2. the bundle adjustment's problem for this one view with the points held (:mod:`bundle_adjustment`'s
   projection and Jacobians): Cauchy-weighted reprojection errors, the same Gaussian prior on the correction,
   reweighted rounds from the recorded pose;
3. kept when it brings more of the matches within two Cauchy scales than the recorded pose does; otherwise the
   view keeps its recorded pose.

Nothing here reaches the fields: the held-out views still train nothing.
"""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.data.bundle_adjustment import BundleProblem, project, project_with_jacobians

__all__ = ['resect_views']

#: Levenberg-Marquardt steps per round at most (a 6 x 6 system: a few suffice).
_STEPS = 30


def resect_views(held: np.ndarray, features: list, T: np.ndarray, K: np.ndarray, observations: tuple,
                 points: np.ndarray, *, radius_px: float, ratio: float, min_inliers: int, sigma: np.ndarray,
                 robust_px: float, rounds: int) -> tuple[np.ndarray, dict]:
    """Pose corrections [len(held), 6] (rotation in the camera frame, translation in the world; zeros where a view
    keeps its recorded pose) of the views ``held`` on the training views' tracks.

    Args:
        held: view indices into ``features``, ``T`` and ``K``.
        features: per view, keypoints [N, 2] (pixels) and SIFT descriptors [N, 128] (or None).
        T: [V, 4, 4] camera-to-world poses (OpenGL camera axes): the held-out views' recorded ones, the training
            views' corrected ones.
        K: [V, 4] fx, fy, cx, cy.
        observations: the tracks' observations (track [M], view [M] dataset index, feature [M] index into its
            view's keypoints).
        points: [P, 3] the tracks' points in the frame the corrected training views live in.
        radius_px: a track is matched with the features within this distance of where the recorded pose projects
            it (guided matching: the recorded poses are off by a few pixels, not by the image).
        ratio: Lowe's ratio test among the tracks within the radius.
        min_inliers: matches a view needs to be posed.
        sigma: [6] the prior's standard deviations of a correction (rad x 3, m x 3), as the bundle adjustment's.
        robust_px: Cauchy scale of the reprojection errors (px).
        rounds: reweighted solves.
    """
    track, view, feature = (np.asarray(a, np.int64) for a in observations)
    descriptors = np.zeros((len(track), 128), np.float32)
    for v in np.unique(view):
        descriptors[view == v] = features[v][1][feature[view == v]]
    centre, axis = T[:, :3, 3], -T[:, :3, 2]
    correction = np.zeros((len(held), 6))
    before, after = [], []
    for row, h in enumerate(held):
        keys, query = features[h]
        if query is None or len(keys) < min_inliers:
            continue
        # each track described by its observation in the training view nearest to this one
        distance = np.linalg.norm(centre[view] - centre[h], axis=1)
        distance[axis[view] @ axis[h] < 0.5] = np.inf
        order = np.lexsort((distance, track))
        _, first = np.unique(track[order], return_index=True)
        nearest = order[first][np.isfinite(distance[order[first]])]
        pairs = _guided_matches(keys, query, points[track[nearest]], descriptors[nearest], T[h], K[h], radius_px,
                                ratio)
        if len(pairs) < min_inliers:
            continue
        solved = _solve(keys[pairs[:, 0]], points[track[nearest][pairs[:, 1]]], T[h], K[h], sigma, robust_px,
                        rounds, 2.0 * robust_px)
        if solved is None:
            continue
        correction[row], error_before, error_after = solved
        before.append(error_before)
        after.append(error_after)
    report = {'views': len(held), 'posed': len(after),
              'reprojection_px_before': round(float(np.median(before)), 3) if before else None,
              'reprojection_px_after': round(float(np.median(after)), 3) if after else None}
    return correction, report


def _guided_matches(keys: np.ndarray, query: np.ndarray, X: np.ndarray, described: np.ndarray, T: np.ndarray,
                    k: np.ndarray, radius_px: float, ratio: float) -> np.ndarray:
    """[M, 2] (feature, candidate) pairs: each feature's nearest descriptor among the candidates ``X`` [P, 3]
    that the pose ``T`` projects within ``radius_px`` of it, passing the ratio test against the second nearest
    there, and the candidate's nearest feature in turn."""
    uv, _, in_front = project(T[None, :3, :3], T[None, :3, 3], k[None], X, np.zeros(len(X), np.int64))
    # the candidates in front of the camera and within the radius of the features' extent only: [N, P] arrays
    candidates = np.flatnonzero(in_front & np.all(uv >= keys.min(0) - radius_px, axis=1)
                                & np.all(uv <= keys.max(0) + radius_px, axis=1))
    if len(candidates) < 2:
        return np.zeros((0, 2), np.int64)
    uv, described = uv[candidates].astype(np.float32), described[candidates]
    near = np.linalg.norm(keys.astype(np.float32)[:, None, :] - uv[None], axis=-1) < radius_px
    q = query.astype(np.float32)
    d2 = (q * q).sum(1)[:, None] + (described * described).sum(1)[None] - 2.0 * q @ described.T
    d = np.where(near, np.sqrt(np.maximum(d2, 0.0)), np.float32(np.inf))
    two = np.partition(d, 1, axis=1)[:, :2]
    best = np.argmin(d, axis=1)
    rows = np.arange(len(d))
    mutual = np.argmin(d, axis=0)[best] == rows
    keep = np.isfinite(two[:, 0]) & (two[:, 0] < ratio * two[:, 1]) & mutual
    return np.stack([rows[keep], candidates[best[keep]]], 1)


def _solve(uv: np.ndarray, X: np.ndarray, T: np.ndarray, k: np.ndarray, sigma: np.ndarray, robust_px: float,
           rounds: int, inlier_px: float) -> tuple[np.ndarray, float, float] | None:
    """(correction [6], median reprojection of the matches within ``inlier_px`` from the recorded pose, from the
    solved one), or None when the solved pose brings no more of the matches within ``inlier_px``.

    The bundle adjustment's problem for one view with its points held: the reprojection errors, Cauchy-weighted
    (scale ``robust_px``, the weights of each round from the last one's errors, the first from the recorded
    pose's), plus the Gaussian prior ``sigma`` [6] on the correction; Levenberg-Marquardt on its 6 x 6 system.
    """
    problem = BundleProblem(T[None, :3, :3], T[None, :3, 3], k[None], np.arange(len(X)), np.zeros(len(X), np.int64),
                            uv, sigma)
    prior = 1.0 / sigma ** 2

    def errors(c: np.ndarray) -> np.ndarray:
        e, in_front, _, _ = project_with_jacobians(problem, c[None], X, jacobians=False)
        return np.where(in_front, np.linalg.norm(e, axis=1), np.inf)

    def cost(c: np.ndarray, error: np.ndarray, w: np.ndarray) -> float:
        """The weighted squared reprojections and the prior; inf where a weighted match went behind the camera."""
        if not np.isfinite(error[w > 0]).all():
            return np.inf
        return float((w[w > 0] * error[w > 0] ** 2).sum() + (prior * c ** 2).sum())

    c = np.zeros(6)
    first = error = errors(c)
    for _ in range(rounds):
        w = np.where(np.isfinite(error), 1.0 / (1.0 + (error / robust_px) ** 2), 0.0)
        current, damping, system = cost(c, error, w), 1e-3, None
        for _ in range(_STEPS):
            if system is None:  # the normal equations at c (again only once a step was taken)
                e, in_front, J, _ = project_with_jacobians(problem, c[None], X)
                wf, e = np.where(in_front, w, 0.0), np.where(in_front[:, None], e, 0.0)
                system = (np.einsum('m,mki,mkj->ij', wf, J, J) + np.diag(prior),
                          np.einsum('m,mki,mk->i', wf, J, e) + prior * c)
            A, b = system
            step = -np.linalg.solve(A + damping * np.diag(np.diag(A)), b)
            trial_error = errors(c + step)
            trial = cost(c + step, trial_error, w)
            if trial < current:
                c, error, current, system, damping = c + step, trial_error, trial, None, damping * 0.3
                if np.abs(step).max() < 1e-9:
                    break
            else:
                damping *= 10.0
                if damping > 1e6:
                    break
    held_before, held_after = first < inlier_px, error < inlier_px
    if held_after.sum() <= held_before.sum():
        return None
    return c, float(np.median(first[held_after])), float(np.median(error[held_after]))
