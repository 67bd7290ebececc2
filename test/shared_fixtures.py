"""Expensive fixtures shared by the whole test session: one tiny synthetic scene, one tiny trained run.

Each is built once per session (``scope='session'``) so the suite stays within its time budget on a 2-core CPU.
The tiny run trains on one core for 2-3 minutes: when the collected tests use it, a child process generates the
scene and trains it from the start of the session (:class:`BackgroundTinyRun`), on the core the tests leave free,
and the fixtures wait for it. Run this module (``python -m test.shared_fixtures ROOT``) to build both into ROOT.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

#: The tiny test scene: 20 apples, 48 hemisphere views of 96 px. With 24 views the briefly trained field stays
#: foggy (held-out PSNR ~17 dB, semantic IoU ~0.28, count F1 0.34); 48 views of the same size give ~21 dB, ~0.40
#: and F1 ~0.89 with the same training steps (docs/results/tiny_preset.md).
TINY_SCENE = dict(fruit='apple', count=20, views=48, resolution=(96, 96), trajectory='hemisphere', seed=0)

_REPO = Path(__file__).resolve().parents[1]
_BACKGROUND = pytest.StashKey['BackgroundTinyRun']()
#: Longest wait for the child's tiny run (it takes 2-3 minutes on one idle core).
_RUN_TIMEOUT_S = 1800.0


def build_tiny_dataset(out: Path) -> Path:
    """Generate the :data:`TINY_SCENE` into ``out`` (transforms.json, images, masks, ground truth)."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    generate_orchard(SynthConfig(**TINY_SCENE), out)
    return out


def train_tiny_run(dataset_dir: Path, run_dir: Path) -> Path:
    """Train ``dataset_dir`` through all three stages with the ``tiny`` preset on the CPU into ``run_dir``."""
    from fruitnerfpp_ros.core.training import TrainConfig, train

    train(dataset_dir, run_dir, TrainConfig.preset('tiny'), device='cpu')
    return run_dir


class BackgroundTinyRun:
    """The tiny scene generated and trained by a child process while the session's other tests run.

    The child writes ``ROOT/tiny_apple`` (then ``ROOT/dataset.done``) and ``ROOT/tiny_run``; its output goes to
    ``ROOT/child.log``, whose tail a failure reports.
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        self.dataset_dir, self.run_dir = root / 'tiny_apple', root / 'tiny_run'
        self._log = root / 'child.log'
        with self._log.open('wb') as log:
            self.proc = subprocess.Popen([sys.executable, '-m', 'test.shared_fixtures', str(root)], cwd=_REPO,
                                         stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def dataset(self) -> Path:
        """The generated scene, once the child has written it."""
        while not (self.root / 'dataset.done').is_file():
            if self.proc.poll() is not None:
                self._fail('generating the tiny scene')
            time.sleep(0.2)
        return self.dataset_dir

    def run(self) -> Path:
        """The trained run, once the child has finished."""
        try:
            self.proc.wait(timeout=_RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self._fail(f'training the tiny run (still running after {_RUN_TIMEOUT_S:.0f} s)')
        if self.proc.returncode != 0:
            self._fail(f'training the tiny run (exit status {self.proc.returncode})')
        return self.run_dir

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        shutil.rmtree(self.root, ignore_errors=True)

    def _fail(self, what: str) -> None:
        tail = self._log.read_bytes()[-4000:].decode(errors='replace')
        pytest.fail(f'the background child failed {what}; the end of {self._log}:\n{tail}', pytrace=False)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Start the tiny run in a child process when a collected test uses it (not for --collect-only)."""
    if session.config.option.collectonly or not any(
            'tiny_trained_run' in getattr(item, 'fixturenames', ()) for item in session.items):
        return
    session.config.stash[_BACKGROUND] = BackgroundTinyRun(Path(tempfile.mkdtemp(prefix='fruitnerfpp-tiny-')))


def pytest_sessionfinish(session: pytest.Session) -> None:
    background = session.config.stash.get(_BACKGROUND, None)
    if background is not None:
        background.close()


@pytest.fixture(scope='session')
def tiny_apple_dataset(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The :data:`TINY_SCENE` synthetic apple tree with ground truth, as transforms.json."""
    background = request.config.stash.get(_BACKGROUND, None)
    if background is not None:
        return background.dataset()
    return build_tiny_dataset(tmp_path_factory.mktemp('tiny_apple'))


@pytest.fixture(scope='session')
def tiny_trained_run(tiny_apple_dataset: Path, request: pytest.FixtureRequest,
                     tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny apple scene trained through all three stages with the ``tiny`` preset on the CPU."""
    background = request.config.stash.get(_BACKGROUND, None)
    if background is not None:
        return background.run()
    return train_tiny_run(tiny_apple_dataset, tmp_path_factory.mktemp('tiny_run'))


def _main(root: Path) -> None:
    """The child of :class:`BackgroundTinyRun`: one core, below the tests' priority."""
    import torch

    os.nice(5)
    torch.set_num_threads(1)
    build_tiny_dataset(root / 'tiny_apple')
    (root / 'dataset.done').touch()
    train_tiny_run(root / 'tiny_apple', root / 'tiny_run')


if __name__ == '__main__':
    _main(Path(sys.argv[1]))
