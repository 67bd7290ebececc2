"""Torch CPU threads: a count as given, or the cores shared among the jobs run at once (the ``cpu`` preset's 0)."""

from __future__ import annotations

import pytest
import torch

from fruitnerfpp_ros.core.device import cpu_thread_count, use_cpu_threads
from fruitnerfpp_ros.core.training import TrainConfig
from fruitnerfpp_ros.errors import ConfigError


@pytest.fixture
def four_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv('OMP_NUM_THREADS', raising=False)
    monkeypatch.setattr('os.sched_getaffinity', lambda pid: {0, 1, 2, 3}, raising=False)


def test_auto_shares_the_cores_among_the_jobs_run_at_once(four_cores: None) -> None:
    assert [cpu_thread_count(0, share) for share in (1, 2, 3, 4, 8)] == [4, 2, 1, 1, 1]
    assert cpu_thread_count(3, 4) == 3                   # a count given is kept whatever the jobs
    assert TrainConfig.preset('cpu').cpu_threads == 0    # a run alone uses the machine
    assert TrainConfig.preset('tiny').cpu_threads == 1   # the tests' preset stays on one thread


def test_auto_follows_omp_num_threads_set_by_a_parent(four_cores: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv('OMP_NUM_THREADS', '1')
    assert cpu_thread_count(0) == 1 and cpu_thread_count(2) == 2
    monkeypatch.setenv('OMP_NUM_THREADS', '3,1')         # OpenMP's nested form: the outer level
    assert cpu_thread_count(0, share=2) == 3
    monkeypatch.setenv('OMP_NUM_THREADS', 'many')        # not a count: the cores, shared
    assert cpu_thread_count(0, share=2) == 2


def test_bad_counts_are_config_errors() -> None:
    with pytest.raises(ConfigError):
        cpu_thread_count(-1)
    with pytest.raises(ConfigError):
        cpu_thread_count(0, share=0)


def test_the_count_is_set_and_returned(four_cores: None) -> None:
    before = torch.get_num_threads()
    try:
        assert use_cpu_threads(0, 'cpu', share=2) == 2 and torch.get_num_threads() == 2
        assert use_cpu_threads(1, 'cpu') == 1 and torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
