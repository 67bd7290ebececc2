"""bench/row_suite.py: its rows are valid `fruitnerfpp synth` rows that differ from each other, its table counts the
trees within 10 % as issue 12 states it, and a reuse copies the segments' results and nothing else."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fruitnerfpp_ros.cli.main import build_parser
from fruitnerfpp_ros.cli.synth import _config_from_args, _row_config
from test.bench_scripts import load_bench_script

suite = load_bench_script('row_suite')


def _parsed(row: object) -> tuple:
    args = build_parser().parse_args(['synth', *suite.COMMON, *row.synth, '--out', 'unused'])
    return args, _config_from_args(args), _row_config(args)


@pytest.mark.parametrize('row', suite.ROWS, ids=[r.name for r in suite.ROWS])
def test_every_row_is_a_synth_row_with_gnss(row: object) -> None:
    args, config, row_config = _parsed(row)
    assert args.scene == 'row' and row_config.gnss and row_config.trees == 5
    assert config.sparse_points == 0                                       # a robot has no SfM cloud


def test_the_rows_vary_fruit_load_drive_and_drift() -> None:
    configs = [_parsed(row)[1] for row in suite.ROWS]
    assert len({row.name for row in suite.ROWS}) == len(suite.ROWS)
    assert len({(c.fruit, c.seed) for c in configs}) == len(configs)         # no row twice
    assert {c.fruit for c in configs} >= {'apple', 'plum', 'peach', 'lemon', 'mixed'}
    assert len({c.count for c in configs}) >= 3
    assert len({(c.row_standoff_m, c.camera_height_m, c.camera_pitch_deg) for c in configs}) >= 3
    assert any(c.pass_offset_m != 0 for c in configs) and any(c.pass_offset_m == 0 for c in configs)


def _evaluation(errors: list[float], f1: float, across: int) -> dict:
    return {'row': {'count': 100, 'gt_count': 98, 'precision': 0.9, 'recall': 0.92, 'f1': f1},
            'double_counts': {'total': across + 1, 'across_cuts': across}, 'trees_true': len(errors),
            'trees': [{'tree': i + 1, 'error_pct': e} for i, e in enumerate(errors)],
            'geo': {'max_error_m': 0.05}}


def test_the_table_counts_trees_within_ten_percent_and_reports_a_failed_row() -> None:
    records = [{'row': 'a', 'wall_s': 300.0, 'peak_rss_mib': 900.0,
                'evaluation': _evaluation([0, 10.0, -12.5], 0.9, 1)},
               {'row': 'b', 'wall_s': 200.0, 'peak_rss_mib': 800.0, 'evaluation': _evaluation([4.0, -5.0], 0.8, 0)},
               {'row': 'c', 'error': 'orchard exited 1'}]
    figures = suite.row_figures(records[0]['evaluation'])
    assert (figures['trees_within'], figures['trees'], figures['worst_tree_pct']) == (2, 3, 12.5)
    lines = suite.table(records, 'test')
    assert '| a | 100 / 98 | 0.900 | 0.920 | 0.900 | 2 (1) | 2 / 3 | +0 / +10 / -12 |' in lines[4]
    assert lines[6].startswith('| c | failed: orchard exited 1')
    summary = lines[-1]
    assert 'Rows: 2 of 3 counted' in summary and 'mean F1 **0.850**' in summary and 'worst 0.800' in summary
    assert 'trees within 10 % of their truth: **4 of 5**' in summary and 'worst tree 12 %' in summary
    assert 'doubles across cuts 1' in summary and 'rows with every tree within 10 %: 1.' in summary


def test_a_reuse_copies_the_plan_and_the_results_only(tmp_path: Path) -> None:
    old = tmp_path / 'old'
    for name in ('seg_000', 'seg_001'):
        (old / 'segments' / name / 'run').mkdir(parents=True)
        (old / 'segments' / name / 'result.json').write_text(json.dumps({'segment': name}))
        (old / 'segments' / name / 'run' / 'cloud.npz').write_bytes(b'x')
    (old / 'row.json').write_text('{}')
    (old / 'eval_row.json').write_text('{}')
    new = tmp_path / 'new'
    suite._copy_finished(old, new)
    copied = sorted(str(p.relative_to(new)) for p in new.rglob('*') if p.is_file())
    assert copied == ['row.json', 'segments/seg_000/result.json', 'segments/seg_001/result.json']


def test_a_row_the_reused_suite_lacks_is_reported_not_trained(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list = []
    monkeypatch.setattr(suite.subprocess, 'run', lambda *a, **k: calls.append(a))
    monkeypatch.setattr(suite.subprocess, 'call', lambda *a, **k: calls.append(a))
    (tmp_path / 'old' / 'other_row' / 'run').mkdir(parents=True)
    record = suite.run_row(suite.ROWS[0], tmp_path / 'new', 'tiny', 1, None, tmp_path / 'old')
    assert record['error'].startswith('nothing to reuse') and not calls      # no synth, no orchard run
    assert suite.table([record], 't')[4].startswith(f'| {suite.ROWS[0].name} | failed: nothing to reuse')
