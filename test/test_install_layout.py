"""The `ros2 run` install layout, produced the way colcon installs an ament_python package."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PKG = 'fruitnerfpp_ros'


def test_setup_py_install_gives_the_ament_layout(tmp_path: Path) -> None:
    prefix = tmp_path / 'install'
    build = tmp_path / 'build'
    build.mkdir()
    env = dict(os.environ)
    proc = subprocess.run(
        [sys.executable, 'setup.py', 'egg_info', '--egg-base', str(build), 'build', '--build-base', str(build),
         'install', '--prefix', str(prefix), '--single-version-externally-managed', '--record',
         str(tmp_path / 'r.txt')],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (prefix / 'share/ament_index/resource_index/packages' / PKG).is_file()
    share = prefix / 'share' / PKG
    assert (share / 'package.xml').is_file()
    params = yaml.safe_load((share / 'config/fruit_counter.yaml').read_text())
    assert 'ros__parameters' in params['/**']
    assert (share / 'launch/fruit_counter.launch.py').is_file()
    assert (share / 'rviz/fruit_counter.rviz').is_file() and (share / 'foxglove/fruit_counter.json').is_file()
    for exe in ('fruit_counter', 'orchard_sim', 'bag_replay', 'fruitnerfpp'):
        path = prefix / 'lib' / PKG / exe
        assert path.is_file() and os.access(path, os.X_OK), f'{path} missing or not executable'
    assert "'console_scripts', 'fruit_counter'" in (prefix / 'lib' / PKG / 'fruit_counter').read_text()
    entry_points = (build / f'{PKG}.egg-info' / 'entry_points.txt').read_text()
    assert 'bag_replay = fruitnerfpp_ros.cli.replay:main' in entry_points  # the CLI calls the replay, not reverse
    assert not (prefix / 'bin' / 'fruit_counter').exists()


def test_launch_file_parses_and_names_the_node() -> None:
    source = (ROOT / 'launch/fruit_counter.launch.py').read_text()
    tree = ast.parse(source)
    functions = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    assert {'fruitnerfpp_ros', 'fruit_counter', 'fruit_counter.yaml', 'orchard_sim', 'rviz', 'rviz2',
            'fruit_counter.rviz'} <= strings


def test_params_file_matches_declared_parameters() -> None:
    from fruitnerfpp_ros.nodes.params import PARAMETERS, load_parameter_file, settings_from_parameters
    values = load_parameter_file(ROOT / 'config/fruit_counter.yaml')
    assert list(values) == [p.name for p in PARAMETERS]
    assert values == {p.name: p.default for p in PARAMETERS}
    settings_from_parameters(values)
