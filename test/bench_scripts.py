"""The scripts of ``bench/`` (not a package) loaded as modules, for their tests."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

BENCH_DIR = Path(__file__).resolve().parents[1] / 'bench'


def load_bench_script(name: str) -> ModuleType:
    """``bench/<name>.py`` as a module (its ``main`` not run)."""
    spec = importlib.util.spec_from_file_location(f'bench_{name}', BENCH_DIR / f'{name}.py')
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
