"""Volume rendering weights, distortion loss, early termination, occupancy grid and ray marching."""

from __future__ import annotations

import math

import pytest
import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb, rays_for_pixels
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, FruitField, HashGridConfig
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, render_rays
from fruitnerfpp_ros.core.rendering.volume import accumulation, composite, distortion, render_weights

AABB = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])


def _rays(n: int) -> RayBundle:
    origins = torch.stack([torch.rand(n) * 0.8 + 0.1, torch.rand(n) * 0.8 + 0.1, torch.full((n,), 2.0)], -1)
    return RayBundle(origins, torch.tensor([[0.0, 0.0, -1.0]]).repeat(n, 1))


def test_constant_density_matches_beer_lambert() -> None:
    grid = OccupancyGrid(AABB, resolution=4, threshold=0.01, decay=0.95)
    samples = march_rays(_rays(8), grid, 0.01)
    sigma = 2.0
    weights = render_weights(samples, torch.full((len(samples.positions),), sigma))
    opacity = accumulation(samples, weights)
    assert torch.allclose(opacity, torch.full((8,), 1 - math.exp(-sigma * 1.0)), atol=1e-4)
    colour = composite(samples, weights, torch.ones(len(weights), 1))[:, 0]
    assert torch.allclose(colour, opacity)


def test_occupancy_grid_skips_empty_space() -> None:
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)

    def slab(xyz: torch.Tensor) -> torch.Tensor:  # dense only for z in [0.4, 0.6]
        return torch.where((xyz[:, 2] > 0.4) & (xyz[:, 2] < 0.6), 100.0, 0.0)

    grid.update(slab, 0.01, torch.Generator().manual_seed(0))
    assert 0.1 < grid.occupied_fraction <= 0.25  # 2 of 8 layers at most
    samples = march_rays(_rays(16), grid, 0.01)
    z = samples.positions[:, 2]
    assert bool(((z > 0.3) & (z < 0.7)).all()) and len(samples.positions) < 16 * 40


def test_occupancy_update_probes_every_occupied_cell_and_a_share_of_the_others() -> None:
    grid = OccupancyGrid(AABB, resolution=16, threshold=0.01, decay=0.5)
    probed: list[torch.Tensor] = []

    def ball(xyz: torch.Tensor) -> torch.Tensor:  # dense within 0.25 of the centre
        probed.append(grid.cell_index(xyz)[0])
        return torch.where((xyz - 0.5).norm(dim=-1) < 0.25, 100.0, 0.0)

    generator = torch.Generator().manual_seed(0)
    grid.update(ball, 0.01, generator, probe_fraction=0.25)  # a fresh grid is all occupied: every cell probed
    assert len(torch.cat(probed)) == 16 ** 3
    occupied = grid.occupied.clone()
    assert 0.03 < float(occupied.float().mean()) < 0.1
    probed.clear()
    grid.update(ball, 0.01, generator, probe_fraction=0.25, chunk=1000)
    cells = torch.cat(probed)
    assert len(torch.unique(cells)) == len(cells)  # one point per probed cell
    hit = torch.zeros(16 ** 3, dtype=torch.bool)
    hit[cells] = True
    assert bool(hit[occupied].all())  # every occupied cell, and about a quarter of the rest
    share = float(hit[~occupied].float().mean())
    assert 0.2 < share < 0.3
    assert bool(grid.occupied[occupied].all())  # an occupied cell stays occupied (its value only decays)
    # a cell left out only decays; the empty cells it left out still hold what they held, halved
    before = grid.values.clone()
    probed.clear()
    grid.update(lambda xyz: torch.zeros(len(xyz)), 0.01, generator, probe_fraction=0.25)
    assert torch.allclose(grid.values, before * 0.5)


def test_occupancy_update_of_every_cell_keeps_the_moving_maximum() -> None:
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.5)
    generator = torch.Generator().manual_seed(0)
    grid.update(lambda xyz: torch.full((len(xyz),), 4.0), 0.01, generator)
    assert torch.allclose(grid.values, torch.full((8 ** 3,), 0.04)) and bool(grid.occupied.all())
    grid.update(lambda xyz: torch.full((len(xyz),), 1.0), 0.01, generator, probe_fraction=1.0)
    assert torch.allclose(grid.values, torch.full((8 ** 3,), 0.02))  # max(0.04 x 0.5, 0.01)


def test_pixel_rays_follow_opengl_convention() -> None:
    T = torch.eye(4)[None]
    K = torch.tensor([[10.0, 10.0, 4.0, 4.0]])
    rays = rays_for_pixels(T, K, torch.tensor([0, 0]), torch.tensor([3, 0]), torch.tensor([3, 7]))
    assert torch.allclose(rays.directions[0], torch.tensor([-0.05, 0.05, -1.0]) / math.sqrt(1.005), atol=1e-6)
    assert float(rays.directions[1, 0]) > 0 and float(rays.directions[1, 1]) > 0  # top-right pixel: +x, +y
    near, far = intersect_aabb(RayBundle(torch.tensor([[0.5, 0.5, 3.0]]), torch.tensor([[0.0, 0.0, -1.0]])), AABB)
    assert float(near) == 2.0 and float(far) == 3.0


