"""Instances split from binary fruit masks: blobs, necks, the smallest piece, how masks are stored."""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.segmentation.config import SegmenterConfig
from fruitnerfpp_ros.core.segmentation.semantic_instances import fruit_pixels, instances_of_mask


def _disc(shape: tuple[int, int], centre: tuple[float, float], radius: float) -> np.ndarray:
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= radius ** 2


def test_blobs_are_instances_and_specks_are_dropped() -> None:
    mask = _disc((40, 60), (12, 12), 6) | _disc((40, 60), (25, 45), 7)
    mask[35, 2] = True                                   # a one-pixel speck, under min_area_px
    ids = instances_of_mask(mask)
    assert ids.dtype == np.uint16 and ids.max() == 2 and ids[35, 2] == 0
    assert {int(ids[12, 12]), int(ids[25, 45])} == {1, 2}


def test_touching_fruits_are_cut_at_their_neck() -> None:
    pair = _disc((40, 60), (20, 20), 9) | _disc((40, 60), (20, 37), 9)   # two discs overlapping by a narrow neck
    assert instances_of_mask(pair, SegmenterConfig(split_depth_fraction=0.0)).max() == 1
    cut = instances_of_mask(pair)                                                          # the default
    assert cut.max() == 2 and cut[20, 20] != cut[20, 37]


def test_fruit_pixels_as_masks_are_stored() -> None:
    jpeg_like = np.array([[0, 3, 127, 128, 255]], np.uint8)        # JPEG ringing around a 0 / 255 mask
    assert fruit_pixels(jpeg_like).tolist() == [[False, False, False, True, True]]
    assert fruit_pixels(np.array([[0, 1, 40000]], np.uint16)).tolist() == [[False, True, True]]
    colour = np.zeros((1, 3, 3), np.uint8)
    colour[0, 1] = (0, 0, 255)                                     # red on black (BGR), as annotation tools paint
    assert fruit_pixels(colour).tolist() == [[False, True, False]]
