"""Blobs of an instance mask: centroid, area, box, size; mask warping, IoU and the two-stage assignment."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.tracking.association import MaskTemplate, assign, mask_ious, warp_mask
from fruitnerfpp_ros.core.tracking.detections import detect_blobs
from fruitnerfpp_ros.errors import DatasetError


def _mask() -> np.ndarray:
    mask = np.zeros((20, 30), np.uint16)
    mask[2:6, 3:7] = 40     # a 4x4 square
    mask[10:12, 20:29] = 7  # a 9x2 bar
    mask[15, 0] = 7         # a second piece of id 7: still the same detection
    return mask


def test_blob_statistics() -> None:
    blobs = detect_blobs(_mask())
    assert len(blobs) == 2 and blobs.ids.tolist() == [7, 40]
    np.testing.assert_allclose(blobs.areas_px, [19, 16])
    np.testing.assert_allclose(blobs.centroids_px[1], [5.0, 4.0])  # pixel centres, top-left corner at 0, 0
    assert blobs.boxes_px.tolist() == [[0, 10, 29, 16], [3, 2, 7, 6]]
    np.testing.assert_allclose(blobs.equivalent_diameters_px[1], np.sqrt(64 / np.pi))
    assert blobs.sizes_px[1] == pytest.approx(np.sqrt(64 / np.pi))  # a square's disc is wider than its side
    assert blobs.crop(1).all() and blobs.crop(1).shape == (4, 4)
    assert blobs.labels[3, 4] == 2 and blobs.labels[0, 0] == 0


def test_masks_without_background_or_blobs() -> None:
    full = detect_blobs(np.full((4, 5), 3, np.int32))
    assert full.ids.tolist() == [3] and full.areas_px.tolist() == [20] and full.labels.min() == 1
    empty = detect_blobs(np.zeros((4, 5), np.int32))
    assert len(empty) == 0 and empty.centroids_px.shape == (0, 2) and empty.boxes_px.shape == (0, 4)
    with pytest.raises(DatasetError, match='2D integer'):
        detect_blobs(np.zeros((4, 5), np.float32))


def test_warped_mask_moves_and_scales() -> None:
    blobs = detect_blobs(_mask())
    template = MaskTemplate.from_detection(blobs, 1)  # the 4x4 square centred at (5, 4)
    rows, cols = warp_mask(template, np.array([15.0, 8.0]), 1.0, (20, 30))
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (6, 9, 13, 16)
    rows, cols = warp_mask(template, np.array([15.0, 8.0]), 2.0, (20, 30))
    assert len(rows) == 64 and (rows.min(), cols.min()) == (4, 11)  # twice the size, no holes
    rows, cols = warp_mask(template, np.array([-1.0, 8.0]), 1.0, (20, 30))
    assert cols.min() == 0 and len(rows) == 4  # clipped at the image edge
    assert len(warp_mask(template, np.array([100.0, 8.0]), 1.0, (20, 30))[0]) == 0


def test_mask_iou_against_every_detection() -> None:
    blobs = detect_blobs(_mask())
    rows, cols = np.mgrid[2:6, 5:9]  # the square shifted right by 2: 8 of 16 pixels overlap
    np.testing.assert_allclose(mask_ious(rows.ravel(), cols.ravel(), blobs), [0.0, 8 / 24])


def test_two_stage_assignment() -> None:
    ious = np.array([[0.6, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    distances = np.array([[0.2, 0.9, 5.0], [0.3, 0.5, 5.0], [5.0, 5.0, 5.0]])
    result = assign(ious, distances, distances <= 1.0, iou_threshold=0.3)
    # track 0 wins detection 0 by IoU; track 1 falls back on detection 1 by distance; track 2 and detection 2 stay
    assert result.pairs.tolist() == [[0, 0], [1, 1]] and result.by_iou.tolist() == [True, False]
    assert result.unmatched_tracks.tolist() == [2] and result.unmatched_detections.tolist() == [2]
    gated_off = assign(ious, distances, np.zeros_like(ious, bool), iou_threshold=0.3)
    assert len(gated_off.pairs) == 0 and gated_off.unmatched_detections.tolist() == [0, 1, 2]
    empty = assign(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), bool), iou_threshold=0.3)
    assert empty.pairs.shape == (0, 2) and empty.unmatched_detections.tolist() == [0, 1]
