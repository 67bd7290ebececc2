"""``fruitnerfpp count`` and ``run`` own the clustering pool: one partition_pool of --jobs workers per command."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterator

import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud
from fruitnerfpp_ros.core.export.npz_io import write_npz
from test.counting_executor import CountingExecutor


@pytest.fixture
def pools(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, CountingExecutor]]:
    """partition_pool replaced by a recorder: (n_jobs, executor) per pool the command opened."""
    import fruitnerfpp_ros.core.clustering.workers as workers
    opened: list[tuple[int, CountingExecutor]] = []

    @contextmanager
    def recording_pool(n_jobs: int) -> Iterator[CountingExecutor]:
        opened.append((n_jobs, CountingExecutor()))
        yield opened[-1][1]
    monkeypatch.setattr(workers, 'partition_pool', recording_pool)
    return opened


def test_count_submits_its_partitions_to_the_pool_it_opens(tmp_path: Path, pools: list) -> None:
    cloud = write_npz(tmp_path / 'cloud.npz', make_fruit_cloud(3000, 8, seed=2).cloud)
    config = tmp_path / 'clustering.yaml'
    config.write_text('partitions: 2\nparallel_min_points: 1000\n')
    assert main(['count', str(cloud), '--config', str(config), '--jobs', '3']) == 0
    assert [(n_jobs, executor.submitted) for n_jobs, executor in pools] == [(3, 2)]
    assert (tmp_path / 'counts.json').is_file()


def test_run_hands_its_pool_to_the_pipeline(tmp_path: Path, pools: list, monkeypatch: pytest.MonkeyPatch) -> None:
    import fruitnerfpp_ros.core.pipeline as pipeline
    calls: list[dict[str, Any]] = []

    def stand_in(dataset_dir: Path, run_dir: Path, **kwargs: Any) -> Any:
        calls.append(kwargs)
        return SimpleNamespace(stopped=True)
    monkeypatch.setattr(pipeline, 'run_pipeline', stand_in)
    assert main(['run', str(tmp_path / 'data'), '--out', str(tmp_path / 'run'), '--jobs', '4']) == 1
    assert [n_jobs for n_jobs, _ in pools] == [4] and calls[0]['executor'] is pools[0][1]
