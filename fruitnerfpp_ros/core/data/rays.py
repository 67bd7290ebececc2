"""Camera rays for pixels of a dataset, and their intersection with the scene box."""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = ['RayBundle', 'PixelBatch', 'rays_for_pixels', 'intersect_aabb', 'pixels_crossing_box']


class PixelBatch(NamedTuple):
    """Pixels picked by a sampler.

    Attributes:
        view: [N] int64 view index.
        row: [N] int64 pixel row (v).
        col: [N] int64 pixel column (u).
        fruit: [N] int64 batch-local fruit label (0..F-1), or None for samplers without instance labels.
    """

    view: torch.Tensor
    row: torch.Tensor
    col: torch.Tensor
    fruit: torch.Tensor | None = None


class RayBundle(NamedTuple):
    """Rays in the world frame.

    Attributes:
        origins: [N, 3] metres.
        directions: [N, 3] unit vectors.
    """

    origins: torch.Tensor
    directions: torch.Tensor


def rays_for_pixels(T_world_camera: torch.Tensor, intrinsics: torch.Tensor, view: torch.Tensor,
                    row: torch.Tensor, col: torch.Tensor) -> RayBundle:
    """Rays through pixel centres (u + 0.5, v + 0.5), OpenGL camera axes (camera looks along -z).

    Args:
        T_world_camera: [V, 4, 4] camera-to-world poses.
        intrinsics: [V, 4] fl_x, fl_y, cx, cy (top-left image corner at 0, 0).
        view: [N] view index; row, col: [N] pixel indices.
    """
    K = intrinsics[view]
    x = (col.to(K.dtype) + 0.5 - K[:, 2]) / K[:, 0]
    y = -(row.to(K.dtype) + 0.5 - K[:, 3]) / K[:, 1]
    d_cam = torch.stack([x, y, -torch.ones_like(x)], dim=-1)
    T = T_world_camera[view]
    d_world = torch.einsum('nij,nj->ni', T[:, :3, :3], d_cam)
    return RayBundle(T[:, :3, 3].contiguous(), torch.nn.functional.normalize(d_world, dim=-1))


def intersect_aabb(rays: RayBundle, aabb: torch.Tensor, near: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances [N] of rays through ``aabb`` [2, 3]; ``t_far <= t_near`` where a ray misses it."""
    inv = 1.0 / torch.where(rays.directions.abs() < 1e-9, torch.full_like(rays.directions, 1e-9), rays.directions)
    t0 = (aabb[0] - rays.origins) * inv
    t1 = (aabb[1] - rays.origins) * inv
    t_near = torch.minimum(t0, t1).amax(-1).clamp_min(near)
    t_far = torch.maximum(t0, t1).amin(-1)
    return t_near, t_far


def pixels_crossing_box(T_world_camera: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int,
                        aabb: torch.Tensor) -> torch.Tensor:
    """[V, H, W] bool: the pixels whose rays (in front of the camera) pass through the box ``aabb`` [2, 3].

    One view at a time (H x W rays each), so memory stays at one image's rays.
    """
    rows, cols = torch.meshgrid(torch.arange(height), torch.arange(width), indexing='ij')
    rows, cols = rows.reshape(-1), cols.reshape(-1)
    box = torch.as_tensor(aabb, dtype=T_world_camera.dtype)
    masks = []
    for view in range(len(T_world_camera)):
        rays = rays_for_pixels(T_world_camera, intrinsics, torch.full_like(rows, view), rows, cols)
        t_near, t_far = intersect_aabb(rays, box)
        masks.append((t_far > t_near).reshape(height, width))
    return torch.stack(masks) if masks else torch.zeros(0, height, width, dtype=torch.bool)
