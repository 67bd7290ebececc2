"""Volume rendering weights, occupancy grid and ray marching."""

from __future__ import annotations

import math

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb, rays_for_pixels
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.volume import accumulation, composite, render_weights

AABB = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])


def _rays(n: int) -> RayBundle:
    origins = torch.stack([torch.rand(n) * 0.8 + 0.1, torch.rand(n) * 0.8 + 0.1, torch.full((n,), 2.0)], -1)
    return RayBundle(origins, torch.tensor([[0.0, 0.0, -1.0]]).repeat(n, 1))


def test_constant_density_matches_beer_lambert() -> None:
    grid = OccupancyGrid(AABB, resolution=4, threshold=0.01, decay=0.95)
    samples = march_rays(_rays(8), grid, 0.01)
    sigma = 2.0
    weights = render_weights(samples, torch.full((len(samples.positions),), sigma))
    opacity = accumulation(samples, weights)
    assert torch.allclose(opacity, torch.full((8,), 1 - math.exp(-sigma * 1.0)), atol=1e-4)
    colour = composite(samples, weights, torch.ones(len(weights), 1))[:, 0]
    assert torch.allclose(colour, opacity)


def test_occupancy_grid_skips_empty_space() -> None:
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)

    def slab(xyz: torch.Tensor) -> torch.Tensor:  # dense only for z in [0.4, 0.6]
        return torch.where((xyz[:, 2] > 0.4) & (xyz[:, 2] < 0.6), 100.0, 0.0)

    grid.update(slab, 0.01, torch.Generator().manual_seed(0))
    assert 0.1 < grid.occupied_fraction <= 0.25  # 2 of 8 layers at most
    samples = march_rays(_rays(16), grid, 0.01)
    z = samples.positions[:, 2]
    assert bool(((z > 0.3) & (z < 0.7)).all()) and len(samples.positions) < 16 * 40


def test_pixel_rays_follow_opengl_convention() -> None:
    T = torch.eye(4)[None]
    K = torch.tensor([[10.0, 10.0, 4.0, 4.0]])
    rays = rays_for_pixels(T, K, torch.tensor([0, 0]), torch.tensor([3, 0]), torch.tensor([3, 7]))
    assert torch.allclose(rays.directions[0], torch.tensor([-0.05, 0.05, -1.0]) / math.sqrt(1.005), atol=1e-6)
    assert float(rays.directions[1, 0]) > 0 and float(rays.directions[1, 1]) > 0  # top-right pixel: +x, +y
    near, far = intersect_aabb(RayBundle(torch.tensor([[0.5, 0.5, 3.0]]), torch.tensor([[0.0, 0.0, -1.0]])), AABB)
    assert float(near) == 2.0 and float(far) == 3.0
