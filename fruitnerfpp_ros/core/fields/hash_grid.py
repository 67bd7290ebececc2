"""Multiresolution hash-grid encoding (instant-NGP) in pure PyTorch.

Levels whose ``(res + 1)^3`` vertices fit the table are indexed densely (no collisions); finer levels hash their
vertices. All levels are looked up in one vectorised gather with trilinear interpolation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from fruitnerfpp_ros.errors import ConfigError

__all__ = ['HashGridConfig', 'HashGridEncoding']

#: points per encoding pass on the CPU (see :meth:`HashGridEncoding.forward`).
CPU_CHUNK_POINTS = 8192

#: instant-NGP hash primes as int32 (multiplication wraps around like the original uint32 arithmetic).
_PRIMES = (1, 2654435761 - 2 ** 32, 805459861)


@dataclass(frozen=True)
class HashGridConfig:
    """One multiresolution hash grid over the scene box, its cells sized in fruit diameters.

    The finest and coarsest resolutions follow from the box and the scene's fruit diameter d (see
    :meth:`resolutions`): a 6 m box and a 2 m box around the same tree resolve its fruit alike.
    """

    num_levels: int = 16
    """Number of resolution levels L."""
    features_per_level: int = 2
    """Features F stored per vertex."""
    log2_table_size: int = 19
    """log2 of the table entries T per level (at most 30)."""
    coarsest_cell: float = 5.0
    """Cell size of the coarsest level, in fruit diameters."""
    finest_cell: float = 0.05
    """Cell size of the finest level, in fruit diameters (geometric progression in between)."""
    max_resolution: int = 8192
    """Cap on the finest resolution (a huge box of small fruit would otherwise ask for more)."""

    def __post_init__(self) -> None:
        if not 1 <= self.num_levels <= 64 or self.features_per_level < 1:
            raise ConfigError(f'hash grid: num_levels must be in 1..64 and features_per_level >= 1, got '
                              f'{self.num_levels} / {self.features_per_level}')
        if not 4 <= self.log2_table_size <= 30:
            raise ConfigError(f'hash grid: log2_table_size must be in 4..30, got {self.log2_table_size}')
        if not 0 < self.finest_cell <= self.coarsest_cell:
            raise ConfigError(f'hash grid: need 0 < finest_cell <= coarsest_cell (fruit diameters), got '
                              f'{self.finest_cell} / {self.coarsest_cell}')
        if self.max_resolution < 2:
            raise ConfigError('hash grid: max_resolution must be >= 2')

    @property
    def output_dim(self) -> int:
        """Features per point, L * F."""
        return self.num_levels * self.features_per_level

    def resolutions(self, extent_m: float, fruit_diameter_m: float) -> tuple[int, int]:
        """(coarsest, finest) grid resolution over a box whose longest side is ``extent_m`` metres."""
        finest = min(self.max_resolution, max(2, math.ceil(extent_m / (self.finest_cell * fruit_diameter_m))))
        coarsest = min(finest, max(1, math.ceil(extent_m / (self.coarsest_cell * fruit_diameter_m))))
        return coarsest, finest


class HashGridEncoding(nn.Module):
    """Encode points of the unit cube [0, 1]^3 into ``num_levels * features_per_level`` features.

    Vertex indices are computed per axis and combined by broadcasting (dense levels: ``x + r1 * y + r1^2 * z``;
    hashed levels: ``x * p0 ^ y * p1 ^ z * p2`` masked to the table size), in int32. The table gradient is the
    backward of ``index_select`` (an index_add), deterministic on the CPU.

    Args:
        config: levels, features and table size.
        base_resolution: coarsest grid resolution over the unit cube.
        max_resolution: finest grid resolution (geometric progression in between).
        init_scale: table entries start uniform in [-init_scale, init_scale].
        generator: random source of the initial table (None: torch's global one).
    """

    def __init__(self, config: HashGridConfig, base_resolution: int, max_resolution: int, *,
                 init_scale: float = 1e-4, generator: torch.Generator | None = None) -> None:
        super().__init__()
        if not 1 <= base_resolution <= max_resolution:
            raise ConfigError(f'hash grid: need 1 <= base_resolution <= max_resolution, got {base_resolution} / '
                              f'{max_resolution}')
        self.config = config
        num_levels, features_per_level = config.num_levels, config.features_per_level
        self.num_levels = num_levels
        self.features_per_level = features_per_level
        self.table_size = 2 ** config.log2_table_size
        base, finest = base_resolution, max_resolution
        growth = math.exp((math.log(finest) - math.log(base)) / max(num_levels - 1, 1))
        resolutions = [int(math.floor(base * growth ** i)) for i in range(num_levels)]
        dense = torch.tensor([(r + 1) ** 3 <= self.table_size for r in resolutions])
        self.num_dense = int(dense.sum())  # resolutions grow, so the dense levels come first
        r1 = torch.tensor([r + 1 for r in resolutions], dtype=torch.int32)
        multipliers = torch.stack([
            torch.where(dense, torch.ones_like(r1), torch.full_like(r1, _PRIMES[0])),
            torch.where(dense, r1, torch.full_like(r1, _PRIMES[1])),
            torch.where(dense, r1 * r1, torch.full_like(r1, _PRIMES[2]))], 0)
        # Point-last layouts ([..., L, N]) keep the innermost loops long, which matters on the CPU.
        self.register_buffer('resolutions', torch.tensor(resolutions, dtype=torch.float32)[:, None],
                             persistent=False)                                                  # [L, 1]
        self.register_buffer('multipliers', multipliers[:, :, None], persistent=False)        # [3, L, 1] int32
        self.register_buffer('level_offsets',
                             (torch.arange(num_levels, dtype=torch.int32) * self.table_size)[:, None],
                             persistent=False)                                                  # [L, 1]
        #: [F, L * T]: feature-major, so each feature is one 1-D gather.
        self.table = nn.Parameter(torch.empty(features_per_level, num_levels * self.table_size))
        nn.init.uniform_(self.table, -init_scale, init_scale, generator=generator)
        #: [L, 1, 1] weight of each level's features: all 1 except while :meth:`open_levels` holds fine ones back
        #: (not saved: a loaded grid has every level open).
        self.register_buffer('level_weights', torch.ones(num_levels, 1, 1), persistent=False)

    @property
    def output_dim(self) -> int:
        return self.num_levels * self.features_per_level

    def open_levels(self, progress: float) -> None:
        """Open the levels coarse to fine (BARF's schedule, Lin et al. 2021): at ``progress`` 0 only the coarsest
        level contributes, each further one fades in with a cosine ramp, and from 1 on all do. In place (a compiled
        forward sees the new weights without recompiling)."""
        alpha = min(max(float(progress), 0.0), 1.0) * (self.num_levels - 1)
        ramp = (torch.arange(self.num_levels, dtype=torch.float32) - alpha).neg().add(1.0).clamp(0.0, 1.0)
        with torch.no_grad():
            self.level_weights.copy_((0.5 - 0.5 * torch.cos(math.pi * ramp))[:, None, None])

    def vertex_index(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Table indices [8, L, N] (int32, level offsets included) and trilinear weights [8, L, N] of ``x``."""
        n, nd, levels = x.shape[0], self.num_dense, self.num_levels
        xt = x.clamp(0.0, 1.0).to(torch.float32).T.contiguous()                         # [3, N]
        scaled = xt[:, None, :] * self.resolutions[None]                                # [3, L, N]
        # x = 1 lies on the last cell's far face: interpolate there (frac = 1) instead of indexing vertex res + 1
        floor = torch.minimum(torch.floor(scaled), self.resolutions[None] - 1.0)
        frac = scaled - floor
        low = floor.to(torch.int32) * self.multipliers
        ax, ay, az = torch.stack([low, low + self.multipliers], 1).unbind(0)           # [2, L, N] each
        parts = []
        if nd:
            dense = ax[:, None, None, :nd] + ay[None, :, None, :nd] + az[None, None, :, :nd]
            parts.append(dense.reshape(8, nd, n))
        if nd < levels:
            hashed = ax[:, None, None, nd:] ^ ay[None, :, None, nd:] ^ az[None, None, :, nd:]
            parts.append((hashed & (self.table_size - 1)).reshape(8, levels - nd, n))
        index = (torch.cat(parts, 1) if len(parts) > 1 else parts[0]) + self.level_offsets
        wx, wy, wz = torch.stack([1.0 - frac, frac], 1).unbind(0)                       # [2, L, N] each
        weights = (wx[:, None, None] * wy[None, :, None] * wz[None, None, :]).reshape(8, levels, n)
        return index, weights

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Features [N, L * F] (level-major) of points ``x`` [N, 3] in [0, 1]^3 (values outside are clamped).

        On the CPU the points are encoded ``CPU_CHUNK_POINTS`` at a time: the [8, L, N] index and weight tensors of
        a chunk stay in cache (measured on 50k points, one thread: 36 -> 16 ms without autograd, 56 -> 43 ms with
        its backward). The values are the same; only the order of the table gradient's sums changes.
        """
        if x.device.type == 'cpu' and x.shape[0] > CPU_CHUNK_POINTS:
            return torch.cat([self._encode(part) for part in x.split(CPU_CHUNK_POINTS)])
        return self._encode(x)

    def _encode(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[0]
        index, weights = self.vertex_index(x)
        flat = index.reshape(-1)
        features = [(self.table[f].index_select(0, flat).view(index.shape) * weights).sum(0)
                    for f in range(self.features_per_level)]                            # F x [L, N]
        stacked = torch.stack(features, -1) * self.level_weights                        # [L, N, F]
        return stacked.permute(1, 0, 2).reshape(n, self.output_dim)
