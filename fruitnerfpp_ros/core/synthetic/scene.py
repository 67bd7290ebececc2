"""Procedural fruit tree: trunk, branches, twigs, stems, leaves and fruits, as render primitives.

World frame: z up, metres, ground plane at z = 0, trunk at the origin. The crown is an ellipsoid whose size grows
with the number (and size) of fruits, so a 20-fruit tree is a small tree and fruits keep their real size.

Primitives (all numpy float64, converted to torch by the rasteriser):
- :class:`Ellipsoids`: fruits (pears are two ellipsoids with one instance id) and bark joints;
- :class:`Leaves`: flat lens-shaped leaves (|y| <= 1 - x^2 in the leaf's normalised coordinates);
- :class:`Cylinders`: trunk, branches, twigs and stems.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.synthetic.config import MIXED_DEFAULT_COUNT, SynthConfig
from fruitnerfpp_ros.core.synthetic.fruit_types import FRUIT_NAMES, MIXED, FruitType, fruit_type

__all__ = ['Ellipsoids', 'Leaves', 'Cylinders', 'GtFruit', 'Scene', 'build_scene', 'fruit_type_counts']

#: Fruit centres are kept this far apart beyond their bounding spheres (metres), except in touching clusters.
_GAP_M = 0.004
#: Shell area per fruit, in units of the fruit's diameter squared (sets the crown size).
_AREA_PER_FRUIT = 3.5 ** 2


class Ellipsoids(NamedTuple):
    """N ellipsoids. ``rotation[:, :, k]`` is the k-th local axis in world coordinates.

    Attributes:
        center: [N, 3] metres.
        rotation: [N, 3, 3] local-to-world rotations.
        radii: [N, 3] semi-axes along the local axes, metres.
        albedo: [N, 3] main colour 0..1.
        blush: [N, 3] secondary colour 0..1 (blended by surface noise).
        blush_amount: [N] fraction of blush.
        instance: [N] fruit id (1..) or 0 for bark joints.
    """

    center: np.ndarray
    rotation: np.ndarray
    radii: np.ndarray
    albedo: np.ndarray
    blush: np.ndarray
    blush_amount: np.ndarray
    instance: np.ndarray


class Leaves(NamedTuple):
    """N flat lens-shaped leaves.

    Attributes:
        center: [N, 3] metres.
        axis_u: [N, 3] unit long axis; axis_v: [N, 3] unit short axis; normal: [N, 3] unit normal.
        half_size: [N, 2] half-length (along u) and half-width (along v), metres.
        albedo: [N, 3] colour 0..1.
    """

    center: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray
    half_size: np.ndarray
    albedo: np.ndarray


class Cylinders(NamedTuple):
    """N open cylinders from ``p0`` to ``p1`` (metres) with ``radius`` [N] and ``albedo`` [N, 3]."""

    p0: np.ndarray
    p1: np.ndarray
    radius: np.ndarray
    albedo: np.ndarray


class GtFruit(NamedTuple):
    """Ground truth of one fruit.

    Attributes:
        id: instance id (value in the instance masks), 1..N.
        type: fruit type name.
        center: [3] centre, metres, world frame (for a pear: volume-weighted centre of body and neck).
        radii: [3] semi-axes (x, y, z-hanging) of the fruit's bounding ellipsoid, metres.
        rotation: [3, 3] fruit-to-world rotation (z = hanging axis).
    """

    id: int
    type: str
    center: np.ndarray
    radii: np.ndarray
    rotation: np.ndarray


class Scene(NamedTuple):
    """A procedural tree.

    Attributes:
        ellipsoids / leaves / cylinders: render primitives.
        fruits: ground truth, ordered by id.
        crown_center: [3] metres; crown_radii: [3] semi-axes of the crown ellipsoid, metres.
        bound_center: [3], bound_radius: sphere (metres) holding the whole tree, used to frame cameras.
    """

    ellipsoids: Ellipsoids
    leaves: Leaves
    cylinders: Cylinders
    fruits: list[GtFruit]
    crown_center: np.ndarray
    crown_radii: np.ndarray
    bound_center: np.ndarray
    bound_radius: float


def fruit_type_counts(config: SynthConfig) -> dict[str, int]:
    """Number of fruits of each type for ``config`` (``mixed`` splits the count evenly over all types)."""
    if config.fruit != MIXED:
        return {config.fruit: config.count if config.count is not None else fruit_type(config.fruit).default_count}
    total = config.count if config.count is not None else MIXED_DEFAULT_COUNT
    n = len(FRUIT_NAMES)
    return {name: total // n + (1 if i < total % n else 0) for i, name in enumerate(FRUIT_NAMES)}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    return _unit(rng.normal(size=(n, 3)))


def _frame_from_z(z: np.ndarray, spin: np.ndarray) -> np.ndarray:
    """[N, 3, 3] rotations whose third column is the unit vector ``z`` [N, 3], spun by ``spin`` [N] radians."""
    helper = np.where(np.abs(z[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    x = _unit(np.cross(helper, z))
    y = np.cross(z, x)
    c, s = np.cos(spin)[:, None], np.sin(spin)[:, None]
    x, y = c * x + s * y, -s * x + c * y
    return np.stack([x, y, z], axis=-1)


def _perpendicular(n: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random unit vectors perpendicular to the unit vectors ``n`` [N, 3]."""
    return _frame_from_z(n, rng.uniform(0.0, 2.0 * np.pi, len(n)))[:, :, 0]


