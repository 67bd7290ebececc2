"""The ``bag_replay`` executable is ``fruitnerfpp replay`` (fruitnerfpp_ros.cli.replay.main), ROS arguments dropped."""

from __future__ import annotations

from pathlib import Path

import pytest

from fruitnerfpp_ros.cli.replay import main
from test.nodes import bag_factory as bf


def test_bag_replay_executable_collects_and_ignores_ros_arguments(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    bag = bf.write_bag(tmp_path / 'bag', bf.messages(4), 'sqlite3')
    params = tmp_path / 'p.yaml'
    params.write_text('/**:\n  ros__parameters:\n    min_translation_m: 0.1\n')
    args = [str(bag), '--out', str(tmp_path / 'run'), '--params', str(params), '--no-train']
    assert main([*args, '--ros-args', '-r', '__node:=bag_replay']) == 0
    assert 'keyframes: 4' in capsys.readouterr().out


def test_bag_replay_executable_reports_errors_in_one_line(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / 'missing'), '--out', str(tmp_path / 'run'), '--ros-args']) == 2
    err = capsys.readouterr().err
    assert err.startswith('fruitnerfpp replay: error: ') and 'no such bag' in err and err.count('\n') == 1
