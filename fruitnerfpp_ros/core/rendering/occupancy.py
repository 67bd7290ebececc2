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

        The random points are drawn on the grid's device, chunk by chunk, from a generator seeded by one draw
        of ``generator``: no res^3 x 3 host buffer and no host-to-device copy per update, and the stream still
        follows the checkpointed generator (resume stays exact).

        Args:
            density_fn: world points [N, 3] -> density [N] (1/m).
            step_size: ray-marching step in metres (turns density into optical thickness).
            generator: random source (CPU generator, part of the checkpointed training state).
        """
        device, res = self.aabb.device, self.resolution
        local = torch.Generator(device=device)
        local.manual_seed(int(torch.randint(0, 2 ** 62, (1,), generator=generator)))
        fresh = torch.empty(res ** 3, device=device)
        for start in range(0, res ** 3, chunk):
            index = torch.arange(start, min(start + chunk, res ** 3), device=device)
            cells = torch.stack([index // res ** 2, (index // res) % res, index % res], -1).to(torch.float32)
            unit = (cells + torch.rand(cells.shape, generator=local, device=device)) / res
            fresh[start:start + len(index)] = density_fn(self.aabb[0] + unit * (self.aabb[1] - self.aabb[0])).float()
        self.values.copy_(torch.maximum(self.values * self.decay, fresh * step_size))
        self.occupied.copy_(self.values > min(self.threshold, float(self.values.mean())))

    @property
    def occupied_fraction(self) -> float:
        return float(self.occupied.float().mean())
