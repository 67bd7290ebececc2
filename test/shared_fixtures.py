"""Expensive fixtures shared by the whole test session: one tiny synthetic scene, one tiny trained run.

Each is built once per session (``scope='session'``) so the suite stays within its time budget on a 2-core CPU.
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope='session')
def tiny_apple_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 24-view 96 px synthetic apple tree (hemisphere views) with ground truth, as transforms.json."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    out = tmp_path_factory.mktemp('tiny_apple')
    generate_orchard(SynthConfig(fruit='apple', count=20, views=24, resolution=(96, 96),
                                 trajectory='hemisphere', seed=0), out)
    return out


@pytest.fixture(scope='session')
def tiny_trained_run(tiny_apple_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny apple scene trained through all three stages with the ``tiny`` preset on the CPU."""
    from fruitnerfpp_ros.core.training import TrainConfig, train

    run_dir = tmp_path_factory.mktemp('tiny_run')
    train(tiny_apple_dataset, run_dir, TrainConfig.preset('tiny'), device='cpu')
    return run_dir
