"""The outer field beyond the scene box: contraction and its rendering behind the box."""

from __future__ import annotations

import math

import pytest
import torch

from fruitnerfpp_ros.core.data.rays import RayBundle
from fruitnerfpp_ros.core.fields.outer_field import OuterField, OuterOutput, contract_to_unit
from fruitnerfpp_ros.core.rendering.outer import render_outer

AABB = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 1.0]])


def test_contraction_keeps_the_box_and_folds_space_around_it() -> None:
    inside = AABB[0] + torch.rand(500, 3) * (AABB[1] - AABB[0])
    unit = contract_to_unit(inside, AABB)
    assert ((unit >= 0.25) & (unit <= 0.75)).all()
    assert torch.allclose(unit, 0.25 + 0.5 * (inside - AABB[0]) / (AABB[1] - AABB[0]), atol=1e-6)
    direction = torch.nn.functional.normalize(torch.randn(500, 3), dim=-1)
    far = contract_to_unit(direction * 1e6, AABB)
    assert ((far - 0.5).abs().amax(-1) > 0.4999).all()  # infinity lies on the cube's faces
    # continuous and monotone along a ray leaving the box
    t = torch.linspace(0.0, 50.0, 2001)[:, None]
    line = contract_to_unit(torch.tensor([[0.5, 0.0, 0.5]]) + t * torch.tensor([[1.0, 0.0, 0.0]]), AABB)
    assert (line[1:, 0] - line[:-1, 0] >= 0).all() and (line[1:, 0] - line[:-1, 0]).max() < 0.01


class _Wall(OuterField):
    """Opaque red where x > wall, empty elsewhere (stands in for a trained outer field)."""

    def __init__(self, wall: float) -> None:
        super().__init__(AABB, num_levels=2, log2_table_size=8, base_resolution=4, max_resolution=8, hidden_dim=8,
                         sh_degree=1)
        self.wall = wall

    def forward(self, xyz: torch.Tensor, directions: torch.Tensor) -> OuterOutput:
        density = torch.where(xyz[:, 0] > self.wall, 1e3, 0.0)
        return OuterOutput(density, torch.tensor([1.0, 0.0, 0.0]).expand(len(xyz), 3))


@pytest.mark.parametrize('jitter', [None, 0.3])
def test_rays_see_what_lies_beyond_the_box(jitter: float | None) -> None:
    origins = torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]])
    directions = torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])  # towards the wall at x = 10, away from it
    n = len(origins)
    rgb, opacity = render_outer(_Wall(10.0), RayBundle(origins, directions), num_samples=64, far_factor=20.0,
                                near=0.05, jitter=None if jitter is None else torch.full((n,), jitter))
    assert opacity[0] == pytest.approx(1.0, abs=1e-4) and torch.allclose(rgb[0], torch.tensor([1.0, 0.0, 0.0]),
                                                                         atol=1e-4)
    assert float(opacity[1]) == 0.0 and float(rgb[1].abs().sum()) == 0.0


def test_samples_are_even_in_disparity_from_the_box_exit() -> None:
    seen: list[torch.Tensor] = []

    class Probe(_Wall):
        def forward(self, xyz: torch.Tensor, directions: torch.Tensor) -> OuterOutput:
            seen.append(xyz)
            return super().forward(xyz, directions)

    k = 16
    render_outer(Probe(1e9), RayBundle(torch.tensor([[0.0, 0.0, 0.5]]), torch.tensor([[1.0, 0.0, 0.0]])),
                 num_samples=k, far_factor=10.0, near=0.05)
    t = seen[0][:, 0]  # the ray runs along +x from x = 0: t = x; it leaves the box at t = 1
    start, end = 1.0, 1.0 + 10.0 * float(torch.linalg.norm(AABB[1] - AABB[0]))
    s = (torch.arange(k) + 0.5) / k
    assert torch.allclose(t, 1.0 / ((1 - s) / start + s / end), rtol=1e-5)
    assert t.min() > start and t.max() < end and not math.isnan(float(t.sum()))
