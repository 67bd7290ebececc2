"""A process pool for the clustering partitions, owned by the caller (CLI command, node, bench) in a ``with`` block.

The core keeps no pool of its own: :func:`~fruitnerfpp_ros.core.clustering.counter.count_fruits` submits its
partitions to the executor it is given and runs them in-process without one.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Iterator

from fruitnerfpp_ros.core.clustering.hdbscan_cluster import worker_init
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['partition_pool']


@contextmanager
def partition_pool(n_jobs: int) -> Iterator[ProcessPoolExecutor | None]:
    """A spawn-context process pool of ``n_jobs`` partition workers, shut down when the block ends.

    Workers start on the first submitted partition (not here), each with one numba thread and a warm
    fast_hdbscan JIT (:func:`~fruitnerfpp_ros.core.clustering.hdbscan_cluster.worker_init`). Spawned workers
    import the main module again, so a ``python script.py`` using this needs an ``if __name__ == '__main__'``
    guard; the package's console scripts have one.

    Args:
        n_jobs: worker processes (``ClusterConfig.n_jobs``); 1 yields None (partitions run in-process).

    Yields:
        The pool, or None when ``n_jobs`` is 1.

    Raises:
        ConfigError: ``n_jobs`` < 1.
    """
    if n_jobs < 1:
        raise ConfigError(f'partition_pool: n_jobs must be >= 1, got {n_jobs}')
    if n_jobs == 1:
        yield None
        return
    pool = ProcessPoolExecutor(max_workers=n_jobs, mp_context=multiprocessing.get_context('spawn'),
                               initializer=worker_init)
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
