"""Procedural fruit tree: trunk, branches, twigs, stems, leaves and fruits, as render primitives.

World frame: z up, metres, ground plane at z = 0, trunk at the origin. The crown is an ellipsoid whose size grows
with the number (and size) of fruits, so a 20-fruit tree is a small tree and fruits keep their real size.

:func:`build_scene` runs a few named steps on one seeded random stream, in a fixed order: the crown, the fruit
placement (``placement.py``), the fruit primitives, the wood (trunk and main branches), the stems and twigs,
and the foliage. The primitive records are in ``primitives.py``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.synthetic.config import MIXED_DEFAULT_COUNT, SynthConfig
from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, MIXED, FruitType, fruit_type
from fruitnerfpp_ros.core.synthetic.placement import FruitLayout, place_fruits
from fruitnerfpp_ros.core.synthetic.primitives import (Cylinders, Ellipsoids, GtFruit, Leaves, Scene, perpendicular,
                                                       random_unit, unit)

__all__ = ['Ellipsoids', 'Leaves', 'Cylinders', 'GtFruit', 'Scene', 'build_scene', 'fruit_type_counts']

#: Shell area per fruit, in units of the fruit's diameter squared (sets the crown size).
_AREA_PER_FRUIT = 3.5 ** 2
_BARK_RGB = np.array([0.36, 0.26, 0.17])
_STEM_RGB = np.array([0.30, 0.28, 0.12])
_LEAF_RGB = np.array([0.17, 0.38, 0.09])
_STEM_RADIUS_M = 0.0028


def fruit_type_counts(config: SynthConfig) -> dict[str, int]:
    """Number of fruits of each type for ``config`` (``mixed`` splits the count evenly over all types)."""
    if config.fruit != MIXED:
        return {config.fruit: config.count if config.count is not None else fruit_type(config.fruit).default_count}
    total = config.count if config.count is not None else MIXED_DEFAULT_COUNT
    n = len(FRUIT_NAMES)
    return {name: total // n + (1 if i < total % n else 0) for i, name in enumerate(FRUIT_NAMES)}


class _Crown(NamedTuple):
    """Crown ellipsoid and trunk of the tree (metres)."""

    center: np.ndarray      # [3]
    radii: np.ndarray       # [3] semi-axes
    radius: float           # nominal horizontal radius
    trunk_height: float     # height of the crown's lowest branches
    trunk_radius: float


class _Wood(NamedTuple):
    """Main branch segments (start -> end, [S, 3] each) that twigs attach to."""

    seg_a: np.ndarray
    seg_b: np.ndarray


class _PrimitiveLists:
    """Ellipsoids and cylinders collected one by one, stacked into :class:`Ellipsoids` / :class:`Cylinders`."""

    def __init__(self) -> None:
        self.ellipsoids: list[tuple] = []
        self.cylinders: list[tuple] = []

    def add_ellipsoid(self, center: np.ndarray, rotation: np.ndarray, radii: np.ndarray, albedo: np.ndarray,
                      blush: np.ndarray, blush_amount: float, instance: int) -> None:
        self.ellipsoids.append((center, rotation, radii, albedo, blush, blush_amount, instance))

    def add_joint(self, center: np.ndarray, radius: float) -> None:
        """A bark sphere where two cylinders meet (instance 0)."""
        self.add_ellipsoid(center, np.eye(3), np.full(3, radius), _BARK_RGB, _BARK_RGB, 0.0, 0)

    def add_cylinder(self, p0: np.ndarray, p1: np.ndarray, radius: float, albedo: np.ndarray) -> None:
        """A cylinder p0 -> p1; long thin ones are split so that their screen rectangles stay tight (speed)."""
        pieces = int(np.clip(np.ceil(np.linalg.norm(p1 - p0) / max(6.0 * radius, 0.04)), 1, 16))
        ends = p0 + np.linspace(0.0, 1.0, pieces + 1)[:, None] * (p1 - p0)
        for a, b in zip(ends[:-1], ends[1:]):
            self.cylinders.append((a, b, radius, albedo))

    def stacked(self) -> tuple[Ellipsoids, Cylinders]:
        e = list(zip(*self.ellipsoids))
        c = list(zip(*self.cylinders))
        ellipsoids = Ellipsoids(np.array(e[0]), np.array(e[1]), np.array(e[2]), np.array(e[3]), np.array(e[4]),
                                np.array(e[5]), np.array(e[6], dtype=np.int64))
        return ellipsoids, Cylinders(np.array(c[0]), np.array(c[1]), np.array(c[2]), np.array(c[3]))


def _crown_of(types: list[FruitType]) -> _Crown:
    """Crown size from the shell area the fruits need; trunk below it."""
    area = sum(_AREA_PER_FRUIT * t.diameter_m ** 2 for t in types)
    radius = max(0.25, float(np.sqrt(area / (4.0 * np.pi))))
    radii = np.array([radius, radius, 0.85 * radius])
    trunk_h = 0.22 + 0.35 * radius
    center = np.array([0.0, 0.0, trunk_h + 0.8 * radii[2]])
    return _Crown(center, radii, radius, trunk_h, 0.02 + 0.05 * radius)


def _add_fruits(layout: FruitLayout, rng: np.random.Generator, parts: _PrimitiveLists
                ) -> tuple[list[GtFruit], np.ndarray]:
    """Fruit ellipsoids (a pear adds a neck with the same id) and their ground truth.

    Returns:
        (ground truth ordered by id, [N, 3] top of each fruit where its stem starts, metres).
    """
    gt: list[GtFruit] = []
    tops = np.zeros((len(layout.types), 3))
    for i, t in enumerate(layout.types):
        fid = i + 1
        R = layout.rotations[i]
        s = layout.scales[i]
        body_r = np.array(t.radii_m) * s
        c = layout.centers[i]
        tint = np.clip(1.0 + rng.normal(scale=0.06, size=3), 0.8, 1.2)
        albedo = np.clip(np.array(t.base_rgb) * tint, 0.0, 1.0)
        blush = np.clip(np.array(t.blush_rgb) * tint, 0.0, 1.0)
        amount = float(np.clip(t.blush_amount + rng.normal(scale=0.15), 0.0, 0.9))
        parts.add_ellipsoid(c, R, body_r, albedo, blush, amount, fid)
        if t.neck_radii_m is not None:
            neck_r = np.array(t.neck_radii_m) * s
            neck_c = c + R[:, 2] * t.neck_offset_m * s
            parts.add_ellipsoid(neck_c, R, neck_r, albedo, blush, amount, fid)
            v_body, v_neck = np.prod(body_r), np.prod(neck_r)
            center = (v_body * c + v_neck * neck_c) / (v_body + v_neck)
            bottom = -body_r[2]
            top = t.neck_offset_m * s + neck_r[2]
            radii = np.array([body_r[0], body_r[1], 0.5 * (top - bottom)])
            tops[i] = c + R[:, 2] * top
        else:
            center = c
            radii = body_r
            tops[i] = c + R[:, 2] * body_r[2]
        gt.append(GtFruit(fid, t.name, center, radii, R))
    return gt, tops


def _add_wood(crown: _Crown, rng: np.random.Generator, parts: _PrimitiveLists) -> _Wood:
    """Trunk and main branches (two cylinders each, bent upwards, bark joints between)."""
    trunk_r, radius = crown.trunk_radius, crown.radius
    trunk_top = np.array([0.0, 0.0, crown.center[2] - 0.1 * crown.radii[2]])
    parts.add_cylinder(np.array([0.0, 0.0, -0.05]), trunk_top, trunk_r, _BARK_RGB)
    parts.add_joint(trunk_top, trunk_r)
    n_main = int(np.clip(4 + round(3 * radius), 4, 12))
    seg_a, seg_b = [], []
    base_az = rng.uniform(0.0, 2.0 * np.pi)
    for k in range(n_main):
        az = base_az + 2.0 * np.pi * k / n_main + rng.uniform(-0.3, 0.3)
        el = rng.uniform(-0.1, 0.7)
        start = np.array([0.0, 0.0, crown.trunk_height + rng.uniform(0.0, 0.5) * (trunk_top[2] - crown.trunk_height)])
        direction = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        end = crown.center + 0.78 * crown.radii * direction
        mid = 0.5 * (start + end) + np.array([0.0, 0.0, 0.12 * radius]) + rng.normal(scale=0.05 * radius, size=3)
        r0, r1 = 0.55 * trunk_r, 0.3 * trunk_r
        parts.add_cylinder(start, mid, r0, _BARK_RGB)
        parts.add_joint(mid, r0)
        parts.add_cylinder(mid, end, r1, _BARK_RGB)
        parts.add_joint(end, r1)
        seg_a += [start, mid]
        seg_b += [mid, end]
    return _Wood(np.array(seg_a), np.array(seg_b))


def _segment_closest(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on segments a->b [S, 3] to ``points`` [P, 3]: (closest [P, 3], distance [P])."""
    ab = b - a
    t = np.einsum('psk,sk->ps', points[:, None, :] - a[None], ab) / np.einsum('sk,sk->s', ab, ab)[None]
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    dist = np.linalg.norm(closest - points[:, None, :], axis=2)
    best = np.argmin(dist, axis=1)
    idx = np.arange(len(points))
    return closest[idx, best], dist[idx, best]


