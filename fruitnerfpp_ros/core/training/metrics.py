"""Held-out evaluation: PSNR, semantic IoU and instance assignment accuracy."""

from __future__ import annotations

import math
from typing import Iterable, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.rays import rays_for_pixels
from fruitnerfpp_ros.core.fields.fruit_field import FruitField
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderOutput, RenderSettings, render_rays
from fruitnerfpp_ros.core.training.losses import fruit_prototypes

__all__ = ['EvalMetrics', 'ViewRender', 'psnr_from_mse', 'semantic_iou', 'instance_assignment_accuracy',
           'render_view', 'eval_stride', 'evaluate_views', 'spread_views']


class EvalMetrics(NamedTuple):
    """Figures over held-out views (NaN when not computable, e.g. no held-out view).

    Attributes:
        psnr: dB of the rendered colour vs the image over all pixels.
        semantic_iou: IoU of (rendered fruit probability > 0.5) vs the fruit mask.
        instance_acc: over the views with at least two GT fruits, the fraction of their fruit pixels whose
            embedding is nearest (cosine) to their own fruit's prototype (mean embedding per GT fruit of the view);
            a pixel tied between m nearest prototypes counts 1/m, so a constant embedding scores chance.
        num_views: views evaluated.
        instance_chance: what a constant embedding scores on the same pixels (the mean of 1/K over them, K the
            fruits of each pixel's view): ``instance_acc`` is only meaningful above it.
    """

    psnr: float
    semantic_iou: float
    instance_acc: float
    num_views: int
    instance_chance: float = float('nan')


class ViewRender(NamedTuple):
    """A whole rendered view: rgb [H, W, 3], fruit_prob [H, W], embedding [H, W, D] (normalised); a head that was
    not rendered is None."""

    rgb: torch.Tensor
    fruit_prob: torch.Tensor | None
    embedding: torch.Tensor | None


def psnr_from_mse(mse: float) -> float:
    """Peak signal-to-noise ratio in dB for colours in [0, 1]."""
    return -10.0 * math.log10(max(mse, 1e-12))


def semantic_iou(fruit_prob: torch.Tensor, is_fruit: torch.Tensor, threshold: float = 0.5) -> tuple[int, int]:
    """(intersection, union) pixel counts of the thresholded probability and the mask."""
    pred = fruit_prob > threshold
    return int((pred & is_fruit).sum()), int((pred | is_fruit).sum())


def instance_assignment_accuracy(embedding: torch.Tensor, instance_mask: torch.Tensor,
                                 min_fruits: int = 2) -> tuple[float, float, int]:
    """Credit of one view's fruit pixels assigned to their own GT fruit's prototype.

    Args:
        embedding: [P, D] normalised embeddings of the view's pixels.
        instance_mask: [P] per-image instance ids, 0 = background.
        min_fruits: views with fewer GT fruits score nothing (a single fruit is always "right").

    Returns:
        (credit, chance credit, fruit pixels counted): a pixel whose own prototype is among its m nearest (ties
        included) earns 1/m when that set holds its own fruit, else 0; chance is 1/K per pixel.
    """
    fruit = instance_mask > 0
    if int(fruit.sum()) == 0:
        return 0.0, 0.0, 0
    ids, labels = torch.unique(instance_mask[fruit], return_inverse=True)
    if len(ids) < min_fruits:
        return 0.0, 0.0, 0
    emb = embedding[fruit].float()
    prototypes = fruit_prototypes(emb, labels, len(ids))
    similarity = emb @ prototypes.T                                                   # [P, K]
    best = similarity.max(dim=1, keepdim=True).values
    nearest = similarity >= best - 1e-6                                                # ties within float error
    own = nearest.gather(1, labels[:, None])[:, 0]
    credit = own.float() / nearest.sum(1).float()
    return float(credit.sum()), len(labels) / len(ids), int(len(labels))


