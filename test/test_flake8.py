"""Style gate: flake8 over the package, tests, bench scripts and launch files (config in setup.cfg)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_flake8_finds_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    legacy = pytest.importorskip('flake8.api.legacy', reason='flake8 is a development dependency')
    cwd = os.getcwd()
    os.chdir(ROOT)  # setup.cfg is found from the working directory
    try:
        report = legacy.get_style_guide().check_files(['fruitnerfpp_ros', 'test', 'bench', 'launch', 'setup.py'])
    finally:
        os.chdir(cwd)
    assert report.total_errors == 0, capsys.readouterr().out
