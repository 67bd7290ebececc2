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
