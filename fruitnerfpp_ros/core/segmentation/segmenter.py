"""The one interface every instance-mask segmenter implements, and the checks they share."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from fruitnerfpp_ros.errors import SegmentationError

__all__ = ['Segmenter', 'check_rgb', 'checkpoint_file', 'first_line', 'segment']


@runtime_checkable
class Segmenter(Protocol):
    """Turns one RGB image into fruit instance ids.

    Output: [H, W] uint16, 0 = background, 1..K = the image's fruits, contiguous. Ids are per-image labels only:
    nothing relates id k of one image to id k of another (the instance field learns the association).
    A segmenter may name itself with a ``method`` attribute (the built-in ones do: ``fallback``, ``torchscript``,
    ``sam``); :func:`~fruitnerfpp_ros.core.segmentation.dataset_masks.segment_dataset` records it as the dataset's
    ``mask_source``.
    """

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """[H, W] uint16 instance ids of the [H, W, 3] uint8 RGB image ``rgb``.

        Raises:
            SegmentationError: the image is not [H, W, 3] uint8, or the model's output is unusable.
        """
        ...


def check_rgb(rgb: np.ndarray) -> np.ndarray:
    """``rgb`` as a C-contiguous [H, W, 3] uint8 array.

    Raises:
        SegmentationError: another shape or dtype.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
        raise SegmentationError(f'segmenters take [H, W, 3] uint8 RGB images, got shape {rgb.shape} {rgb.dtype}')
    return np.ascontiguousarray(rgb)


def checkpoint_file(method: str, checkpoint: str, what: str) -> Path:
    """The local model file of a learned ``method`` (``what`` names its kind in messages, e.g. ``TorchScript``).

    Raises:
        SegmentationError: no checkpoint given, or no file there (nothing is ever downloaded).
    """
    if not checkpoint:
        raise SegmentationError(f'method {method!r} needs a checkpoint: the path of a local {what} file '
                                '(nothing is downloaded)')
    path = Path(checkpoint).expanduser()
    if not path.is_file():
        raise SegmentationError(f'{what} checkpoint not found: {path}')
    return path


def first_line(err: BaseException) -> str:
    """The first line of an exception's message (its type name when empty), for one-line errors."""
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


def segment(segmenter: Segmenter, rgb: np.ndarray, where: str) -> np.ndarray:
    """``segmenter(rgb)`` as [H, W] uint16 ids, checked against the image's size (``where`` starts the message).

    Raises:
        SegmentationError: the segmenter fails or returns another size.
    """
    ids = np.asarray(segmenter(rgb))
    if ids.shape != rgb.shape[:2]:
        raise SegmentationError(f'{where}: instance map of shape {ids.shape} for a {rgb.shape[1]}x{rgb.shape[0]} '
                                'image')
    return ids.astype(np.uint16, copy=False)
