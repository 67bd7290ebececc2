"""Held-out instance accuracy: a figure a constant embedding cannot pass."""

from __future__ import annotations

import pytest
import torch

from fruitnerfpp_ros.core.training.metrics import instance_assignment_accuracy, spread_views


def _view(fruits: int, pixels: int = 20) -> torch.Tensor:
    return torch.cat([torch.zeros(7, dtype=torch.int32),
                      torch.arange(1, fruits + 1, dtype=torch.int32).repeat_interleave(pixels)])


def test_a_constant_embedding_scores_chance() -> None:
    mask = _view(4)
    constant = torch.nn.functional.normalize(torch.ones(len(mask), 8), dim=-1)
    credit, chance, total = instance_assignment_accuracy(constant, mask)
    assert total == 80 and credit / total == pytest.approx(0.25) and chance / total == pytest.approx(0.25)


def test_one_fruit_views_score_nothing_and_separated_fruits_score_one() -> None:
    one = _view(1)
    emb = torch.nn.functional.normalize(torch.randn(len(one), 8), dim=-1)
    assert instance_assignment_accuracy(emb, one) == (0.0, 0.0, 0)
    mask = _view(3)
    separated = torch.nn.functional.one_hot(mask.long(), 8).float()
    credit, chance, total = instance_assignment_accuracy(separated, mask)
    assert credit == total == 60 and chance == pytest.approx(20.0)


def test_swapped_pixels_lose_their_credit() -> None:
    mask = _view(2, pixels=10)
    emb = torch.nn.functional.one_hot(mask.long(), 4).float()
    emb[7:10] = torch.nn.functional.one_hot(torch.tensor([2, 2, 2]), 4).float()  # 3 pixels of fruit 1 look like 2
    credit, _, total = instance_assignment_accuracy(emb, mask)
    assert credit == pytest.approx(17.0) and total == 20


def test_the_evaluated_held_out_views_are_spread_over_the_drive() -> None:
    """A row drive's held-out views 0, 8 ... 48 with views 28-55 on the way back: three evaluated views must
    include the return pass (the first three, evaluated before session 48, were all on the way out)."""
    held = list(range(0, 56, 8))
    assert spread_views(held, 3) == [0, 24, 48]
    assert spread_views(held, 8) == held and spread_views(held, 1) == [0] and spread_views(held, 0) == []
    assert spread_views([5, 9], 2) == [5, 9] and len(set(spread_views(range(0, 800, 8), 8))) == 8
