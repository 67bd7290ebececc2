"""Occupancy grid for empty-space skipping (nerfacc / instant-NGP style).

A ``res^3`` grid over the scene box keeps, per cell, an exponential moving maximum of the optical thickness
``density * step`` seen at random points in the cell (every occupied cell and a random share of the others per
update). Cells above ``min(threshold, mean)`` are occupied; ray marching evaluates the field only at samples inside
occupied cells.
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
               generator: torch.Generator, chunk: int = 1 << 18, probe_fraction: float = 1.0) -> None:
        """Evaluate density at one random point per probed cell and refresh the occupancy.

        The probed cells are every occupied cell and a random ``probe_fraction`` of all cells (instant-NGP's
        update; 1 = every cell). A cell left out only decays: an occupied cell is always probed, so only empty
        cells wait for their turn (on average ``1 / probe_fraction`` updates). A fresh grid is all occupied, so its
        first update probes every cell.

        The random points are drawn on the grid's device, chunk by chunk, from a generator seeded by one draw
        of ``generator``: no res^3 x 3 host buffer and no host-to-device copy per update, and the stream still
        follows the checkpointed generator (resume stays exact).

        Args:
            density_fn: world points [N, 3] -> density [N] (1/m).
            step_size: ray-marching step in metres (turns density into optical thickness).
            generator: random source (CPU generator, part of the checkpointed training state).
            chunk: cells evaluated per call of ``density_fn``.
            probe_fraction: share of all cells probed at random besides the occupied ones, in (0, 1].
        """
        device, res = self.aabb.device, self.resolution
        local = torch.Generator(device=device)
        local.manual_seed(int(torch.randint(0, 2 ** 62, (1,), generator=generator)))
        if probe_fraction >= 1.0:
            probed = None
        else:
            drawn = torch.rand(res ** 3, generator=local, device=device) < probe_fraction
            probed = torch.nonzero(drawn | self.occupied).squeeze(1)
        count = res ** 3 if probed is None else len(probed)
        fresh = torch.empty(count, device=device)
        for start in range(0, count, chunk):
            index = torch.arange(start, min(start + chunk, count), device=device)
            index = index if probed is None else probed[index]
            cells = torch.stack([index // res ** 2, (index // res) % res, index % res], -1).to(torch.float32)
            unit = (cells + torch.rand(cells.shape, generator=local, device=device)) / res
            fresh[start:start + len(index)] = density_fn(self.aabb[0] + unit * (self.aabb[1] - self.aabb[0])).float()
        decayed = self.values * self.decay
        if probed is None:
            self.values.copy_(torch.maximum(decayed, fresh * step_size))
        else:
            decayed[probed] = torch.maximum(decayed[probed], fresh * step_size)
            self.values.copy_(decayed)
        self.occupied.copy_(self.values > min(self.threshold, float(self.values.mean())))

    @property
    def occupied_fraction(self) -> float:
        return float(self.occupied.float().mean())
