"""Built-in, fruit-agnostic classical segmenter: the fallback when no mask topic, folder or model is available.

Fruits are compact blobs whose colour stands out from the foliage. Per image, vectorised with OpenCV / numpy:

1. **Fruit-coloured pixels.** HSV (float, hue in degrees). Saturated, not too dark pixels
   (``S >= min_saturation``, ``V >= min_value``) are either foliage or fruit; soil, bark, sky and grey surfaces
   are less saturated. The foliage is the dominant hue mode of the saturated pixels, searched in the green range
   ``foliage_hue_range_deg``; pixels outside ``mode +- foliage_hue_sigmas`` robust standard deviations are fruit
   candidates. Whatever the fruit's colour (red, purple, orange, yellow, yellow-green), only its difference from
   this image's foliage is used.
2. **Clean-up.** A morphological opening (radius scaled with the image) removes stems, twigs and pixel noise.
3. **Touching fruits.** Each blob's distance transform is split at necks: markers are its h-maxima (peaks higher
   than the saddle to a higher peak by ``split_depth_fraction`` of the blob's largest inscribed radius), grown
   back over the blob by a watershed on the inverted distance transform.
4. **Small and thin pieces** (below ``min_area_fraction`` of the image, or filling less than ``min_fill_ratio``
   of their bounding box) are dropped; ids are relabelled 1..K.

It is a fallback: green fruit on green foliage, fruit whose colour the foliage shares, and heavily occluded fruit
are missed, and a fruit seen through leaves comes out as several blobs. Measured figures on the synthetic fruit
types: README ("Instance masks") and test/core/segmentation/test_fallback.py.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from fruitnerfpp_ros.core.segmentation.config import SegmenterConfig
from fruitnerfpp_ros.core.segmentation.instance_maps import relabel_sequential
from fruitnerfpp_ros.core.segmentation.segmenter import check_rgb

__all__ = ['FallbackSegmenter', 'FoliageBand', 'hsv_from_rgb', 'foliage_hue_band', 'fruit_colour_mask',
           'split_touching']

#: Foliage (the dominant saturated hue mode) is searched in this hue range, degrees (yellow-green to cyan).
FOLIAGE_HUE_RANGE_DEG = (60.0, 180.0)
_HIST_SIGMA_DEG = 3.0
_MIN_SIDE_PIXELS = 20


class FoliageBand:
    """The hue band of the image's foliage: ``centre_deg +- half_width_deg`` (circular), from ``n_pixels``."""

    __slots__ = ('centre_deg', 'half_width_deg', 'n_pixels')

    def __init__(self, centre_deg: float, half_width_deg: float, n_pixels: int) -> None:
        self.centre_deg = centre_deg
        self.half_width_deg = half_width_deg
        self.n_pixels = n_pixels

    def __repr__(self) -> str:
        return f'FoliageBand({self.centre_deg:.1f} +- {self.half_width_deg:.1f} deg, {self.n_pixels} px)'


