"""Per-frame detections: one blob per instance id of a mask, with centroid, area, box and size in pixels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from fruitnerfpp_ros.errors import DatasetError

__all__ = ['FrameDetections', 'detect_blobs']


@dataclass(frozen=True)
class FrameDetections:
    """The instance blobs of one frame (pixel coordinates with the top-left image corner at 0, 0).

    Attributes:
        labels: [H, W] int32 compact blob labels, 0 = background, k + 1 = blob k.
        ids: [N] the blobs' instance ids in the mask (per-image labels: they mean nothing in other frames).
        centroids_px: [N, 2] mean (u, v) of the blob's pixel centres.
        areas_px: [N] pixel counts.
        boxes_px: [N, 4] int (u0, v0, u1, v1), the half-open pixel box ``[u0, u1) x [v0, v1)``.
    """

    labels: np.ndarray
    ids: np.ndarray
    centroids_px: np.ndarray
    areas_px: np.ndarray
    boxes_px: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def equivalent_diameters_px(self) -> np.ndarray:
        """[N] diameter (pixels) of the disc with the blob's area."""
        return np.sqrt(4.0 * self.areas_px / np.pi)

    @property
    def sizes_px(self) -> np.ndarray:
        """[N] apparent fruit size in pixels: the larger of the equivalent diameter and the box's longer side (a
        fruit partly hidden by a leaf often keeps its full width in one direction)."""
        box_side = np.maximum(self.boxes_px[:, 2] - self.boxes_px[:, 0], self.boxes_px[:, 3] - self.boxes_px[:, 1])
        return np.maximum(self.equivalent_diameters_px, box_side.astype(np.float64))

    def crop(self, k: int) -> np.ndarray:
        """[h, w] bool mask of blob ``k`` inside its box."""
        u0, v0, u1, v1 = (int(v) for v in self.boxes_px[k])
        return self.labels[v0:v1, u0:u1] == k + 1


def detect_blobs(instance_mask: np.ndarray, *, source: str = 'instance mask') -> FrameDetections:
    """Blobs of an instance-id mask: every non-zero id is one detection (even when split in several pieces, as a
    segmenter reports a fruit behind a leaf).

    Args:
        instance_mask: [H, W] integer ids, 0 = background.
        source: names the mask in errors.

    Raises:
        DatasetError: the mask is not a 2D integer array.
    """
    mask = np.asarray(instance_mask)
    if mask.ndim != 2 or not np.issubdtype(mask.dtype, np.integer):
        raise DatasetError(f'{source}: expected a 2D integer instance-id mask, got {mask.dtype} {mask.shape}')
    ids, inverse = np.unique(mask, return_inverse=True)
    labels = inverse.reshape(mask.shape).astype(np.int32)
    if ids[0] == 0:
        ids = ids[1:]
    else:  # no background pixel: every label shifts up by one
        labels += 1
    n = len(ids)
    flat = labels.ravel()
    rows, cols = np.divmod(np.arange(flat.size), mask.shape[1])
    areas = np.bincount(flat, minlength=n + 1)[1:].astype(np.float64)
    with np.errstate(invalid='ignore', divide='ignore'):
        u = np.bincount(flat, weights=cols + 0.5, minlength=n + 1)[1:] / areas
        v = np.bincount(flat, weights=rows + 0.5, minlength=n + 1)[1:] / areas
    slices = ndimage.find_objects(labels, max_label=n)
    boxes = np.array([[s[1].start, s[0].start, s[1].stop, s[0].stop] for s in slices], np.int64).reshape(-1, 4)
    return FrameDetections(labels, ids.astype(np.int64), np.stack([u, v], axis=1).reshape(-1, 2), areas, boxes)
