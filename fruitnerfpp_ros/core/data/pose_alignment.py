"""Align the recorded camera poses to the images before training: feature tracks and a bundle adjustment.

Robot odometry is off by centimetres and a degree or so per frame; the photometric pose refinement of the geometry
stage (``geometry.pose_lr``) undoes part of it, from a field that is itself blurred by the error. This step runs
first, from the images alone, as a robot integrator would run COLMAP with pose priors:

1. SIFT features per view (OpenCV; small images are upsampled so that a 240 px frame still gives features);
2. each view matched with its nearest views that look the same way (ratio test, then a fundamental matrix with
   RANSAC against outliers);
3. matches joined into tracks (connected components; a track that holds two features of one view is dropped);
4. each track triangulated from the recorded poses (the rays' least-squares point), tracks that do not reproject
   within ``max_track_error_px`` dropped;
5. a bundle adjustment (:mod:`bundle_adjustment`: Levenberg-Marquardt on the reduced camera system, analytic
   Jacobians) of a 6-vector per view, the same correction :class:`PoseRefinement` learns (a rotation in the camera's
   frame, a translation in the world's), and the track points, with a Gaussian prior on each correction
   (``prior_rotation_deg``, ``prior_translation_m``) that holds the gauge and the views the tracks do not reach;
   ``rounds`` adjustments, each weighing the observations by a Cauchy weight of the last one's reprojection error;
6. the held-out views, left out of steps 2-5, posed on the adjusted tracks (:mod:`pose_resection`).

The result initialises the geometry stage's pose corrections (``core/training/model.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.data.bundle_adjustment import BundleProblem, adjust, project, project_with_jacobians
from fruitnerfpp_ros.core.data.pose_resection import resect_views
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['PoseAlignmentConfig', 'PoseAlignment', 'align_poses']


@dataclass(frozen=True)
class PoseAlignmentConfig:
    """Feature-based pose alignment before training (see the module docstring)."""

    enabled: bool = False
    """Run the alignment; off keeps the recorded poses as the geometry stage's starting point."""
    max_features: int = 2000
    """SIFT features per view at most."""
    upsample_below_px: int = 480
    """Views narrower than this are upsampled 2x for the feature detector (a 240 px frame gives few features)."""
    contrast_threshold: float = 0.01
    """SIFT's contrast threshold (OpenCV's default 0.04 finds few features on foliage at low resolution)."""
    neighbours: int = 8
    """Each view is matched with this many nearest views whose optical axes are within 60 deg of its own."""
    check_neighbours: int = 2
    """The gate's first look matches each view with this many only; when that already shows the recorded poses
    agreeing with the images (``skip_below_px``, ``min_tracks``), the full matching is skipped."""
    ratio: float = 0.8
    """Lowe's ratio test."""
    ransac_px: float = 1.0
    """Epipolar distance (px) for the fundamental matrix's RANSAC."""
    min_inliers: int = 15
    """A view pair with fewer geometric inliers is left out."""
    max_track_error_px: float = 12.0
    """A track whose worst reprojection from the recorded poses is larger is left out (a wrong match)."""
    min_tracks: int = 200
    """With fewer tracks the recorded poses are kept (too little to adjust them by)."""
    skip_below_px: float = 0.5
    """The recorded poses are kept when the tracks' median reprojection from them is below this (px): they agree
    with the images already, and an adjustment would only add its own error (on exact poses about 1 px)."""
    prior_rotation_deg: float = 0.5
    """Standard deviation of the prior on a view's rotation correction (deg)."""
    prior_translation_m: float = 0.02
    """Standard deviation of the prior on a view's translation correction (m)."""
    robust_px: float = 2.0
    """Cauchy scale of the reprojection residuals (px)."""
    max_evaluations: int = 200
    """Steps of the bundle adjustment at most (per round; it stops earlier when a step gains under 1e-6 of the
    cost: about 20 steps a round on a noisy 48-view row)."""
    rounds: int = 3
    """Adjustments; each weighs the observations by a Cauchy weight of the last one's reprojection error (a wrong
    match fades out, the priors stay Gaussian)."""

    def __post_init__(self) -> None:
        if self.min_tracks < 1 or self.rounds < 1 or not 1 <= self.check_neighbours <= self.neighbours:
            raise ConfigError('pose_alignment: min_tracks and rounds must be >= 1, and 1 <= check_neighbours <= '
                              'neighbours')


