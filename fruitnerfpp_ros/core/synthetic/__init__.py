"""Procedural synthetic orchard with exact ground truth: a seeded fruit tree rendered to a transforms.json
dataset (RGB, instance and semantic masks, gt_fruits.json, sparse_pc.ply) and optionally a rosbag2 recording.

Example::

    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    result = generate_orchard(SynthConfig(fruit='apple', count=20, views=24, resolution=(96, 96)), 'out')
"""

from fruitnerfpp_ros.core.synthetic.bag_writer import TOPICS, T_BASE_LINK_CAMERA_OPTICAL, BagWriter
from fruitnerfpp_ros.core.synthetic.config import TRAJECTORIES, SynthConfig
from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, FRUIT_TYPES, MIXED, FruitType
from fruitnerfpp_ros.core.synthetic.generator import SynthResult, generate_orchard
from fruitnerfpp_ros.core.synthetic.rasterizer import Renderer, ViewRender
from fruitnerfpp_ros.core.synthetic.scene import GtFruit, Scene, build_scene

__all__ = ['SynthConfig', 'SynthResult', 'generate_orchard', 'FRUIT_NAMES', 'FRUIT_TYPES', 'MIXED', 'FruitType',
           'TRAJECTORIES', 'TOPICS', 'T_BASE_LINK_CAMERA_OPTICAL', 'BagWriter', 'Renderer', 'ViewRender',
           'GtFruit', 'Scene', 'build_scene']
