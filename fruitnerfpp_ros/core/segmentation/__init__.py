"""Instance masks from RGB images: built-in fallback, TorchScript model or Segment Anything, behind one interface.

- ``config.py``: :class:`SegmenterConfig` (method, checkpoint, thresholds; ``config/segmentation.yaml``).
- ``segmenter.py``: the :class:`Segmenter` protocol (``rgb [H, W, 3] uint8 -> ids [H, W] uint16``).
- ``fallback.py``: the built-in fruit-agnostic colour segmenter (OpenCV / numpy, no model).
- ``torchscript.py``: a TorchScript instance-segmentation model from a local file (imports torch).
- ``sam.py``: Segment Anything's automatic mask generator from a local checkpoint (optional package).
- ``instance_maps.py``: masks -> one id map (shared by the model adapters), relabelling.
- ``factory.py``: :func:`build_segmenter`.

Importing this package does not import torch.
"""

from fruitnerfpp_ros.core.segmentation.config import SEGMENTER_METHODS, SegmenterConfig
from fruitnerfpp_ros.core.segmentation.factory import build_segmenter
from fruitnerfpp_ros.core.segmentation.fallback import FallbackSegmenter
from fruitnerfpp_ros.core.segmentation.instance_maps import instance_map_from_masks, relabel_sequential
from fruitnerfpp_ros.core.segmentation.segmenter import Segmenter

__all__ = ['SEGMENTER_METHODS', 'SegmenterConfig', 'Segmenter', 'build_segmenter', 'FallbackSegmenter',
           'instance_map_from_masks', 'relabel_sequential']
