"""Hash-grid encoding: exact trilinear interpolation on dense levels, valid hashed indices."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.fields.hash_grid import HashGridEncoding


def test_dense_level_is_trilinear_interpolation() -> None:
    enc = HashGridEncoding(num_levels=1, features_per_level=1, log2_table_size=12, base_resolution=4,
                           max_resolution=4)
    assert enc.num_dense == 1
    # vertex value = x + 10 y + 100 z on the 5^3 grid: trilinear interpolation reproduces the linear function
    ijk = torch.stack(torch.meshgrid(*[torch.arange(5)] * 3, indexing='ij'), -1).reshape(-1, 3)
    with torch.no_grad():
        enc.table.zero_()
        enc.table[0, ijk[:, 0] + 5 * ijk[:, 1] + 25 * ijk[:, 2]] = (ijk.float() @ torch.tensor([1.0, 10.0, 100.0]))
    x = torch.rand(200, 3)
    expected = (x * 4) @ torch.tensor([1.0, 10.0, 100.0])
    assert torch.allclose(enc(x)[:, 0], expected, atol=1e-3)


def test_hashed_levels_index_inside_their_table_and_get_gradients() -> None:
    enc = HashGridEncoding(num_levels=4, features_per_level=2, log2_table_size=11, base_resolution=4,
                           max_resolution=64)
    assert enc.num_dense == 2  # 5^3 and 11^3 vertices fit 2048 entries; finer levels are hashed
    index, weights = enc.vertex_index(torch.rand(300, 3))
    for level in range(4):
        assert int(index[:, level].min()) >= level * 2048 and int(index[:, level].max()) < (level + 1) * 2048
    assert torch.allclose(weights.sum(0), torch.ones(4, 300))
    out = enc(torch.rand(50, 3))
    assert out.shape == (50, 8)
    out.sum().backward()
    assert enc.table.grad is not None and int((enc.table.grad != 0).sum()) > 0
