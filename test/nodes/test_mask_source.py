"""Mask sources: a segmenter instead of the mask topic, in the frame assembler and the fruit_counter node."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.core.data.keyframe_store import KeyframeConfig, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.errors import ConfigError, SegmentationError
from fruitnerfpp_ros.nodes.conversions import image_msg_from_array
from fruitnerfpp_ros.nodes.frame_assembler import FrameAssembler
from fruitnerfpp_ros.nodes.log import LogLevel
from fruitnerfpp_ros.nodes.mask_source import (SegmenterMaskSource, TopicMaskSource, mask_source_from_settings,
                                               segmenter_config_from_settings)
from fruitnerfpp_ros.nodes.params import settings_from_parameters
from test.nodes import bag_factory as bf

ROLE = {'/camera/image_raw': 'image', '/camera/camera_info': 'camera_info', '/camera/pose': 'pose'}


class Logs(list):
    def __call__(self, level: LogLevel, message: str) -> None:
        self.append((level, message))


def _orchard_pixels() -> np.ndarray:
    """Green foliage with one red fruit (rows 6..13, cols 10..19)."""
    rgb = np.zeros((bf.H, bf.W, 3), np.uint8)
    rgb[:] = (40, 110, 30)
    rgb[6:14, 10:20] = (210, 30, 25)
    return rgb


def _feed_without_masks(assembler: FrameAssembler, n: int) -> None:
    for topic, _, stamp, msg in bf.messages(n):
        if topic == '/camera/instance_mask':
            continue
        if topic == '/camera/image_raw':
            msg = image_msg_from_array(_orchard_pixels(), 'rgb8', 'camera_optical', stamp)
        assembler.on_message(ROLE[topic], msg)


def test_fallback_mask_source_makes_keyframes_without_a_mask_topic(tmp_path: Path) -> None:
    settings = settings_from_parameters({'mask_source': 'fallback', 'min_translation_m': 0.1})
    assembler = FrameAssembler(settings, KeyframeStore(tmp_path), Logs())
    assert isinstance(assembler.mask_source, SegmenterMaskSource) and assembler.mask_source.topic is None
    assert 'mask' not in assembler.required_roles()
    _feed_without_masks(assembler, 3)
    frames = read_transforms(tmp_path).frames
    assert len(frames) == 3
    instances = cv2.imread(str(tmp_path / frames[0].instance_path), cv2.IMREAD_UNCHANGED)
    assert instances.dtype == np.uint16 and instances.shape == (bf.H, bf.W)
    assert (instances[6:14, 10:20] == 1).all() and instances.sum() == 80


def test_binary_fruit_masks_on_the_mask_topic_become_blob_instances(tmp_path: Path) -> None:
    """A semantic segmenter publishes mono8 0 / 255: with 'topic' that is one fruit of id 255 per image; with
    'semantic_topic' each blob is a fruit."""
    settings = settings_from_parameters({'mask_source': 'semantic_topic', 'min_translation_m': 0.1})
    assembler = FrameAssembler(settings, KeyframeStore(tmp_path, mask_source='semantic_topic'), Logs())
    assert assembler.mask_source.topic == '/camera/instance_mask' and 'mask' in assembler.required_roles()
    for topic, _, stamp, msg in bf.messages(3):
        if topic == '/camera/instance_mask':
            fruit = np.zeros((bf.H, bf.W), np.uint8)
            fruit[2:6, 2:6] = 255
            fruit[12:18, 20:28] = 255
            msg = image_msg_from_array(fruit, 'mono8', 'camera_optical', stamp)
        assembler.on_message({**ROLE, '/camera/instance_mask': 'mask'}[topic], msg)
    frames = read_transforms(tmp_path).frames
    assert len(frames) == 3 and read_transforms(tmp_path).mask_source == 'semantic_topic'
    instances = cv2.imread(str(tmp_path / frames[1].instance_path), cv2.IMREAD_UNCHANGED)
    assert sorted(np.unique(instances).tolist()) == [0, 1, 2]
    assert len(set(instances[2:6, 2:6].ravel())) == 1 and instances[3, 3] != instances[14, 24]


def test_a_failing_segmenter_drops_the_frame_with_a_log(tmp_path: Path) -> None:
    logs = Logs()
    settings = settings_from_parameters({'min_translation_m': 0.1})
    source = SegmenterMaskSource(lambda rgb: np.zeros((2, 2), np.uint16), name='stub segmenter')
    assembler = FrameAssembler(settings, KeyframeStore(tmp_path), logs, mask_source=source)
    _feed_without_masks(assembler, 2)
    assert len(assembler.store) == 0 and assembler.errors['frame'] == 2
    assert any('stub segmenter: instance map of shape (2, 2)' in message for _, message in logs)


def test_topic_is_the_default_and_bad_segmenters_fail_at_construction(tmp_path: Path) -> None:
    assert isinstance(mask_source_from_settings(settings_from_parameters({})), TopicMaskSource)
    missing = tmp_path / 'fruit.pt'
    settings = settings_from_parameters({'mask_source': 'torchscript', 'segmenter_checkpoint': str(missing)})
    with pytest.raises(SegmentationError, match=f'TorchScript checkpoint not found: {missing}.*segmenter_checkpoint'):
        FrameAssembler(settings, KeyframeStore(tmp_path / 'kf'), Logs())
    with pytest.raises(SegmentationError, match="'sam' needs a checkpoint"):
        mask_source_from_settings(settings_from_parameters({'mask_source': 'sam'}))
    with pytest.raises(ConfigError, match='mask_source'):
        settings_from_parameters({'mask_source': 'magic'})


def test_segmenter_config_file_and_parameter_overrides(tmp_path: Path) -> None:
    path = tmp_path / 'segmentation.yaml'
    path.write_text('method: sam\ncheckpoint: from_file.pth\nmin_saturation: 0.7\ndevice: cuda\n')
    config = segmenter_config_from_settings(settings_from_parameters(
        {'mask_source': 'fallback', 'segmenter_config_file': str(path), 'device': 'cpu'}))
    assert (config.method, config.checkpoint, config.min_saturation, config.device) == \
        ('fallback', 'from_file.pth', 0.7, 'cpu')
    path.write_text('min_saturaton: 0.7\n')
    with pytest.raises(ConfigError, match='min_saturaton'):
        segmenter_config_from_settings(settings_from_parameters(
            {'mask_source': 'fallback', 'segmenter_config_file': str(path)}))


@pytest.mark.ros
def test_fruit_counter_node_with_a_segmenter(tmp_path: Path) -> None:
    import rclpy
    from rclpy.parameter import Parameter

    from fruitnerfpp_ros.nodes.fruit_counter import FruitCounterNode

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = FruitCounterNode(context=context, parameter_overrides=[
            Parameter('output_dir', value=str(tmp_path / 'run')), Parameter('mask_source', value='fallback')])
        try:
            topics = {sub.topic_name for sub in node.subscriptions}
            assert '/camera/image_raw' in topics and '/camera/instance_mask' not in topics
        finally:
            node.destroy_node()
        with pytest.raises(SegmentationError, match='TorchScript checkpoint not found'):
            FruitCounterNode(context=context, parameter_overrides=[
                Parameter('output_dir', value=str(tmp_path / 'run2')), Parameter('mask_source', value='torchscript'),
                Parameter('segmenter_checkpoint', value=str(tmp_path / 'missing.pt'))])
    finally:
        rclpy.try_shutdown(context=context)


def test_the_segmenter_runs_only_on_frames_the_store_keeps(tmp_path: Path) -> None:
    calls: list[tuple[int, ...]] = []

    def segmenter(rgb: np.ndarray) -> np.ndarray:
        calls.append(rgb.shape)
        return (rgb[..., 0] > 150).astype(np.uint16)

    # a 100 m / 180 deg keyframe distance keeps only the first of the four frames
    store = KeyframeStore(tmp_path, KeyframeConfig(min_translation_m=100.0, min_rotation_deg=180.0))
    assembler = FrameAssembler(settings_from_parameters({}), store, Logs(), mask_source=SegmenterMaskSource(segmenter))
    _feed_without_masks(assembler, 4)
    assert len(assembler.store) == 1 and assembler.decisions['too_close'] == 3
    assert calls == [(bf.H, bf.W, 3)]
