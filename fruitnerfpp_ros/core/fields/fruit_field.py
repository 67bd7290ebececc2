"""The FruitNeRF++ field: density, colour, fruit semantics and instance embeddings over one scene box.

One geometry hash grid feeds the density MLP, which outputs the density and a geometry feature vector. The colour
head reads that feature plus the SH-encoded view direction. The semantic head and the instance head read the
feature **detached**, and the sample positions detached, so their losses never change density nor the camera
poses; each adds its own small hash grid over the raw position (fruit boundaries and fruits next to each other
need features finer than the 15-d geometry feature carries, above all early in training).

Points are normalised per axis to the unit cube of the scene box; density is returned in 1/m and is zero
outside the box. What rays see after they leave the box comes from the far field (:mod:`.far_field`): a coarse
density + colour field over contracted space, trained with the geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as _field
from typing import Iterator, NamedTuple

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.data.rays import RayBundle
from fruitnerfpp_ros.core.fields.far_field import FarField, FarFieldConfig, far_sample_distances
from fruitnerfpp_ros.core.fields.hash_grid import HashGridConfig, HashGridEncoding
from fruitnerfpp_ros.core.fields.mlp import init_mlp, make_mlp, spherical_harmonics, trunc_exp
from fruitnerfpp_ros.core.fields.query import FieldQuery

__all__ = ['FarFieldConfig', 'FieldConfig', 'FruitField', 'GeometryOutput', 'HashGridConfig']

#: Optical depth of a far-field interval beyond which it is opaque (transmittance e^-30).
_OPAQUE_TAU = 30.0


@dataclass(frozen=True)
class FieldConfig:
    """Sizes of the encodings and heads of :class:`FruitField`."""

    geometry_grid: HashGridConfig = _field(default_factory=HashGridConfig)
    """Hash grid of the density / colour field."""
    hidden_dim: int = 64
    """Width of the density, colour and semantic MLPs."""
    density_layers: int = 1
    """Hidden layers of the density MLP."""
    geo_feature_dim: int = 15
    """Size of the geometry feature passed to the other heads."""
    color_layers: int = 2
    """Hidden layers of the colour MLP."""
    sh_degree: int = 4
    """Spherical-harmonic degree (1..4) of the view-direction encoding."""
    semantic_grid: HashGridConfig = _field(default_factory=lambda: HashGridConfig(
        num_levels=8, log2_table_size=17, coarsest_cell=5.0, finest_cell=0.15))
    """The semantic head's own position encoding, next to the detached geometry feature."""
    semantic_layers: int = 2
    """Hidden layers of the semantic MLP."""
    embedding_dim: int = 32
    """D, the instance embedding size (the paper needs D >= 16 for apples)."""
    instance_grid: HashGridConfig = _field(default_factory=lambda: HashGridConfig(
        num_levels=8, log2_table_size=17, coarsest_cell=5.0, finest_cell=0.15))
    """The instance head's own position encoding."""
    instance_hidden_dim: int = 64
    """Width of the instance MLP."""
    instance_layers: int = 2
    """Hidden layers of the instance MLP."""
    background_sh: bool = False
    """Let the background colour vary with the ray direction (an environment map)."""
    far_field: FarFieldConfig = _field(default_factory=FarFieldConfig)
    """The field beyond the scene box (ground and orchard seen past the tree); ``samples: 0`` = a constant
    background colour only."""
    density_bias: float | None = None
    """Initial bias of the density output (density = exp(raw) 1/m); None = the trainer's choice: half the
    occupancy threshold's density at the run's marching step, so untrained space starts just below occupied."""


class GeometryOutput(NamedTuple):
    """Density [N] (1/m) and geometry features [N, geo_feature_dim] at N points."""

    density: torch.Tensor
    features: torch.Tensor


