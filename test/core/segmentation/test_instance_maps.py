"""Masks -> one instance map (shared by the TorchScript and SAM adapters), relabelling, solidity."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.segmentation.instance_maps import (instance_map_from_masks, mask_solidity,
                                                             relabel_sequential)
from fruitnerfpp_ros.errors import SegmentationError


def test_relabel_sequential_keeps_order_and_drops_small() -> None:
    labels = np.array([[0, 7, 7, 3], [0, 7, 9, 3], [5, 0, 0, 0]])
    out = relabel_sequential(labels, min_area_px=2)
    assert out.dtype == np.uint16
    assert out.tolist() == [[0, 2, 2, 1], [0, 2, 0, 1], [0, 0, 0, 0]]
    with pytest.raises(SegmentationError, match='>= 0'):
        relabel_sequential(np.array([[-1]]))


def test_higher_score_wins_overlaps_and_thresholds_apply() -> None:
    masks = np.zeros((3, 6, 8), np.float32)
    masks[0, 0:4, 0:4] = 0.9   # score 0.6
    masks[1, 2:6, 2:6] = 0.8   # score 0.9: wins the overlap 2:4, 2:4
    masks[2, 0:2, 6:8] = 0.4   # below mask_threshold everywhere: empty
    ids = instance_map_from_masks(masks, np.array([0.6, 0.9, 0.99]), mask_threshold=0.5, score_threshold=0.5)
    assert ids.dtype == np.uint16 and ids.shape == (6, 8)
    assert ids[3, 3] == 1 and ids[0, 0] == 2 and ids[5, 5] == 1  # best score gets id 1
    assert np.array_equal(np.unique(ids), [0, 1, 2])
    dropped = instance_map_from_masks(masks, np.array([0.6, 0.4, 0.99]), score_threshold=0.5)
    assert np.array_equal(np.unique(dropped), [0, 1]) and dropped[5, 5] == 0


def test_logits_and_min_area() -> None:
    logits = np.full((2, 5, 5), -5.0, np.float32)
    logits[0, :2, :2] = 4.0
    logits[1, 4, 4] = 4.0           # one pixel: below min_area_px
    ids = instance_map_from_masks(logits, logits=True, min_area_px=2)
    assert ids.sum() == 4 and ids.max() == 1
    assert instance_map_from_masks(np.zeros((0, 5, 5))).shape == (5, 5)


def test_malformed_masks_are_refused() -> None:
    with pytest.raises(SegmentationError, match=r'\[N, H, W\]'):
        instance_map_from_masks(np.zeros((5, 5)))
    with pytest.raises(SegmentationError, match='2 masks but 3 scores'):
        instance_map_from_masks(np.zeros((2, 5, 5)), np.ones(3))
    with pytest.raises(SegmentationError, match='not finite'):
        instance_map_from_masks(np.full((1, 2, 2), np.nan))


def test_solidity_of_a_disc_and_an_l_shape() -> None:
    yy, xx = np.mgrid[:40, :40]
    disc = (xx - 20) ** 2 + (yy - 20) ** 2 <= 12 ** 2
    ell = np.zeros((40, 40), bool)
    ell[5:35, 5:9] = True
    ell[31:35, 5:35] = True
    assert mask_solidity(disc) > 0.9
    assert mask_solidity(ell) < 0.5
    assert mask_solidity(np.zeros((4, 4), bool)) == 0.0
