"""``fruitnerfpp orchard`` on a bag: keyframes collected as the node collects them, GNSS fixes from the bag's
NavSatFix topic, the row counted by stand-in segment jobs (the ground-truth fruits a segment's keyframes show),
per-tree counts, GeoJSON and the evaluation against the synthetic row's truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from fruitnerfpp_ros.core.orchard.jobs import InProcessRunner
from test.core.orchard.conftest import TINY_ROW, fruits_shown_by_stamps

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def row(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from fruitnerfpp_ros.core.synthetic import SynthConfig
    from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, generate_row

    out = tmp_path_factory.mktemp('row_cli')
    generate_row(SynthConfig(**TINY_ROW), RowSceneConfig(trees=3, gnss=True), out / 'ds', bag=out / 'bag')
    return out


def test_orchard_counts_a_bag_per_tree(row: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    import fruitnerfpp_ros.cli.orchard as orchard
    from fruitnerfpp_ros.cli.main import main

    shown = fruits_shown_by_stamps(row / 'ds' / 'gt_fruits.json')
    monkeypatch.setattr(orchard, 'make_runner', lambda args, log=print: (InProcessRunner(job=shown), None))
    out = tmp_path / 'run'
    code = main(['orchard', str(row / 'bag'), '--out', str(out), '--params', str(ROOT / 'config/fruit_counter.yaml'),
                 '--params', str(ROOT / 'config/orchard_row.yaml'), '--trees', str(row / 'ds' / 'planting_map.csv'),
                 '--gt', str(row / 'ds'), '--preset', 'tiny'])
    printed = capsys.readouterr().out
    assert code == 0, printed
    collected = json.loads((out / 'keyframes' / 'transforms.json').read_text())['frames']
    assert len(collected) >= 30                                     # the bag's frames became keyframes
    evaluation = json.loads((out / 'eval_row.json').read_text())
    assert evaluation['row']['f1'] == 1.0 and evaluation['double_counts']['total'] == 0
    assert [t['count'] for t in evaluation['trees']] == [t['truth_nearest'] for t in evaluation['trees']]
    assert evaluation['geo']['max_error_m'] < 0.2                 # planting grid (4 cm jitter) + GNSS fit
    report: dict[str, Any] = json.loads((out / 'row_report.json').read_text())
    assert report['georef']['source'] == 'gnss' and report['georef']['n_fixes'] >= 10  # from the bag's NavSatFix
    assert report['preset'] == 'tiny' and report['keyframes'] == len(collected)
    assert 'tree   1:' in printed and 'georeferencing: gnss' in printed
    # a second run on the same folder reuses the collected keyframes
    assert main(['orchard', str(row / 'bag'), '--out', str(out), '--params', str(ROOT / 'config/orchard_row.yaml'),
                 '--gt', str(row / 'ds')]) == 0
    assert not list(out.glob('keyframes_previous_*'))


def test_orchard_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fruitnerfpp_ros.cli.main import main

    assert main(['orchard', str(tmp_path / 'nothing'), '--out', str(tmp_path / 'run'), '--no-ray']) == 2
    assert 'neither a transforms.json dataset nor a rosbag2' in capsys.readouterr().err