class FruitField(nn.Module):
    """Neural field over the box ``aabb`` [2, 3] (metres, world frame).

    Satisfies :class:`fruitnerfpp_ros.core.fields.query.QueryableField`.

    Args:
        config: encodings and heads.
        aabb: [2, 3] scene box, metres.
        fruit_diameter_m: the scene's fruit diameter: the grids' cell sizes are given in it.
        generator: random source of every initial weight (None: torch's global one). The trainer passes its own,
            so a run is reproducible without seeding the process.
    """

    def __init__(self, config: FieldConfig, aabb: np.ndarray | torch.Tensor, fruit_diameter_m: float,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.config = config
        self.fruit_diameter_m = float(fruit_diameter_m)
        self.register_buffer('aabb', torch.as_tensor(np.asarray(aabb, dtype=np.float32)).clone())
        c = config
        extent = float((self.aabb[1] - self.aabb[0]).max())

        def grid(grid_config: HashGridConfig) -> HashGridEncoding:
            return HashGridEncoding(grid_config, *grid_config.resolutions(extent, self.fruit_diameter_m),
                                    generator=generator)

        self.encoding = grid(c.geometry_grid)
        self.density_mlp = make_mlp(self.encoding.output_dim, c.hidden_dim, c.density_layers, 1 + c.geo_feature_dim)
        self.color_mlp = make_mlp(c.geo_feature_dim + c.sh_degree ** 2, c.hidden_dim, c.color_layers, 3)
        # Colour of rays leaving the box (sky, distant ground) as a function of the ray direction.
        self.background = nn.Linear(c.sh_degree ** 2, 3)
        self.semantic_encoding = grid(c.semantic_grid)
        self.semantic_mlp = make_mlp(self.semantic_encoding.output_dim + c.geo_feature_dim, c.hidden_dim,
                                     c.semantic_layers, 1)
        self.instance_encoding = grid(c.instance_grid)
        self.instance_mlp = make_mlp(self.instance_encoding.output_dim + c.geo_feature_dim, c.instance_hidden_dim,
                                     c.instance_layers, c.embedding_dim)
        for mlp in (self.density_mlp, self.color_mlp, self.semantic_mlp, self.instance_mlp):
            init_mlp(mlp, generator)
        with torch.no_grad():
            nn.init.zeros_(self.background.weight)
            nn.init.zeros_(self.background.bias)
            if c.density_bias is not None:
                self.density_mlp[-1].bias[0].fill_(c.density_bias)
        # created last: the other modules draw the same initial weights with and without it
        self.far = FarField(c.far_field, generator) if c.far_field.enabled else None

    # -- parameter groups of the cascaded schedule ------------------------------------------------------------
    def geometry_parameters(self) -> Iterator[nn.Parameter]:
        """Density + colour (+ background colour and the far field): trained in stages 1 and 2."""
        for module in (self.encoding, self.density_mlp, self.color_mlp, self.background, self.far):
            if module is not None:
                yield from module.parameters()

    def semantic_parameters(self) -> Iterator[nn.Parameter]:
        """The semantic encoding and head: trained in stage 2."""
        yield from self.semantic_encoding.parameters()
        yield from self.semantic_mlp.parameters()

    def instance_parameters(self) -> Iterator[nn.Parameter]:
        """The instance encoding and head: trained in stage 3 only."""
        yield from self.instance_encoding.parameters()
        yield from self.instance_mlp.parameters()

    # -- evaluation -------------------------------------------------------------------------------------------
    @property
    def embedding_dim(self) -> int:
        return self.config.embedding_dim

    def normalize(self, xyz: torch.Tensor) -> torch.Tensor:
        """World points [N, 3] -> unit-cube coordinates of the scene box."""
        return (xyz - self.aabb[0]) / (self.aabb[1] - self.aabb[0])

    def geometry(self, xyz: torch.Tensor) -> GeometryOutput:
        """Density (1/m, zero outside the box) and geometry features at world points ``xyz`` [N, 3]."""
        unit = self.normalize(xyz)
        inside = ((unit >= 0.0) & (unit <= 1.0)).all(-1)
        out = self.density_mlp(self.encoding(unit))
        density = trunc_exp(out[:, 0].float()) * inside.to(torch.float32)
        return GeometryOutput(density, out[:, 1:])

    def rgb(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Colour [N, 3] in [0, 1] from geometry features and unit view directions [N, 3]."""
        sh = spherical_harmonics(directions, self.config.sh_degree).to(features.dtype)
        return torch.sigmoid(self.color_mlp(torch.cat([features, sh], -1)).float())

    def background_rgb(self, directions: torch.Tensor) -> torch.Tensor:
        """Colour [N, 3] seen along unit ``directions`` [N, 3] by rays that leave the box.

        Only the constant (degree-0) part is used unless ``background_sh`` is set: a direction-dependent
        background can paint the whole scene and leave the geometry transparent.
        """
        sh = spherical_harmonics(directions, self.config.sh_degree)
        if not self.config.background_sh:  # the constant term only (no host-to-device copy per call)
            sh = torch.cat([sh[:, :1], torch.zeros_like(sh[:, 1:])], dim=1)
        return torch.sigmoid(self.background(sh.to(self.background.weight.dtype)).float())

    def beyond_box_rgb(self, rays: RayBundle, t_exit: torch.Tensor, jitter: torch.Tensor | None = None
                       ) -> torch.Tensor:
        """Colour [N, 3] that ``rays`` see after leaving the box at distance ``t_exit`` [N]: the far field's samples
        composited front to back (``jitter``: [N] sample offsets in [0, 1) in training), the background colour
        where the far field stays transparent; the background colour alone without a far field."""
        background = self.background_rgb(rays.directions)
        if self.far is None or len(t_exit) == 0:
            return background
        # rays detached: the far field's points lie up to hundreds of metres out, where a pose's rotation moves
        # them by metres; the camera poses are refined from the box alone
        t, length = far_sample_distances(t_exit.detach(), self.far.config.samples, jitter,
                                         self.far.config.units_per_metre)
        points = rays.origins.detach()[:, None, :] + t[..., None] * rays.directions.detach()[:, None, :]
        density, colour = self.far(2.0 * self.normalize(points.reshape(-1, 3)) - 1.0)
        # optical depth per interval capped where it is opaque anyway (the unbounded last one would overflow)
        tau = (density.view(t.shape) * length).clamp(max=_OPAQUE_TAU)
        before = torch.cumsum(tau, dim=1) - tau
        weights = torch.exp(-before) * (1.0 - torch.exp(-tau))
        far_rgb = (weights[..., None] * colour.view(*t.shape, 3)).sum(1)
        return far_rgb + torch.exp(-(before[:, -1:] + tau[:, -1:])) * background

    def density_and_fruit_prob(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density [N] (1/m) and fruit probability [N] at world points [N, 3], without the colour and instance heads
        (the cheap pass of an export)."""
        with torch.no_grad():
            xyz = xyz.to(self.aabb.device, torch.float32)
            geo = self.geometry(xyz)
            return geo.density, torch.sigmoid(self.fruit_logit(xyz, geo.features))

    def fruit_logit(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Fruit logit [N] at world points [N, 3] from the head's own encoding and the detached geometry features.

        Positions and features are detached: no gradient of the semantic loss reaches density or, through the
        sample positions, the camera poses.
        """
        inputs = torch.cat([self.semantic_encoding(self.normalize(xyz.detach())).to(features.dtype),
                            features.detach()], -1)
        return self.semantic_mlp(inputs)[:, 0].float()

    def embedding(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Raw (not normalised) instance embedding [N, D]; positions and geometry features are detached."""
        inputs = torch.cat([self.instance_encoding(self.normalize(xyz.detach())).to(features.dtype),
                            features.detach()], -1)
        return self.instance_mlp(inputs).float()

    @torch.no_grad()
    def query(self, xyz: torch.Tensor) -> FieldQuery:
        """Field values at world points ``xyz`` [N, 3] (metres); rgb seen looking down (direction -z)."""
        xyz = xyz.to(self.aabb.device, torch.float32)
        geo = self.geometry(xyz)
        down = torch.zeros_like(xyz)
        down[:, 2] = -1.0
        return FieldQuery(
            density=geo.density,
            rgb=self.rgb(geo.features, down),
            fruit_prob=torch.sigmoid(self.fruit_logit(xyz, geo.features)),
            embedding=torch.nn.functional.normalize(self.embedding(xyz, geo.features), dim=-1),
        )