def _random_samples(n_rays: int = 6, seed: int = 0) -> tuple:
    """Packed samples of rays through the unit box with a random, partly empty occupancy grid."""
    torch.manual_seed(seed)
    grid = OccupancyGrid(AABB, resolution=4, threshold=0.01, decay=0.95)
    grid.occupied.copy_(torch.rand(64) > 0.3)
    samples = march_rays(_rays(n_rays), grid, 0.05)
    return samples, torch.rand(len(samples.positions), dtype=torch.float64) * 0.2


def test_distortion_loss_equals_the_brute_force_double_sum() -> None:
    samples, weights = _random_samples()
    t = (samples.slot % samples.max_samples).double() * samples.step
    expected = 0.0
    for ray in range(samples.num_rays):
        on = samples.ray_index == ray
        w, s = weights[on], t[on]
        expected += float((w[:, None] * w[None, :] * (s[:, None] - s[None, :]).abs()).sum()
                          + (w ** 2).sum() * samples.step / 3.0)
    assert float(distortion(samples, weights)) == pytest.approx(expected / samples.num_rays, rel=1e-9)
    # restricted to the first rays: their own mean, the others ignored
    first = samples.ray_index < 2
    only = float(distortion(samples, weights, num_rays=2))
    weights_rest = torch.where(first, weights, weights * 7.0)
    assert float(distortion(samples, weights_rest, num_rays=2)) == pytest.approx(only, rel=1e-12)
    assert only != pytest.approx(float(distortion(samples, weights)))


def _opaque_field() -> tuple[FruitField, OccupancyGrid]:
    """A small random field whose density (e^4 per metre) turns a 1 m ray opaque, and an all-occupied grid."""
    torch.manual_seed(0)
    field = FruitField(FieldConfig(geometry_grid=HashGridConfig(num_levels=4, log2_table_size=12, coarsest_cell=1.0,
                                                                finest_cell=0.125), hidden_dim=16, density_bias=4.0),
                       AABB.numpy(), 0.25)
    return field, OccupancyGrid(AABB, resolution=4, threshold=0.01, decay=0.95)


def test_rendering_with_and_without_early_termination_is_equal() -> None:
    """Dropping samples behind transmittance 1e-3 changes the rendered colour by less than that bound."""
    field, grid = _opaque_field()
    rays = _rays(32)
    full = render_rays(field, grid, rays, RenderSettings(step=0.01, near=0.0, stop_transmittance=0.0))
    early = render_rays(field, grid, rays, RenderSettings(step=0.01, near=0.0, stop_transmittance=1e-3))
    assert early.num_samples < full.num_samples  # it did drop samples (density e^4 over 1 m is opaque)
    assert torch.allclose(early.rgb, full.rgb, atol=2e-3) and torch.allclose(early.opacity, full.opacity, atol=2e-3)


def test_inference_evaluates_the_heads_only_where_the_weight_counts() -> None:
    """Without autograd the colour and semantic heads see only the samples of weight > weight_threshold; the
    rendered colour and fruit probability stay within the dropped weight of the full composite."""
    field, grid = _opaque_field()
    rays = _rays(32)
    settings = RenderSettings(step=0.01, near=0.0, stop_transmittance=0.0, weight_threshold=1e-4)
    seen: list[int] = []
    logit = field.fruit_logit

    def counted_logit(xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        seen.append(len(xyz))
        return logit(xyz, features)

    field.fruit_logit = counted_logit  # type: ignore[method-assign]
    full = render_rays(field, grid, rays, settings, semantic=True)          # autograd on: every sample
    with torch.no_grad():
        fast = render_rays(field, grid, rays, settings, semantic=True)
    assert seen[0] == full.num_samples and 0 < seen[1] < full.num_samples / 2
    assert torch.allclose(fast.rgb, full.rgb.detach(), atol=2e-3)
    assert torch.allclose(fast.fruit_prob, full.fruit_prob.detach(), atol=2e-3)
    assert torch.equal(fast.opacity, full.opacity.detach())


def test_inference_marches_front_to_back_and_stops_at_opaque_surfaces() -> None:
    """Without autograd the field is evaluated window by window along the rays and no longer behind the point
    where a ray's transmittance fell below stop_transmittance: fewer evaluations, the same picture and depth."""
    field, grid = _opaque_field()
    rays = _rays(32)
    evaluated: list[int] = []

    def geometry(xyz: torch.Tensor):  # type: ignore[no-untyped-def]
        evaluated.append(len(xyz))
        return field.geometry(xyz)

    with torch.no_grad():
        full = render_rays(field, grid, rays, RenderSettings(step=0.01, near=0.0, stop_transmittance=0.0),
                           semantic=True, instance=True, depth=True, geometry_fn=geometry)
        n_full = sum(evaluated)
        evaluated.clear()
        fast = render_rays(field, grid, rays, RenderSettings(step=0.01, near=0.0, stop_transmittance=1e-3),
                           semantic=True, instance=True, depth=True, geometry_fn=geometry)
    assert n_full == full.num_samples and max(evaluated) <= 16 * len(rays.origins) and sum(evaluated) < n_full / 2
    for a, b in ((fast.rgb, full.rgb), (fast.opacity, full.opacity), (fast.fruit_prob, full.fruit_prob),
                 (fast.embedding, full.embedding)):
        assert torch.allclose(a, b, atol=2e-3)
    assert torch.equal(fast.depth, full.depth)
