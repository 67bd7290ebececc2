"""Instance masks as imperfect as a learned segmenter's, made from the rendered ground truth.

A robot's masks come from a network (Mask R-CNN, YOLO-seg, SAM with a prompt), not from a renderer: it misses some
fruit (hidden, small, in shadow), puts a boundary a pixel or two off, and takes a leaf or a gap in the canopy for a
fruit now and then. :func:`degrade_instances` does the three to one view's instance ids:

- **missed:** each instance is removed with probability ``missed``;
- **boundary:** each kept instance is, with equal odds, eroded, kept or dilated by ``boundary_px`` (dilation only
  into the background; an instance under ``4 (2 boundary_px + 1)^2`` pixels is never eroded away);
- **false detections:** Binomial(instances in the view, ``false_rate``) discs of the median instance's area at random
  places in the box around the view's fruit pixels, on background pixels, with new ids.

The fruit mask (``semantics/``) a segmenter writes is the union of its instances. The ground truth
(``gt_fruits.json``: which views see which fruit) stays the renderer's.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ['degrade_instances']


def degrade_instances(instance: np.ndarray, rng: np.random.Generator, *, missed: float = 0.0,
                      false_rate: float = 0.0, boundary_px: int = 0) -> np.ndarray:
    """[H, W] uint16 instance ids (0 = background) of one view, degraded as the module says; a new array."""
    labels = np.asarray(instance).astype(np.uint16, copy=True)
    ids, areas = np.unique(labels[labels > 0], return_counts=True)
    if not len(ids):
        return labels
    lut = np.zeros(int(ids.max()) + 1, np.uint16)
    kept = rng.random(len(ids)) >= missed
    lut[ids[kept]] = ids[kept]
    labels = lut[labels]
    if boundary_px > 0:
        labels = _move_boundaries(labels, ids[kept], areas[kept], rng, boundary_px)
    n_false = int(rng.binomial(len(ids), false_rate)) if false_rate > 0 else 0
    if n_false:
        labels = _false_detections(labels, np.asarray(instance) > 0, float(np.median(areas)), n_false,
                                   int(ids.max()) + 1, rng)
    return labels


def _move_boundaries(labels: np.ndarray, ids: np.ndarray, areas: np.ndarray, rng: np.random.Generator,
                     boundary_px: int) -> np.ndarray:
    """Each instance eroded, kept or dilated by ``boundary_px`` (one draw per instance)."""
    if not len(ids):
        return labels
    kernel = np.ones((2 * boundary_px + 1,) * 2, np.uint8)
    move = rng.integers(-1, 2, size=len(ids))               # -1 erode, 0 keep, +1 dilate
    move[(move < 0) & (areas < 4 * kernel.size)] = 0        # a small mask is not eroded away
    choice = np.zeros(int(ids.max()) + 1, np.int8)
    choice[ids] = move
    chosen = choice[labels]
    interior = (cv2.erode(labels, kernel) == labels) & (cv2.dilate(labels, kernel) == labels)
    out = np.where((chosen < 0) & ~interior, 0, labels).astype(np.uint16)
    grown = cv2.dilate(np.where(chosen > 0, labels, 0).astype(np.uint16), kernel)
    return np.where((out == 0) & (labels == 0), grown, out).astype(np.uint16)


def _false_detections(labels: np.ndarray, fruit: np.ndarray, area: float, count: int, first_id: int,
                      rng: np.random.Generator) -> np.ndarray:
    """``count`` discs of ``area`` pixels at random places in the box around ``fruit``, on background pixels."""
    lines, columns = np.nonzero(fruit)
    radius = max(1, int(round(np.sqrt(area / np.pi))))
    y = rng.integers(lines.min(), lines.max() + 1, size=count)
    x = rng.integers(columns.min(), columns.max() + 1, size=count)
    discs = np.zeros(labels.shape, np.uint16)
    for k in range(count):                                   # a few discs per view
        cv2.circle(discs, (int(x[k]), int(y[k])), radius, first_id + k, -1)
    return np.where((labels == 0) & (discs > 0), discs, labels).astype(np.uint16)