def _add_stems_and_twigs(layout: FruitLayout, tops: np.ndarray, wood: _Wood, crown: _Crown,
                         parts: _PrimitiveLists) -> None:
    """Stems from each fruit to its cluster's anchor, a twig from the anchor to the nearest main branch."""
    twig_r = 0.004 + 0.003 * crown.radius
    anchors = []
    for members in layout.clusters:
        t = layout.types[members[0]]
        top_mean = tops[members].mean(axis=0)
        anchor = top_mean + np.array([0.0, 0.0, t.stem_length_m * layout.scales[members[0]] + 0.01 * len(members)])
        anchors.append(anchor)
        for m in members:
            parts.add_cylinder(tops[m] - (tops[m] - layout.centers[m]) * 0.05, anchor, _STEM_RADIUS_M, _STEM_RGB)
    if anchors:
        anchor_arr = np.array(anchors)
        closest, _ = _segment_closest(anchor_arr, wood.seg_a, wood.seg_b)
        for a, b in zip(anchor_arr, closest):
            parts.add_cylinder(b, a, twig_r, _BARK_RGB * 1.1)


def _foliage(layout: FruitLayout, crown: _Crown, leaf_half_size_m: np.ndarray, leaf_scale: float,
             rng: np.random.Generator) -> Leaves:
    """A shell of leaves around the crown plus leaves just outside some fruits (occlusion); none inside fruits."""
    types = layout.types
    density = float(np.mean([t.leaf_density for t in types])) * leaf_scale
    half = leaf_half_size_m
    leaf_area = 8.0 / 3.0 * half[0] * half[1]
    shell_area = 4.0 * np.pi * crown.radius ** 2
    n_shell = int(round(density * shell_area / leaf_area))
    dirs = random_unit(rng, n_shell)
    frac = 1.08 - 0.5 * rng.uniform(size=n_shell) ** 1.5
    leaf_c = crown.center + frac[:, None] * crown.radii * dirs
    leaf_c = leaf_c[leaf_c[:, 2] > crown.trunk_height * 0.8]
    n_fruit = len(types)
    occl_p = np.clip(0.25 * density, 0.0, 0.8)
    occluded = np.flatnonzero(rng.uniform(size=n_fruit) < occl_p) if leaf_scale > 0 else np.zeros(0, int)
    if len(occluded):
        out = unit(layout.centers[occluded] - crown.center)
        lateral = perpendicular(out, rng) * rng.uniform(-1.0, 1.0, (len(occluded), 1))
        b = np.array([types[i].bounding_radius_m for i in occluded])[:, None]
        extra = layout.centers[occluded] + out * (b + rng.uniform(0.01, 0.04, (len(occluded), 1))) + lateral * b
        leaf_c = np.concatenate([leaf_c, extra])
    n_leaves = len(leaf_c)
    outward = unit(leaf_c - crown.center)
    normals = unit(random_unit(rng, n_leaves) + 0.8 * outward + np.array([0.0, 0.0, 0.4]))
    # Keep leaves out of fruits: a leaf close to a fruit becomes tangent to the fruit's bounding sphere.
    if n_fruit:
        fruit_b = np.array([t.bounding_radius_m for t in types]) * layout.scales
        dist, nearest = cKDTree(layout.centers).query(leaf_c)
        clearance = fruit_b[nearest] + 0.002
        close = dist < clearance + half[0]
        away = unit(leaf_c[close] - layout.centers[nearest[close]] + 1e-9)
        leaf_c[close] = layout.centers[nearest[close]] + away * np.maximum(dist[close], clearance[close])[:, None]
        normals[close] = away
    axis_u = perpendicular(normals, rng)
    axis_v = np.cross(normals, axis_u)
    size = np.clip(1.0 + 0.15 * rng.normal(size=(n_leaves, 1)), 0.7, 1.3)
    leaf_rgb = np.clip(_LEAF_RGB * rng.uniform(0.75, 1.25, (n_leaves, 1))
                       + rng.normal(scale=0.025, size=(n_leaves, 3)), 0.02, 1.0)
    return Leaves(leaf_c, axis_u, axis_v, normals, half[None] * size, leaf_rgb)


