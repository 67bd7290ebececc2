"""Run a fruitnerfpp program that stops at a chosen point, so a test can ``kill -9`` it exactly there.

``python -m test.fault_injection POINT MODULE [ARGS...]`` runs ``MODULE`` as ``__main__`` (e.g.
``fruitnerfpp_ros.cli.main run ...`` or ``fruitnerfpp_ros.nodes.fruit_counter --ros-args ...``) after patching
the package in this process only (nothing in the package knows about it). When the program reaches ``POINT`` it
prints ``KILLPOINT <POINT>`` on stdout and sleeps: the test reads that line and sends SIGKILL. Points:

- ``collection:N``: right after the N-th keyframe is stored.
- ``train:<stage>:<step>``: after step ``step`` of training stage ``stage`` (geometry, semantic, instance).
- ``export``: at the start of the export (training finished and checkpointed).
- ``none``: no stop (the program runs to its end).
"""

from __future__ import annotations

import runpy
import sys
import time
from typing import Any

KILLPOINT = 'KILLPOINT'


def _stop_here(point: str) -> None:
    print(f'{KILLPOINT} {point}', flush=True)
    time.sleep(600)


def install(point: str) -> None:
    """Patch the package so that it stops at ``point``."""
    kind, _, rest = point.partition(':')
    if kind == 'collection':
        from fruitnerfpp_ros.core.data import keyframe_store
        original_write = keyframe_store.KeyframeStore._write
        target = int(rest)

        def write(self: Any, keyframe: Any) -> None:
            original_write(self, keyframe)
            if len(self._frames) == target:
                _stop_here(point)
        keyframe_store.KeyframeStore._write = write
    elif kind == 'train':
        import fruitnerfpp_ros.core.training as training
        stage, step = rest.split(':')
        original_train = training.train

        def train(*args: Any, progress: Any = None, **kwargs: Any) -> Any:
            def stopping(event: Any) -> None:
                if progress is not None:
                    progress(event)
                if str(event.phase) == f'train:{stage}' and event.step == int(step):
                    _stop_here(point)
            return original_train(*args, progress=stopping, **kwargs)
        training.train = train
    elif kind == 'export':
        from fruitnerfpp_ros.core import pipeline
        original_export = pipeline.export_run

        def export_run(*args: Any, **kwargs: Any) -> Any:
            _stop_here(point)
            return original_export(*args, **kwargs)
        pipeline.export_run = export_run
    elif kind != 'none':
        raise SystemExit(f'unknown kill point {point!r}')


if __name__ == '__main__':
    install(sys.argv[1])
    module = sys.argv[2]
    sys.argv = [module, *sys.argv[3:]]
    runpy.run_module(module, run_name='__main__', alter_sys=True)
