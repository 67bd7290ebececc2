"""FruitField: query contract, and gradient isolation of the semantic and instance heads."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, FruitField
from fruitnerfpp_ros.core.fields.query import QueryableField
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, render_rays
from fruitnerfpp_ros.core.training.losses import prototype_infonce, semantic_loss

SMALL = FieldConfig(num_levels=4, log2_table_size=12, base_resolution=4, max_resolution=32, hidden_dim=16,
                    embedding_dim=8, instance_num_levels=2, instance_log2_table_size=10, instance_hidden_dim=16)
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _density_params(field: FruitField) -> list[torch.nn.Parameter]:
    return list(field.encoding.parameters()) + list(field.density_mlp.parameters())


def test_query_contract() -> None:
    field = FruitField(SMALL, AABB.numpy())
    as_protocol: QueryableField = field  # static check of the export contract
    assert as_protocol.embedding_dim == 8
    xyz = torch.cat([torch.rand(10, 3) * 2 - 1, torch.tensor([[5.0, 0.0, 0.0]])])
    q = field.query(xyz)
    assert q.density.shape == (11,) and q.rgb.shape == (11, 3) and q.fruit_prob.shape == (11,)
    assert q.embedding.shape == (11, 8) and field.embedding_dim == 8
    assert torch.allclose(q.embedding.norm(dim=-1), torch.ones(11), atol=1e-5)
    assert float(q.density[-1]) == 0.0 and bool((q.density[:-1] > 0).all())  # zero outside the box
    assert not q.density.requires_grad


def test_semantic_and_instance_losses_leave_density_untouched() -> None:
    torch.manual_seed(0)
    field = FruitField(SMALL, AABB.numpy())
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    origins = torch.tensor([[0.0, 0.0, 3.0]]).repeat(64, 1)
    directions = torch.nn.functional.normalize(torch.cat([torch.rand(64, 2) * 0.4 - 0.2, -torch.ones(64, 1)], 1),
                                               dim=-1)
    rays = RayBundle(origins, directions)
    settings = RenderSettings(step=0.05, near=0.0)
    out = render_rays(field, grid, rays, settings, semantic=True, instance=True)
    labels = torch.arange(64) % 4
    loss = semantic_loss(out.fruit_prob, labels == 0) + prototype_infonce(out.embedding, labels, 0.2)
    loss.backward()
    for p in _density_params(field) + list(field.color_mlp.parameters()):
        assert p.grad is None or float(p.grad.abs().max()) == 0.0
    assert any(p.grad is not None and float(p.grad.abs().max()) > 0 for p in field.semantic_parameters())
    assert any(p.grad is not None and float(p.grad.abs().max()) > 0 for p in field.instance_parameters())
    # ... while the photometric path does reach density
    field.zero_grad()
    out = render_rays(field, grid, rays, settings)
    out.rgb.sum().backward()
    assert any(p.grad is not None and float(p.grad.abs().max()) > 0 for p in _density_params(field))
