"""The FruitNeRF++ field: density, colour, fruit semantics and instance embeddings over one scene box.

One geometry hash grid feeds the density MLP, which outputs the density and a geometry feature vector. The colour
head reads that feature plus the SH-encoded view direction. The semantic head and the instance head read the
feature **detached**, so their losses never change density; each adds its own small hash grid over the raw
position (fruit boundaries and fruits next to each other need features finer than the 15-d geometry feature
carries, above all early in training).

Points are normalised per axis to the unit cube of the scene box; density is returned in 1/m and is zero
outside the box. Space outside the box (ground, sky) is the optional outer field's (outer_field.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, NamedTuple

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.fields.hash_grid import HashGridEncoding
from fruitnerfpp_ros.core.fields.mlp import make_mlp, spherical_harmonics, trunc_exp
from fruitnerfpp_ros.core.fields.outer_field import OuterField
from fruitnerfpp_ros.core.fields.query import FieldQuery

__all__ = ['FieldConfig', 'FruitField', 'GeometryOutput']


@dataclass(frozen=True)
class FieldConfig:
    """Sizes of the encodings and heads of :class:`FruitField`."""

    num_levels: int = 16
    """Geometry hash grid: number of resolution levels."""
    features_per_level: int = 2
    """Geometry hash grid: features per level."""
    log2_table_size: int = 19
    """Geometry hash grid: log2 of entries per level."""
    base_resolution: int = 16
    """Geometry hash grid: coarsest resolution over the scene box."""
    max_resolution: int = 2048
    """Geometry hash grid: finest resolution over the scene box."""
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
    semantic_layers: int = 2
    """Hidden layers of the semantic MLP."""
    semantic_num_levels: int = 8
    """Semantic hash grid (the head's own position encoding, next to the detached geometry feature): levels."""
    semantic_log2_table_size: int = 17
    """Semantic hash grid: log2 of entries per level."""
    semantic_base_resolution: int = 16
    """Semantic hash grid: coarsest resolution."""
    semantic_max_resolution: int = 512
    """Semantic hash grid: finest resolution."""
    embedding_dim: int = 32
    """D, the instance embedding size (the paper needs D >= 16 for apples)."""
    instance_num_levels: int = 8
    """Instance hash grid: number of levels."""
    instance_log2_table_size: int = 17
    """Instance hash grid: log2 of entries per level."""
    instance_base_resolution: int = 16
    """Instance hash grid: coarsest resolution."""
    instance_max_resolution: int = 512
    """Instance hash grid: finest resolution."""
    instance_hidden_dim: int = 64
    """Width of the instance MLP."""
    instance_layers: int = 2
    """Hidden layers of the instance MLP."""
    background_sh: bool = False
    """Let the background colour vary with the ray direction (an environment map)."""
    density_bias: float | None = None
    """Initial bias of the density output (density = exp(raw) 1/m); None = the trainer's choice: half the
    occupancy threshold's density at the run's marching step, so untrained space starts just below occupied."""
    outer_samples: int = 0
    """Samples per ray of the outer field that models the ground and sky beyond the scene box (outer_field.py),
    spaced evenly in inverse distance; 0 = no outer field, a background colour only."""
    outer_far_factor: float = 20.0
    """The outer field is rendered from where a ray leaves the box to this many box diagonals beyond."""
    outer_num_levels: int = 4
    """Outer field hash grid (over the contracted cube): levels. Kept coarse on purpose: 8 levels up to 512
    painted the tree onto the shell behind the box and left the box empty (docs/results/tiny_preset.md)."""
    outer_log2_table_size: int = 17
    """Outer field hash grid: log2 of entries per level."""
    outer_max_resolution: int = 64
    """Outer field hash grid: finest resolution over the contracted cube (the box spans half of it)."""


class GeometryOutput(NamedTuple):
    """Density [N] (1/m) and geometry features [N, geo_feature_dim] at N points."""

    density: torch.Tensor
    features: torch.Tensor


class FruitField(nn.Module):
    """Neural field over the box ``aabb`` [2, 3] (metres, world frame).

    Satisfies :class:`fruitnerfpp_ros.core.fields.query.QueryableField`.
    """

    def __init__(self, config: FieldConfig, aabb: np.ndarray | torch.Tensor) -> None:
        super().__init__()
        self.config = config
        self.register_buffer('aabb', torch.as_tensor(np.asarray(aabb, dtype=np.float32)).clone())
        c = config
        self.encoding = HashGridEncoding(num_levels=c.num_levels, features_per_level=c.features_per_level,
                                         log2_table_size=c.log2_table_size, base_resolution=c.base_resolution,
                                         max_resolution=c.max_resolution)
        self.density_mlp = make_mlp(self.encoding.output_dim, c.hidden_dim, c.density_layers, 1 + c.geo_feature_dim)
        if c.density_bias is not None:
            with torch.no_grad():
                self.density_mlp[-1].bias[0].fill_(c.density_bias)
        self.color_mlp = make_mlp(c.geo_feature_dim + c.sh_degree ** 2, c.hidden_dim, c.color_layers, 3)
        # Colour of rays leaving the box (sky, distant ground) as a function of the ray direction.
        self.background = nn.Linear(c.sh_degree ** 2, 3)
        nn.init.zeros_(self.background.weight)
        nn.init.zeros_(self.background.bias)
        self.outer = None if c.outer_samples <= 0 else OuterField(
            self.aabb, num_levels=c.outer_num_levels, log2_table_size=c.outer_log2_table_size,
            base_resolution=c.base_resolution, max_resolution=c.outer_max_resolution, hidden_dim=c.hidden_dim,
            sh_degree=c.sh_degree)
        self.semantic_encoding = HashGridEncoding(
            num_levels=c.semantic_num_levels, features_per_level=2, log2_table_size=c.semantic_log2_table_size,
            base_resolution=c.semantic_base_resolution, max_resolution=c.semantic_max_resolution)
        self.semantic_mlp = make_mlp(self.semantic_encoding.output_dim + c.geo_feature_dim, c.hidden_dim,
                                     c.semantic_layers, 1)
        self.instance_encoding = HashGridEncoding(
            num_levels=c.instance_num_levels, features_per_level=2, log2_table_size=c.instance_log2_table_size,
            base_resolution=c.instance_base_resolution, max_resolution=c.instance_max_resolution)
        self.instance_mlp = make_mlp(self.instance_encoding.output_dim + c.geo_feature_dim, c.instance_hidden_dim,
                                     c.instance_layers, c.embedding_dim)

    # -- parameter groups of the cascaded schedule ------------------------------------------------------------
    def geometry_parameters(self) -> Iterator[nn.Parameter]:
        """Density + colour (+ background colour and outer field): trained in stages 1 and 2."""
        for module in (self.encoding, self.density_mlp, self.color_mlp, self.background, self.outer):
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

    def density_and_fruit_prob(self, xyz: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density [N] (1/m) and fruit probability [N] at world points [N, 3], without the colour and instance heads
        (the cheap pass of an export)."""
        with torch.no_grad():
            xyz = xyz.to(self.aabb.device, torch.float32)
            geo = self.geometry(xyz)
            return geo.density, torch.sigmoid(self.fruit_logit(xyz, geo.features))

    def fruit_logit(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Fruit logit [N] at world points [N, 3] from the head's own encoding and the detached geometry features
        (no gradient reaches density)."""
        inputs = torch.cat([self.semantic_encoding(self.normalize(xyz)).to(features.dtype), features.detach()], -1)
        return self.semantic_mlp(inputs)[:, 0].float()

    def embedding(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Raw (not normalised) instance embedding [N, D]; geometry features are detached."""
        inputs = torch.cat([self.instance_encoding(self.normalize(xyz)).to(features.dtype), features.detach()], -1)
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
