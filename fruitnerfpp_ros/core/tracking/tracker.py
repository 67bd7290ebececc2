"""Multi-object tracking of instance blobs with a pose-driven 3D motion model (SORT / ByteTrack style counting).

Per frame (:meth:`FruitTracker.update`): project every live track's 3D point with the new pose, move its last mask
there (scaled by the depth ratio), associate tracks and blobs with the Hungarian algorithm by mask IoU and then by
Mahalanobis distance on (u, v, ln depth), extend the matched tracks and re-triangulate them, age the others (ended
after ``max_age`` missed frames) and start a track for every unmatched blob large enough. A blob's depth prior is
its size-depth, fused with the scene depth (the confirmed tracks' depths in the view) once that is known.
:meth:`FruitTracker.result` counts each track with at least ``min_hits`` detections once.

Known weakness (shared by every tracking counter): a track that loses its fruit for more than ``max_age`` frames
ends, and the fruit starts a new one when it reappears. A fruit seen from both sides of a row is counted twice
when the robot needs more than ``max_age`` frames to come back along the other side (a turn at the row's end).
Occlusion is not modelled either: a track whose fruit hides behind another may take over that fruit's blobs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fruitnerfpp_ros.core.tracking.association import MaskTemplate, assign, mask_ious, warp_mask
from fruitnerfpp_ros.core.tracking.camera import PinholeView, triangulate
from fruitnerfpp_ros.core.tracking.config import TrackConfig
from fruitnerfpp_ros.core.tracking.detections import FrameDetections
from fruitnerfpp_ros.core.tracking.result import TrackCount, TrackedFruit

__all__ = ['FruitTracker']


@dataclass
class _Track:
    """A track's detections (rays with their weights) and its current state."""

    track_id: int
    origins: list[np.ndarray] = field(default_factory=list)
    directions: list[np.ndarray] = field(default_factory=list)
    prior_ranges: list[float] = field(default_factory=list)
    perp_weights: list[float] = field(default_factory=list)
    prior_weights: list[float] = field(default_factory=list)
    sizes_m_per_depth: list[float] = field(default_factory=list)
    optical_axes: list[np.ndarray] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    covariance: np.ndarray = field(default_factory=lambda: np.eye(3))
    parallax_information: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    diameter_m: float = 0.0
    last_view: PinholeView | None = None
    template: MaskTemplate | None = None
    misses: int = 0

    @property
    def hits(self) -> int:
        return len(self.frames)

    def parallax_depth_sd(self, axis: np.ndarray) -> float:
        """Standard deviation (m) of the point along the unit vector ``axis`` from the rays' crossing alone,
        without the depth priors (inf while the rays do not pin it down)."""
        eigenvalues, eigenvectors = np.linalg.eigh(self.parallax_information)
        along = (eigenvectors.T @ axis) ** 2
        if np.any((eigenvalues <= 1e-9 * max(eigenvalues[-1], 1e-300)) & (along > 1e-12)):
            return float('inf')
        return float(np.sqrt(np.sum(along / np.maximum(eigenvalues, 1e-300))))

    def refine(self) -> None:
        """Re-triangulate the point from all rays; the diameter is the median over the detections of blob size
        x depth / focal length (m), with the depths of the new point."""
        origins = np.array(self.origins)
        # the depth priors share their errors (the fruit's true size, the scene's depth): together they weigh as
        # much as one detection's, however many there are
        prior_weights = np.array(self.prior_weights) / len(self.prior_weights)
        self.point, information = triangulate(origins, np.array(self.directions), np.array(self.prior_ranges),
                                              np.array(self.perp_weights), prior_weights)
        try:
            self.covariance = np.linalg.inv(information)
        except np.linalg.LinAlgError:
            self.covariance = np.eye(3)
        directions = np.array(self.directions)
        perp = np.eye(3) - directions[:, :, None] * directions[:, None, :]
        self.parallax_information = np.einsum('m,mij->ij', np.array(self.perp_weights), perp)
        depths = np.einsum('mi,mi->m', np.array(self.optical_axes), self.point - origins)
        self.diameter_m = float(np.median(np.array(self.sizes_m_per_depth) * np.maximum(depths, 0.0)))


@dataclass(frozen=True)
class _DepthPriors:
    """Per detection of a frame: natural log of its depth (m) and the standard deviation of that log (inf: the
    blob says nothing about its depth)."""

    log_depth: np.ndarray
    sigma: np.ndarray


