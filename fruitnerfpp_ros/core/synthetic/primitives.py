"""Render primitives and ground truth of the procedural tree, plus the small vector helpers that build them.

World frame: z up, metres, ground plane at z = 0, trunk at the origin. All arrays are numpy float64 (the
rasteriser converts them to torch):

- :class:`Ellipsoids`: fruits (pears are two ellipsoids with one instance id) and bark joints;
- :class:`Leaves`: flat lens-shaped leaves (|y| <= 1 - x^2 in the leaf's normalised coordinates);
- :class:`Cylinders`: trunk, branches, twigs and stems.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ['Ellipsoids', 'Leaves', 'Cylinders', 'GtFruit', 'Scene', 'unit', 'random_unit', 'frame_from_z',
           'perpendicular']


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
        tree_id: the tree it grows on (a row of trees, ``row_scene.py``), None for a single tree.
    """

    id: int
    type: str
    center: np.ndarray
    radii: np.ndarray
    rotation: np.ndarray
    tree_id: int | None = None


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


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` [..., 3] scaled to unit length along the last axis."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    """[n, 3] directions uniform on the unit sphere."""
    return unit(rng.normal(size=(n, 3)))


def frame_from_z(z: np.ndarray, spin: np.ndarray) -> np.ndarray:
    """[N, 3, 3] rotations whose third column is the unit vector ``z`` [N, 3], spun by ``spin`` [N] radians."""
    helper = np.where(np.abs(z[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    x = unit(np.cross(helper, z))
    y = np.cross(z, x)
    c, s = np.cos(spin)[:, None], np.sin(spin)[:, None]
    x, y = c * x + s * y, -s * x + c * y
    return np.stack([x, y, z], axis=-1)


def perpendicular(n: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random unit vectors perpendicular to the unit vectors ``n`` [N, 3]."""
    return frame_from_z(n, rng.uniform(0.0, 2.0 * np.pi, len(n)))[:, :, 0]