@torch.no_grad()
def render_view(field: FruitField, grid: OccupancyGrid, dataset: SceneDataset, view: int, settings: RenderSettings,
                chunk_rays: int, *, semantic: bool = True, instance: bool = True, stride: int = 1) -> ViewRender:
    """Render the pixels of dataset view ``view`` on every ``stride``-th row and column (chunked): [ceil(H / stride),
    ceil(W / stride)] images; the heads not asked for come back as None."""
    device = grid.aabb.device
    rows = torch.arange(0, dataset.height, stride, device=device)
    cols = torch.arange(0, dataset.width, stride, device=device)
    h, w = len(rows), len(cols)
    flat = torch.arange(h * w, device=device)
    views = torch.full_like(flat, view)
    poses = dataset.T_world_camera.to(device)
    intrinsics = dataset.intrinsics.to(device)
    outs: list[RenderOutput] = []
    for start in range(0, h * w, chunk_rays):
        part = flat[start:start + chunk_rays]
        rays = rays_for_pixels(poses, intrinsics, views[start:start + chunk_rays], rows[part // w], cols[part % w])
        outs.append(render_rays(field, grid, rays, settings, semantic=semantic, instance=instance))
    rgb = torch.cat([o.rgb for o in outs]).reshape(h, w, 3)
    prob = torch.cat([o.fruit_prob for o in outs]).reshape(h, w) if semantic else None
    emb = F.normalize(torch.cat([o.embedding for o in outs]), dim=-1).reshape(h, w, -1) if instance else None
    return ViewRender(rgb, prob, emb)


def eval_stride(height: int, width: int, max_pixels: int | None) -> int:
    """The row and column stride that leaves at most ``max_pixels`` of a ``height`` x ``width`` view (1: every
    pixel; None: no limit)."""
    if max_pixels is None or height * width <= max_pixels:
        return 1
    return math.ceil(math.sqrt(height * width / max_pixels))


def spread_views(views: Iterable[int] | torch.Tensor, count: int) -> list[int]:
    """``count`` of ``views`` spread evenly over them, the first and the last included: a row drive's held-out
    figures then see both passes (its first views are all on the way out)."""
    views = [int(v) for v in views]
    if count >= len(views) or count <= 1:
        return views[:max(count, 0)]
    return [views[i] for i in np.linspace(0, len(views) - 1, count).round().astype(int)]


@torch.no_grad()
def evaluate_views(field: FruitField, grid: OccupancyGrid, dataset: SceneDataset, views: list[int],
                   settings: RenderSettings, chunk_rays: int, *, semantic: bool = True,
                   instance: bool = True, max_pixels: int | None = None) -> EvalMetrics:
    """PSNR, semantic IoU and instance assignment accuracy over ``views`` (typically the held-out ones).

    ``semantic`` / ``instance`` False: that head is not rendered (not trained yet: the stage-end evaluation of the
    earlier stages) and its figure is NaN. ``max_pixels``: a larger view is scored on every k-th row and column
    (:func:`eval_stride`), so that high-resolution images do not make each stage's evaluation render millions of
    rays.
    """
    if not views:
        nan = float('nan')
        return EvalMetrics(nan, nan, nan, 0)
    sq_err, pixels, inter, union, correct, chance, total = 0.0, 0, 0, 0, 0.0, 0.0, 0
    k = eval_stride(dataset.height, dataset.width, max_pixels)
    for view in views:
        out = render_view(field, grid, dataset, view, settings, chunk_rays, semantic=semantic, instance=instance,
                          stride=k)
        device = out.rgb.device
        valid = (torch.ones(out.rgb.shape[:2], dtype=torch.bool, device=device) if dataset.valid_masks is None
                 else dataset.valid_masks[view, ::k, ::k].to(device))
        image = dataset.images[view, ::k, ::k].to(device)
        sq_err += float(((out.rgb - image) ** 2)[valid].sum()) / 3.0
        pixels += int(valid.sum())
        if out.fruit_prob is not None:
            i, u = semantic_iou(out.fruit_prob[valid], dataset.semantic_masks[view, ::k, ::k].to(device)[valid])
            inter, union = inter + i, union + u
        if out.embedding is not None:
            c, ch, t = instance_assignment_accuracy(out.embedding.reshape(-1, out.embedding.shape[-1]),
                                                    dataset.instance_masks[view, ::k, ::k].reshape(-1).to(device))
            correct, chance, total = correct + c, chance + ch, total + t
    nan = float('nan')
    return EvalMetrics(psnr_from_mse(sq_err / pixels) if pixels else nan, inter / union if union else nan,
                       correct / total if total else nan, len(views), chance / total if total else nan)
