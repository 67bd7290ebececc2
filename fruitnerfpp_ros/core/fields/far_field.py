"""What a ray sees after it leaves the scene box: a coarse density + colour field over contracted space.

A camera on a row drive sees the ground and the far side of the orchard many metres beyond the box around the
tree. With only a constant background colour the box field has to paint that world on surfaces inside the box,
between the cameras and the tree (floaters that also take fruit probability), or on the tree's plane. The far
field gives it a place of its own, as NeRF++ (Zhang et al. 2020) and mip-NeRF 360's contraction (Barron et al.
2022) do for unbounded scenes:

- space outside the box is contracted: with ``u`` the point in box coordinates ([-1, 1]^3 inside the box) and
  ``r = |u|_inf``, ``contract(u) = (2 - 1/r) u / r`` for ``r > 1``, so all of space beyond the box fits in
  [-2, 2]^3 and infinitely far points lie on its surface;
- each ray gets ``samples`` points beyond the box exit, spaced evenly in inverse distance (disparity) out to
  infinity; the last interval is unbounded and so opaque: the far field also replaces the constant background;
- density and a view-independent colour come from one small hash grid over [-2, 2]^3 and one MLP. It is trained
  by the colour loss only, with the geometry; the semantic and instance heads never see it (beyond the box there
  is no fruit to count) and the export never samples it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from fruitnerfpp_ros.core.fields.hash_grid import HashGridConfig, HashGridEncoding
from fruitnerfpp_ros.core.fields.mlp import init_mlp, make_mlp, trunc_exp
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['FarFieldConfig', 'FarField', 'contract', 'far_sample_distances']

#: The last interval along a ray is unbounded: its length, metres (large enough that any density makes it opaque).
_LAST_INTERVAL_M = 1e4


@dataclass(frozen=True)
class FarFieldConfig:
    """The field beyond the scene box (0 samples: rays leaving the box see a constant background colour)."""

    samples: int = 16
    """Samples per ray beyond the box exit (evenly spaced in inverse distance); 0 disables the far field."""
    base_resolution: int = 8
    """Coarsest grid resolution over the contracted cube [-2, 2]^3 (the box is its middle half)."""
    max_resolution: int = 128
    """Finest grid resolution over the contracted cube."""
    num_levels: int = 6
    log2_table_size: int = 15
    hidden_dim: int = 32
    units_per_metre: float = 1.0
    """The poses' units in a metre (set by the run from its scale, ``SceneScale.units_per_metre``): the far field's
    density starts at about 1 per metre whatever the units (its intervals span metres to kilometres; a plum row in
    units of 3 cm, its first far sample opaque from the start: held-out PSNR 18.3 dB, converted 23.9 dB)."""

    def __post_init__(self) -> None:
        if self.samples < 0:
            raise ConfigError(f'far field: samples must be >= 0, got {self.samples}')
        if not 1 <= self.base_resolution <= self.max_resolution:
            raise ConfigError(f'far field: need 1 <= base_resolution <= max_resolution, got {self.base_resolution} / '
                              f'{self.max_resolution}')
        if self.hidden_dim < 1:
            raise ConfigError(f'far field: hidden_dim must be >= 1, got {self.hidden_dim}')
        if not self.units_per_metre > 0:
            raise ConfigError(f'far field: units_per_metre must be > 0, got {self.units_per_metre}')

    @property
    def enabled(self) -> bool:
        return self.samples > 0


def contract(u: torch.Tensor) -> torch.Tensor:
    """Box coordinates [N, 3] ([-1, 1]^3 is the box) -> [-2, 2]^3: identity inside the box, ``(2 - 1/r) u / r``
    outside, ``r = |u|_inf``."""
    r = u.abs().amax(-1, keepdim=True).clamp_min(1e-9)
    return torch.where(r <= 1.0, u, (2.0 - 1.0 / r) * u / r)


def far_sample_distances(t_exit: torch.Tensor, samples: int, jitter: torch.Tensor | None = None,
                         units_per_metre: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances [N, K] of ``samples`` points per ray beyond ``t_exit`` [N] and the lengths [N, K] of their
    intervals, evenly spaced in inverse distance: interval k spans ``t_exit / (1 - k/K)`` to
    ``t_exit / (1 - (k+1)/K)``; the last one is unbounded (length ``_LAST_INTERVAL_M``, in the poses' units).

    Args:
        t_exit: [N] distance where each ray leaves the box, metres (> 0).
        samples: K.
        jitter: [N] offsets in [0, 1) of the samples inside their intervals (training); None = 0.5.
        units_per_metre: the poses' units in a metre (``FarFieldConfig.units_per_metre``).
    """
    k = torch.arange(samples + 1, device=t_exit.device, dtype=t_exit.dtype)
    edges = t_exit[:, None] / (1.0 - k[None, :-1] / samples)                          # [N, K] interval starts
    ends = torch.cat([edges[:, 1:], edges[:, -1:] + _LAST_INTERVAL_M * units_per_metre], 1)
    offset = torch.full_like(t_exit, 0.5) if jitter is None else jitter.to(t_exit)
    # inside an interval the point is placed in inverse distance too; the unbounded one gets twice its start
    inv_start, inv_end = 1.0 / edges, torch.cat([1.0 / edges[:, 1:], torch.zeros_like(edges[:, -1:])], 1)
    inv = inv_start + offset[:, None] * (inv_end - inv_start)
    t = 1.0 / inv.clamp_min(0.5 / edges[:, -1:])
    return t, ends - edges


class FarField(nn.Module):
    """Density (1/m) and colour of the world beyond the scene box, at points given in box coordinates."""

    def __init__(self, config: FarFieldConfig, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.config = config
        grid = HashGridConfig(num_levels=config.num_levels, log2_table_size=config.log2_table_size)
        self.encoding = HashGridEncoding(grid, config.base_resolution, config.max_resolution, generator=generator)
        self.mlp = make_mlp(self.encoding.output_dim, config.hidden_dim, 1, 4)
        init_mlp(self.mlp, generator)

    def forward(self, box_coords: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density [N] (1 / pose unit) and colour [N, 3] at points [N, 3] in box coordinates ([-1, 1]^3 is the box)."""
        out = self.mlp(self.encoding((contract(box_coords) + 2.0) / 4.0)).float()
        return trunc_exp(out[:, 0]) / self.config.units_per_metre, torch.sigmoid(out[:, 1:])
