"""Hash-grid encoding: exact trilinear interpolation on dense levels, valid indices everywhere, also on the faces."""

from __future__ import annotations

import pytest
import torch

from fruitnerfpp_ros.core.fields.hash_grid import HashGridConfig, HashGridEncoding
from fruitnerfpp_ros.errors import ConfigError


def test_dense_level_is_trilinear_interpolation() -> None:
    enc = HashGridEncoding(HashGridConfig(num_levels=1, features_per_level=1, log2_table_size=12), 4, 4)
    assert enc.num_dense == 1
    # vertex value = x + 10 y + 100 z on the 5^3 grid: trilinear interpolation reproduces the linear function
    ijk = torch.stack(torch.meshgrid(*[torch.arange(5)] * 3, indexing='ij'), -1).reshape(-1, 3)
    with torch.no_grad():
        enc.table.zero_()
        enc.table[0, ijk[:, 0] + 5 * ijk[:, 1] + 25 * ijk[:, 2]] = (ijk.float() @ torch.tensor([1.0, 10.0, 100.0]))
    x = torch.cat([torch.rand(200, 3), torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5]])])
    expected = (x * 4) @ torch.tensor([1.0, 10.0, 100.0])
    assert torch.allclose(enc(x)[:, 0], expected, atol=1e-3)


def test_hashed_levels_index_inside_their_table_and_get_gradients() -> None:
    enc = HashGridEncoding(HashGridConfig(num_levels=4, features_per_level=2, log2_table_size=11), 4, 64)
    assert enc.num_dense == 2  # 5^3 and 11^3 vertices fit 2048 entries; finer levels are hashed
    index, weights = enc.vertex_index(torch.rand(300, 3))
    for level in range(4):
        assert int(index[:, level].min()) >= level * 2048 and int(index[:, level].max()) < (level + 1) * 2048
    assert torch.allclose(weights.sum(0), torch.ones(4, 300))
    out = enc(torch.rand(50, 3))
    assert out.shape == (50, 8)
    out.sum().backward()
    assert enc.table.grad is not None and int((enc.table.grad != 0).sum()) > 0


@pytest.mark.parametrize('log2_table, finest', [(9, 7), (11, 12), (11, 64)])
def test_faces_of_the_unit_cube_index_only_their_own_level(log2_table: int, finest: int) -> None:
    """x = 0 and x = 1 exactly, on every level: every vertex index (zero-weight ones too) lies in its level's part
    of the table; a dense last level that fills the table (8^3 = 2^9) used to index past its end at x = 1."""
    table = 2 ** log2_table
    enc = HashGridEncoding(HashGridConfig(num_levels=3, features_per_level=2, log2_table_size=log2_table), 2, finest)
    corners = torch.stack(torch.meshgrid(*[torch.tensor([0.0, 1.0])] * 3, indexing='ij'), -1).reshape(-1, 3)
    index, weights = enc.vertex_index(corners)
    resolutions = enc.resolutions[:, 0].long()
    for level in range(3):
        size = (int(resolutions[level]) + 1) ** 3 if level < enc.num_dense else table
        assert int(index[:, level].min()) >= level * table, level
        assert int(index[:, level].max()) < level * table + size, level
    assert torch.allclose(weights.sum(0), torch.ones_like(weights[0]))
    assert torch.isfinite(enc(corners)).all()


def test_bad_grid_settings_are_config_errors() -> None:
    with pytest.raises(ConfigError, match='log2_table_size'):
        HashGridConfig(log2_table_size=31)
    with pytest.raises(ConfigError, match='finest_cell'):
        HashGridConfig(coarsest_cell=0.1, finest_cell=0.5)
    with pytest.raises(ConfigError, match='base_resolution'):
        HashGridEncoding(HashGridConfig(), 64, 32)


def test_resolutions_follow_the_fruit_size_not_the_box() -> None:
    grid = HashGridConfig(coarsest_cell=4.0, finest_cell=0.25, max_resolution=4096)
    # the same 7.5 cm fruit in a 2 m and a 6 m box: the same cell size in metres (1.9 cm finest, 30 cm coarsest)
    small, large = grid.resolutions(2.0, 0.075), grid.resolutions(6.0, 0.075)
    assert small == (7, 107) and large == (20, 320)
    assert 2.0 / small[1] == pytest.approx(6.0 / large[1], rel=0.01)
    assert grid.resolutions(100.0, 0.01)[1] == 4096  # capped


def test_levels_open_coarse_to_fine_and_closed_levels_neither_contribute_nor_learn() -> None:
    torch.manual_seed(0)
    grid = HashGridEncoding(HashGridConfig(num_levels=4, features_per_level=2, log2_table_size=10), 4, 64,
                            init_scale=1.0)
    x = torch.rand(64, 3)
    full = grid(x).detach()
    grid.open_levels(0.0)
    out = grid(x)
    assert torch.equal(out[:, :2], full[:, :2])             # the coarsest level is always on
    assert torch.count_nonzero(out[:, 2:]) == 0              # the finer ones are held back
    out.sum().backward()
    grad = grid.table.grad.view(2, 4, -1)
    assert torch.count_nonzero(grad[:, 1:]) == 0 and torch.count_nonzero(grad[:, 0]) > 0
    grid.open_levels(0.5)                                      # alpha 1.5: level 1 on, level 2 half, level 3 off
    half = grid(x).detach()
    assert torch.equal(half[:, 2:4], full[:, 2:4]) and torch.allclose(half[:, 4:6], 0.5 * full[:, 4:6])
    assert torch.count_nonzero(half[:, 6:]) == 0
    grid.open_levels(1.0)
    assert torch.equal(grid(x).detach(), full)
    assert 'level_weights' not in grid.state_dict()           # a loaded grid has every level open


def test_cpu_chunks_give_the_features_and_table_gradient_of_one_pass() -> None:
    from fruitnerfpp_ros.core.fields.hash_grid import CPU_CHUNK_POINTS
    enc = HashGridEncoding(HashGridConfig(num_levels=4, features_per_level=2, log2_table_size=11), 4, 64,
                           init_scale=1.0, generator=torch.Generator().manual_seed(0))
    x = torch.rand(2 * CPU_CHUNK_POINTS + 123, 3, generator=torch.Generator().manual_seed(1))
    chunked = enc(x)                                    # three chunks
    whole = enc._encode(x)                              # one pass
    assert torch.equal(chunked, whole)
    (chunked * torch.arange(chunked.shape[1])).sum().backward()
    grad_chunked = enc.table.grad.clone()
    enc.table.grad = None
    (whole * torch.arange(whole.shape[1])).sum().backward()
    assert bool(grad_chunked.abs().sum() > 0) and torch.allclose(grad_chunked, enc.table.grad, rtol=1e-5, atol=1e-3)