@dataclass(frozen=True)
class PoseAlignment:
    """The alignment's outcome.

    Attributes:
        correction: [V, 6] float64 per view: rotation (axis times angle, rad, camera frame), translation (m, world).
        report: figures for ``pose_alignment.json`` (features, pairs, tracks, reprojection before / after, and the
            held-out views' ``held_out``: views, posed, their reprojection before / after).
    """

    correction: np.ndarray
    report: dict
    tracks: _Tracks | None = None
    """The tracks adjusted on (views numbered among the aligned ones), None when it kept the recorded poses."""
    points: np.ndarray | None = None
    """[P, 3] the tracks' adjusted points, None when it kept the recorded poses."""


def align_poses(images: np.ndarray, intrinsics: np.ndarray, T_world_camera: np.ndarray,
                config: PoseAlignmentConfig, valid: np.ndarray | None = None,
                held_out: np.ndarray | None = None) -> PoseAlignment:
    """Pose corrections that make the views' feature tracks meet.

    Args:
        images: [V, H, W, 3] uint8 RGB.
        intrinsics: [V, 4] (fl_x, fl_y, cx, cy), pixels.
        T_world_camera: [V, 4, 4] camera-to-world poses, OpenGL camera axes, metres.
        config: the alignment's settings.
        valid: optional [V, H, W] bool, False where a pixel holds no data (no features there).
        held_out: optional [V] bool, the views left out of the tracks and the adjustment and posed on them
            afterwards (:mod:`pose_resection`; the report's ``held_out``); their correction is zero where that
            fails.
    """
    T_all = np.asarray(T_world_camera, np.float64)
    K_all = np.asarray(intrinsics, np.float64)
    held = np.zeros(len(T_all), bool) if held_out is None else np.asarray(held_out, bool)
    train = np.flatnonzero(~held)
    features_all: list = [None] * len(T_all)

    def describe(views: np.ndarray) -> None:
        for v in views:
            features_all[v] = _features(images[v], None if valid is None else valid[v], config)

    describe(train)
    result = _align(features_all, train, T_all, K_all, config)
    if not result.report.get('applied') or not held.any():
        return result
    describe(np.flatnonzero(held))  # only once the training views were corrected: most datasets stop before
    correction, X = result.correction, result.points
    posed = T_all.copy()
    posed[train, :3, :3] = T_all[train, :3, :3] @ Rotation.from_rotvec(correction[train, :3]).as_matrix()
    posed[train, :3, 3] += correction[train, 3:]
    held_views = np.flatnonzero(held)
    tracks = result.tracks
    correction[held_views], figures = resect_views(
        held_views, features_all, posed, K_all, (tracks.track, train[tracks.view], tracks.feature), X,
        radius_px=2.0 * config.max_track_error_px, ratio=config.ratio, min_inliers=config.min_inliers,
        sigma=_prior_sigma(config), robust_px=config.robust_px, rounds=config.rounds)
    return PoseAlignment(correction, {**result.report, 'held_out': figures})


def _align(features_all: list, train: np.ndarray, T_all: np.ndarray, K_all: np.ndarray, config: PoseAlignmentConfig
           ) -> PoseAlignment:
    """The alignment of the views ``train`` (corrections [V, 6] of every view, zero outside ``train``)."""
    features = [features_all[v] for v in train]
    T, K = T_all[train], K_all[train]
    # The check first, on each view's nearest neighbours only (a quarter of the matching): most datasets stop here.
    tracks = _measured_tracks(features, T, K, config, config.check_neighbours)
    # with all neighbours, about neighbours / check_neighbours times the tracks: too few is too few there as well
    enough = len(tracks.points) * config.neighbours >= config.min_tracks * config.check_neighbours
    if enough and not tracks.agree(config) and config.check_neighbours < config.neighbours:
        tracks = _measured_tracks(features, T, K, config, config.neighbours)
    reason = ('the recorded poses agree with the images' if tracks.agree(config) else
              f'fewer than {config.min_tracks} tracks' if len(tracks.points) < config.min_tracks else None)
    if reason is not None:
        return PoseAlignment(np.zeros((len(T_all), 6)), {**tracks.report, 'applied': False, 'reason': reason})
    report = dict(tracks.report)
    track, view, uv, X = tracks.track, tracks.view, tracks.uv, tracks.points
    correction, X, after = _bundle_adjust(T, K, X, track, view, uv, config)
    angles = np.rad2deg(np.linalg.norm(correction[:, :3], axis=1))
    report.update(applied=True, reprojection_px_after=round(float(np.median(after)), 3),
                  max_rotation_deg=round(float(angles.max()), 4),
                  max_translation_m=round(float(np.linalg.norm(correction[:, 3:], axis=1).max()), 5))
    out = np.zeros((len(T_all), 6))
    out[train] = correction
    return PoseAlignment(out, report, tracks, X)