class _FruitLayout(NamedTuple):
    types: list[FruitType]
    centers: np.ndarray      # body centres [N, 3]
    rotations: np.ndarray    # [N, 3, 3]
    scales: np.ndarray       # [N]
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


def _place_fruits(types: list[FruitType], crown_c: np.ndarray, crown_r: np.ndarray, trunk_top: float,
                  cluster_scale: float, rng: np.random.Generator) -> _FruitLayout:
    """Place fruits (in touching clusters) near the crown surface without overlaps (loop over fruits only).

    Two fruits are kept apart by a separating plane: along the unit vector n between their centres, the centre
    distance is at least h_a(n) + h_b(-n) (support functions), which excludes interpenetration for any shape.
    Cluster members are placed exactly at that distance (plus under 2 mm) from a member: touching fruits.
    """
    n = len(types)
    centers = np.zeros((n, 3))
    scales = np.clip(1.0 + np.array([t.size_jitter for t in types]) * rng.normal(size=n), 0.8, 1.2)
    tilt = np.radians([t.max_tilt_deg for t in types]) * np.sqrt(rng.uniform(size=n))
    azim = rng.uniform(0.0, 2.0 * np.pi, n)
    axes = np.stack([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)], axis=1)
    rotations = _frame_from_z(axes, rng.uniform(0.0, 2.0 * np.pi, n))
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
        direction = _random_unit(rng, 1)[0]
        direction[2] = np.clip(direction[2], -0.75, 0.8)
        lo, hi = t.radial_range
        attempts += 1
        if attempts > 200 * n:  # the crown is full: loosen the radial range (never expected at default density)
            lo, hi = 0.3, 1.1
        seed = crown_c + rng.uniform(lo, hi) * crown_r * direction
        if seed[2] - bounds[placed] < trunk_top * 0.9:
            continue
        if placed and np.min(clearance(placed, seed, placed)) < _GAP_M:
            continue
        centers[placed] = seed
        members = [placed]
        placed += 1
        radial = _unit(seed - crown_c)
        for _ in range(size - 1):
            if placed >= n:
                break
            for _try in range(12):
                anchor = members[int(rng.integers(len(members)))]
                side = _unit(_perpendicular(radial[None], rng)[0] + rng.normal(scale=0.3, size=3))
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
    return _FruitLayout(types, centers, rotations, scales, clusters)


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


