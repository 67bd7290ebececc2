"""Where instance masks come from: a topic, or a segmenter run on each image, behind one interface.

The frame assembler asks the mask source whether it needs a topic (then the mask message is synchronised with
the image and pose) and turns what it gets into a [H, W] uint16 instance-id array for one image.
:func:`mask_source_from_settings` maps the ``mask_source`` / ``segmenter_*`` parameters onto one.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from fruitnerfpp_ros.errors import SegmentationError
from fruitnerfpp_ros.nodes.conversions import mask_from_msg

if TYPE_CHECKING:
    from fruitnerfpp_ros.core.segmentation import Segmenter, SegmenterConfig
    from fruitnerfpp_ros.nodes.params import CounterSettings

__all__ = ['MaskSource', 'TopicMaskSource', 'FruitMaskTopicSource', 'SegmenterMaskSource',
           'segmenter_config_from_settings', 'mask_source_from_settings']


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
            SegmentationError: the segmenter failed on this image.
        """
        ...


class TopicMaskSource:
    """Instance masks published on a topic (``mono16`` / ``16UC1`` / ``32SC1`` images, one per camera image)."""

    def __init__(self, topic: str) -> None:
        self.topic: str | None = topic

    def instances_for(self, rgb: np.ndarray, mask_msg: Any | None) -> np.ndarray:
        return mask_from_msg(mask_msg, topic=str(self.topic), expected_shape=rgb.shape[:2])


class FruitMaskTopicSource(TopicMaskSource):
    """Binary fruit masks published on a topic (non-zero = fruit), split into instances by connected blobs
    (:func:`~fruitnerfpp_ros.core.segmentation.semantic_instances.instances_of_mask`)."""

    def __init__(self, topic: str, config: SegmenterConfig) -> None:
        super().__init__(topic)
        self.config = config

    def instances_for(self, rgb: np.ndarray, mask_msg: Any | None) -> np.ndarray:
        from fruitnerfpp_ros.core.segmentation.semantic_instances import instances_of_mask
        return instances_of_mask(super().instances_for(rgb, mask_msg) > 0, self.config)


class SegmenterMaskSource:
    """Instance masks computed from the image by a core segmenter (no mask topic)."""

    def __init__(self, segmenter: Segmenter, name: str = 'segmenter') -> None:
        self.topic: str | None = None
        self.segmenter = segmenter
        self.name = name

    def instances_for(self, rgb: np.ndarray, mask_msg: Any | None) -> np.ndarray:
        from fruitnerfpp_ros.core.segmentation.segmenter import segment
        return segment(self.segmenter, rgb, self.name)


def segmenter_config_from_settings(settings: CounterSettings) -> SegmenterConfig:
    """The SegmenterConfig of ``segmenter_config_file`` (or the defaults), with ``mask_source`` as its method,
    ``segmenter_checkpoint`` (when set) as its checkpoint and ``device`` as its device.

    Raises:
        ConfigError: an unreadable segmenter_config_file or a bad value in it (the message names the file).
    """
    from fruitnerfpp_ros.core.segmentation import SegmenterConfig
    return SegmenterConfig.load(settings.segmenter_config_file, method=settings.mask_source,
                                checkpoint=settings.segmenter_checkpoint, device=settings.device)


def mask_source_from_settings(settings: CounterSettings) -> MaskSource:
    """``mask_source: topic`` -> :class:`TopicMaskSource` on ``mask_topic``; ``semantic_topic`` ->
    :class:`FruitMaskTopicSource` on it (blobs as ``segmenter_config_file`` sets them); a segmenter method ->
    :class:`SegmenterMaskSource` with the core segmenter built (and its model loaded) now.

    Raises:
        SegmentationError: the segmenter cannot be built (no or a bad checkpoint, a missing package); the message
            names the parameter to fix.
        ConfigError: a bad segmenter_config_file or device.
    """
    if settings.mask_source == 'topic':
        return TopicMaskSource(settings.mask_topic)
    if settings.mask_source == 'semantic_topic':
        from fruitnerfpp_ros.core.segmentation import SegmenterConfig
        return FruitMaskTopicSource(settings.mask_topic, SegmenterConfig.load(settings.segmenter_config_file))
    from fruitnerfpp_ros.core.segmentation import build_segmenter
    config = segmenter_config_from_settings(settings)
    try:
        segmenter = build_segmenter(config)
    except SegmentationError as err:
        raise SegmentationError(f'mask_source {settings.mask_source!r}: {err} (parameters mask_source, '
                                'segmenter_checkpoint, segmenter_config_file)') from err
    return SegmenterMaskSource(segmenter, name=f'{settings.mask_source} segmenter')
