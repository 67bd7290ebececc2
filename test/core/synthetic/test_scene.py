"""The procedural tree: fruit types, counts, real sizes, no overlaps, touching clusters, canopy scaling."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.synthetic import FRUIT_NAMES, FRUIT_TYPES, SynthConfig, build_scene
from fruitnerfpp_ros.core.synthetic.scene import fruit_type_counts

PAPER_COUNTS = {'apple': 283, 'plum': 745, 'lemon': 326, 'pear': 250, 'peach': 152, 'mango': 1150}


def _max_penetration(scene) -> float:
    """Deepest point (metres, approx.) of one fruit's surface inside another fruit's ellipsoid."""
    e = scene.ellipsoids
    fruit = np.flatnonzero(e.instance > 0)
    reach = e.radii[fruit].max(1)
    pairs = np.array(sorted(cKDTree(e.center[fruit]).query_pairs(2 * reach.max())))
    pairs = pairs[e.instance[fruit[pairs[:, 0]]] != e.instance[fruit[pairs[:, 1]]]]
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(400, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    worst = 0.0
    for a, b in fruit[pairs]:
        for p, q in ((a, b), (b, a)):
            pts = e.center[p] + (sphere * e.radii[p]) @ e.rotation[p].T
            local = (pts - e.center[q]) @ e.rotation[q] / e.radii[q]
            inside = 1.0 - np.linalg.norm(local, axis=1).min()
            worst = max(worst, inside * e.radii[q].min())
    return worst


def _pair_gaps(centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Centre distance minus the sum of horizontal radii, for all pairs i < j."""
    i, j = np.triu_indices(len(centers), 1)
    return np.linalg.norm(centers[i] - centers[j], axis=1) - (radii[i, 0] + radii[j, 0])


@pytest.mark.parametrize('fruit', FRUIT_NAMES)
def test_default_tree_of_each_type(fruit: str) -> None:
    scene = build_scene(SynthConfig(fruit=fruit))
    assert len(scene.fruits) == PAPER_COUNTS[fruit]
    assert [f.id for f in scene.fruits] == list(range(1, PAPER_COUNTS[fruit] + 1))
    assert {f.type for f in scene.fruits} == {fruit}
    centers = np.array([f.center for f in scene.fruits])
    radii = np.array([f.radii for f in scene.fruits])
    # Fruits never interpenetrate (surface samples of each fruit lie outside every other fruit's ellipsoids)...
    assert _max_penetration(scene) < 0.002
    # ...yet some touch (clusters): bodies side by side less than 3 mm apart.
    gaps = _pair_gaps(centers, radii)
    assert np.count_nonzero(gaps < 0.003) >= 0.05 * len(scene.fruits)
    # Above the ground, within the crown; trunk, branches and leaves exist.
    assert centers[:, 2].min() > 0.2
    assert np.all(np.linalg.norm((centers - scene.crown_center) / scene.crown_radii, axis=1) < 1.15)
    assert len(scene.leaves.center) > 10 * len(scene.fruits) ** 0.5 and len(scene.cylinders.p0) > 5


def test_real_sizes_and_shapes() -> None:
    widths = {name: 2 * t.radii_m[0] for name, t in FRUIT_TYPES.items()}
    assert 0.065 < widths['apple'] < 0.085 and 0.035 < widths['plum'] < 0.05 and widths['plum'] < widths['apple']
    for name in ('lemon', 'mango'):
        t = FRUIT_TYPES[name]
        assert t.radii_m[2] > 1.3 * t.radii_m[0], f'{name} is elongated'
    pear = build_scene(SynthConfig(fruit='pear', count=5)).fruits[0]
    assert pear.radii[2] > 1.2 * pear.radii[0]  # body + neck: pear-shaped, taller than wide


def test_canopy_scales_with_fruit_count() -> None:
    small = build_scene(SynthConfig(fruit='apple', count=20))
    large = build_scene(SynthConfig(fruit='apple'))
    assert small.crown_radii[0] < 0.45 < 1.0 < large.crown_radii[0]
    assert small.bound_radius < large.bound_radius
    # The fruit keeps its real size.
    assert abs(small.fruits[0].radii[0] - large.fruits[0].radii[0]) < 0.01


def test_mixed_tree_has_every_type_and_count_override() -> None:
    assert fruit_type_counts(SynthConfig(fruit='mixed', count=14)) == {
        'apple': 3, 'plum': 3, 'lemon': 2, 'pear': 2, 'peach': 2, 'mango': 2}
    scene = build_scene(SynthConfig(fruit='mixed', count=30))
    assert len(scene.fruits) == 30 and {f.type for f in scene.fruits} == set(FRUIT_NAMES)
    assert len(build_scene(SynthConfig(fruit='mango', count=17)).fruits) == 17
