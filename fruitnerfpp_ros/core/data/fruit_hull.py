"""Where the fruit masks' visual hull begins along every pixel's ray: a lower bound on a fruit ray's depth.

A fruit pixel sees a fruit (the masks hold a fruit's visible part), so nothing opaque lies between the camera and
that fruit's surface, and the surface lies in the fruit voxels of the masks' vote (``core/data/scene_scale.py``),
which hold every fruit the views agree on: along a fruit pixel's ray, the space in front of the first hull voxel
is free. A field that puts the fruit's surface there (few views of a small fruit, and the photometric loss finds a
surface 0.2-0.5 m in front of it: docs/results/accuracy_suite.md, session 48) is wrong in a way the masks can
tell.

:func:`hull_depths` renders the hull's front into the views: every hull voxel is projected, the nearest one per
pixel kept (a z-buffer by ``scatter_reduce``), and spread over the voxel's footprint at the nearest voxels' depth
(a min filter: no gaps between voxel centres, where a ray would otherwise reach a voxel behind the one it
crosses). The depth is the voxel centre's minus half a voxel: the front of its cell.

Used by ``bench/fruit_ray_depth.py`` to tell where a trained field's fruit rays end against the masks. As a
training term (the fruit rays' render weight in front of the hull, session 49, commit ``0ef1f3c``) it was
rejected: on the rows it moved the field's fruit surfaces back but brought few missed fruits in (+0.01 to +0.04
F1), and on a row with odometry noise it smeared fruits into two counts each (0.766 -> 0.577).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.scene_scale import project_points

__all__ = ['hull_depths']


def hull_depths(dataset: SceneDataset, centres: torch.Tensor, voxel: float, views: torch.Tensor) -> torch.Tensor:
    """[len(views), H, W] float32: depth along the optical axis of the first hull voxel on each pixel's ray (inf
    where the ray meets none).

    Args:
        dataset: the views' poses, intrinsics and image size.
        centres: [M, 3] the hull voxels' centres (m).
        voxel: their edge (m).
        views: the views to render.
    """
    poses = dataset.T_world_camera
    height, width = dataset.height, dataset.width
    out = torch.full((len(views), height * width), math.inf, dtype=torch.float32, device=centres.device)
    for i, view in enumerate(views.tolist()):
        T = poses[view].to(centres.device, torch.float32)
        K = dataset.intrinsics[view].to(centres.device)
        u, v, depth, inside = project_points(centres, T, K, width, height)
        if not bool(inside.any()):
            continue
        depth = depth[inside]
        out[i].scatter_reduce_(0, v[inside] * width + u[inside], depth - 0.5 * voxel, 'amin')
        nearest = float(torch.quantile(depth, 0.05)) if len(depth) > 1 else float(depth[0])
        radius = max(1, math.ceil(0.5 * voxel * float(K[:2].max()) / max(nearest, 1e-3)))
        image = out[i].view(1, 1, height, width)
        out[i] = -F.max_pool2d(-image, 2 * radius + 1, stride=1, padding=radius).reshape(-1)
    return out.view(len(views), height, width)
