"""The scene box of a training run: the configured one, or one derived from the data."""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.data.bounds import scene_aabb
from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['build_scene_box']


def build_scene_box(dataset: SceneDataset, config: TrainConfig) -> np.ndarray:
    """The scene box [2, 3]: ``config.data.aabb`` when set, else derived from cameras and sparse points."""
    if config.data.aabb is not None:
        box = np.asarray(config.data.aabb, dtype=np.float64).reshape(2, 3)
        if not np.all(box[1] > box[0]):
            raise DatasetError(f'data.aabb {config.data.aabb}: max must exceed min on every axis')
        return box
    return scene_aabb(dataset.T_world_camera, dataset.intrinsics, dataset.width, dataset.height,
                      ply_path=dataset.ply_path, min_view_fraction=config.data.min_view_fraction,
                      padding=config.data.aabb_padding, points_growth=config.data.points_growth)