@dataclass(frozen=True)
class _Prediction:
    """Where a live track is expected in the new frame: the pixel position and log depth of its point with their
    [3, 3] covariance (the point's covariance carried through the projection plus a blob centroid's noise), its
    size in pixels and its warped mask."""

    center_px: np.ndarray
    covariance: np.ndarray
    depth_m: float
    size_px: float
    rows: np.ndarray
    cols: np.ndarray


class FruitTracker:
    """Tracks fruit blobs through a sequence of posed frames and counts the confirmed tracks.

    Args:
        config: tracking settings.
    """

    def __init__(self, config: TrackConfig | None = None) -> None:
        self.config = config or TrackConfig()
        self._tracks: list[_Track] = []
        self._live: list[_Track] = []
        self._n_frames = 0
        self._stats = {'detections': 0, 'matched_by_iou': 0, 'matched_by_distance': 0, 'ended': 0,
                       'frames_with_scene_depth': 0}

    @property
    def n_live(self) -> int:
        """Tracks still alive (matched within the last ``max_age`` frames)."""
        return len(self._live)

    def update(self, frame_index: int, view: PinholeView, detections: FrameDetections) -> None:
        """Process one frame.

        Args:
            frame_index: the frame's index in the dataset (kept as first/last frame of its tracks).
            view: its camera.
            detections: its blobs.
        """
        cfg = self.config
        self._n_frames += 1
        self._stats['detections'] += len(detections)
        priors = self._depth_priors(view, detections)
        predictions = [self._predict(track, view, detections.labels.shape) for track in self._live]
        ious, distances = self._costs(predictions, detections, priors)
        result = assign(ious, distances, distances <= 1.0, iou_threshold=cfg.iou_threshold)
        for (t, k), by_iou in zip(result.pairs, result.by_iou):
            prediction = predictions[t]
            assert prediction is not None  # a gated pair has a prediction
            self._add_detection(self._live[t], frame_index, view, detections, int(k), priors, prediction.depth_m)
            self._stats['matched_by_iou' if by_iou else 'matched_by_distance'] += 1
        for t in result.unmatched_tracks:
            self._live[t].misses += 1
        live = [t for t in self._live if t.misses <= cfg.max_age]
        self._stats['ended'] += len(self._live) - len(live)
        self._live = live
        starts = result.unmatched_detections[detections.areas_px[result.unmatched_detections] >= cfg.min_area_px]
        for k in starts:
            track = _Track(len(self._tracks) + 1)
            self._add_detection(track, frame_index, view, detections, int(k), priors, None)
            self._tracks.append(track)
            self._live.append(track)

    def result(self) -> TrackCount:
        """The count so far: one fruit per track with at least ``min_hits`` detections."""
        counted = [t for t in self._tracks if t.hits >= self.config.min_hits]
        fruits = [TrackedFruit(i + 1, t.point.copy(), t.diameter_m, t.hits, t.frames[0], t.frames[-1])
                  for i, t in enumerate(counted)]
        return TrackCount(fruits, len(self._tracks), self._n_frames, dict(self._stats, live=len(self._live)))

    def _scene_depth(self, view: PinholeView) -> tuple[float, float] | None:
        """(median, spread) of the log depths (m) in ``view`` of the confirmed live tracks whose depth the rays'
        parallax alone knows to ``depth_sigma_rel``; None when fewer than ``scene_depth_tracks`` are in front of the
        camera."""
        cfg = self.config
        if cfg.scene_depth_tracks == 0:
            return None
        known = [t for t in self._live if t.hits >= cfg.min_hits]
        if len(known) < cfg.scene_depth_tracks:
            return None
        points = np.array([t.point for t in known])
        axis = -view.T_world_camera[:3, 2]
        depths = (points - view.origin) @ axis
        depth_sd = np.array([t.parallax_depth_sd(axis) for t in known])
        good = (depths > 0) & (depth_sd < cfg.depth_sigma_rel * np.maximum(depths, 0.0))
        if good.sum() < cfg.scene_depth_tracks:
            return None
        log_depths = np.log(depths[good])
        median = float(np.median(log_depths))
        spread = 1.4826 * float(np.median(np.abs(log_depths - median)))
        return median, max(spread, 0.1)

    def _depth_priors(self, view: PinholeView, detections: FrameDetections) -> _DepthPriors:
        """Each blob's depth from its size (blobs of at least ``min_area_px``), fused with the depth of the scene
        (the confirmed tracks) when known: a fragment of a hidden fruit looks small, hence far."""
        cfg = self.config
        log_size = np.log(cfg.fruit_diameter_m * view.focal_px / np.maximum(detections.sizes_px, 1e-6))
        weight = np.where(detections.areas_px >= cfg.min_area_px, cfg.depth_sigma_rel ** -2, 0.0)
        scene = self._scene_depth(view)
        if scene is None:
            with np.errstate(divide='ignore'):
                return _DepthPriors(log_size, 1.0 / np.sqrt(weight))
        self._stats['frames_with_scene_depth'] += 1
        scene_weight = scene[1] ** -2
        total = weight + scene_weight
        return _DepthPriors((weight * log_size + scene_weight * scene[0]) / total, 1.0 / np.sqrt(total))

    def _predict(self, track: _Track, view: PinholeView, shape: tuple[int, int]) -> _Prediction | None:
        cfg = self.config
        uv, depth = view.project(track.point)
        if not depth[0] > 0:
            return None
        size_px = view.focal_px * track.diameter_m / depth[0]
        H = np.vstack([view.jacobian(track.point), -view.T_world_camera[:3, 2] / depth[0]])  # d(u, v, ln z)/dp
        sigma_px = cfg.ray_sigma_px + cfg.centroid_sigma_rel * size_px
        covariance = H @ track.covariance @ H.T + np.diag([sigma_px ** 2, sigma_px ** 2, 0.0])
        reach = 0.5 * size_px + cfg.gate_sigmas * float(np.sqrt(covariance[0, 0] + covariance[1, 1]))
        u, v = uv[0]
        if not (-reach <= u <= shape[1] + reach and -reach <= v <= shape[0] + reach):
            return None
        assert track.template is not None and track.last_view is not None
        last_depth = float(track.last_view.project(track.point)[1][0])
        rows, cols = warp_mask(track.template, uv[0], last_depth / depth[0] if last_depth > 0 else 1.0, shape)
        return _Prediction(uv[0], covariance, float(depth[0]), float(size_px), rows, cols)

    def _costs(self, predictions: list[_Prediction | None], detections: FrameDetections, priors: _DepthPriors,
               ) -> tuple[np.ndarray, np.ndarray]:
        """[T, D] IoU and Mahalanobis distance in gate radii (``gate_sigmas``: 1 is the gate's edge, inf for a
        track out of view) of every (live track, detection) pair.

        The distance compares the blob's (u, v, ln depth prior) with the track's projection; a blob without a
        depth prior is compared in (u, v) only.
        """
        n_t, n_d = len(predictions), len(detections)
        ious, distances = np.zeros((n_t, n_d)), np.full((n_t, n_d), np.inf)
        has_depth = np.isfinite(priors.sigma)
        for t, pred in enumerate(predictions):
            if pred is None:
                continue
            ious[t] = mask_ious(pred.rows, pred.cols, detections)
            residual = np.column_stack([detections.centroids_px - pred.center_px,
                                        np.where(has_depth, priors.log_depth - np.log(pred.depth_m), 0.0)])
            S = np.repeat(pred.covariance[None], n_d, axis=0)
            S[:, 2, 2] += np.where(has_depth, priors.sigma, 0.0) ** 2
            S[~has_depth, 2, :] = S[~has_depth, :, 2] = 0.0  # (u, v) marginal
            S[~has_depth, 2, 2] = 1.0
            d2 = np.einsum('di,di->d', residual, np.linalg.solve(S, residual[:, :, None])[:, :, 0])
            distances[t] = np.sqrt(np.maximum(d2, 0.0)) / self.config.gate_sigmas
        return ious, distances

    def _add_detection(self, track: _Track, frame_index: int, view: PinholeView, detections: FrameDetections,
                       k: int, priors: _DepthPriors, predicted_depth: float | None) -> None:
        """Append blob ``k`` to ``track`` and re-triangulate. ``predicted_depth`` (m): the track's depth in this
        view (None for a new track, whose depth comes from the prior)."""
        cfg = self.config
        size_px = float(detections.sizes_px[k])
        direction, range_per_depth = view.rays(detections.centroids_px[k:k + 1])
        prior_range = float(np.exp(priors.log_depth[k]) * range_per_depth[0])
        weight_range = prior_range if predicted_depth is None else predicted_depth * float(range_per_depth[0])
        sigma_px = cfg.ray_sigma_px + cfg.centroid_sigma_rel * size_px
        track.origins.append(view.origin)
        track.directions.append(direction[0])
        track.prior_ranges.append(prior_range)
        track.perp_weights.append((view.focal_px / (sigma_px * weight_range)) ** 2)
        track.prior_weights.append(float((priors.sigma[k] * prior_range) ** -2))
        track.sizes_m_per_depth.append(size_px / view.focal_px)
        track.optical_axes.append(-view.T_world_camera[:3, 2])
        track.frames.append(frame_index)
        track.last_view = view
        track.template = MaskTemplate.from_detection(detections, k)
        track.misses = 0
        track.refine()