def build_scene(config: SynthConfig) -> Scene:
    """Build the procedural tree of ``config`` (deterministic in ``config.seed``)."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x5EED]))
    counts = fruit_type_counts(config)
    types = [fruit_type(name) for name, k in counts.items() for _ in range(k)]
    order = rng.permutation(len(types))
    types = [types[i] for i in order]
    main_type = fruit_type(config.fruit) if config.fruit != MIXED else fruit_type('apple')

    crown = _crown_of(types)
    layout = place_fruits(types, crown.center, crown.radii, crown.trunk_height, config.cluster_scale, rng)
    parts = _PrimitiveLists()
    gt, tops = _add_fruits(layout, rng, parts)
    wood = _add_wood(crown, rng, parts)
    _add_stems_and_twigs(layout, tops, wood, crown, parts)
    leaves = _foliage(layout, crown, np.array(main_type.leaf_half_size_m), config.leaf_scale, rng)
    ellipsoids, cylinders = parts.stacked()

    top = crown.center[2] + crown.radii[2] * 1.1
    bound_center = np.array([0.0, 0.0, 0.5 * top])
    bound_radius = float(max(np.hypot(crown.radii[0] * 1.08, crown.center[2] - bound_center[2]), 0.5 * top))
    return Scene(ellipsoids, leaves, cylinders, gt, crown.center, crown.radii, bound_center, bound_radius)
