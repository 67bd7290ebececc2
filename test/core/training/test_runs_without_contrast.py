"""A dataset whose views never show two fruits (or no fruit at all) still trains and counts.

Found by a blind draw (docs/results/accuracy_suite.md, session 50): a camera looking over a small tree showed no
fruit, and the run failed in the instance stage's sampler instead of counting what there was (nothing).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.pipeline import run_pipeline
from fruitnerfpp_ros.core.training import RunDir, TrainConfig, load_trained_scene
from test.core.training.stand_in_scene import make_sphere_scene
from test.core.training.test_trainer import MICRO


@pytest.fixture(scope='module')
def one_fruit(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sphere tree with a single fruit: no view shows two."""
    return make_sphere_scene(tmp_path_factory.mktemp('one_fruit'), views=10, size=48, fruits=1)


def _without_fruit(scene: Path, out: Path) -> Path:
    """A copy of ``scene`` whose instance masks are empty (a camera that saw no fruit)."""
    for path in scene.rglob('*'):
        if path.is_file():
            target = out / path.relative_to(scene)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(path.read_bytes())
    for mask in (out / 'instances').glob('*.png'):
        cv2.imwrite(str(mask), np.zeros_like(cv2.imread(str(mask), cv2.IMREAD_UNCHANGED)))
    return out


def test_one_fruit_a_view_trains_without_the_instance_stage_and_counts_by_position(one_fruit: Path, tmp_path: Path,
                                                                                   caplog) -> None:
    assert MICRO.instance.iterations > 0
    with caplog.at_level('WARNING', logger='fruitnerfpp_ros.core.training.stages'):
        result = run_pipeline(one_fruit, tmp_path / 'run', train_config=MICRO, device='cpu')
    assert 'no training view shows two fruits' in caplog.text and 'hold no fruit' not in caplog.text
    assert result.train_summary.completed and not result.stopped
    saved = load_config(TrainConfig, RunDir(tmp_path / 'run').config_path)
    assert saved.instance.iterations == 0 and saved.geometry.iterations == MICRO.geometry.iterations
    assert load_trained_scene(tmp_path / 'run', device='cpu').completed_stages == 3
    emb = result.cloud.embedding
    assert len(emb) > 0 and np.allclose(emb, emb[:1]) and np.allclose(np.linalg.norm(emb, axis=1), 1.0)
    counts = json.loads(result.paths.counts_json.read_text())
    assert counts['total'] == result.count.count


def test_masks_without_fruit_count_zero_instead_of_failing(one_fruit: Path, tmp_path: Path, caplog) -> None:
    empty = _without_fruit(one_fruit, tmp_path / 'empty')
    with caplog.at_level('WARNING', logger='fruitnerfpp_ros.core.training.stages'):
        result = run_pipeline(empty, tmp_path / 'run', train_config=MICRO, device='cpu')
    assert 'hold no fruit: nothing to count' in caplog.text
    assert result.count.count == 0 and len(result.cloud) == 0
    saved = load_config(TrainConfig, RunDir(tmp_path / 'run').config_path)   # nothing trained for nothing
    assert saved.geometry.iterations == saved.semantic.iterations == saved.instance.iterations == 0
    ends = [r for r in RunDir(tmp_path / 'run').read_metrics() if r.get('event') == 'stage_end']
    assert len(ends) == 3 and all(r['eval_views'] == 0 for r in ends)   # an untrained field is not rendered
    assert json.loads(result.paths.counts_json.read_text())['total'] == 0
