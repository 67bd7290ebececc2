"""HDBSCAN (fast_hdbscan, sparse precomputed distances) on one partition of the fruit cloud.

fast_hdbscan compiles its numba kernels on first use (20-80 s) and caches them on disk; :func:`warm_up` triggers
that once per process so the first real count (or test) does not pay it.
"""

from __future__ import annotations

import os
import time

import numpy as np

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.graph import build_graph

__all__ = ['cluster_partition', 'warm_up', 'worker_init', 'cluster_job']

_WARM = False


def warm_up() -> float:
    """Compile (or load from the disk cache) fast_hdbscan's sparse-precomputed kernels; returns seconds spent.

    Cheap after the first call in a process.
    """
    global _WARM
    if _WARM:
        return 0.0
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    xyz = np.concatenate([rng.normal(0, 0.01, (60, 3)), rng.normal(0.2, 0.01, (60, 3))]).astype(np.float32)
    emb = rng.normal(size=(120, 8)).astype(np.float32)
    emb /= np.linalg.norm(emb, axis=1, keepdims=True)
    cluster_partition(xyz, emb, ClusterConfig(), min_cluster_size=10, workers=1)
    _WARM = True
    return time.perf_counter() - start


def cluster_partition(xyz: np.ndarray, embedding: np.ndarray, config: ClusterConfig, *, min_cluster_size: int,
                      workers: int = 1) -> tuple[np.ndarray, float]:
    """Cluster one partition's points with HDBSCAN on the sparse metric graph.

    Args:
        xyz: [N, 3] positions (m).
        embedding: [N, D] unit instance embeddings.
        config: metric and HDBSCAN settings.
        min_cluster_size: HDBSCAN minimum cluster size for this point set.
        workers: threads for the KD-tree query.

    Returns:
        ([N] int labels, -1 = noise, 0.. = cluster), share of graph rows that are exact under the metric.
    """
    from fast_hdbscan.hdbscan import fast_hdbscan

    n = len(xyz)
    min_samples = min(config.min_samples, config.knn_k)
    if n < max(min_cluster_size, min_samples + 1, 3):
        return np.full(n, -1, np.int64), 1.0
    graph = build_graph(xyz, embedding, knn_k=config.knn_k, candidate_factor=config.candidate_factor,
                        lambda_c=config.lambda_c, lambda_e=config.lambda_e, metric=config.metric, workers=workers)
    labels, _ = fast_hdbscan(graph.matrix, metric='precomputed', min_samples=int(min_samples),
                             min_cluster_size=int(min_cluster_size),
                             cluster_selection_method=config.cluster_selection_method,
                             cluster_selection_epsilon=float(config.cluster_selection_epsilon))
    return np.asarray(labels, np.int64), graph.exact_fraction


def worker_init() -> None:
    """Initialiser of a partition worker process: one numba thread (the workers are the parallelism), warm JIT.

    Lives here, not in ``counter``, so a spawned worker imports only numpy, scipy and fast_hdbscan.
    """
    os.environ.setdefault('OMP_NUM_THREADS', '1')
    try:
        import numba
        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    warm_up()


def cluster_job(xyz: np.ndarray, embedding: np.ndarray, config: ClusterConfig,
                min_cluster_size: int) -> tuple[np.ndarray, float]:
    """One partition, in a worker process (see :func:`cluster_partition`)."""
    return cluster_partition(xyz, embedding, config, min_cluster_size=min_cluster_size, workers=1)
