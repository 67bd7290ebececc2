"""Segment Anything (SAM) adapter: the automatic mask generator, from a LOCAL checkpoint, filtered to fruit.

Needs the ``segment_anything`` package (not a dependency of fruitnerfpp_ros; install it with
``pip install segment-anything`` from a wheel or a source checkout) and a SAM checkpoint file such as
``sam_vit_b_01ec64.pth`` on disk; nothing is downloaded at run time.

SAM segments everything (leaves, branches, ground, sky), so its masks are filtered to fruit-like ones
(:func:`fruit_like_masks`: area between ``min_area_fraction`` and ``max_area_fraction`` of the image, solidity
``area / convex-hull area >= min_solidity``) and merged into one id map by the same function as the TorchScript
adapter (:func:`~fruitnerfpp_ros.core.segmentation.instance_maps.instance_map_from_masks`, scored by SAM's
predicted IoU; the better mask wins overlaps).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from fruitnerfpp_ros.core.segmentation.config import SegmenterConfig
from fruitnerfpp_ros.core.segmentation.instance_maps import instance_map_from_masks, mask_solidity
from fruitnerfpp_ros.core.segmentation.segmenter import check_rgb, checkpoint_file, first_line
from fruitnerfpp_ros.errors import SegmentationError

__all__ = ['SamSegmenter', 'fruit_like_masks', 'instance_map_from_sam_records', 'SAM_PACKAGE']

#: The Python package the adapter imports.
SAM_PACKAGE = 'segment_anything'


def fruit_like_masks(masks: np.ndarray, config: SegmenterConfig) -> np.ndarray:
    """[N] bool: which of the [N, H, W] boolean masks look like a fruit (area range, solidity)."""
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise SegmentationError(f'masks must be [N, H, W], got shape {masks.shape}')
    n, height, width = masks.shape
    area = masks.reshape(n, -1).sum(axis=1)
    keep = (area >= config.min_area_for(height, width)) & (area <= config.max_area_fraction * height * width)
    for i in np.flatnonzero(keep):  # one convex hull per candidate mask (tens per image), not per pixel
        keep[i] = mask_solidity(masks[i]) >= config.min_solidity
    return keep


def instance_map_from_sam_records(records: Sequence[dict[str, Any]], height: int, width: int,
                                  config: SegmenterConfig) -> np.ndarray:
    """[H, W] uint16 ids from SAM's automatic-generator records (``segmentation`` [H, W] bool, ``predicted_iou``)."""
    if not records:
        return np.zeros((height, width), np.uint16)
    masks = np.stack([np.asarray(r['segmentation'], dtype=bool) for r in records])
    if masks.shape[1:] != (height, width):
        raise SegmentationError(f'SAM masks have size {masks.shape[1:]}, the image {(height, width)}')
    scores = np.array([float(r.get('predicted_iou', 1.0)) for r in records], np.float32)
    keep = fruit_like_masks(masks, config)
    return instance_map_from_masks(masks[keep], scores[keep], mask_threshold=0.5,
                                   score_threshold=config.score_threshold,
                                   min_area_px=config.min_area_for(height, width))


class SamSegmenter:
    """Segment Anything's automatic mask generator on each image, filtered to fruit-like masks.

    Raises:
        SegmentationError: at construction, when the checkpoint is empty or missing, the ``segment_anything``
            package is not installed, or the checkpoint does not load as ``sam_model_type``.
    """

    method = 'sam'
    """Recorded as the dataset's ``mask_source``."""

    def __init__(self, config: SegmenterConfig) -> None:
        self.config = config
        path = checkpoint_file('sam', config.checkpoint, 'Segment Anything')
        try:
            from segment_anything import SamAutomaticMaskGenerator, sam_model_registry
        except ImportError as err:
            raise SegmentationError(
                f"method 'sam' needs the Python package '{SAM_PACKAGE}', which is not installed in this environment "
                f"({err}); install it with `pip install segment-anything` (or from a local wheel / source checkout "
                "on an offline machine), or use method 'fallback' or 'torchscript'") from err
        from fruitnerfpp_ros.core.device import resolve_device
        self.device = resolve_device(config.device)
        try:
            model = sam_model_registry[config.sam_model_type](checkpoint=str(path))
        except Exception as err:  # noqa: BLE001 - torch.load / load_state_dict errors
            raise SegmentationError(f'{path}: cannot load as a SAM {config.sam_model_type} checkpoint '
                                    f'({first_line(err)})') from err
        model.to(self.device)
        self.generator = SamAutomaticMaskGenerator(model, points_per_side=config.sam_points_per_side)
        self.path = path

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        rgb = check_rgb(rgb)
        try:
            records = self.generator.generate(rgb)
        except Exception as err:  # noqa: BLE001 - model errors on odd inputs
            raise SegmentationError(f'{self.path}: Segment Anything failed on a {rgb.shape[1]}x{rgb.shape[0]} image '
                                    f'({err})') from err
        return instance_map_from_sam_records(records, rgb.shape[0], rgb.shape[1], self.config)
