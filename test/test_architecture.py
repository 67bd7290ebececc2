"""Architecture rules that keep the core reusable without ROS: checked on the source, not by convention."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'fruitnerfpp_ros'
ROS_MODULES = ('rclpy', 'std_msgs', 'sensor_msgs', 'geometry_msgs', 'nav_msgs', 'visualization_msgs',
               'diagnostic_msgs', 'std_srvs', 'tf2_msgs', 'builtin_interfaces', 'launch', 'launch_ros')


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


CORE_FILES = sorted((PACKAGE / 'core').rglob('*.py'))


@pytest.mark.parametrize('path', CORE_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_imports_no_ros(path: Path) -> None:
    ros = {m for m in _imported_modules(path) if m.split('.')[0] in ROS_MODULES}
    assert not ros, f'{path} imports ROS modules {sorted(ros)}; the core must stay ROS-free'


@pytest.mark.parametrize('path', CORE_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_does_not_import_nodes_or_cli(path: Path) -> None:
    upward = {m for m in _imported_modules(path)
              if m.startswith(('fruitnerfpp_ros.nodes', 'fruitnerfpp_ros.cli'))}
    assert not upward, f'{path} imports {sorted(upward)}: data flows one way (core <- cli/nodes)'


def test_core_has_files() -> None:
    assert len(CORE_FILES) >= 10
