"""Volume rendering of packed samples: one set of weights for colour, semantics and embeddings."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.rendering.marching import RaySamples

__all__ = ['render_weights', 'composite', 'accumulation', 'distortion']


def render_weights(samples: RaySamples, density: torch.Tensor) -> torch.Tensor:
    """Weights w_k = T_k * alpha_k [S] of the packed samples.

    alpha_k = 1 - exp(-sigma_k * step), T_k = exp(-sum_{a<k} sigma_a * step) over the ray's earlier samples
    (skipped empty samples contribute nothing).

    Args:
        samples: S packed samples of N rays.
        density: [S] density sigma (1/m).
    """
    tau = density.float() * samples.step
    dense = tau.new_zeros(samples.num_rays * samples.max_samples).index_put((samples.slot,), tau)
    dense = dense.view(samples.num_rays, samples.max_samples)
    before = torch.cumsum(dense, dim=1) - dense
    weights = torch.exp(-before) * (1.0 - torch.exp(-dense))
    return weights.reshape(-1)[samples.slot]


def composite(samples: RaySamples, weights: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Sum of ``weights`` [S] times ``values`` [S, C] per ray -> [N, C]."""
    out = values.new_zeros(samples.num_rays, values.shape[1])
    return out.index_add(0, samples.ray_index, weights[:, None].to(values.dtype) * values)


def accumulation(samples: RaySamples, weights: torch.Tensor) -> torch.Tensor:
    """Total weight (opacity) [N] per ray."""
    return weights.new_zeros(samples.num_rays).index_add(0, samples.ray_index, weights)


def distortion(samples: RaySamples, weights: torch.Tensor) -> torch.Tensor:
    """Mean over rays of the mip-NeRF 360 distortion loss (metres): small when each ray's weight is concentrated.

    L = sum_ij w_i w_j |t_i - t_j| + 1/3 sum_i w_i^2 step, computed with prefix sums in O(samples).
    """
    t = (samples.slot % samples.max_samples).to(weights.dtype) * samples.step
    dense_w = weights.new_zeros(samples.num_rays * samples.max_samples).index_put((samples.slot,), weights)
    dense_wt = weights.new_zeros(samples.num_rays * samples.max_samples).index_put((samples.slot,), weights * t)
    dense_w = dense_w.view(samples.num_rays, samples.max_samples)
    dense_wt = dense_wt.view(samples.num_rays, samples.max_samples)
    w_before = (torch.cumsum(dense_w, 1) - dense_w).reshape(-1)[samples.slot]
    wt_before = (torch.cumsum(dense_wt, 1) - dense_wt).reshape(-1)[samples.slot]
    pairwise = 2.0 * weights * (t * w_before - wt_before)
    own = weights ** 2 * samples.step / 3.0
    return (pairwise + own).sum() / max(samples.num_rays, 1)
