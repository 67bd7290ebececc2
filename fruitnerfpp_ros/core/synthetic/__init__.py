"""Procedural synthetic orchard with exact ground truth: a seeded fruit tree rendered to a transforms.json
dataset (RGB, instance and semantic masks, gt_fruits.json, sparse_pc.ply) and optionally a rosbag2 recording.

Example::

    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    result = generate_orchard(SynthConfig(fruit='apple', count=20, views=24, resolution=(96, 96)), 'out')

Modules: ``config`` (SynthConfig), ``fruit_types``, ``primitives`` + ``placement`` + ``scene`` (the tree),
``appearance`` (lighting and colour variation), ``cameras`` (intrinsics, hemisphere and row trajectories), ``lens``
(plumb_bob distortion), ``intersect`` + ``shading`` + ``rasterizer`` (the renderer), ``generator``,
``dataset_writer``, ``bag_writer``, ``preview``.
"""

from fruitnerfpp_ros.core.synthetic.appearance import DEFAULT_APPEARANCE, Appearance, sample_appearance
from fruitnerfpp_ros.core.synthetic.bag_writer import (COMPRESSED_IMAGE_TOPIC, JPEG_FORMAT, TOPICS,
                                                       T_BASE_LINK_CAMERA_OPTICAL, BagWriter, image_topic)
from fruitnerfpp_ros.core.synthetic.cameras import make_intrinsics, make_poses, row_drive
from fruitnerfpp_ros.core.synthetic.config import BAG_IMAGE_FORMATS, TRAJECTORIES, SynthConfig
from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, FRUIT_TYPES, MIXED, FruitType
from fruitnerfpp_ros.core.synthetic.generator import SynthResult, generate_orchard
from fruitnerfpp_ros.core.synthetic.lens import project_points, undistorted_pixel_grid
from fruitnerfpp_ros.core.synthetic.rasterizer import Renderer, ViewRender
from fruitnerfpp_ros.core.synthetic.scene import GtFruit, Scene, build_scene

__all__ = ['SynthConfig', 'SynthResult', 'generate_orchard', 'FRUIT_NAMES', 'FRUIT_TYPES', 'MIXED', 'FruitType',
           'TRAJECTORIES', 'BAG_IMAGE_FORMATS', 'TOPICS', 'COMPRESSED_IMAGE_TOPIC', 'JPEG_FORMAT', 'image_topic',
           'T_BASE_LINK_CAMERA_OPTICAL', 'BagWriter', 'Renderer', 'ViewRender', 'GtFruit', 'Scene', 'build_scene',
           'make_intrinsics', 'make_poses', 'row_drive', 'project_points', 'undistorted_pixel_grid', 'Appearance',
           'DEFAULT_APPEARANCE', 'sample_appearance']
