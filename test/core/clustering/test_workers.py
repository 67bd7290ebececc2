"""The caller-owned partition pool and how count_fruits uses (or falls back from) an executor."""

from __future__ import annotations

from concurrent.futures import Executor, Future, ThreadPoolExecutor
from typing import Any, Callable

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud
from fruitnerfpp_ros.core.clustering.workers import partition_pool
from fruitnerfpp_ros.errors import ConfigError
from test.counting_executor import CountingExecutor


class _BrokenExecutor(Executor):
    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        raise RuntimeError('cannot schedule new futures after shutdown')


def test_one_job_means_no_pool_and_zero_jobs_is_refused() -> None:
    with partition_pool(1) as pool:
        assert pool is None
    with pytest.raises(ConfigError, match='n_jobs must be >= 1'):
        with partition_pool(0):
            pass


def test_a_pool_is_shut_down_when_the_block_ends() -> None:
    with partition_pool(2) as pool:
        assert pool is not None
    with pytest.raises(RuntimeError, match='shutdown'):
        pool.submit(int, 1)


def test_any_executor_gives_the_in_process_labels() -> None:
    synth = make_fruit_cloud(4000, 16, seed=11)
    config = ClusterConfig(partitions=3, parallel_min_points=1000)
    in_process = count_fruits(synth.cloud, config)
    with ThreadPoolExecutor(2) as threads:
        threaded = count_fruits(synth.cloud, config, executor=threads)
    assert threaded.stats['partitions_in_executor'] == 3
    assert np.array_equal(threaded.labels, in_process.labels) and threaded.count == in_process.count == 16


def test_the_executor_is_left_out_below_parallel_min_points_or_for_one_partition() -> None:
    synth = make_fruit_cloud(3000, 8, seed=12)
    executor = CountingExecutor()
    small = count_fruits(synth.cloud, ClusterConfig(partitions=2, parallel_min_points=10_000), executor=executor)
    single = count_fruits(synth.cloud, ClusterConfig(partitions=1, parallel_min_points=1000), executor=executor)
    assert executor.submitted == 0
    assert small.stats['partitions_in_executor'] == single.stats['partitions_in_executor'] == 0
    used = count_fruits(synth.cloud, ClusterConfig(partitions=2, parallel_min_points=1000), executor=executor)
    assert executor.submitted == 2 and used.stats['partitions_in_executor'] == 2


def test_a_failing_executor_falls_back_to_this_process_with_a_note() -> None:
    synth = make_fruit_cloud(3000, 8, seed=13)
    config = ClusterConfig(partitions=2, parallel_min_points=1000)
    fallback = count_fruits(synth.cloud, config, executor=_BrokenExecutor())
    assert fallback.stats['partitions_in_executor'] == 0
    assert fallback.stats['parallel_error'].startswith('RuntimeError: cannot schedule')
    assert np.array_equal(fallback.labels, count_fruits(synth.cloud, config).labels)
