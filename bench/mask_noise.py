#!/usr/bin/env python3
"""Instance masks made as imperfect as a learned segmenter's: missed fruit and false detections.

``bench/recount.py --mask-noise DROPPED,FALSE`` counts trained runs against such masks (the training keeps the
masks it had): how much the masks step of the count (``clustering.masks``) depends on their quality.

- **Missed fruit:** each instance mask of a view is removed with probability ``dropped``.
- **False detections:** each view gets Binomial(its instance count, ``false``) discs, the median mask's area, at
  random places within the box around the view's masks (where a segmenter mistakes leaves for fruit); real masks
  stay on top.

Seeded: the same masks on every run. The errors are ``core/synthetic/mask_noise.degrade_instances``' (the
generator's ``--mask-noise`` without its boundary error); until session 46 this script held its own copy of the
same model with other random draws, so re-counts made before then do not repeat draw for draw.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fruitnerfpp_ros.core.clustering.mask_views import MaskViews
from fruitnerfpp_ros.core.synthetic.mask_noise import degrade_instances

__all__ = ['noisy_masks']


def noisy_masks(views: MaskViews, dropped: float, false: float, seed: int = 0) -> MaskViews:
    """``views`` with its training views' masks corrupted (module doc); the other views are left as they are."""
    rng = np.random.default_rng(seed)
    masks = np.array(views.instance_masks, copy=True)
    for view in np.asarray(views.views, np.int64):
        masks[view] = degrade_instances(masks[view], rng, missed=dropped, false_rate=false)
    return dataclasses.replace(views, instance_masks=masks)
