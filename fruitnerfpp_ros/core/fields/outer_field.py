"""The unbounded world beyond the scene box (NeRF++'s outer field, on a contracted grid).

An orchard capture sees ground and sky far outside any box around the tree. Without a model of them, training
paints that content onto floaters inside the box, which then fog held-out views and the fruit. This field covers
all of space outside the box: a point is contracted (mip-NeRF 360, with the box's L-inf norm) into a shell
around it, encoded by a small hash grid, and decoded to density and colour. It is rendered along each ray from
where the ray leaves the box to a far distance; it carries no fruit and no instance, so the semantic and
instance fields are untouched by it.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from fruitnerfpp_ros.core.fields.hash_grid import HashGridEncoding
from fruitnerfpp_ros.core.fields.mlp import make_mlp, spherical_harmonics, trunc_exp

__all__ = ['OuterField', 'OuterOutput', 'contract_to_unit', 'INITIAL_LOG_DENSITY']

#: Initial log density (1/m) of the outer field: exp(-6) ~ 0.0025/m, nearly transparent over tens of metres.
INITIAL_LOG_DENSITY = -6.0


def contract_to_unit(xyz: torch.Tensor, aabb: torch.Tensor) -> torch.Tensor:
    """World points [N, 3] -> [0, 1]^3: the box fills [1/4, 3/4]^3, all space outside it the shell up to 0 and 1.

    With u the point in box units (box = [-1, 1]^3) and n = |u|_inf: u stays where n <= 1, else it becomes
    (2 - 1/n) u / n (infinity maps onto the cube of half-size 2), then [-2, 2] is scaled onto [0, 1].
    """
    centre = 0.5 * (aabb[0] + aabb[1])
    half = 0.5 * (aabb[1] - aabb[0])
    u = (xyz - centre) / half
    n = u.abs().amax(-1, keepdim=True).clamp_min(1.0)
    return ((2.0 - 1.0 / n) * u / n + 2.0) * 0.25


class OuterOutput(NamedTuple):
    """Density [N] (1/m) and colour [N, 3] in [0, 1] at N points outside the box."""

    density: torch.Tensor
    rgb: torch.Tensor


class OuterField(nn.Module):
    """Density and view-dependent colour of everything outside the scene box ``aabb`` [2, 3].

    Args:
        aabb: the scene box, metres.
        num_levels, log2_table_size, base_resolution, max_resolution: the hash grid over the contracted cube.
        hidden_dim: width of the two small MLPs.
        sh_degree: view-direction encoding of the colour.
    """

    def __init__(self, aabb: torch.Tensor, *, num_levels: int, log2_table_size: int, base_resolution: int,
                 max_resolution: int, hidden_dim: int, sh_degree: int) -> None:
        super().__init__()
        self.register_buffer('aabb', torch.as_tensor(aabb, dtype=torch.float32).clone())
        self.sh_degree = sh_degree
        self.encoding = HashGridEncoding(num_levels=num_levels, features_per_level=2,
                                         log2_table_size=log2_table_size, base_resolution=base_resolution,
                                         max_resolution=max_resolution)
        self.density_mlp = make_mlp(self.encoding.output_dim, hidden_dim, 1, 1 + 7)
        self.color_mlp = make_mlp(7 + sh_degree ** 2, hidden_dim, 1, 3)
        with torch.no_grad():  # start nearly transparent: the box, not the outer field, explains the scene first
            self.density_mlp[-1].bias[0].fill_(INITIAL_LOG_DENSITY)

    def forward(self, xyz: torch.Tensor, directions: torch.Tensor) -> OuterOutput:
        """Density and colour at world points ``xyz`` [N, 3] seen along unit ``directions`` [N, 3]."""
        out = self.density_mlp(self.encoding(contract_to_unit(xyz, self.aabb)))
        sh = spherical_harmonics(directions, self.sh_degree).to(out.dtype)
        rgb = torch.sigmoid(self.color_mlp(torch.cat([out[:, 1:], sh], -1)).float())
        return OuterOutput(trunc_exp(out[:, 0].float()), rgb)
