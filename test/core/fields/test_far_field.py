"""The far field: contraction, samples beyond the box, what a ray leaving the box sees, and who trains it."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from fruitnerfpp_ros.core.data.rays import RayBundle
from fruitnerfpp_ros.core.fields.far_field import FarFieldConfig, contract, far_sample_distances
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, FruitField, HashGridConfig
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, render_rays
from fruitnerfpp_ros.core.training.losses import prototype_infonce, semantic_loss
from fruitnerfpp_ros.errors import ConfigError

SMALL = FieldConfig(
    geometry_grid=HashGridConfig(num_levels=4, log2_table_size=12, coarsest_cell=2.0, finest_cell=0.25),
    semantic_grid=HashGridConfig(num_levels=2, log2_table_size=10, coarsest_cell=2.0, finest_cell=0.5),
    instance_grid=HashGridConfig(num_levels=2, log2_table_size=10, coarsest_cell=2.0, finest_cell=0.5),
    hidden_dim=16, embedding_dim=8, instance_hidden_dim=16,
    far_field=FarFieldConfig(samples=8, base_resolution=4, max_resolution=32, num_levels=3, log2_table_size=10,
                             hidden_dim=8))
FRUIT_M = 0.25
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
SETTINGS = RenderSettings(step=0.05, near=0.0)


def _outward_rays(n: int = 32) -> RayBundle:
    """Rays from the box centre out through its sides, slightly upward."""
    angle = torch.linspace(0.0, 6.0, n)
    directions = torch.nn.functional.normalize(torch.stack([angle.cos(), angle.sin(), torch.full_like(angle, 0.2)],
                                                           1), dim=-1)
    return RayBundle(torch.zeros(n, 3), directions)


def _empty_box_field(config: FieldConfig) -> FruitField:
    """A field whose box is empty (density ~0) and whose far field, if any, is opaque and red."""
    field = FruitField(config, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        field.density_mlp[-1].weight.zero_()
        field.density_mlp[-1].bias[0].fill_(-30.0)
        if field.far is not None:
            field.far.mlp[-1].weight.zero_()
            field.far.mlp[-1].bias.copy_(torch.tensor([3.0, 8.0, -8.0, -8.0]))  # density e^3 /m, red
    return field


def test_contraction_keeps_the_box_and_brings_infinity_to_the_cube_of_side_four() -> None:
    inside = torch.rand(100, 3) * 2 - 1
    assert torch.equal(contract(inside), inside)
    direction = torch.nn.functional.normalize(torch.tensor([[1.0, 0.3, -0.5]]), dim=-1)
    far = torch.tensor([1.0, 2.0, 10.0, 1e3, 1e6])[:, None] * direction / direction.abs().max()
    norms = contract(far).abs().amax(-1)
    assert torch.allclose(norms, torch.tensor([1.0, 1.5, 1.9, 1.999, 2.0]), atol=1e-5)
    # straight through the boundary without a jump, and in the same direction
    edge = torch.tensor([[0.999, 0.2, 0.1], [1.001, 0.2, 0.1]])
    assert float((contract(edge)[1] - contract(edge)[0]).norm()) < 3e-3
    assert torch.allclose(torch.nn.functional.normalize(contract(far), dim=-1), direction.expand(5, 3), atol=1e-6)


def test_far_samples_run_from_the_box_exit_to_infinity_evenly_in_inverse_distance() -> None:
    t_exit = torch.tensor([0.5, 2.0, 7.0])
    t, length = far_sample_distances(t_exit, 8)
    assert t.shape == length.shape == (3, 8)
    assert bool((t >= t_exit[:, None]).all()) and bool((t[:, 1:] > t[:, :-1]).all())
    starts = t_exit[:, None] + torch.cat([torch.zeros(3, 1), torch.cumsum(length, 1)[:, :-1]], 1)
    assert torch.allclose(1.0 / starts, (1.0 / t_exit)[:, None] * (1 - torch.arange(8) / 8), rtol=1e-5)
    assert bool((t >= starts).all()) and bool((t[:, :-1] <= (starts + length)[:, :-1]).all())
    assert bool((length[:, -1] >= 1e3).all())  # the last interval is unbounded: the far field ends opaque
    jittered, _ = far_sample_distances(t_exit, 8, torch.tensor([0.0, 0.3, 0.99]))
    assert bool((jittered >= starts).all()) and bool((jittered[:, :-1] <= (starts + length)[:, :-1]).all())


def test_a_ray_leaving_an_empty_box_sees_the_far_field_and_without_one_the_background() -> None:
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    rays = _outward_rays()
    with_far = _empty_box_field(SMALL)
    without = _empty_box_field(dataclasses.replace(SMALL, far_field=FarFieldConfig(samples=0)))
    assert without.far is None
    with torch.no_grad():
        seen = render_rays(with_far, grid, rays, SETTINGS)
        plain = render_rays(without, grid, rays, SETTINGS)
    assert float(seen.opacity.max()) < 1e-6 and float(plain.opacity.max()) < 1e-6  # nothing in the box
    assert torch.allclose(seen.rgb, torch.tensor([1.0, 0.0, 0.0]).expand(32, 3), atol=1e-3)
    background = without.background_rgb(rays.directions)
    assert torch.allclose(plain.rgb, background, atol=1e-6)


def test_an_opaque_box_hides_the_far_field() -> None:
    field = _empty_box_field(SMALL)
    with torch.no_grad():
        field.density_mlp[-1].bias[0].fill_(8.0)  # 3000 /m: opaque within a few centimetres
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    rays = _outward_rays()
    with torch.no_grad():
        out = render_rays(field, grid, rays, SETTINGS)
        # the density MLP's output weights are zero: its features are the same everywhere
        box_only = field.rgb(field.geometry(torch.zeros(32, 3)).features, rays.directions)
    assert float(out.opacity.min()) > 0.999
    assert float((out.rgb - box_only).abs().max()) < 2e-3
    assert float(out.rgb[:, 0].max()) < 0.6  # none of the far field's red


def test_rendering_with_and_without_autograd_sees_the_same_far_field() -> None:
    field = FruitField(SMALL, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(1))
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    rays = _outward_rays()
    trained = render_rays(field, grid, rays, SETTINGS._replace(stop_transmittance=0.0))
    with torch.no_grad():
        inferred = render_rays(field, grid, rays, SETTINGS._replace(weight_threshold=0.0, stop_transmittance=0.0))
    assert torch.allclose(trained.rgb.detach(), inferred.rgb, atol=1e-5)


def test_an_overflowing_far_density_trains_without_nan_and_leaves_the_poses_alone() -> None:
    """exp(100) overflows float32: the unbounded last interval must not turn the colour or a gradient into NaN; the
    far field's points (up to hundreds of metres out) give the rays no gradient (poses are refined from the box)."""
    field = _empty_box_field(SMALL)
    with torch.no_grad():
        field.far.mlp[-1].bias[0].fill_(100.0)
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    base = _outward_rays()
    origins, directions = base.origins.clone().requires_grad_(), base.directions.clone().requires_grad_()
    out = render_rays(field, grid, RayBundle(origins, directions), SETTINGS)
    out.rgb.sum().backward()
    assert bool(torch.isfinite(out.rgb).all())
    assert all(bool(torch.isfinite(p.grad).all()) for p in field.far.parameters() if p.grad is not None)
    assert float(directions.grad.abs().max()) < 1e-3  # the box is empty: no ray gradient from anywhere