def build_scene(config: SynthConfig) -> Scene:
    """Build the procedural tree of ``config`` (deterministic in ``config.seed``)."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0x5EED]))
    counts = fruit_type_counts(config)
    types = [fruit_type(name) for name, k in counts.items() for _ in range(k)]
    order = rng.permutation(len(types))
    types = [types[i] for i in order]
    main_type = fruit_type(config.fruit) if config.fruit != MIXED else fruit_type('apple')

    # Crown size from the shell area the fruits need; trunk below it.
    area = sum(_AREA_PER_FRUIT * t.diameter_m ** 2 for t in types)
    radius = max(0.25, float(np.sqrt(area / (4.0 * np.pi))))
    crown_r = np.array([radius, radius, 0.85 * radius])
    trunk_h = 0.22 + 0.35 * radius
    crown_c = np.array([0.0, 0.0, trunk_h + 0.8 * crown_r[2]])
    trunk_r = 0.02 + 0.05 * radius

    layout = _place_fruits(types, crown_c, crown_r, trunk_h, config.cluster_scale, rng)

    # --- fruits as ellipsoids (a pear adds a neck) ---
    e_center, e_rot, e_radii, e_albedo, e_blush, e_amount, e_inst = [], [], [], [], [], [], []
    gt: list[GtFruit] = []
    tops = np.zeros((len(types), 3))
    for i, t in enumerate(types):
        fid = i + 1
        R = layout.rotations[i]
        s = layout.scales[i]
        body_r = np.array(t.radii_m) * s
        c = layout.centers[i]
        tint = np.clip(1.0 + rng.normal(scale=0.06, size=3), 0.8, 1.2)
        albedo = np.clip(np.array(t.base_rgb) * tint, 0.0, 1.0)
        blush = np.clip(np.array(t.blush_rgb) * tint, 0.0, 1.0)
        amount = float(np.clip(t.blush_amount + rng.normal(scale=0.15), 0.0, 0.9))
        e_center.append(c)
        e_rot.append(R)
        e_radii.append(body_r)
        e_albedo.append(albedo)
        e_blush.append(blush)
        e_amount.append(amount)
        e_inst.append(fid)
        if t.neck_radii_m is not None:
            neck_r = np.array(t.neck_radii_m) * s
            neck_c = c + R[:, 2] * t.neck_offset_m * s
            e_center.append(neck_c)
            e_rot.append(R)
            e_radii.append(neck_r)
            e_albedo.append(albedo)
            e_blush.append(blush)
            e_amount.append(amount)
            e_inst.append(fid)
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

    # --- trunk, main branches ---
    cyl_p0, cyl_p1, cyl_r, cyl_albedo = [], [], [], []
    bark = np.array([0.36, 0.26, 0.17])

    def add_cylinder(p0: np.ndarray, p1: np.ndarray, r: float, albedo: np.ndarray) -> None:
        # Long thin cylinders are split into pieces so that their screen rectangles stay tight (fast rendering).
        pieces = int(np.clip(np.ceil(np.linalg.norm(p1 - p0) / max(6.0 * r, 0.04)), 1, 16))
        ends = p0 + np.linspace(0.0, 1.0, pieces + 1)[:, None] * (p1 - p0)
        for a, b in zip(ends[:-1], ends[1:]):
            cyl_p0.append(a)
            cyl_p1.append(b)
            cyl_r.append(r)
            cyl_albedo.append(albedo)

    def add_joint(c: np.ndarray, r: float) -> None:
        e_center.append(c)
        e_rot.append(np.eye(3))
        e_radii.append(np.full(3, r))
        e_albedo.append(bark)
        e_blush.append(bark)
        e_amount.append(0.0)
        e_inst.append(0)

    trunk_top = np.array([0.0, 0.0, crown_c[2] - 0.1 * crown_r[2]])
    add_cylinder(np.array([0.0, 0.0, -0.05]), trunk_top, trunk_r, bark)
    add_joint(trunk_top, trunk_r)
    n_main = int(np.clip(4 + round(3 * radius), 4, 12))
    seg_a, seg_b = [], []
    base_az = rng.uniform(0.0, 2.0 * np.pi)
    for k in range(n_main):
        az = base_az + 2.0 * np.pi * k / n_main + rng.uniform(-0.3, 0.3)
        el = rng.uniform(-0.1, 0.7)
        start = np.array([0.0, 0.0, trunk_h + rng.uniform(0.0, 0.5) * (trunk_top[2] - trunk_h)])
        direction = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        end = crown_c + 0.78 * crown_r * direction
        mid = 0.5 * (start + end) + np.array([0.0, 0.0, 0.12 * radius]) + rng.normal(scale=0.05 * radius, size=3)
        r0, r1 = 0.55 * trunk_r, 0.3 * trunk_r
        add_cylinder(start, mid, r0, bark)
        add_joint(mid, r0)
        add_cylinder(mid, end, r1, bark)
        add_joint(end, r1)
        seg_a += [start, mid]
        seg_b += [mid, end]
    seg_a_arr, seg_b_arr = np.array(seg_a), np.array(seg_b)

    # --- stems from fruits to a cluster anchor, twigs from the anchor to the nearest main branch ---
    stem_rgb = np.array([0.30, 0.28, 0.12])
    twig_r = 0.004 + 0.003 * radius
    anchors = []
    for members in layout.clusters:
        t = types[members[0]]
        top_mean = tops[members].mean(axis=0)
        anchor = top_mean + np.array([0.0, 0.0, t.stem_length_m * layout.scales[members[0]] + 0.01 * len(members)])
        anchors.append(anchor)
        for m in members:
            add_cylinder(tops[m] - (tops[m] - layout.centers[m]) * 0.05, anchor, 0.0028, stem_rgb)
    if anchors:
        anchor_arr = np.array(anchors)
        closest, _ = _segment_closest(anchor_arr, seg_a_arr, seg_b_arr)
        for a, b in zip(anchor_arr, closest):
            add_cylinder(b, a, twig_r, bark * 1.1)

    # --- leaves: a shell of leaves around the crown plus leaves just outside some fruits ---
    density = float(np.mean([t.leaf_density for t in types])) * config.leaf_scale
    half = np.array(main_type.leaf_half_size_m)
    leaf_area = 8.0 / 3.0 * half[0] * half[1]
    shell_area = 4.0 * np.pi * radius ** 2
    n_shell = int(round(density * shell_area / leaf_area))
    dirs = _random_unit(rng, n_shell)
    frac = 1.08 - 0.5 * rng.uniform(size=n_shell) ** 1.5
    leaf_c = crown_c + frac[:, None] * crown_r * dirs
    leaf_c = leaf_c[leaf_c[:, 2] > trunk_h * 0.8]
    n_fruit = len(types)
    occl_p = np.clip(0.25 * density, 0.0, 0.8)
    occluded = np.flatnonzero(rng.uniform(size=n_fruit) < occl_p) if config.leaf_scale > 0 else np.zeros(0, int)
    if len(occluded):
        out = _unit(layout.centers[occluded] - crown_c)
        lateral = _perpendicular(out, rng) * rng.uniform(-1.0, 1.0, (len(occluded), 1))
        b = np.array([types[i].bounding_radius_m for i in occluded])[:, None]
        extra = layout.centers[occluded] + out * (b + rng.uniform(0.01, 0.04, (len(occluded), 1))) + lateral * b
        leaf_c = np.concatenate([leaf_c, extra])
    n_leaves = len(leaf_c)
    outward = _unit(leaf_c - crown_c)
    normals = _unit(_random_unit(rng, n_leaves) + 0.8 * outward + np.array([0.0, 0.0, 0.4]))
    # Keep leaves out of fruits: a leaf close to a fruit becomes tangent to the fruit's bounding sphere.
    if n_fruit:
        fruit_b = np.array([t.bounding_radius_m for t in types]) * layout.scales
        dist, nearest = cKDTree(layout.centers).query(leaf_c)
        clearance = fruit_b[nearest] + 0.002
        close = dist < clearance + half[0]
        away = _unit(leaf_c[close] - layout.centers[nearest[close]] + 1e-9)
        leaf_c[close] = layout.centers[nearest[close]] + away * np.maximum(dist[close], clearance[close])[:, None]
        normals[close] = away
    axis_u = _perpendicular(normals, rng)
    axis_v = np.cross(normals, axis_u)
    leaf_scale = np.clip(1.0 + 0.15 * rng.normal(size=(n_leaves, 1)), 0.7, 1.3)
    green = np.array([0.17, 0.38, 0.09])
    leaf_rgb = np.clip(green * rng.uniform(0.75, 1.25, (n_leaves, 1))
                       + rng.normal(scale=0.025, size=(n_leaves, 3)), 0.02, 1.0)
    leaves = Leaves(leaf_c, axis_u, axis_v, normals, half[None] * leaf_scale, leaf_rgb)

    ellipsoids = Ellipsoids(np.array(e_center), np.array(e_rot), np.array(e_radii), np.array(e_albedo),
                            np.array(e_blush), np.array(e_amount), np.array(e_inst, dtype=np.int64))
    cylinders = Cylinders(np.array(cyl_p0), np.array(cyl_p1), np.array(cyl_r), np.array(cyl_albedo))
    top = crown_c[2] + crown_r[2] * 1.1
    bound_center = np.array([0.0, 0.0, 0.5 * top])
    bound_radius = float(max(np.hypot(crown_r[0] * 1.08, crown_c[2] - bound_center[2]), 0.5 * top))
    return Scene(ellipsoids, leaves, cylinders, gt, crown_c, crown_r, bound_center, bound_radius)
