"""``build_segmenter(config)``: the one place that turns a :class:`SegmenterConfig` into a segmenter.

Torch and the optional ``segment_anything`` package are imported only for the methods that need them, so the
fallback (and everything that merely imports this package) stays light.
"""

from __future__ import annotations

from fruitnerfpp_ros.core.segmentation.config import SegmenterConfig
from fruitnerfpp_ros.core.segmentation.segmenter import Segmenter

__all__ = ['build_segmenter']


def build_segmenter(config: SegmenterConfig = SegmenterConfig()) -> Segmenter:
    """The segmenter of ``config.method``, ready to call on [H, W, 3] uint8 images.

    Raises:
        SegmentationError: a learned method without a checkpoint, a checkpoint that is missing or does not load,
            or a missing optional package (``sam``: segment_anything).
        ConfigError: an unavailable ``device`` (e.g. cuda on a machine without CUDA).
    """
    if config.method == 'fallback':
        from fruitnerfpp_ros.core.segmentation.fallback import FallbackSegmenter
        return FallbackSegmenter(config)
    if config.method == 'torchscript':
        from fruitnerfpp_ros.core.segmentation.torchscript import TorchScriptSegmenter
        return TorchScriptSegmenter(config)
    from fruitnerfpp_ros.core.segmentation.sam import SamSegmenter
    return SamSegmenter(config)
