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


def build_scene_box(config: TrainConfig, cameras: np.ndarray, scale: SceneScale,
                    camera_centres: np.ndarray | None = None) -> np.ndarray:
    """``config.data.aabb`` when set; else the cameras' box, cut to the fruit region (``data.box_around``).

    ``box_around: fruit`` (the default) cuts every axis to the fruit region grown by ``box_margin_m``: the cameras,
    the ground and everything past the tree are the far field's (``field.far_field``), which needs no box face to
    paint them on, and the hash grids spend their cells on the tree alone (the suite: 2-4x faster, better counts on
    most scenes). ``fruit_and_cameras`` (the box before the far field existed) holds the cameras and the fruit
    region with ``box_margin_m`` to spare across (x, y) and keeps the camera box's full height (the ground under
    the tree stays in). Without a far field a box must reach past the cameras: a view sees ground and sky beyond
    the tree, and what a box cannot hold behind the tree is painted on its far face, which, unless it lies behind
    the cameras on the other side of the tree, stands in front of their views (a robot row with the box cut 0.5 m
    from the fruit: held-out PSNR 16 dB; with the far faces behind the other side's cameras: 22 dB).

    Raises:
        DatasetError: an explicit box with max <= min on an axis, or a cut that leaves nothing.
    """
    if config.data.aabb is not None:
        box = np.asarray(config.data.aabb, dtype=np.float64).reshape(2, 3)
        if not np.all(box[1] > box[0]):
            raise DatasetError(f'data.aabb {config.data.aabb}: max must exceed min on every axis')
        return box
    box = np.asarray(cameras, np.float64).copy()
    margin = config.data.box_margin_m
    if margin is None or scale.fruit_region is None:
        return box
    margin *= scale.units_per_metre   # metres, in the poses' units
    region = scale.fruit_region
    if config.data.box_around == 'fruit':  # every axis; the far field holds the rest
        box = np.stack([np.maximum(box[0], region[0] - margin), np.minimum(box[1], region[1] + margin)])
    else:  # across (x, y) only, holding the cameras too
        held = region if camera_centres is None or not len(camera_centres) else np.stack(
            [np.minimum(region[0], camera_centres.min(0)), np.maximum(region[1], camera_centres.max(0))])
        box[0, :2] = np.maximum(box[0, :2], held[0, :2] - margin)
        box[1, :2] = np.minimum(box[1, :2], held[1, :2] + margin)
    if not np.all(box[1] > box[0]):
        raise DatasetError(f'the fruit region {np.round(region, 3).tolist()} lies outside the cameras\' box '
                           f'{np.round(cameras, 3).tolist()}: check the poses\' frame and the masks')
    return box
