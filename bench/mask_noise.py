#!/usr/bin/env python3
"""Instance masks made as imperfect as a learned segmenter's: missed fruit and false detections.

``bench/recount.py --mask-noise DROPPED,FALSE`` counts trained runs against such masks (the training keeps the
masks it had): how much the masks step of the count (``clustering.masks``) depends on their quality.

- **Missed fruit:** each instance mask of a view is removed with probability ``dropped``.
- **False detections:** each view gets Binomial(its instance count, ``false``) discs, the median mask's area, at
  random places within the box around the view's masks (where a segmenter mistakes leaves for fruit); real masks
  stay on top.

Seeded: the same masks on every run. Nothing here is used by the package.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fruitnerfpp_ros.core.clustering.mask_views import MaskViews

__all__ = ['noisy_masks']


def noisy_masks(views: MaskViews, dropped: float, false: float, seed: int = 0) -> MaskViews:
    """``views`` with its training views' masks corrupted (module doc); the other views are left as they are."""
    rng = np.random.default_rng(seed)
    masks = np.array(views.instance_masks, copy=True)
    next_id = int(masks.max()) + 1
    height, width = masks.shape[1:3]
    for view in np.asarray(views.views, np.int64):
        mask = masks[view]
        ids, areas = np.unique(mask[mask > 0], return_counts=True)
        if not len(ids):
            continue
        lines, columns = np.nonzero(mask > 0)
        mask[np.isin(mask, ids[rng.random(len(ids)) < dropped])] = 0
        radius2 = np.median(areas) / np.pi
        reach = int(np.ceil(np.sqrt(radius2)))
        for _ in range(rng.binomial(len(ids), false)):
            y = rng.integers(lines.min(), lines.max() + 1)
            x = rng.integers(columns.min(), columns.max() + 1)
            top, left = max(0, y - reach), max(0, x - reach)      # the disc's window, not the whole image
            window = mask[top:min(height, y + reach + 1), left:min(width, x + reach + 1)]
            rows, cols = np.ogrid[top:top + window.shape[0], left:left + window.shape[1]]
            window[((rows - y) ** 2 + (cols - x) ** 2 <= radius2) & (window == 0)] = next_id
            next_id += 1
    return dataclasses.replace(views, instance_masks=masks)
