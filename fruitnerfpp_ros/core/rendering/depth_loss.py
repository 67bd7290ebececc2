"""Line-of-sight depth supervision: a measured depth says where a ray's weight belongs.

For a ray with a measured surface at distance z (along the unit ray, metres) and a window of half-width eps (the
sensor's uncertainty), the render weights w_k of its samples at distances t_k split into

- **free**: sum of w_k with t_k < z - eps: weight in space the sensor saw through (fog, floaters);
- **surface**: sum of w_k with |t_k - z| <= eps: weight where the sensor saw the surface.

The loss of a ray is c * (lambda_free * free + (1 - surface)) (DS-NeRF and Urban Radiance Fields push the
weight distribution towards the measured surface in the same spirit): it empties the space in front of the
surface and makes the surface opaque within the sensor's error. Both terms are linear in the weight, so moving
weight from the free space into the window always pays (a squared surface term, whose pull fades as the surface
becomes opaque, let the free-space term thin the fruit out to 75 % opacity on the test scene). The surface term
is dropped where the measured point lies outside the marched box (the ray cannot end there; its free term still
empties the box in front).
Rays without a depth (c = 0) contribute nothing, and the mean runs over the rays with depth only.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb
from fruitnerfpp_ros.core.rendering.marching import RaySamples

__all__ = ['DepthTarget', 'LineOfSight', 'line_of_sight', 'line_of_sight_loss']


class DepthTarget(NamedTuple):
    """The measured depth of each ray of a batch.

    Attributes:
        distance: [N] distance (m) along the unit ray to the measured surface; ignored where ``weight`` is 0.
        window: [N] half-width (m) of the surface window around it (from the sensor's uncertainty).
        weight: [N] per-ray weight c >= 0 of the loss; 0 = no depth for this ray.
    """

    distance: torch.Tensor
    window: torch.Tensor
    weight: torch.Tensor


class LineOfSight(NamedTuple):
    """Per-ray split of the render weight against the measured depth (differentiable).

    Attributes:
        free: [N] weight in front of the surface window.
        surface: [N] weight inside the surface window.
        reachable: [N] bool, the measured surface lies within the marched part of the ray (inside the box).
    """

    free: torch.Tensor
    surface: torch.Tensor
    reachable: torch.Tensor


def line_of_sight(samples: RaySamples, rays: RayBundle, weights: torch.Tensor, target: DepthTarget,
                  aabb: torch.Tensor, near: float) -> LineOfSight:
    """Split every ray's render ``weights`` [S] at its measured depth (see the module doc).

    Args:
        samples: the rays' packed samples.
        rays: the N rays.
        weights: [S] render weights (with their graph: the loss trains density through them).
        target: the measured depths.
        aabb: [2, 3] the marched box (the surface term needs the surface inside it).
        near: the marching's minimum distance (m).
    """
    index = samples.ray_index
    with torch.no_grad():
        t = ((samples.positions - rays.origins[index]) * rays.directions[index]).sum(-1)
        z, eps = target.distance[index], target.window[index]
        front = (t < z - eps).to(weights.dtype)
        inside = ((t - z).abs() <= eps).to(weights.dtype)
        t_near, t_far = intersect_aabb(rays, aabb, near)
        reachable = (target.distance >= t_near) & (target.distance <= t_far)
    zeros = weights.new_zeros(samples.num_rays)
    return LineOfSight(zeros.index_add(0, index, weights * front), zeros.index_add(0, index, weights * inside),
                       reachable)


def line_of_sight_loss(los: LineOfSight, target: DepthTarget, free_space_weight: float = 1.0) -> torch.Tensor:
    """Mean over the rays with depth of c * (free_space_weight * free + (1 - surface)); 0 when none has depth."""
    has = target.weight > 0
    surface = torch.where(los.reachable, 1.0 - los.surface, torch.zeros_like(los.surface))
    per_ray = target.weight * (free_space_weight * los.free + surface)
    return per_ray.sum() / has.sum().clamp_min(1)
