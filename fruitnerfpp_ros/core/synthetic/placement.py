"""Fruit placement near the crown surface: touching clusters, never interpenetrating (any fruit shape)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fruitnerfpp_ros.core.synthetic.fruit_types import FruitType
from fruitnerfpp_ros.core.synthetic.primitives import frame_from_z, perpendicular, random_unit, unit

__all__ = ['FruitLayout', 'place_fruits', 'GAP_M']

#: Fruit centres are kept this far apart beyond their bounding spheres (metres), except in touching clusters.
GAP_M = 0.004


class FruitLayout(NamedTuple):
    """Where the fruits hang.

    Attributes:
        types: [N] fruit type of each fruit.
        centers: [N, 3] body centres, metres.
        rotations: [N, 3, 3] fruit-to-world rotations (z = hanging axis).
        scales: [N] size factor of each fruit (1 = the type's nominal size).
        clusters: groups of fruit indices hanging together (one stem anchor each).
    """

    types: list[FruitType]
    centers: np.ndarray
    rotations: np.ndarray
    scales: np.ndarray
    clusters: list[list[int]]


def _support(n: np.ndarray, rot: np.ndarray, body: np.ndarray, neck: np.ndarray, neck_h: np.ndarray) -> np.ndarray:
    """Support function h(n) = max over the fruit of p . n, relative to the body centre.

    Args:
        n: [M, 3] unit directions; rot: [M, 3, 3]; body, neck: [M, 3] semi-axes (neck zeros when none);
        neck_h: [M] neck centre height along the fruit's z axis.
    """
    local = np.einsum('mji,mj->mi', rot, n)
    h_body = np.sqrt(np.sum((local * body) ** 2, axis=1))
    h_neck = local[:, 2] * neck_h + np.sqrt(np.sum((local * neck) ** 2, axis=1))
    return np.where(neck_h > 0, np.maximum(h_body, h_neck), h_body)


def place_fruits(types: list[FruitType], crown_c: np.ndarray, crown_r: np.ndarray, trunk_top: float,
                 cluster_scale: float, rng: np.random.Generator) -> FruitLayout:
    """Place fruits (in touching clusters) near the crown surface without overlaps (loop over fruits only).

    Two fruits are kept apart by a separating plane: along the unit vector n between their centres, the centre
    distance is at least h_a(n) + h_b(-n) (support functions), which excludes interpenetration for any shape.
    Cluster members are placed exactly at that distance (plus under 2 mm) from a member: touching fruits.

    Args:
        types: fruit type of each fruit to place.
        crown_c: [3] crown centre, metres; crown_r: [3] crown semi-axes, metres.
        trunk_top: height (m) below which no fruit hangs (0.9 x this).
        cluster_scale: multiplier on the probability of clusters of two or more.
        rng: the scene's random stream.
    """
    n = len(types)
    centers = np.zeros((n, 3))
    scales = np.clip(1.0 + np.array([t.size_jitter for t in types]) * rng.normal(size=n), 0.8, 1.2)
    tilt = np.radians([t.max_tilt_deg for t in types]) * np.sqrt(rng.uniform(size=n))
    azim = rng.uniform(0.0, 2.0 * np.pi, n)
    axes = np.stack([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)], axis=1)
    rotations = frame_from_z(axes, rng.uniform(0.0, 2.0 * np.pi, n))
    body = np.array([t.radii_m for t in types]) * scales[:, None]
    neck = np.array([t.neck_radii_m or (0.0, 0.0, 0.0) for t in types]) * scales[:, None]
    neck_h = np.array([t.neck_offset_m for t in types]) * scales
    bounds = np.array([t.bounding_radius_m for t in types]) * scales

    def support(idx: np.ndarray, direction: np.ndarray) -> np.ndarray:
        return _support(direction, rotations[idx], body[idx], neck[idx], neck_h[idx])

    def clearance(k: int, candidate: np.ndarray, placed: int) -> np.ndarray:
        """Centre distance minus the separating distance, against every placed fruit ([placed])."""
        if placed == 0:
            return np.zeros(0)
        delta = centers[:placed] - candidate
        dist = np.linalg.norm(delta, axis=1)
        direction = delta / np.maximum(dist, 1e-12)[:, None]
        idx = np.arange(placed)
        need = support(np.full(placed, k), direction) + support(idx, -direction)
        return dist - need

    clusters: list[list[int]] = []
    placed = 0
    attempts = 0
    while placed < n:
        t = types[placed]
        probs = np.array(t.cluster_probs, dtype=float)
        probs[1:] *= cluster_scale
        size = int(rng.choice(len(probs), p=probs / probs.sum())) + 1
        # Seed fruit: a random direction, between the type's inner and outer radial fraction of the crown.
        direction = random_unit(rng, 1)[0]
        direction[2] = np.clip(direction[2], -0.75, 0.8)
        lo, hi = t.radial_range
        attempts += 1
        if attempts > 200 * n:  # the crown is full: loosen the radial range (never expected at default density)
            lo, hi = 0.3, 1.1
        seed = crown_c + rng.uniform(lo, hi) * crown_r * direction
        if seed[2] - bounds[placed] < trunk_top * 0.9:
            continue
        if placed and np.min(clearance(placed, seed, placed)) < GAP_M:
            continue
        centers[placed] = seed
        members = [placed]
        placed += 1
        radial = unit(seed - crown_c)
        for _ in range(size - 1):
            if placed >= n:
                break
            for _try in range(12):
                anchor = members[int(rng.integers(len(members)))]
                side = unit(perpendicular(radial[None], rng)[0] + rng.normal(scale=0.3, size=3))
                reach = support(np.array([anchor]), side[None])[0] + support(np.array([placed]), -side[None])[0]
                candidate = centers[anchor] + side * (reach + rng.uniform(0.0, 0.002))
                if (candidate[2] - bounds[placed] > trunk_top * 0.9
                        and np.min(clearance(placed, candidate, placed)) >= 0.0):
                    centers[placed] = candidate
                    members.append(placed)
                    placed += 1
                    break
            else:
                break
        clusters.append(members)
    return FruitLayout(types, centers, rotations, scales, clusters)