@dataclass(frozen=True)
class _Tracks:
    """Observations of the feature tracks that reproject within ``max_track_error_px`` from the recorded poses."""

    track: np.ndarray
    """[M] track id of each observation (0..P-1)."""
    view: np.ndarray
    """[M] view of each observation."""
    uv: np.ndarray
    """[M, 2] pixel of each observation."""
    feature: np.ndarray
    """[M] each observation's feature, an index into its view's keypoints."""
    points: np.ndarray
    """[P, 3] each track's point, triangulated from the recorded poses."""
    report: dict
    """View pairs, tracks, observations, ``reprojection_px_before`` (median; None without tracks)."""

    def agree(self, config: PoseAlignmentConfig) -> bool:
        """Enough tracks, and the recorded poses reproject them within ``skip_below_px``."""
        before = self.report['reprojection_px_before']
        return len(self.points) >= max(config.min_tracks, 1) and before < config.skip_below_px


def _measured_tracks(features: list, T: np.ndarray, K: np.ndarray, config: PoseAlignmentConfig,
                     neighbours: int) -> _Tracks:
    """The tracks of the matches with each view's ``neighbours`` nearest views."""
    edges, pairs = _matches(features, T, config, neighbours)
    report = {'views': len(T), 'features_median': int(np.median([len(k) for k, _ in features])) if len(T) else 0,
              'pairs': pairs, 'tracks': 0, 'observations': 0, 'reprojection_px_before': None}
    if len(edges) == 0:
        empty = np.zeros(0, np.int64)
        return _Tracks(empty, empty, np.zeros((0, 2)), empty, np.zeros((0, 3)), report)
    view_of, points_px = _observations(features)
    track, view, uv, node = _tracks(edges, view_of, points_px, len(T))
    X = _triangulate(T, K, track, view, uv)
    projected, _, in_front = project(T[:, :3, :3], T[:, :3, 3], K, X[track], view)
    error = np.where(in_front, np.linalg.norm(projected - uv, axis=1), np.inf)
    worst = np.zeros(len(X))
    np.maximum.at(worst, track, error)
    keep = (worst < config.max_track_error_px)[track]
    kept_tracks, track = np.unique(track[keep], return_inverse=True)
    report.update(tracks=len(kept_tracks), observations=int(keep.sum()),
                  reprojection_px_before=round(float(np.median(error[keep])), 3) if keep.any() else None)
    return _Tracks(track, view[keep], uv[keep], (node - _first_features(features)[view])[keep], X[kept_tracks],
                   report)


