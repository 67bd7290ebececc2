"""Adapter for a learned (foundation or fine-tuned) instance-segmentation model exported with TorchScript.

The model is loaded from a LOCAL file with ``torch.jit.load`` (nothing is downloaded). Contract of its
``forward``:

- **Input**: one float32 tensor ``[1, 3, H, W]``, RGB in [0, 1], on the configured device.
- **Output**, one of:

  - an integer tensor ``[H, W]`` (or ``[1, H, W]``): instance ids, 0 = background (relabelled 1..K);
  - a float or bool tensor ``[N, H, W]`` (or ``[1, N, H, W]``): per-instance mask probabilities in [0, 1], or
    logits (any value outside [0, 1] means logits; a sigmoid is applied);
  - a tuple / list ``(masks, scores)`` or a dict ``{'masks': masks, 'scores': scores}`` with masks as above and
    ``scores`` a float ``[N]`` tensor of confidences.

Masks are turned into one id map by :func:`~fruitnerfpp_ros.core.segmentation.instance_maps.instance_map_from_masks`
(``score_threshold``, ``mask_threshold``; the higher score wins overlaps). Masks must have the image's size.

Export a model, e.g.::

    scripted = torch.jit.script(model)   # or torch.jit.trace(model, torch.rand(1, 3, 480, 640))
    scripted.save('fruit_instances.pt')
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.segmentation.config import SegmenterConfig
from fruitnerfpp_ros.core.segmentation.instance_maps import instance_map_from_masks, relabel_sequential
from fruitnerfpp_ros.core.segmentation.segmenter import check_rgb, checkpoint_file, first_line
from fruitnerfpp_ros.errors import SegmentationError

__all__ = ['TorchScriptSegmenter', 'instance_map_from_model_output']


def instance_map_from_model_output(output: Any, height: int, width: int, config: SegmenterConfig) -> np.ndarray:
    """[H, W] uint16 instance ids from a model output of one of the forms of the module docstring.

    Raises:
        SegmentationError: an output of another form or size.
    """
    scores = None
    if isinstance(output, dict):
        if 'masks' not in output:
            raise SegmentationError(f"model output dict needs a 'masks' entry, got keys {sorted(output)}")
        masks, scores = output['masks'], output.get('scores')
    elif isinstance(output, (tuple, list)):
        if len(output) != 2:
            raise SegmentationError(f'model output tuple must be (masks, scores), got {len(output)} items')
        masks, scores = output
    else:
        masks = output
    if not isinstance(masks, torch.Tensor) or (scores is not None and not isinstance(scores, torch.Tensor)):
        raise SegmentationError(f'model output must be tensors, got {type(masks).__name__}')
    masks = masks.detach().to('cpu')
    min_area = config.min_area_for(height, width)
    integer = not masks.dtype.is_floating_point and masks.dtype != torch.bool
    if masks.ndim == 4 and masks.shape[0] == 1:
        masks = masks[0]
    if integer and masks.ndim == 3 and masks.shape[0] == 1 and scores is None:
        masks = masks[0]
    if masks.shape[-2:] != (height, width):
        raise SegmentationError(f'model output has size {tuple(masks.shape[-2:])}, the image {(height, width)}')
    if masks.ndim == 2:
        if not integer:
            raise SegmentationError(f'a [H, W] model output must be an integer instance map, got {masks.dtype}')
        return relabel_sequential(masks.numpy().clip(min=0), min_area)
    if masks.ndim != 3:
        raise SegmentationError(f'model output masks must be [N, H, W], got shape {tuple(masks.shape)}')
    values = masks.float().numpy() if masks.dtype != torch.bool else masks.numpy()
    logits = values.dtype != np.bool_ and values.size > 0 and (values.min() < 0.0 or values.max() > 1.0)
    score_values = None if scores is None else scores.detach().to('cpu').float().reshape(-1).numpy()
    return instance_map_from_masks(values, score_values, mask_threshold=config.mask_threshold,
                                   score_threshold=config.score_threshold, min_area_px=min_area,
                                   logits=bool(logits))


class TorchScriptSegmenter:
    """Runs a TorchScript instance-segmentation model (contract in the module docstring) on each image.

    Raises:
        SegmentationError: at construction, when ``config.checkpoint`` is empty, missing or not a TorchScript
            file; when called, when the model fails or its output breaks the contract.
    """

    method = 'torchscript'
    """Recorded as the dataset's ``mask_source``."""

    def __init__(self, config: SegmenterConfig) -> None:
        self.config = config
        path = checkpoint_file('torchscript', config.checkpoint, 'TorchScript')
        self.device = resolve_device(config.device)
        try:
            model = torch.jit.load(str(path), map_location=self.device)
        except Exception as err:  # noqa: BLE001 - torch raises RuntimeError, ValueError, zipfile errors...
            raise SegmentationError(f'{path}: not a loadable TorchScript model ({first_line(err)})') from err
        self.model = model.eval()
        self.path = path

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        rgb = check_rgb(rgb)
        height, width = rgb.shape[:2]
        image = torch.from_numpy(rgb).to(self.device).permute(2, 0, 1)[None].float().div_(255.0)
        try:
            with torch.inference_mode():
                output = self.model(image)
        except Exception as err:  # noqa: BLE001 - a scripted model may raise anything
            raise SegmentationError(f'{self.path}: the model failed on a {width}x{height} image '
                                    f'({first_line(err)})') from err
        return instance_map_from_model_output(output, height, width, self.config)
