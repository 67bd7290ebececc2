"""Volume rendering of packed samples: one set of weights for colour, semantics and embeddings."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.rendering.marching import RaySamples

__all__ = ['exclusive_cumsum', 'render_weights', 'composite', 'accumulation', 'distortion']


def exclusive_cumsum(samples: RaySamples, values: torch.Tensor) -> torch.Tensor:
    """Per sample [S], the sum of ``values`` [S] over the same ray's earlier samples (prefix sum in ray order)."""
    dense = values.new_zeros(samples.num_rays * samples.max_samples).index_put((samples.slot,), values)
    dense = dense.view(samples.num_rays, samples.max_samples)
    return (torch.cumsum(dense, dim=1) - dense).reshape(-1)[samples.slot]


def render_weights(samples: RaySamples, density: torch.Tensor) -> torch.Tensor:
    """Weights w_k = T_k * alpha_k [S] of the packed samples.

    alpha_k = 1 - exp(-sigma_k * step), T_k = exp(-sum_{a<k} sigma_a * step) over the ray's earlier samples
    (skipped empty samples contribute nothing).

    Args:
        samples: S packed samples of N rays.
        density: [S] density sigma (1/m).
    """
    tau = density.float() * samples.step
    return torch.exp(-exclusive_cumsum(samples, tau)) * (1.0 - torch.exp(-tau))


def composite(samples: RaySamples, weights: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Sum of ``weights`` [S] times ``values`` [S, C] per ray -> [N, C]."""
    out = values.new_zeros(samples.num_rays, values.shape[1])
    return out.index_add(0, samples.ray_index, weights[:, None].to(values.dtype) * values)


def accumulation(samples: RaySamples, weights: torch.Tensor) -> torch.Tensor:
    """Total weight (opacity) [N] per ray."""
    return weights.new_zeros(samples.num_rays).index_add(0, samples.ray_index, weights)


def distortion(samples: RaySamples, weights: torch.Tensor, *, num_rays: int | None = None) -> torch.Tensor:
    """Mean over rays of the mip-NeRF 360 distortion loss (metres): small when each ray's weight is concentrated.

    L = sum_ij w_i w_j |t_i - t_j| + 1/3 sum_i w_i^2 step, computed with prefix sums in O(samples).

    Args:
        samples: S packed samples of N rays.
        weights: [S] render weights.
        num_rays: only rays ``0..num_rays-1`` count (the mean is over them); None = all N.
    """
    t = (samples.slot % samples.max_samples).to(weights.dtype) * samples.step
    w_before = exclusive_cumsum(samples, weights)
    wt_before = exclusive_cumsum(samples, weights * t)
    pairwise = 2.0 * weights * (t * w_before - wt_before)
    own = weights ** 2 * samples.step / 3.0
    per_sample = pairwise + own
    if num_rays is None or num_rays >= samples.num_rays:
        return per_sample.sum() / max(samples.num_rays, 1)
    return per_sample[samples.ray_index < num_rays].sum() / max(num_rays, 1)