def hsv_from_rgb(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hue in degrees [0, 360), saturation and value in [0, 1], each [H, W] float32, of a uint8 RGB image."""
    hsv = cv2.cvtColor(rgb.astype(np.float32) * np.float32(1.0 / 255.0), cv2.COLOR_RGB2HSV)
    return hsv[..., 0], hsv[..., 1], hsv[..., 2]


def _circular_difference(a: np.ndarray, b: float) -> np.ndarray:
    """Signed hue difference ``a - b`` in (-180, 180] degrees."""
    return (a - b + 180.0) % 360.0 - 180.0


def foliage_hue_band(hue_deg: np.ndarray, config: SegmenterConfig) -> FoliageBand | None:
    """The foliage hue band from the hues of the saturated pixels (any shape); None without foliage pixels.

    The mode is the peak of a smoothed 1-degree histogram within :data:`FOLIAGE_HUE_RANGE_DEG`; its spread is a
    one-sided robust standard deviation (1.4826 x median absolute deviation) of the hues within
    ``foliage_max_half_width_deg`` of the mode, taken on the side where it is smaller (fruit colours next to the
    foliage widen one side only).
    """
    hue = np.asarray(hue_deg, dtype=np.float32).reshape(-1)
    lo, hi = FOLIAGE_HUE_RANGE_DEG
    in_range = (hue >= lo) & (hue <= hi)
    if int(in_range.sum()) < _MIN_SIDE_PIXELS:
        return None
    hist = np.bincount(np.floor(hue).astype(np.int64) % 360, minlength=360).astype(np.float64)
    offsets = np.arange(-int(4 * _HIST_SIGMA_DEG), int(4 * _HIST_SIGMA_DEG) + 1)
    kernel = np.exp(-0.5 * (offsets / _HIST_SIGMA_DEG) ** 2)
    smooth = np.convolve(np.concatenate([hist, hist, hist]), kernel, mode='same')[360:720]
    bins = np.arange(360)
    allowed = (bins + 0.5 >= lo) & (bins + 0.5 <= hi)
    centre = float(np.argmax(np.where(allowed, smooth, -1.0)) + 0.5)
    diff = _circular_difference(hue, centre)
    near = np.abs(diff) <= config.foliage_max_half_width_deg
    sides = [np.abs(diff[near & (diff < 0)]), diff[near & (diff >= 0)]]
    sigmas = [1.4826 * float(np.median(side)) for side in sides if side.size >= _MIN_SIDE_PIXELS]
    sigma = min(sigmas) if sigmas else 0.0
    half = float(np.clip(config.foliage_hue_sigmas * sigma, config.foliage_min_half_width_deg,
                         config.foliage_max_half_width_deg))
    return FoliageBand(centre, half, int(near.sum()))


def fruit_colour_mask(rgb: np.ndarray, config: SegmenterConfig = SegmenterConfig()) -> np.ndarray:
    """[H, W] bool: saturated, bright enough pixels whose hue is outside the image's foliage band."""
    hue, sat, val = hsv_from_rgb(check_rgb(rgb))
    saturated = (sat >= config.min_saturation) & (val >= config.min_value)
    band = foliage_hue_band(hue[saturated], config)
    if band is None:
        return saturated
    return saturated & (np.abs(_circular_difference(hue, band.centre_deg)) > band.half_width_deg)


def _reconstruct_by_dilation(seed: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Greyscale reconstruction of ``seed`` (<= ``mask``) under ``mask`` (8-connected), float32."""
    kernel = np.ones((3, 3), np.uint8)
    current = np.minimum(seed, mask)
    for _ in range(4 * max(mask.shape)):  # converges in about the blobs' diameter
        grown = np.minimum(cv2.dilate(current, kernel), mask)
        if np.array_equal(grown, current):
            break
        current = grown
    return current


def split_touching(mask: np.ndarray, depth_fraction: float) -> np.ndarray:
    """Connected components of the bool [H, W] ``mask``, touching blobs split at necks; [H, W] int32 labels.

    A blob's markers are the h-maxima of its distance transform with ``h = max(1 px, depth_fraction x the blob's
    largest inscribed radius)``; a watershed on the inverted distance transform grows them back over the blob.
    ``depth_fraction = 0`` returns plain 8-connected components.
    """
    mask_u8 = mask.astype(np.uint8)
    n_blobs, blobs = cv2.connectedComponents(mask_u8, connectivity=8)
    if n_blobs <= 1 or depth_fraction <= 0:
        return blobs.astype(np.int32)
    dist = cv2.distanceTransform(mask_u8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    blob_max = np.zeros(n_blobs, np.float32)
    blob_max[1:] = ndimage.maximum(dist, blobs, index=np.arange(1, n_blobs))
    radius = blob_max[blobs]
    depth = np.minimum(np.maximum(1.0, depth_fraction * radius), 0.999 * radius).astype(np.float32)
    inside = blobs > 0
    surface = np.where(inside, dist, -1.0).astype(np.float32)  # -1 outside: nothing floods across background
    rec = _reconstruct_by_dilation(np.where(inside, dist - depth, -1.0).astype(np.float32), surface)
    peaks = inside & (dist - rec >= depth - 1e-4)
    n_markers, markers = cv2.connectedComponents(peaks.astype(np.uint8), connectivity=8)
    if n_markers - 1 <= n_blobs - 1:  # one peak per blob: nothing to split
        return blobs.astype(np.int32)
    top = float(blob_max.max())
    elevation = np.round((top - np.where(inside, dist, 0.0)) * (60000.0 / max(top, 1e-6))).astype(np.uint16)
    seeds = np.where(inside, markers, -1).astype(np.int32)  # negative marker = background
    labels = ndimage.watershed_ift(elevation, seeds)
    labels = np.where(inside, labels, 0)
    # A blob whose peaks were all lost (cannot happen with depth < radius) keeps its own label.
    orphan = inside & (labels <= 0)
    if orphan.any():
        labels = np.where(orphan, blobs + n_markers, labels)
    return labels.astype(np.int32)


def _drop_thin(labels: np.ndarray, min_fill_ratio: float, max_elongation: float) -> np.ndarray:
    """Zero the labels that fill less than ``min_fill_ratio`` of their bounding box, or whose area exceeds
    ``max_elongation`` times the disc of their largest inscribed radius (twigs, stems, leaf edges)."""
    n = int(labels.max())
    if n == 0:
        return labels
    index = np.arange(1, n + 1)
    rows, cols = np.indices(labels.shape)
    area = ndimage.sum_labels(np.ones_like(labels), labels, index).astype(np.float64)
    height = ndimage.maximum(rows, labels, index) - ndimage.minimum(rows, labels, index) + 1
    width = ndimage.maximum(cols, labels, index) - ndimage.minimum(cols, labels, index) + 1
    keep = np.ones(n + 1, bool)
    keep[1:] = area >= min_fill_ratio * height * width
    if max_elongation > 0:
        # Each label's own distance transform: pixels next to another label count as its border.
        own = labels.copy()
        grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8))
        shrunk = -cv2.dilate(-labels.astype(np.float32), np.ones((3, 3), np.uint8))
        own[(grown != labels) | (shrunk != labels)] = 0
        dist = cv2.distanceTransform((own > 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        radius = ndimage.maximum(dist, labels, index) + 1.0  # + the border ring removed above
        keep[1:] &= area <= max_elongation * np.pi * radius ** 2
    return np.where(keep[labels], labels, 0)


class FallbackSegmenter:
    """The built-in fruit-agnostic colour segmenter (see the module docstring); no model, no torch."""

    method = 'fallback'
    """Recorded as the dataset's ``mask_source``."""

    def __init__(self, config: SegmenterConfig = SegmenterConfig()) -> None:
        self.config = config

    def fruit_mask(self, rgb: np.ndarray) -> np.ndarray:
        """[H, W] bool fruit pixels after the morphological clean-up (before instance splitting)."""
        rgb = check_rgb(rgb)
        mask = fruit_colour_mask(rgb, self.config).astype(np.uint8)
        radius = int(round(self.config.opening_radius_fraction * min(rgb.shape[:2])))
        if self.config.opening_radius_fraction > 0:
            radius = max(1, radius)
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
        return mask.astype(bool)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        rgb = check_rgb(rgb)
        height, width = rgb.shape[:2]
        min_area = self.config.min_area_for(height, width)
        mask = self.fruit_mask(rgb)
        mask = relabel_sequential(cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)[1], min_area) > 0
        labels = split_touching(mask, self.config.split_depth_fraction)
        labels = relabel_sequential(labels, min_area).astype(np.int32)
        return relabel_sequential(_drop_thin(labels, self.config.min_fill_ratio, self.config.max_elongation))
