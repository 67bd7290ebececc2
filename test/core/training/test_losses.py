"""The training losses against hand computations on three pixels."""

from __future__ import annotations

import math

import pytest
import torch

from fruitnerfpp_ros.core.training.losses import (fruit_transparency, opacity_entropy, photometric_loss,
                                                  prototype_infonce, semantic_loss)


def test_bce_of_three_pixels() -> None:
    prob = torch.tensor([0.9, 0.2, 0.6])
    fruit = torch.tensor([True, False, False])
    expected = -(math.log(0.9) + math.log(0.8) + math.log(0.4)) / 3
    assert float(semantic_loss(prob, fruit)) == pytest.approx(expected, rel=1e-6)


def test_opacity_entropy_of_three_rays_and_its_pull_towards_clear_or_opaque() -> None:
    opacity = torch.tensor([0.5, 1.0, 0.0])
    assert float(opacity_entropy(opacity)) == pytest.approx(math.log(2) / 3, abs=2e-3)  # 0 and 1 clamped by 1e-4
    semi = torch.tensor([0.3, 0.8], requires_grad=True)
    opacity_entropy(semi).backward()
    assert float(semi.grad[0]) > 0 and float(semi.grad[1]) < 0  # descent: 0.3 -> clear, 0.8 -> opaque


def test_photometric_mse_of_three_pixels() -> None:
    rgb = torch.tensor([[0.0, 0.5, 1.0], [0.2, 0.2, 0.2], [1.0, 1.0, 1.0]])
    target = torch.tensor([[0.0, 0.0, 1.0], [0.2, 0.4, 0.2], [1.0, 1.0, 0.0]])
    assert float(photometric_loss(rgb, target)) == pytest.approx((0.25 + 0.04 + 1.0) / 9, rel=1e-6)


def test_prototype_infonce_of_three_pixels() -> None:
    """Pixels 0, 1 belong to fruit 0 and pixel 2 to fruit 1 (2-d embeddings, already unit length)."""
    emb = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.6, 0.8]])
    labels = torch.tensor([0, 0, 1])
    tau = 0.2
    proto0 = torch.tensor([1.0, 1.0]) / math.sqrt(2.0)   # normalised mean of pixels 0 and 1
    proto1 = torch.tensor([0.6, 0.8])
    expected = 0.0
    for j in range(3):
        s0, s1 = float(emb[j] @ proto0) / tau, float(emb[j] @ proto1) / tau
        own = s0 if int(labels[j]) == 0 else s1
        expected += -(own - math.log(math.exp(s0) + math.exp(s1)))
    assert float(prototype_infonce(emb, labels, tau)) == pytest.approx(expected / 3, rel=1e-5)
    # scaling an embedding changes nothing (it is normalised inside)
    assert float(prototype_infonce(emb * torch.tensor([[3.0], [1.0], [0.5]]), labels, tau)) == pytest.approx(
        expected / 3, rel=1e-5)


def test_fruit_transparency_is_the_mean_squared_transparency_of_the_kept_rays() -> None:
    opacity = torch.tensor([1.0, 0.5, 0.0, 0.9])
    assert float(fruit_transparency(opacity)) == pytest.approx((0.0 + 0.25 + 1.0 + 0.01) / 4)
    keep = torch.tensor([True, False, True, False])
    assert float(fruit_transparency(opacity, keep)) == pytest.approx(0.5)
    assert float(fruit_transparency(opacity, torch.zeros(4, dtype=torch.bool))) == 0.0