def _features(image: np.ndarray, valid: np.ndarray | None, config: PoseAlignmentConfig
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Keypoints [N, 2] (pixels of the original image) and SIFT descriptors [N, 128] of one view."""
    gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    mask = None if valid is None else np.ascontiguousarray(valid, np.uint8) * 255
    factor = 2.0 if gray.shape[1] < config.upsample_below_px else 1.0
    if factor != 1.0:
        gray = cv2.resize(gray, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)
        mask = None if mask is None else cv2.resize(mask, None, fx=factor, fy=factor,
                                                    interpolation=cv2.INTER_NEAREST)
    sift = cv2.SIFT_create(nfeatures=config.max_features, contrastThreshold=config.contrast_threshold)
    keypoints, descriptors = sift.detectAndCompute(gray, mask)
    points = np.array([k.pt for k in keypoints], np.float64).reshape(-1, 2)
    return (points + 0.5) / factor - 0.5, descriptors


def _neighbours(T: np.ndarray, count: int) -> list[tuple[int, int]]:
    """View pairs (i < j): each view's ``count`` nearest views whose optical axes are within 60 deg."""
    centre, axis = T[:, :3, 3], -T[:, :3, 2]
    distance = np.linalg.norm(centre[:, None] - centre[None], axis=-1)
    distance[axis @ axis.T < 0.5] = np.inf
    np.fill_diagonal(distance, np.inf)
    nearest = np.argsort(distance, axis=1)[:, :count]
    pairs = {(min(i, j), max(i, j)) for i, row in enumerate(nearest) for j in row if np.isfinite(distance[i, j])}
    return sorted(pairs)


def _matches(features: list, T: np.ndarray, config: PoseAlignmentConfig, neighbours: int
             ) -> tuple[np.ndarray, int]:
    """Geometrically verified matches as pairs of global feature indices [M, 2], and the number of view pairs."""
    offsets = _first_features(features)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    edges, pairs = [], 0
    for i, j in _neighbours(T, neighbours):
        (ki, di), (kj, dj) = features[i], features[j]
        if di is None or dj is None or len(ki) < 2 or len(kj) < 2:
            continue
        knn = matcher.knnMatch(di, dj, k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < config.ratio * m[1].distance]
        if len(good) < config.min_inliers:
            continue
        qi = np.array([m.queryIdx for m in good])
        tj = np.array([m.trainIdx for m in good])
        try:
            F, inliers = cv2.findFundamentalMat(ki[qi], kj[tj], cv2.FM_RANSAC, config.ransac_px, 0.999)
        except cv2.error:
            continue
        if F is None or inliers is None or int(inliers.sum()) < config.min_inliers:
            continue
        ok = inliers.ravel().astype(bool)
        edges.append(np.stack([offsets[i] + qi[ok], offsets[j] + tj[ok]], 1))
        pairs += 1
    return (np.concatenate(edges) if edges else np.zeros((0, 2), np.int64)), pairs


def _first_features(features: list) -> np.ndarray:
    """[V] the global index of each view's first feature (the features of all views numbered in view order)."""
    return np.cumsum([0] + [len(k) for k, _ in features])[:-1]


def _observations(features: list) -> tuple[np.ndarray, np.ndarray]:
    """The view of every feature [N] and its pixel position [N, 2]."""
    counts = [len(k) for k, _ in features]
    return np.repeat(np.arange(len(features)), counts), np.concatenate([k for k, _ in features])


def _tracks(edges: np.ndarray, view_of: np.ndarray, points_px: np.ndarray, V: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Observations (track id, view, pixel, global feature index) of the matches' connected components, one
    feature per view."""
    n = len(view_of)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    nodes = np.unique(edges)
    track, view = label[nodes], view_of[nodes]
    _, inverse, count = np.unique(track.astype(np.int64) * V + view, return_inverse=True, return_counts=True)
    ambiguous = np.unique(track[count[inverse] > 1])
    keep = ~np.isin(track, ambiguous)
    _, track = np.unique(track[keep], return_inverse=True)
    return track, view[keep], points_px[nodes][keep], nodes[keep]


def _rays(R: np.ndarray, t: np.ndarray, K: np.ndarray, view: np.ndarray, uv: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """World origins and unit directions of the pixels ``uv`` of views ``view`` (OpenGL camera axes)."""
    k = K[view]
    d = np.stack([(uv[:, 0] - k[:, 2]) / k[:, 0], -(uv[:, 1] - k[:, 3]) / k[:, 1], -np.ones(len(view))], 1)
    d = np.einsum('nij,nj->ni', R[view], d)
    return t[view], d / np.linalg.norm(d, axis=1, keepdims=True)


def _triangulate(T: np.ndarray, K: np.ndarray, track: np.ndarray, view: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Each track's point [P, 3]: the least-squares meeting point of its rays."""
    origin, d = _rays(T[:, :3, :3], T[:, :3, 3], K, view, uv)
    A = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    P = int(track.max()) + 1
    A_sum, b_sum = np.zeros((P, 3, 3)), np.zeros((P, 3))
    np.add.at(A_sum, track, A)
    np.add.at(b_sum, track, np.einsum('nij,nj->ni', A, origin))
    return np.linalg.solve(A_sum + 1e-9 * np.eye(3), b_sum[..., None])[..., 0]


def _bundle_adjust(T: np.ndarray, K: np.ndarray, X0: np.ndarray, track: np.ndarray, view: np.ndarray,
                   uv: np.ndarray, config: PoseAlignmentConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-view corrections [V, 6], the adjusted points [P, 3] and the observations' reprojection errors (px)
    after the adjustment."""
    problem = BundleProblem(T[:, :3, :3], T[:, :3, 3], K, track, view, uv, _prior_sigma(config))
    correction, X = np.zeros((len(T), 6)), X0
    weight = np.ones(len(view))
    for _ in range(config.rounds):  # iteratively reweighted: Cauchy on the reprojections, Gaussian priors
        correction, X = adjust(problem, correction, X, weight, config.max_evaluations)
        error, in_front, _, _ = project_with_jacobians(problem, correction, X, jacobians=False)
        after = np.where(in_front, np.linalg.norm(error, axis=1), np.inf)
        weight = np.sqrt(1.0 / (1.0 + (after / config.robust_px) ** 2))
    return correction, X, after


def _prior_sigma(config: PoseAlignmentConfig) -> np.ndarray:
    """[6] the prior's standard deviations of a view's correction (rad x 3, m x 3)."""
    return np.r_[np.full(3, np.deg2rad(config.prior_rotation_deg)), np.full(3, config.prior_translation_m)]