@pytest.mark.parametrize('loss_name', ['photometric', 'semantic', 'contrastive'])
def test_only_the_photometric_loss_trains_the_far_field(loss_name: str) -> None:
    field = FruitField(SMALL, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(2))
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    out = render_rays(field, grid, _outward_rays(), SETTINGS, semantic=True, instance=True)
    labels = torch.arange(32) % 4
    loss = {'photometric': lambda: out.rgb.sum(),
            'semantic': lambda: semantic_loss(out.fruit_prob, labels == 0),
            'contrastive': lambda: prototype_infonce(out.embedding, labels, 0.2)}[loss_name]()
    loss.backward()
    far = list(field.far.parameters())
    assert any(p.grad is not None and bool((p.grad != 0).any()) for p in far) == (loss_name == 'photometric')
    geometry = {id(p) for p in field.geometry_parameters()}
    assert all(id(p) in geometry for p in far)  # trained with density and colour, in the geometry stages


def test_far_field_config_is_checked() -> None:
    with pytest.raises(ConfigError, match='samples'):
        FarFieldConfig(samples=-1)
    with pytest.raises(ConfigError, match='base_resolution'):
        FarFieldConfig(base_resolution=64, max_resolution=32)


@pytest.mark.parametrize('autograd', [False, True])
def test_rays_past_far_field_rays_see_the_background_behind_the_box(autograd: bool) -> None:
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    rays = _outward_rays()
    field = _empty_box_field(SMALL)
    with torch.set_grad_enabled(autograd):
        every = render_rays(field, grid, rays, SETTINGS).rgb
        split = render_rays(field, grid, rays, SETTINGS, far_field_rays=20).rgb
    background = field.background_rgb(rays.directions[20:])
    assert torch.allclose(split[:20], every[:20], atol=1e-5)
    assert torch.allclose(split[20:], background, atol=1e-3)
    assert not torch.allclose(every[20:], background, atol=0.1)  # the far field (red) there when all rays see it


def test_the_far_field_sees_the_same_in_any_pose_units() -> None:
    """A scene in units of 5 cm (everything 20x the metric lengths, ``units_per_metre`` 20) shows the same colours
    beyond its box as in metres; with the far field's density per pose unit instead, they differ."""
    def far_rgb(units: float, units_per_metre: float) -> torch.Tensor:
        config = dataclasses.replace(SMALL, far_field=dataclasses.replace(SMALL.far_field,
                                                                          units_per_metre=units_per_metre))
        field = FruitField(config, (AABB * units).numpy(), FRUIT_M * units, generator=torch.Generator().manual_seed(5))
        generator = torch.Generator().manual_seed(6)
        with torch.no_grad():   # a far field whose density and colour vary over space, as a trained one's do
            for parameter in field.far.parameters():
                parameter.copy_(torch.randn(parameter.shape, generator=generator))
            rays = _outward_rays()
            t_exit = torch.linspace(1.05, 1.4, len(rays.origins)) * units
            return field.beyond_box_rgb(RayBundle(rays.origins * units, rays.directions), t_exit)

    metric = far_rgb(1.0, 1.0)
    assert float(metric.std(0).max()) > 0.005                    # the far field's colours vary over the rays
    torch.testing.assert_close(far_rgb(20.0, 20.0), metric, atol=1e-4, rtol=1e-4)
    assert float((far_rgb(20.0, 1.0) - metric).abs().max()) > 0.01
    with pytest.raises(ConfigError, match='units_per_metre must be > 0'):
        FarFieldConfig(units_per_metre=0.0)
