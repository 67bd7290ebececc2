"""Trees: planting maps (CSV world / WGS84, GeoJSON), found from the fruit of a synthetic row, nearest crown."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.orchard.geodesy import Datum
from fruitnerfpp_ros.core.orchard.georef import georef_from_datum
from fruitnerfpp_ros.core.orchard.report import planting_map_geojson
from fruitnerfpp_ros.core.orchard.row_frame import RowFrame
from fruitnerfpp_ros.core.orchard.trees import TreeConfig, TreeMap, assign_to_trees, count_trees, find_trees, \
    read_planting_map
from fruitnerfpp_ros.core.synthetic import SynthConfig
from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, build_row_scene
from fruitnerfpp_ros.errors import ConfigError, OrchardError

FRAME = RowFrame(np.array([-5.0, 0.0]), np.array([1.0, 0.0]))
GEOREF = georef_from_datum(Datum(49.5732, 11.0275, 290.0), 30.0)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_trees_found_from_the_fruit_of_overlapping_crowns(seed: int) -> None:
    row = build_row_scene(SynthConfig(fruit='apple', count=20, seed=seed), RowSceneConfig(trees=5))
    centers = np.array([f.center for f in row.scene.fruits])
    found = find_trees(centers, FRAME)
    assert found.source == 'data' and len(found) == 5
    assert np.abs(found.positions[:, 0] - row.trunks[:, 0]).max() < 0.08
    known = find_trees(centers, FRAME, TreeConfig(spacing_m=row.spacing_m))
    assert len(known) == 5


def test_planting_maps(tmp_path: Path) -> None:
    world = np.array([[0.0, 0.0, 0.0], [1.5, 0.1, 0.0], [3.0, -0.1, 0.0]])
    (tmp_path / 'xy.csv').write_text('tree_id,x,y\n' + ''.join(f'{i + 7},{p[0]},{p[1]}\n' for i, p in enumerate(world)))
    trees = read_planting_map(tmp_path / 'xy.csv')
    assert trees.ids.tolist() == [7, 8, 9] and np.allclose(trees.positions, world)
    geo = GEOREF.geodetic_of(world)
    rows = ''.join(f'{i},{g[0]:.10f},{g[1]:.10f}\n' for i, g in enumerate(geo))
    (tmp_path / 'll.csv').write_text('id,lat,lon\n' + rows)
    assert np.allclose(read_planting_map(tmp_path / 'll.csv', GEOREF).positions, world, atol=1e-3)
    (tmp_path / 'map.geojson').write_text(json.dumps(planting_map_geojson([1, 2, 3], geo)))
    from_geojson = read_planting_map(tmp_path / 'map.geojson', GEOREF)
    assert from_geojson.ids.tolist() == [1, 2, 3] and np.allclose(from_geojson.positions, world, atol=1e-3)
    with pytest.raises(OrchardError, match='WGS84 relation'):
        read_planting_map(tmp_path / 'map.geojson')
    (tmp_path / 'bad.csv').write_text('tree,east,north\n1,2,3\n')
    with pytest.raises(OrchardError, match='expected columns'):
        read_planting_map(tmp_path / 'bad.csv')
    with pytest.raises(OrchardError, match='no such'):
        read_planting_map(tmp_path / 'missing.csv')


def test_few_fruit_go_to_the_nearer_trunk() -> None:
    trees = TreeMap(np.array([1, 2]), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), 'planting_map')
    fruit = np.array([[0.45, 0.3, 1.0], [0.55, -0.3, 1.2], [-0.2, 0.0, 1.0]])
    assert assign_to_trees(fruit, trees).tolist() == [0, 1, 0]
    counts, index = count_trees(trees, FRAME, fruit, np.array([0.07, 0.08, 0.09]), counted=[(4.0, 5.8)])
    assert [c.count for c in counts] == [2, 1] and index.tolist() == [0, 1, 0]
    assert counts[0].diameter_mean_m == pytest.approx(0.08) and counts[0].diameter_std_m == pytest.approx(0.01)
    assert [c.complete for c in counts] == [True, False]  # tree 2's crown reaches beyond the counted stretch
    # the third fruit was added from the masks (no points, the scene's diameter): counted, but its size unmeasured
    counts, _ = count_trees(trees, FRAME, fruit, np.array([0.07, 0.08, 0.2]), measured=np.array([True, True, False]))
    assert [c.count for c in counts] == [2, 1]
    assert counts[0].diameter_mean_m == pytest.approx(0.07) and counts[0].diameter_std_m == 0.0


def _shell(centre: list[float], radius: float, n: int, rng: np.random.Generator) -> np.ndarray:
    directions = rng.normal(size=(n, 3))
    directions[:, 2] = np.abs(directions[:, 2]) * 0.5 - 0.2  # a crown's fruit hang round and below its middle
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return np.asarray(centre) + directions * (radius + rng.normal(scale=0.015, size=(n, 1)))


def test_a_large_crowns_fruit_past_the_midpoint_stay_on_it() -> None:
    """A 0.5 m crown beside a 0.3 m one, trunks 0.75 m apart: the large crown's fruit reach 0.1 m past the midpoint
    between the trunks; they belong to their crown, not to the small tree's nearer trunk."""
    rng = np.random.default_rng(3)
    big, small = _shell([0.0, 0.0, 1.0], 0.5, 400, rng), _shell([0.75, 0.0, 0.9], 0.3, 400, rng)
    big = big[np.linalg.norm(big - [0.75, 0.0, 0.9], axis=1) > 0.38][:40]  # none inside the other crown
    small = small[np.linalg.norm(small - [0.0, 0.0, 1.0], axis=1) > 0.58][:25]
    fruit, truth = np.r_[big, small], np.r_[np.zeros(len(big), int), np.ones(len(small), int)]
    trees = TreeMap(np.array([1, 2]), np.array([[0.02, 0.01, 0.0], [0.73, -0.02, 0.0]]), 'planting_map')
    by_trunk = assign_to_trees(fruit, trees, TreeConfig(assign='trunk'))
    assert (by_trunk[:len(big)] == 1).sum() >= 2  # what the nearest trunk gets wrong
    assert assign_to_trees(fruit, trees).tolist() == truth.tolist()
    counts, _ = count_trees(trees, FRAME, fruit, np.full(len(fruit), 0.07))
    assert [c.count for c in counts] == [len(big), len(small)]


def test_tree_config_rejects_an_unknown_assignment() -> None:
    with pytest.raises(ConfigError, match='assign'):
        TreeConfig(assign='nearest')
