"""Occupancy grid for empty-space skipping (nerfacc / instant-NGP style).

A ``res^3`` grid over the scene box keeps, per cell, an exponential moving maximum of the optical thickness
``density * step`` seen at random points in the cell. Cells above ``min(threshold, mean)`` are occupied; ray
marching evaluates the field only at samples inside occupied cells.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import nn

__all__ = ['OccupancyGrid']


class OccupancyGrid(nn.Module):
    """Binary occupancy over the box ``aabb`` [2, 3].

    Args:
        aabb: scene box, metres.
        resolution: cells per axis.
        threshold: optical thickness (density * step) above which a cell is occupied.
        decay: per-update decay of the stored values (an exponential moving maximum).
    """

    def __init__(self, aabb: torch.Tensor, *, resolution: int, threshold: float, decay: float) -> None:
        super().__init__()
        self.resolution = resolution
        self.threshold = threshold
        self.decay = decay
        self.register_buffer('aabb', torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.register_buffer('values', torch.zeros(resolution ** 3))
        self.register_buffer('occupied', torch.ones(resolution ** 3, dtype=torch.bool))
        index = torch.arange(resolution ** 3)
        cells = torch.stack([index // resolution ** 2, (index // resolution) % resolution, index % resolution], -1)
        self.register_buffer('cells', cells, persistent=False)

    def cell_index(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat cell index [N] of world points and whether each lies inside the box [N]."""
        unit = (xyz - self.aabb[0]) / (self.aabb[1] - self.aabb[0])
        inside = ((unit >= 0.0) & (unit < 1.0)).all(-1)
        ijk = (unit * self.resolution).long().clamp(0, self.resolution - 1)
        return (ijk[:, 0] * self.resolution + ijk[:, 1]) * self.resolution + ijk[:, 2], inside

    def is_occupied(self, xyz: torch.Tensor) -> torch.Tensor:
        """Bool [N]: the point lies inside the box and in an occupied cell."""
        index, inside = self.cell_index(xyz)
        return inside & self.occupied[index]

    @torch.no_grad()
    def update(self, density_fn: Callable[[torch.Tensor], torch.Tensor], step_size: float,
               generator: torch.Generator, chunk: int = 1 << 18) -> None:
        """Evaluate density at one random point per cell and refresh the occupancy.

        Args:
            density_fn: world points [N, 3] -> density [N] (1/m).
            step_size: ray-marching step in metres (turns density into optical thickness).
            generator: random source (CPU generator, part of the checkpointed training state).
        """
        jitter = torch.rand(self.cells.shape, generator=generator).to(self.aabb.device)
        unit = (self.cells.to(torch.float32) + jitter) / self.resolution
        xyz = self.aabb[0] + unit * (self.aabb[1] - self.aabb[0])
        fresh = torch.cat([density_fn(xyz[i:i + chunk]).float() for i in range(0, len(xyz), chunk)]) * step_size
        self.values.copy_(torch.maximum(self.values * self.decay, fresh))
        self.occupied.copy_(self.values > min(self.threshold, float(self.values.mean())))

    @property
    def occupied_fraction(self) -> float:
        return float(self.occupied.float().mean())
