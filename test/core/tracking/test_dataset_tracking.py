"""The tracker on a synthetic tree, its counts.json (scored like the pipeline's) and its input errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, load_predicted_centers
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.tracking import TrackConfig, track_dataset, write_track_counts
from fruitnerfpp_ros.core.tracking.result import COUNTS_FORMAT_VERSION
from fruitnerfpp_ros.errors import DatasetError
from test.core.tracking.scenes import render, row_pose, write_scene


def test_counts_a_small_hemisphere_scene_within_tolerance(tiny_apple_dataset: Path, tmp_path: Path) -> None:
    """The shared tiny scene (20 apples, 48 hemisphere views of 96 px): measured 24 fruits, P 0.83, R 1.0."""
    config = TrackConfig()
    result = track_dataset(tiny_apple_dataset, config)
    gt = load_ground_truth(tiny_apple_dataset / 'gt_fruits.json')
    assert 16 <= result.count <= 30 and result.n_frames == 48
    out = write_track_counts(tmp_path / 'counts.json', result, config, source=str(tiny_apple_dataset))
    centers = load_predicted_centers(out)  # what `fruitnerfpp eval` reads
    np.testing.assert_allclose(centers, result.centers())
    metrics = evaluate_counts(centers, gt)
    assert metrics.recall >= 0.9 and metrics.f1 >= 0.75, metrics.table()
    data = json.loads(out.read_text())
    assert data['total'] == result.count and data['method'] == 'tracking'
    assert data['track_config']['max_age'] == config.max_age
    fruit = data['fruits'][0]
    assert set(fruit) >= {'id', 'center', 'diameter', 'n_detections', 'first_frame', 'last_frame'}
    assert 0.03 < np.median([f['diameter'] for f in data['fruits']]) < 0.12


def test_counts_json_version_is_the_pipelines() -> None:
    from fruitnerfpp_ros.core.pipeline import COUNTS_FORMAT_VERSION as PIPELINE_VERSION
    assert COUNTS_FORMAT_VERSION == PIPELINE_VERSION


@pytest.fixture
def small_scene(tmp_path: Path) -> Path:
    poses = [row_pose(x, -1.0) for x in np.linspace(-0.2, 0.2, 4)]
    return write_scene(tmp_path / 'scene', poses, [render(T, np.zeros((1, 3))) for T in poses])


def test_input_errors(small_scene: Path) -> None:
    data = json.loads((small_scene / 'transforms.json').read_text())
    del data['frames'][1]['instance_path']
    (small_scene / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match=r'frame 1 .*no instance_path'):
        track_dataset(small_scene)
    data['frames'][1]['instance_path'] = 'instances/missing.png'
    (small_scene / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match='missing.png: instance mask not found'):
        track_dataset(small_scene)
    data['frames'][1]['instance_path'] = 'images/0001.png'
    data['frames'][1].update(fl_x=100.0, fl_y=100.0, cx=40.0, cy=40.0, w=80, h=80)
    (small_scene / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match='96x96 but .* says 80x80'):
        track_dataset(small_scene)
    shutil.rmtree(small_scene)
    with pytest.raises(DatasetError, match='not found'):
        track_dataset(small_scene)
