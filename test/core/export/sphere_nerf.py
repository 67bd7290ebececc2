"""An exact stand-in for a trained FruitField over the stand-in sphere scene (test/core/training/stand_in_scene.py):
opaque spheres (fruit or leaf) with a one-hot instance embedding each, optional semi-transparent fruit fog."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.fields.fruit_field import GeometryOutput
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid

AABB = np.array([[-1.2, -1.2, 0.0], [1.2, 1.2, 2.4]])


class SphereNeRF(nn.Module):
    """Density ``density`` inside every sphere (1/m); fruit logit +8 in fruit spheres (and in the fog), -8 elsewhere;
    embedding: one-hot of the sphere index. ``fog``: (centre, radius, density) of a fruit-labelled haze. ``veil``: the
    same for a haze of foliage (not fruit), as a briefly trained field leaves where leaves and gaps mix. ``faded``:
    sphere index -> density (1/m) for spheres the field renders semi-transparent."""

    def __init__(self, dataset_dir: Path, *, density: float = 400.0,
                 fog: tuple[np.ndarray, float, float] | None = None, faded: dict[int, float] | None = None,
                 veil: tuple[np.ndarray, float, float] | None = None, dim: int = 32) -> None:
        super().__init__()
        spheres = np.load(dataset_dir / 'spheres.npz')
        self.register_buffer('centres', torch.as_tensor(spheres['centres'], dtype=torch.float32))
        self.register_buffer('radii', torch.as_tensor(spheres['radii'], dtype=torch.float32))
        self.register_buffer('is_fruit', torch.as_tensor(spheres['is_fruit']))
        self.register_buffer('aabb', torch.as_tensor(AABB, dtype=torch.float32))
        self.density, self.fog, self.veil, self.dim = density, fog, veil, dim
        per_sphere = torch.full((len(self.centres),), float(density))
        for index, value in (faded or {}).items():
            per_sphere[index] = value
        self.register_buffer('sphere_density', per_sphere)
        self.anchor = nn.Parameter(torch.zeros(1))  # gives the module a device

    @property
    def embedding_dim(self) -> int:
        return self.dim

    def _nearest(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        gap = torch.cdist(xyz, self.centres) - self.radii[None]
        inside, index = gap.min(dim=1)
        return inside <= 0, index

    @staticmethod
    def _in_haze(xyz: torch.Tensor, haze: tuple[np.ndarray, float, float] | None) -> torch.Tensor:
        if haze is None:
            return torch.zeros(len(xyz), dtype=torch.bool, device=xyz.device)
        centre, radius, _ = haze
        return torch.linalg.norm(xyz - torch.as_tensor(centre, dtype=xyz.dtype, device=xyz.device), dim=1) < radius

    def geometry(self, xyz: torch.Tensor) -> GeometryOutput:
        inside, index = self._nearest(xyz)
        density = torch.where(inside, self.sphere_density[index], torch.tensor(0.0))
        for haze in (self.fog, self.veil):
            if haze is not None:
                density = torch.where(self._in_haze(xyz, haze) & ~inside, torch.tensor(float(haze[2])), density)
        return GeometryOutput(density, index[:, None].float())

    def rgb(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        fruit = self.is_fruit[features[:, 0].long()]
        return torch.where(fruit[:, None], torch.tensor([0.8, 0.1, 0.1]), torch.tensor([0.2, 0.5, 0.15]))

    def background_rgb(self, directions: torch.Tensor) -> torch.Tensor:
        return torch.full((len(directions), 3), 0.8)

    def beyond_box_rgb(self, rays, t_exit: torch.Tensor, jitter: torch.Tensor | None = None) -> torch.Tensor:
        return self.background_rgb(rays.directions)

    def fruit_logit(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        inside, index = self._nearest(xyz)
        fruit = (inside & self.is_fruit[index]) | (self._in_haze(xyz, self.fog) & ~inside)
        return torch.where(fruit, torch.tensor(8.0), torch.tensor(-8.0))

    def embedding(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        _, index = self._nearest(xyz)
        return torch.nn.functional.one_hot(index % self.dim, self.dim).float()


def full_grid() -> OccupancyGrid:
    """An occupancy grid over the scene box with every cell occupied."""
    return OccupancyGrid(torch.as_tensor(AABB, dtype=torch.float32), resolution=16, threshold=0.01, decay=0.95)
