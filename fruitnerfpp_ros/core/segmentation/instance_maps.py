"""Instance-id maps: from stacks of model masks (TorchScript, SAM) to one [H, W] uint16 map, and relabelling.

Shared by every segmenter, so all of them give the same output: 0 = background, 1..K contiguous, uint16.
"""

from __future__ import annotations

import cv2
import numpy as np

from fruitnerfpp_ros.errors import SegmentationError

__all__ = ['relabel_sequential', 'instance_map_from_masks', 'mask_solidity', 'MAX_INSTANCES']

#: uint16 ids: at most this many instances per image.
MAX_INSTANCES = 65535


def relabel_sequential(labels: np.ndarray, min_area_px: int = 1) -> np.ndarray:
    """Relabel a non-negative [H, W] integer map to 0 = background, 1..K contiguous (in order of the old ids),
    dropping labels with fewer than ``min_area_px`` pixels; returns uint16.

    Raises:
        SegmentationError: more than 65535 instances remain.
    """
    labels = np.asarray(labels)
    if labels.size == 0:
        return labels.astype(np.uint16)
    flat = labels.reshape(-1).astype(np.int64)
    if flat.min() < 0:
        raise SegmentationError('instance labels must be >= 0')
    old, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    keep = (old > 0) & (counts >= min_area_px)
    new = np.zeros(len(old), np.int64)
    new[keep] = np.arange(1, int(keep.sum()) + 1)
    if keep.sum() > MAX_INSTANCES:
        raise SegmentationError(f'{int(keep.sum())} instances in one image; uint16 masks hold at most {MAX_INSTANCES}')
    return new[inverse].reshape(labels.shape).astype(np.uint16)


def instance_map_from_masks(masks: np.ndarray, scores: np.ndarray | None = None, *, mask_threshold: float = 0.5,
                            score_threshold: float = 0.5, min_area_px: int = 1,
                            logits: bool = False) -> np.ndarray:
    """One [H, W] uint16 instance map from N per-instance masks.

    Args:
        masks: [N, H, W] probabilities in [0, 1], boolean masks, or logits (``logits=True``: a sigmoid is applied).
        scores: [N] confidences; None = all 1. Masks scoring below ``score_threshold`` are dropped.
        mask_threshold: a pixel belongs to a mask when its probability is >= this.
        score_threshold: see ``scores``.
        min_area_px: instances with fewer pixels (after overlaps are resolved) are dropped.
        logits: ``masks`` are logits.

    Where masks overlap, the higher-scoring mask wins (equal scores: the earlier mask). Ids are 1..K in decreasing
    score order.

    Raises:
        SegmentationError: malformed shapes or non-finite values.
    """
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise SegmentationError(f'masks must be [N, H, W], got shape {masks.shape}')
    n, height, width = masks.shape
    if scores is None:
        scores = np.ones(n, np.float32)
    scores = np.asarray(scores, dtype=np.float32).reshape(-1)
    if scores.shape != (n,):
        raise SegmentationError(f'{n} masks but {scores.shape[0]} scores')
    if not np.all(np.isfinite(scores)):
        raise SegmentationError('mask scores are not finite')
    prob = masks.astype(np.float32)
    if logits:
        prob = 1.0 / (1.0 + np.exp(-np.clip(prob, -60.0, 60.0)))
    if not np.all(np.isfinite(prob)):
        raise SegmentationError('mask values are not finite')
    keep = np.flatnonzero(scores >= score_threshold)
    if keep.size == 0:
        return np.zeros((height, width), np.uint16)
    order = keep[np.argsort(-scores[keep], kind='stable')]  # best first
    ids = np.zeros((height, width), np.int64)
    for rank in range(len(order) - 1, -1, -1):  # one vectorised write per mask, the best mask last (it wins)
        ids[prob[order[rank]] >= mask_threshold] = rank + 1
    return relabel_sequential(ids, min_area_px)


def mask_solidity(mask: np.ndarray) -> float:
    """``area / convex-hull area`` of a boolean [H, W] mask (1 for a convex blob; 0 for an empty mask)."""
    mask = np.asarray(mask, dtype=np.uint8)
    area = int(mask.sum())
    if area == 0:
        return 0.0
    points = cv2.findNonZero(mask)
    hull = cv2.convexHull(points)
    # Pixel centres: a hull of n collinear pixels has zero area; count each pixel's unit square.
    hull_area = cv2.contourArea(hull) + cv2.arcLength(hull, True) / 2.0 + 1.0
    return float(min(1.0, area / hull_area))
