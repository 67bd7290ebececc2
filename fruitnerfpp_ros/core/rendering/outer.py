"""Rendering of the outer field (ground and sky beyond the scene box) behind what the box renders."""

from __future__ import annotations

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb
from fruitnerfpp_ros.core.fields.outer_field import OuterField

__all__ = ['render_outer']


def render_outer(outer: OuterField, rays: RayBundle, *, num_samples: int, far_factor: float, near: float,
                 jitter: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Colour [N, 3] and opacity [N] of the outer field along each ray, from where it leaves the box.

    Samples are spaced evenly in inverse distance (disparity) between the box exit (the ray's ``near`` point
    when it misses the box) and ``far_factor`` box diagonals beyond it, so near ground gets fine steps and the
    distance to the horizon a few coarse ones.

    Args:
        outer: the outer field.
        rays: N rays.
        num_samples: K samples per ray.
        far_factor: far end, in box diagonals past the start.
        near: minimum distance from the camera, metres.
        jitter: [N] offsets in [0, 1) of the samples within their intervals (training); None = 0.5.
    """
    t_near, t_far = intersect_aabb(rays, outer.aabb, near)
    start = torch.where(t_far > t_near, t_far, t_near).clamp_min(max(near, 1e-3))
    end = start + far_factor * torch.linalg.norm(outer.aabb[1] - outer.aabb[0])
    steps = torch.arange(num_samples + 1, device=start.device, dtype=start.dtype) / num_samples
    offset = torch.full_like(start, 0.5) if jitter is None else jitter.to(start)
    mid = (torch.arange(num_samples, device=start.device, dtype=start.dtype)[None] + offset[:, None]) / num_samples

    def distance(s: torch.Tensor) -> torch.Tensor:  # s in [0, 1] -> t, linear in 1/t
        return 1.0 / ((1.0 - s) / start[:, None] + s / end[:, None])

    edges = distance(steps[None].expand(len(start), -1))
    t = distance(mid)
    points = rays.origins[:, None, :] + t[..., None] * rays.directions[:, None, :]
    dirs = rays.directions[:, None, :].expand_as(points)
    out = outer(points.reshape(-1, 3), dirs.reshape(-1, 3))
    tau = out.density.view(-1, num_samples) * (edges[:, 1:] - edges[:, :-1])
    transmittance = torch.exp(-(torch.cumsum(tau, dim=1) - tau))
    weights = transmittance * (1.0 - torch.exp(-tau))
    rgb = (weights[..., None] * out.rgb.view(-1, num_samples, 3)).sum(1)
    return rgb, weights.sum(1)
