"""Architecture rules that keep the core reusable without ROS: checked on the source, not by convention."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'fruitnerfpp_ros'
ROS_ROOTS = ('rclpy', 'rcl', 'rcutils', 'rmw', 'rosidl', 'rosbag2_py', 'tf2', 'launch', 'message_filters', 'ament')
ROS_SUFFIXES = ('_msgs', '_srvs', '_interfaces')


def is_ros_module(name: str) -> bool:
    """ROS client libraries, message/service packages and launch, by name (any *_msgs, tf2*, rcl*, ...)."""
    root = name.split('.')[0]
    return root.startswith(ROS_ROOTS) or root.endswith(ROS_SUFFIXES)


def _imported_modules(path: Path, source: str | None = None) -> set[str]:
    """Absolute names of every module ``path`` (or ``source`` as if it were there) imports: relative imports
    resolved; ``from a import b`` also yields ``a.b``, which may be a module."""
    tree = ast.parse(path.read_text() if source is None else source, filename=str(path))
    package = path.relative_to(PACKAGE.parent).with_suffix('').parts[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = '.'.join([*package[:len(package) - node.level + 1], *([node.module] if node.module else [])]) \
                if node.level else node.module or ''
            names.add(base)
            names.update(f'{base}.{alias.name}' for alias in node.names)
    return names


CORE_FILES = sorted((PACKAGE / 'core').rglob('*.py'))


@pytest.mark.parametrize('path', CORE_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_imports_no_ros(path: Path) -> None:
    ros = {m for m in _imported_modules(path) if is_ros_module(m)}
    assert not ros, f'{path} imports ROS modules {sorted(ros)}; the core must stay ROS-free'


@pytest.mark.parametrize('path', CORE_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_core_does_not_import_nodes_or_cli(path: Path) -> None:
    upward = {m for m in _imported_modules(path)
              if m.startswith(('fruitnerfpp_ros.nodes', 'fruitnerfpp_ros.cli'))}
    assert not upward, f'{path} imports {sorted(upward)}: data flows one way (core <- cli/nodes)'


NODE_FILES = sorted((PACKAGE / 'nodes').rglob('*.py'))


@pytest.mark.parametrize('path', CORE_FILES + NODE_FILES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_nothing_below_the_command_line_imports_it(path: Path) -> None:
    """The CLI calls nodes and core (``fruitnerfpp replay`` -> nodes/bag_replay.py), never the reverse; imports
    inside functions count too."""
    cli = {m for m in _imported_modules(path) if m == 'fruitnerfpp_ros.cli' or m.startswith('fruitnerfpp_ros.cli.')}
    assert not cli, f'{path} imports {sorted(cli)}: the command line sits on top of nodes and core'


def test_core_has_files() -> None:
    assert len(CORE_FILES) >= 10 and len(NODE_FILES) >= 5


def test_the_rules_catch_what_they_are_for() -> None:
    source = ('from rcl_interfaces.msg import ParameterDescriptor\nimport tf2_ros\n'
              'from ...nodes.conversions import image_to_rgb\nfrom fruitnerfpp_ros import cli\n')
    names = _imported_modules(PACKAGE / 'core' / 'data' / 'probe.py', source)
    assert {'rcl_interfaces.msg', 'tf2_ros'} <= {m for m in names if is_ros_module(m)}
    assert {'fruitnerfpp_ros.nodes.conversions', 'fruitnerfpp_ros.cli'} <= names
    lazy = 'def main():\n    from fruitnerfpp_ros.cli.main import main as cli_main\n    return cli_main()\n'
    assert 'fruitnerfpp_ros.cli.main' in _imported_modules(PACKAGE / 'nodes' / 'probe.py', lazy)
    assert not any(is_ros_module(m) for m in ('numpy', 'rosbags.highlevel', 'mcap', 'fruitnerfpp_ros.core'))


def test_importing_the_whole_core_loads_no_ros_and_no_nodes() -> None:
    code = ('import importlib, pkgutil, sys, fruitnerfpp_ros.core as core\n'
            'for m in pkgutil.walk_packages(core.__path__, "fruitnerfpp_ros.core."): importlib.import_module(m.name)\n'
            'print("\\n".join(sys.modules))')
    loaded = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True).stdout.split()
    bad = [m for m in loaded if is_ros_module(m) or m.startswith(('fruitnerfpp_ros.nodes', 'fruitnerfpp_ros.cli'))]
    assert not bad, f'importing fruitnerfpp_ros.core loads {bad}'
