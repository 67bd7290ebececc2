"""``synth --scene row``: trees of varied load with overlapping crowns, each fruit's tree, gt_trees.json, the
planting map, GNSS fixes in gnss.json and as sensor_msgs/NavSatFix in the bag, the datum in transforms.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.orchard.georef import georef_from_datum
from fruitnerfpp_ros.core.orchard.geodesy import Datum
from fruitnerfpp_ros.core.orchard.gnss import fixes_from_bag, read_gnss_json
from fruitnerfpp_ros.core.synthetic import SynthConfig
from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, build_row_scene
from fruitnerfpp_ros.errors import OrchardError, SynthError


def test_row_scene_trees_overlap_and_vary() -> None:
    row = build_row_scene(SynthConfig(fruit='apple', count=20, seed=5), RowSceneConfig(trees=4, planting_jitter_m=0))
    ids = np.array([f.tree_id for f in row.scene.fruits])
    assert sorted(set(ids.tolist())) == [1, 2, 3, 4]
    assert [f.id for f in row.scene.fruits] == list(range(1, len(ids) + 1))
    loads = np.bincount(ids)[1:]
    assert loads.min() < loads.max()                              # fruit load varies from tree to tree
    assert np.allclose(np.diff(row.trunks[:, 0]), row.spacing_m)  # no jitter: the planting grid itself
    assert np.allclose(row.trunks[:, 0].mean(), 0.0)              # the row is centred on the world origin
    assert (2 * row.crown_radii[:-1] > row.spacing_m).any()       # neighbouring crowns overlap
    instances = row.scene.ellipsoids.instance
    assert set(np.unique(instances[instances > 0]).tolist()) == set(range(1, len(ids) + 1))
    with pytest.raises(SynthError, match='trees'):
        RowSceneConfig(trees=0)


def test_row_dataset_truth_planting_map_and_gnss(row_dataset: Path) -> None:
    fruits = json.loads((row_dataset / 'gt_fruits.json').read_text())['fruits']
    trees = json.loads((row_dataset / 'gt_trees.json').read_text())
    assert [t['id'] for t in trees['trees']] == [1, 2, 3]
    per_tree = np.bincount([f['tree_id'] for f in fruits], minlength=4)[1:]
    assert per_tree.tolist() == [t['n_fruits'] for t in trees['trees']]
    # a fruit grows on its tree: nearer to that tree's crown centre than the other crowns' (on average)
    crowns = np.array([t['crown_center'] for t in trees['trees']])
    own = [np.linalg.norm(np.array(f['center']) - crowns[f['tree_id'] - 1]) for f in fruits]
    other = [min(np.linalg.norm(np.array(f['center']) - c) for k, c in enumerate(crowns) if k != f['tree_id'] - 1)
             for f in fruits]
    assert np.mean(own) < np.mean(other)
    # the trunks' WGS84 positions follow from the datum and the row's heading
    datum = trees['datum']
    georef = georef_from_datum(Datum(datum['latitude'], datum['longitude'], datum['altitude']), datum['yaw_deg'])
    geo = georef.geodetic_of(np.array([t['trunk'] for t in trees['trees']]))
    assert np.allclose(geo[:, :2], [[t['latitude'], t['longitude']] for t in trees['trees']], atol=1e-9)
    assert read_transforms(row_dataset).extra['datum']['yaw_deg'] == datum['yaw_deg']
    planted = np.loadtxt(row_dataset / 'planting_map.csv', delimiter=',', skiprows=1)
    assert planted[:, 0].tolist() == [1, 2, 3]
    assert np.abs(planted[:, 1:] - np.array([t['trunk'] for t in trees['trees']])[:, :2]).max() < 0.2
    geojson = json.loads((row_dataset / 'planting_map.geojson').read_text())
    assert [f['geometry']['coordinates'][0] for f in geojson['features']][0] == pytest.approx(datum['longitude'],
                                                                                              abs=1e-4)


def test_bag_carries_the_gnss_fixes_as_navsatfix(row_dataset: Path) -> None:
    bag = row_dataset.parent / 'bag'
    from_json, antenna = read_gnss_json(row_dataset / 'gnss.json')
    from_bag = fixes_from_bag(bag, '/gnss/fix')
    assert len(from_bag) == len(from_json) >= 10 and np.allclose(antenna, [0.0, -0.5, 0.0])
    assert [f.stamp_ns for f in from_bag] == [f.stamp_ns for f in from_json]
    lat_lon = np.array([[f.latitude_deg, f.longitude_deg] for f in from_bag])
    assert np.allclose(lat_lon, [[f.latitude_deg, f.longitude_deg] for f in from_json], atol=1e-9)
    assert all(f.status == 2 and f.horizontal_sigma_m() == pytest.approx(0.02) for f in from_bag)
    # fixes come while the robot drives: within the stamps of the keyframes
    stamps = [f.stamp_ns for f in read_transforms(row_dataset).frames]
    assert min(stamps) <= from_bag[0].stamp_ns and from_bag[-1].stamp_ns <= max(stamps)
    with pytest.raises(OrchardError, match='no GNSS topic'):
        fixes_from_bag(bag, '/fix')
    with pytest.raises(OrchardError, match='expected sensor_msgs/msg/NavSatFix'):
        fixes_from_bag(bag, '/camera/camera_info')


def test_synth_cli_row_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fruitnerfpp_ros.cli.main import main

    assert main(['synth', '--trees', '3', '--gnss', '--out', str(tmp_path / 'x')]) == 2
    assert '--trees, --gnss: only with --scene row' in capsys.readouterr().err
    assert main(['synth', '--scene', 'row', '--datum', '49', '11', '--out', str(tmp_path / 'y')]) == 2
    assert 'LAT LON ALT' in capsys.readouterr().err
    assert not (tmp_path / 'x').exists() and not (tmp_path / 'y').exists()
    assert main(['synth', '--scene', 'row', '--trees', '2', '--tree-spacing', '0.6', '--count', '4', '--views', '8',
                 '--resolution', '48', '36', '--row-standoff', '1.0', '--datum', '10', '20', '30', '45', '--quiet',
                 '--out', str(tmp_path / 'row')]) == 0
    trees = json.loads((tmp_path / 'row' / 'gt_trees.json').read_text())
    assert trees['spacing_m'] == 0.6 and trees['datum'] == {'latitude': 10.0, 'longitude': 20.0, 'altitude': 30.0,
                                                            'yaw_deg': 45.0}
    assert not (tmp_path / 'row' / 'gnss.json').exists()
