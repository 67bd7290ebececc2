"""The masks step of the count: the clustering's count checked against the training views' instance masks.

1. A counted fruit the masks show as two touching fruits is cut in two (``mask_merges.py``; with the cloud's points).
2. Fruit the masks agree on where the cloud has none are added (``mask_fruits.py``).
3. Counted fruits the masks show as pieces of one fruit are joined (``mask_pieces.py``).

Masks whose source ``skip_mask_sources`` lists (the dataset's ``mask_source``: the built-in colour segmenter's by
default) are not used: that segmenter merges touching fruit and marks leaves, so its masks agree where no fruit
hangs and show two touching fruits as one.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from fruitnerfpp_ros.core.clustering.config import MaskFruitConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.clustering.mask_fruits import add_mask_fruits
from fruitnerfpp_ros.core.clustering.mask_merges import split_mask_merges
from fruitnerfpp_ros.core.clustering.mask_pieces import join_mask_pieces
from fruitnerfpp_ros.core.clustering.mask_views import MaskViews

__all__ = ['skipped_mask_source', 'count_with_masks']

_LOG = logging.getLogger(__name__)


def skipped_mask_source(mask_source: str | None, config: MaskFruitConfig) -> str | None:
    """The part of ``mask_source`` (``fallback``, or a joined ``fallback+topic``) that ``config`` does not use, or
    None when its masks are used (an unknown source included)."""
    parts = str(mask_source or '').split('+')
    return next((p for p in parts if p in config.skip_mask_sources), None)


def count_with_masks(count: CountResult, views: MaskViews, fruit_diameter_m: float, aabb: np.ndarray | None,
                     config: MaskFruitConfig, points: tuple[np.ndarray, np.ndarray] | None = None) -> CountResult:
    """The clustering's ``count`` checked against the training views' masks: a fruit they show as two touching ones
    cut in two (needs ``points``: the cloud's [N, 3] positions and the same moved to their fruits' centres), the
    fruit they agree on where the cloud has none added, then the counted fruits they show as pieces of one joined.
    Unchanged when ``config`` is off or the masks' source is skipped (``stats['mask_fruits']`` then says so)."""
    if not config.enabled:
        return count
    skipped = skipped_mask_source(views.mask_source, config)
    if skipped is not None:
        _LOG.info('masks from %r (mask_source %r) left out of the count (clustering.masks.skip_mask_sources)',
                  skipped, views.mask_source)
        return dataclasses.replace(count, stats={**count.stats, 'mask_fruits': {
            'added': 0, 'skipped_mask_source': views.mask_source}})
    if points is not None:
        count = split_mask_merges(count, views, *points, fruit_diameter_m, config)
    count = add_mask_fruits(count, views, fruit_diameter_m, aabb, config)
    count = join_mask_pieces(count, views, fruit_diameter_m, config)
    added, joined = count.stats.get('mask_fruits', {}), count.stats.get('mask_pieces', {})
    cut = count.stats.get('mask_merges', {})
    if added:  # add_mask_fruits ran (its stats are all there)
        _LOG.info('masks: %d touching pair(s) counted as one cut in two, %d fruit added from %d unexplained masks '
                  'of >= %d px (each seen in >= %d views; shuffled masks would give %.1f), %d pieces joined',
                  cut.get('split', 0), added['added'], added['unexplained_masks'], added['min_mask_pixels'],
                  added['min_views'], added['chance_fruits'], joined.get('joined', 0))
    return count
