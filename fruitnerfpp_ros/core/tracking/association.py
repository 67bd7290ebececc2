"""Track-to-detection association: warped-mask IoU, centroid gates and a two-stage Hungarian assignment."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from fruitnerfpp_ros.core.tracking.detections import FrameDetections

__all__ = ['MaskTemplate', 'warp_mask', 'mask_ious', 'Assignment', 'assign']

_FORBIDDEN = 1e6


@dataclass(frozen=True)
class MaskTemplate:
    """A track's last mask, to be moved to where the track is predicted.

    Attributes:
        crop: [h, w] bool mask inside its box.
        anchor_px: [2] (u, v) of the blob's centroid relative to the crop's top-left corner, pixels.
    """

    crop: np.ndarray
    anchor_px: np.ndarray

    @classmethod
    def from_detection(cls, detections: FrameDetections, k: int) -> 'MaskTemplate':
        """The template of blob ``k``."""
        return cls(detections.crop(k), detections.centroids_px[k] - detections.boxes_px[k, :2])


def warp_mask(template: MaskTemplate, center_px: np.ndarray, scale: float, shape: tuple[int, int],
              ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of a mask moved so that its centroid lands on ``center_px`` and scaled by ``scale`` about it.

    Each pixel of the predicted box samples the template at its back-mapped position (nearest neighbour), so an
    enlarged mask has no holes.

    Args:
        template: the mask to move.
        center_px: [2] (u, v) predicted centroid, pixels.
        scale: size ratio, new / old (the old depth over the new depth).
        shape: (H, W) of the image; pixels outside it are dropped.

    Returns:
        (rows, cols) int arrays of the predicted mask's pixels inside the image.
    """
    h, w = template.crop.shape
    scale = float(np.clip(scale, 0.1, 10.0))
    lo = np.floor(center_px - scale * template.anchor_px).astype(int)
    hi = np.ceil(center_px + scale * (np.array([w, h]) - template.anchor_px)).astype(int)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [shape[1], shape[0]])
    if np.any(hi <= lo):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    cols, rows = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]))
    src_u = np.floor(template.anchor_px[0] + (cols + 0.5 - center_px[0]) / scale).astype(int)
    src_v = np.floor(template.anchor_px[1] + (rows + 0.5 - center_px[1]) / scale).astype(int)
    inside = (src_u >= 0) & (src_u < w) & (src_v >= 0) & (src_v < h)
    keep = np.zeros_like(inside)
    keep[inside] = template.crop[src_v[inside], src_u[inside]]
    return rows[keep], cols[keep]


def mask_ious(rows: np.ndarray, cols: np.ndarray, detections: FrameDetections) -> np.ndarray:
    """[N] IoU of a predicted mask (its pixel rows and cols) with every detection's mask."""
    n = len(detections)
    if len(rows) == 0 or n == 0:
        return np.zeros(n)
    inter = np.bincount(detections.labels[rows, cols], minlength=n + 1)[1:].astype(np.float64)
    return inter / (len(rows) + detections.areas_px - inter)


@dataclass(frozen=True)
class Assignment:
    """The outcome of one frame's association.

    Attributes:
        pairs: [M, 2] int (track index, detection index).
        by_iou: [M] bool, True for the pairs made in the first (mask IoU) stage.
        unmatched_tracks: track indices left without a detection.
        unmatched_detections: detection indices left without a track.
    """

    pairs: np.ndarray
    by_iou: np.ndarray
    unmatched_tracks: np.ndarray
    unmatched_detections: np.ndarray


def _hungarian(cost: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    if not allowed.any():
        return np.zeros((0, 2), np.int64)
    rows, cols = linear_sum_assignment(np.where(allowed, cost, _FORBIDDEN))
    keep = allowed[rows, cols]
    return np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)


def assign(ious: np.ndarray, distances: np.ndarray, gated: np.ndarray, *, iou_threshold: float) -> Assignment:
    """Two-stage Hungarian assignment (ByteTrack style).

    Stage 1 pairs tracks and detections by mask IoU (cost 1 - IoU, pairs below ``iou_threshold`` forbidden);
    stage 2 pairs what is left by centroid distance. Both stages only pair what the gates allow.

    Args:
        ious: [T, D] warped-mask IoU of each live track with each detection.
        distances: [T, D] centroid distance between the projected track and the detection, in gate radii
            (a pair is within reach below 1).
        gated: [T, D] bool, pairs allowed by the gates (centroid reach, depth ratio, track in view).
        iou_threshold: smallest IoU of a first-stage pair.
    """
    n_tracks, n_dets = ious.shape
    first = _hungarian(1.0 - ious, gated & (ious >= iou_threshold))
    free_t = np.setdiff1d(np.arange(n_tracks), first[:, 0])
    free_d = np.setdiff1d(np.arange(n_dets), first[:, 1])
    sub = np.ix_(free_t, free_d)
    second = _hungarian(distances[sub], gated[sub] & (distances[sub] <= 1.0))
    second = np.stack([free_t[second[:, 0]], free_d[second[:, 1]]], axis=1).reshape(-1, 2)
    pairs = np.concatenate([first, second]).astype(np.int64)
    by_iou = np.r_[np.ones(len(first), bool), np.zeros(len(second), bool)]
    return Assignment(pairs, by_iou, np.setdiff1d(np.arange(n_tracks), pairs[:, 0]),
                      np.setdiff1d(np.arange(n_dets), pairs[:, 1]))
