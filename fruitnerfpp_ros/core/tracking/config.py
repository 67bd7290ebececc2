"""Configuration of the tracking-by-detection fruit counter (``fruitnerfpp track``, the accuracy benchmark's peer)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['TrackConfig']


@dataclass(frozen=True)
class TrackConfig:
    """How instance masks are tracked from frame to frame and turned into a count (SORT / ByteTrack style).

    Each track holds a 3D point (metres, world frame): started on the first blob's centroid ray at a prior depth
    (the blob's size-depth for a fruit of ``fruit_diameter_m``, fused with the scene depth once known), then
    triangulated by weighted least squares over the rays of all its detections, the priors together weighing as one
    detection. Every frame, each live track's point is projected with the new pose, its last mask is moved there and
    scaled by the depth ratio, and tracks and blobs are associated with the Hungarian algorithm: first by mask IoU,
    then the leftovers by Mahalanobis distance, both within a gate on (u, v, ln depth). A fruit is counted once per
    track with at least ``min_hits`` detections.
    """

    fruit_diameter_m: float = 0.075
    """Prior fruit diameter (m): a blob of s pixels lies at the size-depth focal * diameter / s (m); apples of
    the synthetic generator are 6.2-8.2 cm wide."""

    max_age: int = 8
    """Frames a track survives without a matched detection (ByteTrack's track buffer); then it ends."""

    min_hits: int = 3
    """Detections a track needs to be counted (SORT's default; 1 counts every blob that started a track)."""

    min_area_px: int = 4
    """Blobs smaller than this (pixels) never start a track and have no size-depth: like ByteTrack's low-score
    detections they can only extend a track (a few-pixel sliver of a hidden fruit says nothing about its size)."""

    iou_threshold: float = 0.1
    """First stage: a track and a detection can be paired when the warped mask and the detection's mask overlap
    by at least this IoU."""

    gate_sigmas: float = 3.0
    """Gate of both stages, in standard deviations: a blob can only be paired with a track when the Mahalanobis
    distance between its (centroid u, v, ln depth prior) and the track's projection is below this. The covariance
    is the track point's carried through the projection (a young track's uncertain depth stretches the gate along
    the epipolar line) plus the blob's centroid noise and depth prior's variance."""

    centroid_sigma_rel: float = 0.25
    """Standard deviation of a blob's centroid about the fruit's projected centre, as a fraction of the fruit's size
    in pixels (a leaf or a neighbour hiding part of a fruit moves it); added to ``ray_sigma_px``."""

    ray_sigma_px: float = 1.0
    """Standard deviation (pixels) of a blob centroid on top of ``centroid_sigma_rel`` (pixel quantisation); the
    two weight the rays in the triangulation and widen the gate."""

    depth_sigma_rel: float = 0.3
    """Relative standard deviation of a blob's size-depth (the fruit's true size, partial occlusion)."""

    scene_depth_tracks: int = 3
    """Once this many confirmed live tracks have a depth known from parallax (standard deviation below
    ``depth_sigma_rel``), their median depth in the new view (spread: their scatter) is fused with every blob's
    size-depth: a fragment of a hidden fruit looks small, hence far, and would start a track metres behind the
    tree. 0 disables (size-depth only)."""

    frame_order: Literal['time', 'file'] = 'time'
    """``time``: frames sorted by ``stamp_ns`` when every frame has one (else file order); ``file``: the order of
    transforms.json."""

    def __post_init__(self) -> None:
        checks = [
            (self.fruit_diameter_m > 0, 'fruit_diameter_m must be > 0'),
            (self.max_age >= 0, 'max_age must be >= 0'),
            (self.min_hits >= 1, 'min_hits must be >= 1'),
            (self.min_area_px >= 1, 'min_area_px must be >= 1'),
            (0.0 < self.iou_threshold <= 1.0, 'iou_threshold must be in (0, 1]'),
            (self.gate_sigmas > 0, 'gate_sigmas must be > 0'),
            (self.centroid_sigma_rel >= 0, 'centroid_sigma_rel must be >= 0'),
            (self.ray_sigma_px > 0, 'ray_sigma_px must be > 0'),
            (self.depth_sigma_rel > 0, 'depth_sigma_rel must be > 0'),
            (self.scene_depth_tracks >= 0, 'scene_depth_tracks must be >= 0'),
            (self.frame_order in ('time', 'file'), "frame_order must be 'time' or 'file'"),
        ]
        for ok, message in checks:
            if not ok:
                raise ConfigError(f'TrackConfig: {message}')
