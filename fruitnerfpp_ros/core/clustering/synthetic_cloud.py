"""Synthetic fruit point clouds with known instances, for clustering tests and ``bench/cluster_bench.py``.

Fruits are spherical shells (the surface an export keeps) with one random unit embedding each, a smooth
variation across the fruit and a little per-point noise. ``touching=True`` packs fruits in groups of three whose
shells overlap (centre distance < diameter): the points of a group then form one connected blob that only the
embeddings separate. Within 0.15 r of a contact, embeddings are blended (up to 30 %) with the neighbour's, as a
smooth instance field would render them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud

__all__ = ['SyntheticFruitCloud', 'make_fruit_cloud']


class SyntheticFruitCloud(NamedTuple):
    """A fruit point cloud with its ground truth.

    Attributes:
        cloud: the points (xyz m, rgb, semantic 1, unit embeddings).
        labels: [N] true fruit index per point (0..F-1), -1 for clutter points.
        centers: [F, 3] fruit centres (m).
        radius_m: fruit radius (m).
    """

    cloud: FruitPointCloud
    labels: np.ndarray
    centers: np.ndarray
    radius_m: float


def _fruit_centers(n_fruits: int, radius: float, touching: bool, rng: np.random.Generator) -> np.ndarray:
    if touching:
        n_groups = int(np.ceil(n_fruits / 3))
        anchors = _lattice(n_groups, 6.0 * radius, radius, rng)
        # an equilateral triangle of fruits, centre distance 1.8 r (shells overlap by 0.2 r)
        angle = rng.uniform(0, 2 * np.pi, n_groups)[:, None] + np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3])
        side = 1.8 * radius / np.sqrt(3.0)
        offsets = np.stack([side * np.cos(angle), side * np.sin(angle), rng.normal(0, 0.1 * radius, angle.shape)],
                           axis=-1)
        return (anchors[:, None, :] + offsets).reshape(-1, 3)[:n_fruits]
    return _lattice(n_fruits, 3.0 * radius, 0.25 * radius, rng)


def _lattice(n: int, spacing: float, jitter: float, rng: np.random.Generator) -> np.ndarray:
    side = int(np.ceil(n ** (1.0 / 3.0)))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing='ij'), -1).reshape(-1, 3)[:n]
    return grid * spacing + rng.uniform(-jitter, jitter, (n, 3))


def make_fruit_cloud(n_points: int, n_fruits: int, *, touching: bool = False, dim: int = 32,
                     radius_m: float = 0.035, noise: float = 0.15, smooth_noise: float = 0.3,
                     clutter_fraction: float = 0.0,
                     seed: int = 0) -> SyntheticFruitCloud:
    """A cloud of about ``n_points`` fruit-surface points on ``n_fruits`` fruits of radius ``radius_m`` (m).

    Args:
        n_points: total points (fruit points plus clutter), approximately.
        n_fruits: number of fruits F.
        touching: groups of three overlapping fruits instead of separated ones.
        dim: embedding size D.
        radius_m: fruit radius.
        noise: i.i.d. per-point embedding noise (norm relative to the unit fruit embedding).
        smooth_noise: spatially smooth embedding variation across a fruit (norm at the fruit's surface): a
            trained field varies slowly in space, so neighbouring points have nearly equal embeddings.
        clutter_fraction: share of extra points scattered uniformly in the scene box (label -1).
        seed: random seed.
    """
    rng = np.random.default_rng(seed)
    centers = _fruit_centers(n_fruits, radius_m, touching, rng)
    n_clutter = int(round(clutter_fraction * n_points))
    # draw extra points then drop those inside a neighbouring fruit, so about n_points remain
    per_fruit = int(np.ceil((n_points - n_clutter) / n_fruits * (1.25 if touching else 1.0)))
    direction = rng.normal(size=(n_fruits, per_fruit, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    depth = radius_m * (1.0 - 0.25 * rng.uniform(size=(n_fruits, per_fruit, 1)))
    xyz = (centers[:, None, :] + direction * depth).reshape(-1, 3)
    labels = np.repeat(np.arange(n_fruits), per_fruit)

    base = rng.normal(size=(n_fruits, dim))
    base /= np.linalg.norm(base, axis=1, keepdims=True)
    emb = base[labels].copy()
    if touching:
        others = np.stack([(labels // 3) * 3 + (labels + s) % 3 for s in (1, 2)], axis=1)  # [N, 2] group mates
        others = np.minimum(others, n_fruits - 1)
        dist_other = np.linalg.norm(xyz[:, None, :] - centers[others], axis=-1) - radius_m  # [N, 2]
        inside = np.any((dist_other < -0.05 * radius_m) & (others != labels[:, None]), axis=1)
        blend_m = 0.15 * radius_m
        weight = 0.3 * np.clip(1.0 - dist_other / blend_m, 0.0, 1.0) * (others != labels[:, None])
        emb = emb * (1.0 - weight.sum(1, keepdims=True)) + (weight[..., None] * base[others]).sum(1)
        keep = ~inside
        xyz, labels, emb = xyz[keep], labels[keep], emb[keep]
        if len(xyz) > n_points - n_clutter:
            pick = np.sort(rng.choice(len(xyz), n_points - n_clutter, replace=False))
            xyz, labels, emb = xyz[pick], labels[pick], emb[pick]
    gradient = rng.normal(size=(n_fruits, 3, dim)) * (smooth_noise / np.sqrt(3 * dim))  # per-fruit linear field
    offset = (xyz - centers[labels]) / radius_m
    emb = emb + np.einsum('nc,ncd->nd', offset, gradient[labels]) + rng.normal(size=emb.shape) * (noise / np.sqrt(dim))
    if n_clutter:
        lo, hi = centers.min(0) - 2 * radius_m, centers.max(0) + 2 * radius_m
        xyz = np.concatenate([xyz, rng.uniform(lo, hi, (n_clutter, 3))])
        clutter_emb = rng.normal(size=(n_clutter, dim))
        emb = np.concatenate([emb, clutter_emb])
        labels = np.concatenate([labels, np.full(n_clutter, -1)])
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    n = len(xyz)
    rgb = np.tile(np.array([[200, 30, 30]], np.uint8), (n, 1))
    # the spacing of a grid export with the same number of points on a fruit's surface
    spacing = float(np.sqrt(4.0 * np.pi * radius_m ** 2 / max(1.0, (n - n_clutter) / n_fruits)))
    cloud = FruitPointCloud(xyz.astype(np.float32), rgb, np.ones(n, np.float32), emb.astype(np.float32),
                            spacing_m=spacing)
    return SyntheticFruitCloud(cloud, labels.astype(np.int64), centers, radius_m)
