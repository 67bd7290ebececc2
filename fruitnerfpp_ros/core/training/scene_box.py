"""The scene box and scale of a training run: the configured box, or one bounded by what the data agree on."""

from __future__ import annotations

import numpy as np
import torch

from fruitnerfpp_ros.core.data.bounds import scene_aabb
from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.scene_scale import SceneScale, estimate_scene_scale
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['build_scene_box', 'camera_box', 'measure_scene']


def camera_box(dataset: SceneDataset, config: TrainConfig) -> np.ndarray:
    """The region the cameras' views overlap (and the sparse points, when the dataset has them) [2, 3]."""
    return scene_aabb(dataset.T_world_camera, dataset.intrinsics, dataset.width, dataset.height,
                      ply_path=dataset.ply_path, min_view_fraction=config.data.min_view_fraction,
                      padding=config.data.aabb_padding, points_growth=config.data.points_growth)


def measure_scene(dataset: SceneDataset, config: TrainConfig, device: torch.device | str = 'cpu'
                  ) -> tuple[np.ndarray, SceneScale]:
    """The scene box [2, 3] and scale of a run (see :func:`build_scene_box`)."""
    cameras = camera_box(dataset, config)
    scale = estimate_scene_scale(dataset, cameras, config.scale, device=device)
    centres = dataset.T_world_camera[:, :3, 3].double().numpy()
    return build_scene_box(config, cameras, scale, centres), scale


def _camera_clearance(region: np.ndarray, camera_centres: np.ndarray) -> float:
    """Median distance (m) of the cameras from the fruit region box (0 for a camera inside it)."""
    outside = np.maximum(region[0] - camera_centres, 0.0) + np.maximum(camera_centres - region[1], 0.0)
    return float(np.median(np.linalg.norm(outside, axis=1)))


def build_scene_box(config: TrainConfig, cameras: np.ndarray, scale: SceneScale,
                    camera_centres: np.ndarray | None = None) -> np.ndarray:
    """``config.data.aabb`` when set; else the cameras' box cut to the fruit region grown by a margin.

    The margin is ``box_margin_m``, at most ``camera_clearance`` of the cameras' median distance from the fruit
    region: the box stops well short of the cameras (space around a camera is seen by one view only and fills with
    floaters that shadow the fruit).

    Raises:
        DatasetError: an explicit box with max <= min on an axis, or a cut that leaves nothing.
    """
    if config.data.aabb is not None:
        box = np.asarray(config.data.aabb, dtype=np.float64).reshape(2, 3)
        if not np.all(box[1] > box[0]):
            raise DatasetError(f'data.aabb {config.data.aabb}: max must exceed min on every axis')
        return box
    box = np.asarray(cameras, np.float64)
    margin = config.data.box_margin_m
    if margin is None or scale.fruit_region is None:
        return box
    region = scale.fruit_region
    if camera_centres is not None and len(camera_centres):
        margin = min(margin, config.data.camera_clearance * _camera_clearance(region, camera_centres))
    cut = np.stack([np.maximum(box[0], region[0] - margin), np.minimum(box[1], region[1] + margin)])
    if not np.all(cut[1] > cut[0]):
        raise DatasetError(f'the fruit region {np.round(region, 3).tolist()} lies outside the cameras\' box '
                           f'{np.round(box, 3).tolist()}: check the poses\' frame and the masks')
    return cut
