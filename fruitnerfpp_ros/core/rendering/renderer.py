"""Render colour, fruit probability and instance embeddings of rays with one set of volume-rendering weights."""

from __future__ import annotations

import contextlib
import math
from typing import Callable, NamedTuple

import torch

from fruitnerfpp_ros.core.data.rays import RayBundle, intersect_aabb
from fruitnerfpp_ros.core.rendering.depth_loss import DepthTarget, LineOfSight, line_of_sight
from fruitnerfpp_ros.core.fields.fruit_field import FruitField, GeometryOutput
from fruitnerfpp_ros.core.rendering.marching import RaySamples, march_rays
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.volume import (accumulation, composite, distortion, exclusive_cumsum,
                                                   render_weights)

__all__ = ['RenderOutput', 'RenderSettings', 'render_rays', 'autocast_for']

GeometryFn = Callable[[torch.Tensor], GeometryOutput]


class RenderSettings(NamedTuple):
    """How rays are marched.

    Attributes:
        step: sample spacing, metres.
        near: minimum distance from the camera, metres.
        mixed_precision: bfloat16 autocast of the field on CUDA.
        weight_threshold: instance head evaluated only where the render weight exceeds this.
        stop_transmittance: samples behind the point where a ray's transmittance (from a first, gradient-free
            density pass) falls below this are dropped before the differentiable pass; 0 disables it.
    """

    step: float
    near: float
    mixed_precision: bool = False
    weight_threshold: float = 1e-4
    stop_transmittance: float = 1e-3


class RenderOutput(NamedTuple):
    """Per-ray results.

    Attributes:
        rgb: [N, 3] colour in [0, 1] (the background colour blended in where the ray stays transparent).
        opacity: [N] accumulated weight in [0, 1].
        fruit_prob: [N] rendered fruit probability (sum of weight * sigmoid(logit)), or None.
        embedding: [N, D] rendered instance embedding (not normalised), or None.
        num_samples: samples evaluated by the field.
        distortion: mean distortion loss of the colour weights over the first ``distortion_rays`` rays (metres;
            differentiable), or None.
        depth: [N] median termination distance (m): where the accumulated weight reaches half the ray's opacity
            (``inf`` for a ray with no weight), or None when not asked for.
        line_of_sight: the colour weights split at each ray's measured depth (``depth_target``; differentiable),
            or None.
    """

    rgb: torch.Tensor | None
    opacity: torch.Tensor
    fruit_prob: torch.Tensor | None
    embedding: torch.Tensor | None
    num_samples: int
    distortion: torch.Tensor | None = None
    depth: torch.Tensor | None = None
    line_of_sight: LineOfSight | None = None


def autocast_for(device: torch.device, enabled: bool) -> contextlib.AbstractContextManager:
    """bfloat16 autocast on CUDA when ``enabled``; a no-op elsewhere."""
    if enabled and device.type == 'cuda':
        return torch.autocast('cuda', dtype=torch.bfloat16)
    return contextlib.nullcontext()


def _early_terminated(samples: RaySamples, geometry: GeometryFn, stop_transmittance: float) -> RaySamples:
    """The samples in front of where each ray becomes opaque (transmittance < ``stop_transmittance``)."""
    with torch.no_grad():
        weights = render_weights(samples, geometry(samples.positions).density)
        # transmittance before sample k = 1 - (accumulated weight before k)
        before = exclusive_cumsum(samples, weights)
        keep = torch.nonzero(1.0 - before > stop_transmittance).squeeze(1)
    return RaySamples(samples.positions[keep], samples.directions[keep], samples.ray_index[keep], samples.slot[keep],
                      samples.num_rays, samples.max_samples, samples.step)


