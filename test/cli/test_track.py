"""``fruitnerfpp track``: counts.json from a dataset, scored by ``fruitnerfpp eval``; one-line errors, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.cli.main import main
from test.core.tracking.scenes import render, row_pose, write_scene


@pytest.fixture
def two_fruits(tmp_path: Path) -> Path:
    fruits = np.array([[-0.1, 0.0, 0.0], [0.12, 0.05, 0.08]])
    poses = [row_pose(x, -1.0) for x in np.linspace(-0.2, 0.2, 8)]
    dataset = write_scene(tmp_path / 'scene', poses, [render(T, fruits) for T in poses])
    gt = {'fruits': [{'id': i + 1, 'center': c.tolist(), 'radius': 0.0375} for i, c in enumerate(fruits)]}
    (dataset / 'gt_fruits.json').write_text(json.dumps(gt))
    return dataset


def test_track_then_eval(two_fruits: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / 'track.yaml'
    config.write_text('max_age: 4\n')
    out = tmp_path / 'out' / 'counts.json'
    assert main(['track', str(two_fruits), '--out', str(out), '--config', str(config), '--min-hits', '2']) == 0
    printed = capsys.readouterr().out
    assert printed.startswith('fruits: 2 (2 tracks over 8 frames') and 'hungarian' in printed  # GT found: scored
    data = json.loads(out.read_text())
    assert data['total'] == 2 and data['track_config']['max_age'] == 4 and data['track_config']['min_hits'] == 2
    assert main(['eval', str(out), '--gt', str(two_fruits / 'gt_fruits.json'), '--json']) == 0
    assert json.loads(capsys.readouterr().out)['f1'] == 1.0


@pytest.mark.parametrize('case, message', [
    ('no_dataset', 'transforms.json: not found'),
    ('bad_config', "unknown TrackConfig key(s): max_ages"),
    ('bad_value', 'TrackConfig: min_hits must be >= 1'),
])
def test_errors_are_one_line(case: str, message: str, two_fruits: Path, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    args = ['track', str(two_fruits), '--out', str(tmp_path / 'counts.json')]
    if case == 'no_dataset':
        args[1] = str(tmp_path / 'nowhere')
    elif case == 'bad_config':
        (tmp_path / 'bad.yaml').write_text('max_ages: 3\n')
        args += ['--config', str(tmp_path / 'bad.yaml')]
    else:
        args += ['--min-hits', '0']
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith('fruitnerfpp track: error: ') and err.count('\n') == 1 and message in err, err
    assert not (tmp_path / 'counts.json').exists()
