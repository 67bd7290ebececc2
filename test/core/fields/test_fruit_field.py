"""FruitField: query contract, seeded initialisation, and exact gradient isolation of every head."""

from __future__ import annotations

import pytest
import torch

from fruitnerfpp_ros.core.data.rays import RayBundle
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, FruitField, HashGridConfig
from fruitnerfpp_ros.core.fields.query import QueryableField
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, render_rays
from fruitnerfpp_ros.core.training.losses import prototype_infonce, semantic_loss

SMALL = FieldConfig(
    geometry_grid=HashGridConfig(num_levels=4, log2_table_size=12, coarsest_cell=2.0, finest_cell=0.25),
    hidden_dim=16, embedding_dim=8, instance_hidden_dim=16,
    instance_grid=HashGridConfig(num_levels=2, log2_table_size=10, coarsest_cell=0.5, finest_cell=0.02))
FRUIT_M = 0.25  # the grids' cells are given in fruit diameters: 2 m box / (0.25 m * 0.25) = 32 cells
AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _rays(n: int = 64) -> RayBundle:
    origins = torch.tensor([[0.0, 0.0, 3.0]]).repeat(n, 1)
    directions = torch.nn.functional.normalize(torch.cat([torch.rand(n, 2) * 0.4 - 0.2, -torch.ones(n, 1)], 1),
                                               dim=-1)
    return RayBundle(origins, directions)


def _heads(field: FruitField) -> dict[str, list[torch.nn.Parameter]]:
    return {'geometry': list(field.geometry_parameters()), 'semantic': list(field.semantic_parameters()),
            'instance': list(field.instance_parameters())}


def _reached(params: list[torch.nn.Parameter]) -> bool:
    return any(p.grad is not None and bool((p.grad != 0).any()) for p in params)


def test_query_contract() -> None:
    field = FruitField(SMALL, AABB.numpy(), FRUIT_M)
    as_protocol: QueryableField = field  # static check of the export contract
    assert as_protocol.embedding_dim == 8
    xyz = torch.cat([torch.rand(10, 3) * 2 - 1, torch.tensor([[5.0, 0.0, 0.0]])])
    q = field.query(xyz)
    assert q.density.shape == (11,) and q.rgb.shape == (11, 3) and q.fruit_prob.shape == (11,)
    assert q.embedding.shape == (11, 8) and field.embedding_dim == 8
    assert torch.allclose(q.embedding.norm(dim=-1), torch.ones(11), atol=1e-5)
    assert float(q.density[-1]) == 0.0 and bool((q.density[:-1] > 0).all())  # zero outside the box
    assert not q.density.requires_grad


def test_a_generator_makes_the_weights_reproducible_without_the_global_seed() -> None:
    a = FruitField(SMALL, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(3))
    torch.manual_seed(123)
    b = FruitField(SMALL, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(3))
    c = FruitField(SMALL, AABB.numpy(), FRUIT_M, generator=torch.Generator().manual_seed(4))
    state_a, state_b, state_c = a.state_dict(), b.state_dict(), c.state_dict()
    assert all(torch.equal(state_a[k], state_b[k]) for k in state_a)
    assert not all(torch.equal(state_a[k], state_c[k]) for k in state_a)


@pytest.mark.parametrize('loss_name', ['photometric', 'semantic', 'contrastive'])
def test_each_loss_reaches_exactly_its_own_head(loss_name: str) -> None:
    """Photometric -> density/colour only; BCE -> semantic head only; InfoNCE -> instance head only."""
    torch.manual_seed(0)
    field = FruitField(SMALL, AABB.numpy(), FRUIT_M)
    grid = OccupancyGrid(AABB, resolution=8, threshold=0.01, decay=0.95)
    out = render_rays(field, grid, _rays(), RenderSettings(step=0.05, near=0.0), semantic=True, instance=True)
    labels = torch.arange(64) % 4
    loss = {'photometric': lambda: out.rgb.sum(),
            'semantic': lambda: semantic_loss(out.fruit_prob, labels == 0),
            'contrastive': lambda: prototype_infonce(out.embedding, labels, 0.2)}[loss_name]()
    loss.backward()
    own = {'photometric': 'geometry', 'semantic': 'semantic', 'contrastive': 'instance'}[loss_name]
    for head, params in _heads(field).items():
        assert _reached(params) == (head == own), (loss_name, head)
