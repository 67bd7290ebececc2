"""Where instance masks come from: a topic now, a segmenter later, behind one interface.

The frame assembler asks the mask source whether it needs a topic (then the mask message is synchronised with
the image and pose) and turns what it gets into a [H, W] uint16 instance-id array for one image.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from fruitnerfpp_ros.nodes.conversions import mask_from_msg

__all__ = ['MaskSource', 'TopicMaskSource']


class MaskSource(Protocol):
    """Gives the instance mask of an image.

    Attributes:
        topic: the mask topic to synchronise with the image, or None when the source computes masks itself
            (a segmenter); then ``mask_msg`` is None.
    """

    topic: str | None

    def instances_for(self, rgb: np.ndarray, mask_msg: Any | None) -> np.ndarray:
        """[H, W] uint16 instance ids (0 = background) for the [H, W, 3] uint8 image ``rgb``.

        Raises:
            ConversionError: the mask cannot be used (encoding, size).
        """
        ...


class TopicMaskSource:
    """Instance masks published on a topic (``mono16`` / ``16UC1`` / ``32SC1`` images, one per camera image)."""

    def __init__(self, topic: str) -> None:
        self.topic: str | None = topic

    def instances_for(self, rgb: np.ndarray, mask_msg: Any | None) -> np.ndarray:
        return mask_from_msg(mask_msg, topic=str(self.topic), expected_shape=rgb.shape[:2])
