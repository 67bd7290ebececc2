"""The report renders the tables, means and worst F1 of a (fake) suite run; a failed scene keeps its row."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from fruitnerfpp_ros.core.benchmark.report import (LOG_TITLE, append_log_section, git_commit, render_log_section,
                                                   render_markdown)
from fruitnerfpp_ros.core.benchmark.result import CounterScore, SceneResult, SuiteResult


def _scene(name: str, f1: float, peer_f1: float, ours_s: float = 118.0, **values: object) -> SceneResult:
    return SceneResult(name, covers=f'axis of {name}', ours=CounterScore(10, 9, 0.9, f1, f1),
                       peer=CounterScore(12, 8, 0.7, peer_f1, peer_f1), gt_count=11, gt_seen=10, n_views=48,
                       psnr_db=21.5, semantic_iou=0.61, instance_acc=0.83, box_size_m=(2.0, 2.5, 3.0), voxel_mm=9.4,
                       diameter_m=0.075, gt_diameter_m=0.072,
                       times_s={'synth': 2.0, 'prepare': 3.5, 'geometry': 60.0, 'semantic': 30.0, 'instance': 20.0,
                                'evaluate': 0.75, 'checkpoint': 0.25, 'export': 5.0, 'count': 1.5, 'ours': ours_s,
                                'tracking': 0.4, 'total': 121.0},
                       peak_rss_mb=1500.0, picture=f'{name}/count.png', **values)  # type: ignore[arg-type]


@pytest.fixture
def suite() -> SuiteResult:
    failed = SceneResult('broken', covers='a bad scene', error="scene: SynthError: unknown fruit type 'banana'",
                         times_s={'total': 0.2})
    return SuiteResult('quick', (_scene('a', 0.90, 0.80), _scene('b', 0.60, 0.95, 119.5, via_bag=True), failed), 'cpu',
                       'gt', 'cpu', 2, '', '2026-12-01T12:00:00Z', 600.0,
                       'fruitnerfpp bench accuracy --suite quick --out out --jobs 2', 'abc1234')


def test_means_and_worst(suite: SuiteResult) -> None:
    assert suite.mean_f1('ours') == pytest.approx(0.75) and suite.worst('ours') == (0.60, 'b')
    assert suite.mean_f1('peer') == pytest.approx(0.875) and suite.worst('peer') == (0.80, 'a')
    assert [s.name for s in suite.failed] == ['broken']
    assert suite.scenes[0].f1_delta == pytest.approx(0.10) and math.isnan(suite.scenes[2].f1_delta)


def test_markdown_tables(suite: SuiteResult) -> None:
    text = render_markdown(suite)
    assert text.startswith('# Accuracy suite quick\n') and 'commit abc1234' in text
    rows: dict[str, str] = {}
    for line in text.splitlines():  # the accuracy table comes first
        if line.startswith('| '):
            rows.setdefault(line.split(' | ')[0][2:], line)
    assert rows['a'].startswith('| a | 10 / 11 | 0.900 | 0.900 | 0.900 | 12 | 0.800 | +0.100 | 21.50 | 0.610 | '
                                '0.830 | 2.00 x 2.50 x 3.00 | 9.4 | 75.0 (72.0) | [count.png](a/count.png) |')
    assert rows['b (bag)'].split(' | ')[7] == '-0.350'
    assert "failed: scene: SynthError: unknown fruit type 'banana'" in rows['broken']
    assert rows['broken'].count('–') >= 10  # no figures: dashes
    assert '- FruitNeRF++ (ours): mean F1 **0.750**, worst 0.600 (b) over 2 of 3 scenes' in text
    assert '- tracking peer: mean F1 **0.875**, worst 0.800 (a) over 2 of 3 scenes' in text
    assert '- failed scenes: 1: broken' in text and '- total time: 600 s (10.0 min), 2 scene(s) at once' in text
    assert '- slowest count, data to count: 120 s (b; 121 s with the scene generation and the peer)' in text
    time_row = next(line for line in text.splitlines() if line.startswith('| a | 2.0 |'))
    assert time_row == ('| a | 2.0 | – | – | 3.5 | 60.0 | 30.0 | 20.0 | 0.8 | 0.2 | 5.0 | 1.5 | 118.0 | 0.4 | 121.0 '
                        '| 1500 | – |')
    assert '| b | rosbag2 + replay | axis of b |' in text and '### Errors' in text


def test_log_section_links_no_output_file(suite: SuiteResult, tmp_path: Path) -> None:
    section = render_log_section(suite)
    assert section.startswith('## 2026-12-01 quick suite, commit abc1234\n')
    assert '`fruitnerfpp bench accuracy --suite quick --out out --jobs 2`' in section
    assert 'count.png' not in section and 'mean F1 **0.750**' in section
    log = tmp_path / 'log.md'
    append_log_section(log, suite)
    append_log_section(log, suite)
    text = log.read_text()
    assert text.startswith(LOG_TITLE + '\n\n## 2026-12-01') and text.count('## 2026-12-01 quick suite') == 2


def test_json_round_trip(suite: SuiteResult) -> None:
    data = json.loads(json.dumps(suite.to_json()))  # NaN written as null: strict JSON
    assert data['summary']['mean_f1'] == pytest.approx(0.75) and data['summary']['failed'] == ['broken']
    assert data['scenes'][2]['psnr_db'] is None
    back = SuiteResult.from_json(data)
    assert back.scenes[:2] == suite.scenes[:2] and back.scenes[2].error == suite.scenes[2].error
    assert math.isnan(back.scenes[2].psnr_db) and render_markdown(back) == render_markdown(suite)


def test_git_commit_of_this_repository_and_outside_one(tmp_path: Path) -> None:
    commit = git_commit()
    assert commit == '' or len(commit.split('+')[0]) >= 7
    assert git_commit(tmp_path) == ''


def test_an_unfinished_run_says_so_and_round_trips(suite: SuiteResult) -> None:
    from dataclasses import replace
    running = replace(suite, pending=('c', 'd'))
    text = render_markdown(running)
    assert '- **unfinished run**: 2 scene(s) still to come (c, d); 600 s so far, 2 scene(s) at once' in text
    assert '- total time' not in text and '- total time' in render_markdown(suite)
    back = SuiteResult.from_json(json.loads(json.dumps(running.to_json())))
    assert back.pending == ('c', 'd') and render_markdown(back) == text
