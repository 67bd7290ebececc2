"""The one interface every instance-mask segmenter implements, and the input check they share."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from fruitnerfpp_ros.errors import SegmentationError

__all__ = ['Segmenter', 'check_rgb']


@runtime_checkable
class Segmenter(Protocol):
    """Turns one RGB image into fruit instance ids.

    Output: [H, W] uint16, 0 = background, 1..K = the image's fruits, contiguous. Ids are per-image labels only:
    nothing relates id k of one image to id k of another (the instance field learns the association).
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
