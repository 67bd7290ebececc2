"""Training losses: photometric MSE, fruit BCE, and the prototype InfoNCE of FruitNeRF++."""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ['photometric_loss', 'semantic_loss', 'opacity_entropy', 'fruit_transparency', 'prototype_infonce',
           'fruit_prototypes']


def photometric_loss(rgb: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error between rendered and true colours, both [N, 3] in [0, 1]."""
    return torch.mean((rgb.float() - target.float()) ** 2)


def semantic_loss(fruit_prob: torch.Tensor, is_fruit: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of rendered fruit probabilities [N] in [0, 1] against fruit masks [N] (bool)."""
    prob = fruit_prob.float().clamp(1e-5, 1.0 - 1e-5)
    return F.binary_cross_entropy(prob, is_fruit.float())


def opacity_entropy(opacity: torch.Tensor, eps: float = 1e-4) -> torch.Tensor:
    """Mean binary entropy (nats) of per-ray opacities [N]: 0 where a ray is opaque or clear, ln 2 at one half."""
    o = opacity.float().clamp(eps, 1.0 - eps)
    return -(o * torch.log(o) + (1.0 - o) * torch.log(1.0 - o)).mean()


def fruit_transparency(opacity: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
    """Mean (1 - opacity)^2 of fruit rays' opacities [N] through the box, over the rays ``keep`` [N] (bool) marks
    (every ray when None; 0 when it marks none): a fruit pixel sees a solid fruit inside the box."""
    clear = (1.0 - opacity.float()).square()
    if keep is None:
        return clear.mean()
    keep = keep.to(clear.device, clear.dtype)
    return (clear * keep).sum() / keep.sum().clamp_min(1.0)


def fruit_prototypes(embeddings: torch.Tensor, labels: torch.Tensor, num_fruits: int) -> torch.Tensor:
    """Unit-length mean embedding [F, D] per fruit label from L2-normalised ``embeddings`` [N, D]."""
    sums = embeddings.new_zeros(num_fruits, embeddings.shape[1]).index_add(0, labels, embeddings)
    return F.normalize(sums, dim=-1)


def prototype_infonce(embeddings: torch.Tensor, labels: torch.Tensor, temperature: float,
                      num_fruits: int | None = None) -> torch.Tensor:
    """Prototype InfoNCE: each pixel against the mean embeddings of every fruit of the batch.

    L_j = -log( exp(<i_j, F_a(j)> / tau) / sum_a' exp(<i_j, F_a'> / tau) ), averaged over the pixels.

    Args:
        embeddings: [N, D] rendered embeddings (normalised here).
        labels: [N] int64 batch-local fruit label in 0..F-1 (background pixels never enter).
        temperature: tau.
        num_fruits: F when the caller knows it (saves reading ``labels`` back from the GPU).
    """
    unit = F.normalize(embeddings.float(), dim=-1)
    if num_fruits is None:
        num_fruits = int(labels.max()) + 1
    prototypes = fruit_prototypes(unit, labels, num_fruits)
    logits = unit @ prototypes.T / temperature
    return F.cross_entropy(logits, labels)