def render_rays(field: FruitField, grid: OccupancyGrid, rays: RayBundle, settings: RenderSettings, *,
                jitter: torch.Tensor | None = None, colour: bool = True, semantic: bool = False,
                instance: bool = False, geometry_fn: GeometryFn | None = None,
                distortion_rays: int | None = None, far_field_rays: int | None = None, depth: bool = False,
                depth_target: DepthTarget | None = None) -> RenderOutput:
    """Volume-render ``rays`` through the field.

    Gradients: colour/opacity reach density and colour; the fruit probability and the embedding are composited
    with **detached** weights from detached features, so they only train their own heads. When only the
    instance head is wanted (``colour=False, semantic=False``), density is evaluated without autograd and the
    instance head only at samples whose weight exceeds ``settings.weight_threshold``. Without autograd (evaluation,
    export) the colour and semantic heads are evaluated at those samples only, too: the ones left out add less
    than ``weight_threshold`` each (opacity and depth still use every sample); and whenever density needs no
    autograd (also the instance stage) it is evaluated front to back, no further along a ray than where its
    transmittance falls below ``settings.stop_transmittance``.

    Args:
        field: the neural field.
        grid: occupancy grid for empty-space skipping.
        rays: N rays.
        settings: marching parameters.
        jitter: [N] first-sample offsets in [0, 1) (training), None for deterministic mid-step samples.
        colour, semantic, instance: which quantities to render.
        geometry_fn: replacement for ``field.geometry`` (e.g. a compiled version).
        distortion_rays: the distortion loss covers rays ``0..distortion_rays-1`` only (the uniformly drawn part of a
            training batch); None = every ray.
        far_field_rays: only rays ``0..far_field_rays-1`` see the far field behind the box; the others see the
            background colour there (rays known to end in the box: a fruit pixel's); None = every ray.
        depth: also return each ray's median termination distance.
        depth_target: measured depths of the rays: return their line-of-sight split of the weights (``colour``
            rendering only, as it trains density).
    """
    geometry = geometry_fn or field.geometry
    device = rays.origins.device
    samples: RaySamples = march_rays(rays, grid, settings.step, near=settings.near, jitter=jitter)
    with autocast_for(device, settings.mixed_precision):
        if settings.stop_transmittance > 0 and (colour or semantic) and torch.is_grad_enabled():
            samples = _early_terminated(samples, geometry, settings.stop_transmittance)
        needs_graph = (colour or semantic) and torch.is_grad_enabled()
        with torch.set_grad_enabled(needs_graph):
            if not torch.is_grad_enabled() and settings.stop_transmittance > 0:
                geo = _front_to_back(samples, geometry, settings.stop_transmittance)
            else:
                geo = geometry(samples.positions)
            weights = render_weights(samples, geo.density)
        rgb = fruit_prob = embedding = dist = los = None
        # the heads only where the weight counts (weighted): the instance head always, colour and semantic without
        # autograd (inference_at: evaluation, export); training needs their gradient at every sample
        weighted = (torch.nonzero(weights.detach() > settings.weight_threshold).squeeze(1)
                    if instance or not torch.is_grad_enabled() else None)
        inference_at = weighted if not torch.is_grad_enabled() and settings.weight_threshold > 0 else None
        if colour:
            if torch.is_grad_enabled():
                dist = distortion(samples, weights, num_rays=distortion_rays)
            if depth_target is not None:
                los = line_of_sight(samples, rays, weights, depth_target, grid.aabb, settings.near)
            opacity = accumulation(samples, weights)
            values = field.rgb(_take(geo.features, inference_at), _take(samples.directions, inference_at))
            rgb = _composite_at(samples, weights, inference_at, values)
            rgb = rgb + (1.0 - opacity[:, None]) * _beyond_box(field, grid, rays, opacity, settings, jitter,
                                                               far_field_rays)
        else:
            opacity = accumulation(samples, weights.detach())
        if semantic:
            logit = field.fruit_logit(_take(samples.positions, inference_at), _take(geo.features, inference_at))
            prob = torch.sigmoid(logit)
            fruit_prob = _composite_at(samples, weights.detach(), inference_at, prob[:, None])[:, 0]
        if instance:
            emb = field.embedding(samples.positions[weighted], geo.features.detach()[weighted])
            embedding = _composite_at(samples, weights.detach(), weighted, emb)
        median = _median_depth(samples, rays, weights.detach(), opacity.detach()) if depth else None
    return RenderOutput(rgb, opacity, fruit_prob, embedding, int(samples.positions.shape[0]), dist, median, los)


