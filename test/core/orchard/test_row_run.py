"""A whole row without training: stub segment jobs that return the ground-truth fruits their keyframes show, run
in this process and on a local Ray with 2 workers; the row is counted once per fruit, per tree, georeferenced, and
a failing segment is retried once, then reported while the rest of the row is counted."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from fruitnerfpp_ros.core.orchard.config import OrchardConfig, SegmentConfig
from fruitnerfpp_ros.core.orchard.evaluation import evaluate_row
from fruitnerfpp_ros.core.orchard.geodesy import Datum, enu_from_geodetic
from fruitnerfpp_ros.core.orchard.gnss import read_gnss_json
from fruitnerfpp_ros.core.orchard.jobs import ATTEMPTS_NAME, InProcessRunner, SegmentJob
from fruitnerfpp_ros.core.orchard.merge import SegmentFruits
from fruitnerfpp_ros.core.orchard.row_run import RowResult, run_row


def shown_fruits(gt_path: Path, fail: dict[int, int] | None = None) -> Callable[[SegmentJob], SegmentFruits]:
    """A job function returning the ground-truth fruits seen by >= 2 of the segment's keyframes (a perfect count);
    segment k fails its first ``fail[k]`` attempts. Self-contained: Ray pickles it by value."""
    def job(segment: SegmentJob) -> SegmentFruits:
        attempts = len((Path(segment.segment_dir) / 'attempts.jsonl').read_text().splitlines())
        if attempts <= (fail or {}).get(segment.index, 0):
            raise RuntimeError(f'stub failure of segment {segment.index}, attempt {attempts}')
        info = json.loads((Path(segment.dataset_dir) / 'transforms.json').read_text())['segment']
        frames = set(info['frames'])
        fruits = [f for f in json.loads(gt_path.read_text())['fruits'] if len(frames & set(f['views_visible'])) >= 2]
        return SegmentFruits(segment.index, np.array([f['center'] for f in fruits], np.float64).reshape(-1, 3),
                             np.array([f['diameter'] for f in fruits], np.float64), np.full(len(fruits), 50),
                             np.array([f['id'] for f in fruits], np.int64))
    return job


def _gt(row_dataset: Path) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    fruits = json.loads((row_dataset / 'gt_fruits.json').read_text())['fruits']
    trees = json.loads((row_dataset / 'gt_trees.json').read_text())
    return np.array([f['center'] for f in fruits]), np.array([f['tree_id'] for f in fruits]), trees


def _run(row_dataset: Path, out: Path, runner: Any, planting_map: Path | None = None,
         config: OrchardConfig = OrchardConfig()) -> RowResult:
    fixes, antenna = read_gnss_json(row_dataset / 'gnss.json')
    return run_row(row_dataset, out, runner, config=config, fixes=fixes, antenna_in_camera_m=antenna,
                   planting_map=planting_map, log=lambda _: None)


@pytest.mark.parametrize('planting_map', [None, 'planting_map.csv', 'planting_map.geojson'])
def test_every_fruit_once_on_its_nearest_trunk(row_dataset: Path, tmp_path: Path, planting_map: str | None) -> None:
    centers, grown_on, truth = _gt(row_dataset)
    trunks = np.array([t['trunk'] for t in truth['trees']])
    result = _run(row_dataset, tmp_path, InProcessRunner(job=shown_fruits(row_dataset / 'gt_fruits.json')),
                  row_dataset / planting_map if planting_map else None)
    assert len(result.plan.segments) >= 2 and all(o.ok for o in result.outcomes)
    # every fruit of the row once, though neighbouring segments both counted the ones near their cut
    assert len(result.fruits) == len(centers) and int(result.fruits.matched.sum()) > 0
    assert np.allclose(np.sort(result.fruits.centers[:, 0]), np.sort(centers[:, 0]))
    # one tree per trunk, each counting the fruits grown on it
    assert result.trees.source == ('data' if planting_map is None else 'planting_map') and len(result.trees) == 3
    assert [t.count for t in result.tree_counts] == np.bincount(grown_on - 1, minlength=3).tolist()
    assert np.abs(result.trees.positions[:, :2] - trunks[:, :2]).max() < 0.1
    evaluation = evaluate_row(row_dataset, result.fruits.centers, result.fruits.segments, result.fruit_trees,
                              result.trees.ids, result.trees.positions,
                              np.array([t.count for t in result.tree_counts]), result.paths['trees_geojson'])
    assert evaluation['row']['f1'] == 1.0 and evaluation['double_counts']['total'] == 0
    assert len(grown_on) == len(centers)


def test_trees_geojson_is_rfc7946_lon_lat_within_a_metre(row_dataset: Path, tmp_path: Path) -> None:
    _, _, truth = _gt(row_dataset)
    result = _run(row_dataset, tmp_path, InProcessRunner(job=shown_fruits(row_dataset / 'gt_fruits.json')))
    assert result.georef is not None and result.georef.source == 'gnss'
    assert result.georef.residual_rms_m < 0.06  # fixes with 2 cm horizontal noise
    data = json.loads((tmp_path / 'trees.geojson').read_text())
    assert data['type'] == 'FeatureCollection' and 'crs' not in data and len(data['features']) == 3
    datum = Datum(truth['datum']['latitude'], truth['datum']['longitude'], truth['datum']['altitude'])
    for feature, tree in zip(sorted(data['features'], key=lambda f: f['properties']['position_along_row_m']),
                             truth['trees']):
        assert feature['type'] == 'Feature' and feature['geometry']['type'] == 'Point'
        lon, lat = feature['geometry']['coordinates']          # RFC 7946: longitude first
        assert abs(lon - datum.longitude_deg) < 1e-3 and abs(lat - datum.latitude_deg) < 1e-3
        assert {'tree_id', 'fruit_count', 'diameter_mean_m', 'diameter_std_m', 'row',
                'position_along_row_m'} <= set(feature['properties'])
        found, true = enu_from_geodetic(np.array([[lat, lon, datum.altitude_m],
                                                  [tree['latitude'], tree['longitude'], datum.altitude_m]]), datum)
        assert np.linalg.norm(found[:2] - true[:2]) < 1.0
    fruits = json.loads((tmp_path / 'fruits.geojson').read_text())
    assert len(fruits['features']) == len(result.fruits)
    assert all(len(f['geometry']['coordinates']) == 3 for f in fruits['features'])
    report = json.loads((tmp_path / 'row_report.json').read_text())
    assert report['version'] == 2 and report['kind'] == 'row' and report['total'] == len(result.fruits)
    assert sum(t['count'] for t in report['trees']) == report['total']
    csv_lines = (tmp_path / 'trees.csv').read_text().splitlines()
    assert csv_lines[0].startswith('tree_id,row,') and len(csv_lines) == 4


def test_local_ray_two_workers_retries_once_then_reports(row_dataset: Path, tmp_path: Path) -> None:
    ray = pytest.importorskip('ray')
    from fruitnerfpp_ros.core.orchard.jobs import RayRunner

    centers, _, _ = _gt(row_dataset)
    # segment 0 fails once (the retry counts it), segment 1 always fails, segment 2 counts at once
    job = shown_fruits(row_dataset / 'gt_fruits.json', fail={0: 1, 1: 99})
    # segments trusted only 5 cm beyond their own stretch: the failed one leaves a gap its neighbours do not fill
    config = OrchardConfig(segments=SegmentConfig(trust_fraction=0.1))
    ray.init(num_cpus=2, include_dashboard=False, configure_logging=False, log_to_driver=False)
    try:
        result = _run(row_dataset, tmp_path, RayRunner(ray, num_cpus=1, job=job), row_dataset / 'planting_map.csv',
                      config)
    finally:
        ray.shutdown()
    by_index = {o.index: o for o in result.outcomes}
    assert len(by_index) == 3
    assert by_index[0].ok and by_index[0].attempts == 2
    assert not by_index[1].ok and by_index[1].attempts == 2 and 'stub failure of segment 1' in by_index[1].error
    assert by_index[2].ok and by_index[2].attempts == 1
    assert len((tmp_path / 'segments' / 'seg_001' / ATTEMPTS_NAME).read_text().splitlines()) == 2
    # the rest of the row is counted: every fruit in the trusted stretches of segments 0 and 2, once
    s = result.plan.frame.along(centers)
    trusted = np.zeros(len(centers), bool)
    for seg in result.plan.segments:
        if seg.index != 1:
            trusted |= (s >= seg.trust[0]) & (s <= seg.trust[1])
    assert 0 < len(result.fruits) == int(trusted.sum()) < len(centers)
    states = {r['index']: r['state'] for r in result.report['segments']}
    assert states == {0: 'done', 1: 'failed', 2: 'done'}
    assert (tmp_path / 'trees.geojson').is_file()
