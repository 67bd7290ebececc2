"""Pixel samplers: uniform rays and the group instance sampler (per-image labels, no background)."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.data.samplers import GroupInstanceSampler, UniformPixelSampler, index_view_fruits, \
    mask_interior


def _blobs(relabel: torch.Tensor | None = None) -> torch.Tensor:
    """[2, 40, 40] masks with 6 square fruits per view, ids 1..6 (or relabelled)."""
    mask = torch.zeros(2, 40, 40, dtype=torch.int32)
    for k in range(6):
        r, c = 3 + 6 * k, 2 + 5 * k
        mask[:, r:r + 4, c:c + 4] = k + 1
    if relabel is not None:
        mask = torch.where(mask > 0, relabel[mask.long()].to(torch.int32), mask)
    return mask


def test_uniform_sampler_covers_train_views_only() -> None:
    sampler = UniformPixelSampler(torch.tensor([1, 3]), 8, 10)
    batch = sampler.sample(500, torch.Generator().manual_seed(0))
    assert set(batch.view.tolist()) == {1, 3}
    assert int(batch.row.max()) < 8 and int(batch.col.max()) < 10


def test_group_sampler_labels_match_masks_and_skip_background() -> None:
    masks = _blobs()
    sampler = GroupInstanceSampler(torch.tensor([0, 1]), masks, groups=2, group_size=3, pixels_per_fruit=5)
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        batch = sampler.sample(gen)
        assert batch.fruit is not None
        ids = masks[batch.view, batch.row, batch.col]
        assert bool((ids > 0).all())                      # background never sampled
        assert len(set(batch.view.tolist())) == 1          # one image per step
        for label in batch.fruit.unique():
            assert len(ids[batch.fruit == label].unique()) == 1  # one fruit per label
        assert len(ids.unique()) == len(batch.fruit.unique())   # distinct labels <-> distinct fruits
        assert bool((torch.bincount(batch.fruit) == 5).all())   # P pixels per fruit


def test_groups_are_nearest_fruits() -> None:
    fruits = index_view_fruits(0, _blobs()[0])
    assert fruits is not None
    # fruits lie on a diagonal line: the nearest of fruit k are k-1 and k+1
    assert fruits.neighbours[0, :2].tolist() == [0, 1]
    assert set(fruits.neighbours[3, 1:3].tolist()) == {2, 4}


def test_sampler_is_invariant_to_relabelling() -> None:
    perm = torch.tensor([0, 907, 12, 5, 300, 2, 41])
    a = GroupInstanceSampler(torch.tensor([0, 1]), _blobs(), groups=2, group_size=3, pixels_per_fruit=4)
    b = GroupInstanceSampler(torch.tensor([0, 1]), _blobs(perm), groups=2, group_size=3, pixels_per_fruit=4)
    ba, bb = a.sample(torch.Generator().manual_seed(3)), b.sample(torch.Generator().manual_seed(3))
    assert torch.equal(ba.row, bb.row) and torch.equal(ba.col, bb.col) and torch.equal(ba.fruit, bb.fruit)


def test_mask_interior_drops_edges_and_keeps_fruits_too_small_for_an_interior() -> None:
    ids = torch.zeros(2, 12, 12, dtype=torch.int32)
    ids[0, 1:6, 1:6] = 1          # 5 x 5: its 3 x 3 core
    ids[0, 1:6, 6:9] = 2          # 5 x 3, touching fruit 1: its middle column, not the shared edge
    ids[0, 9:11, 3:5] = 3         # 2 x 2: no pixel with four fruit neighbours, so all four stay
    ids[1, 0:3, 9:12] = 1         # in the corner: beyond the image counts as the same fruit
    fruit = ids > 0
    fruit[0, 3, 3] = False        # a pixel the sampler's mask leaves out is never kept
    kept = mask_interior(ids, fruit)
    expected = torch.zeros_like(fruit)
    expected[0, 2:5, 2:5] = True
    expected[0, 3, 3] = False
    expected[0, 2:5, 7] = True
    expected[0, 9:11, 3:5] = True
    expected[1, 0:2, 10:12] = True
    assert torch.equal(kept, expected)
    sampler = UniformPixelSampler(torch.tensor([0, 1]), 12, 12, fruit_masks=kept, fruit_fraction=0.5)
    batch = sampler.sample(400, torch.Generator().manual_seed(1))
    fruit_part = slice(sampler.num_uniform(400), None)
    assert bool(kept[batch.view[fruit_part], batch.row[fruit_part], batch.col[fruit_part]].all())


def test_uniform_sampler_draws_its_background_share_but_never_more_than_the_background_holds() -> None:
    views, height, width = torch.arange(4), 20, 50
    wide = torch.zeros(4, height, width, dtype=torch.bool)
    wide[:, :, :30] = True                       # 60 % of the pixels: the share asked for is drawn
    narrow = torch.zeros_like(wide)
    narrow[:, 0, :8] = True                      # 8 of 1000 pixels per view: their own 0.8 %
    for background, share in ((wide, 0.1), (narrow, 0.008)):
        sampler = UniformPixelSampler(views, height, width, valid_masks=~background, background_masks=background,
                                      background_fraction=0.1)
        drawn = sampler.sample(5000, torch.Generator().manual_seed(1))
        hit = background[drawn.view, drawn.row, drawn.col]
        n_background = int(round(5000 * share))
        assert int(hit.sum()) == n_background and bool(hit[5000 - n_background:].all())


def test_fruit_draws_follow_each_fruits_pixel_count_to_the_area_exponent() -> None:
    ids = torch.zeros(2, 40, 40, dtype=torch.int32)
    ids[0, 0:30, 0:30] = 1                       # 900 pixels
    ids[0, 35:38, 35:38] = 2                     # 9 pixels
    ids[1, 0:5, 0:5] = 1                         # 25 pixels: the same id in another view is another fruit
    cases = {1.0: (900, 9, 25), 0.5: (30, 3, 5), 0.0: (1, 1, 1)}
    for exponent, weights in cases.items():
        sampler = UniformPixelSampler(torch.tensor([0, 1]), 40, 40, fruit_masks=ids > 0, fruit_fraction=0.5,
                                      fruit_ids=ids, fruit_area_exponent=exponent)
        batch = sampler.sample(40_000, torch.Generator().manual_seed(3))
        n = sampler.num_uniform(40_000)
        view, fruit = batch.view[n:], ids[batch.view[n:], batch.row[n:], batch.col[n:]]
        assert bool((fruit > 0).all())
        shares = [float(((view == v) & (fruit == f)).float().mean()) for v, f in ((0, 1), (0, 2), (1, 1))]
        expected = [w / sum(weights) for w in weights]
        assert all(abs(s - e) < 0.01 for s, e in zip(shares, expected)), (exponent, shares, expected)
        # within a fruit its pixels are drawn alike: the big fruit's two halves get half its draws each
        big = batch.view[n:] == 0
        left = big & (fruit == 1) & (batch.col[n:] < 15)
        assert abs(float(left.sum()) / float((big & (fruit == 1)).sum()) - 0.5) < 0.03


def test_area_exponent_one_draws_exactly_the_uniform_fruit_pixels() -> None:
    ids = _blobs()
    ids[0, 30:40, 30:40] = 9
    plain = UniformPixelSampler(torch.tensor([0, 1]), 40, 40, fruit_masks=ids > 0, fruit_fraction=0.3)
    same = UniformPixelSampler(torch.tensor([0, 1]), 40, 40, fruit_masks=ids > 0, fruit_fraction=0.3, fruit_ids=ids,
                               fruit_area_exponent=1.0)
    a, b = (s.sample(1000, torch.Generator().manual_seed(4)) for s in (plain, same))
    assert torch.equal(a.view, b.view) and torch.equal(a.row, b.row) and torch.equal(a.col, b.col)