def _beyond_box(field: FruitField, grid: OccupancyGrid, rays: RayBundle, opacity: torch.Tensor,
                settings: RenderSettings, jitter: torch.Tensor | None, far_field_rays: int | None = None
                ) -> torch.Tensor:
    """[N, 3] what each ray sees behind the box (:meth:`FruitField.beyond_box_rgb`); without autograd only for the
    rays whose transmittance through the box is above ``settings.stop_transmittance`` (zero for the others). Rays
    from ``far_field_rays`` on see the background colour alone."""
    if far_field_rays is not None and far_field_rays < len(rays.origins):
        head = RayBundle(rays.origins[:far_field_rays], rays.directions[:far_field_rays])
        tail = field.background_rgb(rays.directions[far_field_rays:])
        front = _beyond_box(field, grid, head, opacity[:far_field_rays], settings,
                            None if jitter is None else jitter[:far_field_rays])
        return torch.cat([front, tail.to(front.dtype)])
    _, t_exit = intersect_aabb(rays, grid.aabb, settings.near)
    t_exit = t_exit.clamp_min(max(settings.near, 1e-3))  # a ray that misses the box: from ``near`` on
    if torch.is_grad_enabled():
        return field.beyond_box_rgb(rays, t_exit, jitter)
    seen = torch.nonzero(1.0 - opacity.detach() > settings.stop_transmittance).squeeze(1)
    out = torch.zeros(len(t_exit), 3, device=t_exit.device)
    if len(seen):
        part = RayBundle(rays.origins[seen], rays.directions[seen])
        out[seen] = field.beyond_box_rgb(part, t_exit[seen], None if jitter is None else jitter[seen]).float()
    return out


def _front_to_back(samples: RaySamples, geometry: GeometryFn, stop_transmittance: float, *,
                   window: int = 16) -> GeometryOutput:
    """The field at ``samples``, evaluated ``window`` steps at a time along the rays and only on rays whose
    transmittance is still above ``stop_transmittance`` (inference: the samples behind an opaque surface are never
    evaluated; they get density 0 and zero features, and would have added less than ``stop_transmittance``)."""
    n = samples.positions.shape[0]
    step_index = samples.slot % samples.max_samples
    alive = torch.ones(samples.num_rays, dtype=torch.bool, device=samples.positions.device)
    optical = torch.zeros(samples.num_rays, device=samples.positions.device)
    density = features = None
    limit = -math.log(stop_transmittance)
    for first in range(0, samples.max_samples, window):
        if not bool(alive.any()):
            break
        in_window = (step_index >= first) & (step_index < first + window)
        idx = torch.nonzero(in_window & alive[samples.ray_index]).squeeze(1)
        if len(idx) == 0:
            continue
        part = geometry(samples.positions[idx])
        if density is None:
            density = part.density.new_zeros(n)
            features = part.features.new_zeros(n, part.features.shape[1])
        density[idx] = part.density
        features[idx] = part.features
        optical.index_add_(0, samples.ray_index[idx], part.density.float() * samples.step)
        alive = optical < limit
    if density is None:  # no sample at all
        return geometry(samples.positions)
    return GeometryOutput(density, features)


def _take(values: torch.Tensor, index: torch.Tensor | None) -> torch.Tensor:
    """``values`` at the samples ``index`` (all of them when None)."""
    return values if index is None else values[index]


def _composite_at(samples: RaySamples, weights: torch.Tensor, index: torch.Tensor | None, values: torch.Tensor
                  ) -> torch.Tensor:
    """Per ray [N, C], the sum of ``weights[index]`` times ``values`` [K, C] (the values of samples ``index``;
    every sample when None)."""
    if index is None:
        return composite(samples, weights, values)
    out = values.new_zeros(samples.num_rays, values.shape[1])
    return out.index_add(0, samples.ray_index[index], weights[index, None].to(values.dtype) * values)


def _median_depth(samples: RaySamples, rays: RayBundle, weights: torch.Tensor, opacity: torch.Tensor) -> torch.Tensor:
    """Per ray, the distance of the first sample where the accumulated weight reaches half the ray's opacity."""
    weights = weights.float()
    reached = exclusive_cumsum(samples, weights) + weights >= 0.5 * opacity.float()[samples.ray_index]
    t = ((samples.positions - rays.origins[samples.ray_index]) * rays.directions[samples.ray_index]).sum(-1)
    t = torch.where(reached & (weights > 0), t.float(), torch.full_like(t, float('inf'), dtype=torch.float32))
    return torch.full((samples.num_rays,), float('inf'), device=t.device).scatter_reduce(
        0, samples.ray_index, t, 'amin')
