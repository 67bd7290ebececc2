"""Ray marching with empty-space skipping: fixed-step samples inside the box, kept only in occupied cells."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid

__all__ = ['RaySamples', 'march_rays']


class RaySamples(NamedTuple):
    """Packed samples along a batch of rays (only the ones in occupied space).

    Attributes:
        positions: [S, 3] world points, metres.
        directions: [S, 3] unit ray directions.
        ray_index: [S] int64 ray of each sample.
        slot: [S] int64 flat index ``ray * max_samples + k`` into the dense [num_rays, max_samples] layout
            (samples of one ray are in increasing distance).
        num_rays: N.
        max_samples: K, the dense layout's samples per ray.
        step: distance between samples, metres.
    """

    positions: torch.Tensor
    directions: torch.Tensor
    ray_index: torch.Tensor
    slot: torch.Tensor
    num_rays: int
    max_samples: int
    step: float


def march_rays(rays: RayBundle, grid: OccupancyGrid, step: float, *, near: float = 0.0,
               jitter: torch.Tensor | None = None) -> RaySamples:
    """Samples every ``step`` metres from where each ray enters the box to where it leaves it.

    Args:
        rays: N rays.
        grid: occupancy grid; samples in empty cells are dropped.
        step: sample spacing, metres.
        near: minimum distance from the camera, metres.
        jitter: [N] offsets in [0, 1) of the first sample (fractions of a step) for training; None = 0.5.
    """
    t_near, t_far = intersect_aabb(rays, grid.aabb, near)
    n = rays.origins.shape[0]
    span = (t_far - t_near).clamp_min(0.0)
    k = max(1, int(math.ceil(float(span.detach().max()) / step))) if n else 1
    offset = torch.full_like(t_near, 0.5) if jitter is None else jitter.to(t_near)
    t = t_near[:, None] + (torch.arange(k, device=t_near.device, dtype=t_near.dtype)[None] + offset[:, None]) * step
    valid = t < t_far[:, None]
    positions = rays.origins[:, None, :] + t[..., None] * rays.directions[:, None, :]
    flat_valid = torch.nonzero(valid.reshape(-1)).squeeze(1)
    points = positions.reshape(-1, 3)[flat_valid]
    keep = grid.is_occupied(points)
    slot = flat_valid[keep]
    ray_index = slot // k
    return RaySamples(points[keep], rays.directions[ray_index], ray_index, slot, n, k, step)
