"""Count fruits in an exported fruit point cloud: subsample -> partitions -> HDBSCAN -> merge -> assign -> fruits.

Cluster ids start at 1 and are ordered by fruit centre (x, then y, then z); 0 means noise / unassigned. The same
ids appear in the labels, ``counts.json`` and the ROS outputs.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import Executor, Future
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit, fruit_diameter, label_groups
from fruitnerfpp_ros.core.clustering.graph import nearest_labels
from fruitnerfpp_ros.core.clustering.hdbscan_cluster import cluster_job, cluster_partition
from fruitnerfpp_ros.core.clustering.merge import (keep_owned_clusters, merge_agreeing_neighbours, merge_close_centers,
                                                   merge_clusters, merge_opposite_caps)
from fruitnerfpp_ros.core.clustering.partitions import make_partitions
from fruitnerfpp_ros.core.clustering.split import split_oversized
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent, ignore_progress
from fruitnerfpp_ros.errors import ClusteringError

__all__ = ['count_fruits', 'points_per_fruit', 'fruits_from_labels', 'centre_positions']


def _validate(cloud: FruitPointCloud) -> None:
    if not isinstance(cloud, FruitPointCloud):
        raise ClusteringError(f'count_fruits expects a FruitPointCloud, got {type(cloud).__name__}')
    if len(cloud) and (not np.all(np.isfinite(cloud.xyz)) or not np.all(np.isfinite(cloud.embedding))):
        raise ClusteringError('fruit point cloud holds NaN or infinite positions or embeddings')
    if len(cloud) and cloud.embedding_dim == 0:
        raise ClusteringError('fruit point cloud has no embedding columns (D = 0)')


def fruits_from_labels(xyz: np.ndarray, labels: np.ndarray,
                       centre_xyz: np.ndarray | None = None) -> tuple[np.ndarray, list[Fruit]]:
    """Fruit records from cluster labels, renumbered 1..K by centre (x, y, z).

    Args:
        xyz: [N, 3] positions (m).
        labels: [N] cluster labels, < 0 or 0-based; -1 = noise.
        centre_xyz: [N, 3] the positions the centres are the medians of (the points moved towards their fruit's
            centre, :func:`centre_positions`); None: ``xyz``. Diameters and extents are always ``xyz``'s: twice
            the median distance of the points from a centre so found (on 30 trained clouds of the suites and the
            5-tree row: 0.92 of the true diameter, 10-90 % 0.77-1.14), twice the 90th percentile from their own
            median without it (1.25, 1.00-1.97: a cap's median lies inside the cap).

    Returns:
        ([N] int32 labels with ids 1..K and 0 = noise, the K fruits in id order).
    """
    out = np.zeros(len(xyz), np.int32)
    _, groups = label_groups(labels)
    if not groups:
        return out, []
    percentile = 90.0 if centre_xyz is None else 50.0
    centre_xyz = xyz if centre_xyz is None else centre_xyz
    centers = np.array([np.median(centre_xyz[g], axis=0) for g in groups], np.float64)
    rank = np.lexsort((centers[:, 2], centers[:, 1], centers[:, 0]))
    fruits = []
    for new_id, g_index in enumerate(rank, start=1):
        g = groups[g_index]
        p = xyz[g].astype(np.float64)
        center = centers[g_index]
        lo, hi = np.percentile(p, [2.0, 98.0], axis=0)
        out[g] = new_id
        fruits.append(Fruit(id=new_id, center=center, diameter_m=fruit_diameter(p, center, percentile),
                            extent_m=hi - lo, n_points=len(g)))
    return out, fruits


def _cluster_partitions(jobs: list[tuple[np.ndarray, np.ndarray]], config: ClusterConfig, min_cluster_size: int,
                        executor: Executor | None, progress: ProgressCallback,
                        stats: dict[str, Any]) -> tuple[list[tuple[np.ndarray, float]], bool]:
    """HDBSCAN on every partition: submitted to ``executor`` when given, else in this process.

    An executor that fails (a broken pool, a refused submit) is noted in ``stats['parallel_error']`` and the
    partitions run in this process instead; the executor is the caller's and is left as it is.

    Returns:
        (per partition: labels and exact-row share, whether the executor ran them).
    """
    def report(i: int) -> None:
        progress(ProgressEvent(Phase.CLUSTER, i + 1, len(jobs), f'partition {i + 1}/{len(jobs)}'))

    if executor is not None:
        futures: list[Future[tuple[np.ndarray, float]]] = []
        try:
            futures.extend(executor.submit(cluster_job, p, e, config, min_cluster_size) for p, e in jobs)
            results = []
            for i, future in enumerate(futures):
                results.append(future.result())
                report(i)
            return results, True
        except (BrokenProcessPool, RuntimeError, OSError) as err:
            for future in futures:
                future.cancel()
            stats['parallel_error'] = f'{type(err).__name__}: {err}'.splitlines()[0]
    results = []
    for i, (p, e) in enumerate(jobs):
        results.append(cluster_partition(p, e, config, min_cluster_size=min_cluster_size, workers=config.n_jobs))
        report(i)
    return results, False


def _centre_shift_m(cloud: FruitPointCloud, config: ClusterConfig) -> float:
    """How far (m) :func:`centre_positions` moves the points: 0 when the cloud has no viewing directions, the shift
    is off or no fruit diameter is known (neither the cloud's nor ``reference_fruit_diameter_m``)."""
    diameter = cloud.fruit_diameter_m or config.reference_fruit_diameter_m
    if cloud.view_dir is None or not diameter:
        return 0.0
    return config.centre_shift_diameters * diameter


def centre_positions(cloud: FruitPointCloud, config: ClusterConfig) -> np.ndarray:
    """[N, 3] float32: the cloud's points moved ``config.centre_shift_diameters`` fruit diameters along their mean
    viewing direction (towards the centre of the fruit they are the surface of); the points as they are when the
    cloud has no viewing directions or the shift is 0."""
    xyz = np.ascontiguousarray(cloud.xyz, np.float32)
    shift = _centre_shift_m(cloud, config)
    if not shift:
        return xyz
    return np.ascontiguousarray(xyz + np.float32(shift) * np.asarray(cloud.view_dir, np.float32))


def points_per_fruit(xyz: np.ndarray, fruit_diameter_m: float, *, sample: int = 4000, seed: int = 0) -> float:
    """The points a fruit shows in a cloud: the median number of points within half a fruit diameter of a point
    (of a random sample of ``sample`` points)."""
    from scipy.spatial import cKDTree
    xyz = np.asarray(xyz, np.float64)
    rng = np.random.default_rng(seed)
    probe = xyz if len(xyz) <= sample else xyz[rng.choice(len(xyz), sample, replace=False)]
    counts = cKDTree(xyz).query_ball_point(probe, 0.5 * fruit_diameter_m, return_length=True)
    return float(np.median(counts))


def count_fruits(cloud: FruitPointCloud, config: ClusterConfig | None = None, *, executor: Executor | None = None,
                 progress: ProgressCallback | None = None) -> CountResult:
    """Cluster a fruit point cloud into fruits with the paper's multi-modal metric.

    Args:
        cloud: the exported fruit points (xyz in m, unit embeddings).
        config: clustering settings (defaults when None); scaled to ``cloud.spacing_m`` (the export voxel) and
            ``cloud.fruit_diameter_m`` when known (:meth:`ClusterConfig.for_cloud`).
        executor: where partitions run when there are several and at least ``config.parallel_min_points`` points
            are clustered (e.g. :func:`~fruitnerfpp_ros.core.clustering.workers.partition_pool`); the caller owns
            and shuts it down. None: every partition runs in this process (KD-tree queries on ``config.n_jobs``
            threads). The labels are the same either way.
        progress: receives ``cluster`` phase events (one per partition).

    Returns:
        Labels (ids from 1, 0 = noise), one :class:`Fruit` per cluster, and stats (timings, partitions, subsample,
        exact-row share of the graph).

    Raises:
        ClusteringError: on a malformed cloud (NaN, no embedding).
    """
    started = time.perf_counter()
    _validate(cloud)
    base = config or ClusterConfig()
    fruit_points = None
    if cloud.fruit_diameter_m is not None and len(cloud) >= 2:
        fruit_points = points_per_fruit(cloud.xyz, cloud.fruit_diameter_m, seed=base.seed)
    config = base.for_cloud(cloud.spacing_m, cloud.fruit_diameter_m, fruit_points)
    progress = progress or ignore_progress
    n = len(cloud)
    stats: dict[str, Any] = {'n_points': n, 'metric': config.metric, 'lambda_c': config.lambda_c,
                             'lambda_e': config.lambda_e, 'point_spacing_m': cloud.spacing_m,
                             'fruit_diameter_m': cloud.fruit_diameter_m, 'overlap_m': config.overlap_m,
                             'points_per_fruit': fruit_points, 'min_cluster_size': config.min_cluster_size,
                             'min_samples': config.min_samples, 'min_fruit_points': config.min_fruit_points}
    if n == 0:
        stats.update(note='empty fruit point cloud: nothing to count', time_total_s=time.perf_counter() - started)
        return CountResult(np.zeros(0, np.int32), [], stats)
    t0 = time.perf_counter()
    xyz = centre_positions(cloud, base)
    moved = _centre_shift_m(cloud, base) > 0
    if config.centre_shift_diameters > 0 and cloud.view_dir is None:
        stats['centre_shift_note'] = ('the cloud has no viewing directions (a grid export, or exported before they '
                                      'were kept): points not moved to their fruits\' centres')
    stats['mean_centre_shift_m'] = float(np.linalg.norm(xyz - cloud.xyz, axis=1).mean()) if moved else 0.0
    emb = np.asarray(cloud.embedding, np.float32)
    emb = emb / np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12)

    rng = np.random.default_rng(config.seed)
    if config.subsample_size and n > config.subsample_size:
        sub = np.sort(rng.choice(n, config.subsample_size, replace=False))
    else:
        sub = np.arange(n)
    n_sub = len(sub)
    min_cluster_size = max(config.min_samples, 2, int(round(config.min_cluster_size * n_sub / n)))
    n_partitions = config.partitions or math.ceil(n_sub / config.points_per_partition)
    xyz_sub, emb_sub = xyz[sub], emb[sub]
    parts = make_partitions(xyz_sub, n_partitions, overlap_m=config.overlap_m, seed=config.seed)
    t_part = time.perf_counter()

    jobs = [(xyz_sub[m], emb_sub[m]) for m in parts.members]
    use_executor = executor is not None and len(jobs) > 1 and n_sub >= config.parallel_min_points
    results, parallel = _cluster_partitions(jobs, config, min_cluster_size, executor if use_executor else None,
                                            progress, stats)
    t_hdb = time.perf_counter()

    clusters = []
    for p, (members, (local, _)) in enumerate(zip(parts.members, results)):
        clusters.extend(keep_owned_clusters(xyz_sub, members, local, p, parts.centers))
    sub_labels = merge_clusters(n_sub, clusters)

    if n_sub < n:
        labels = np.full(n, -1, np.int64)
        labels[sub] = sub_labels
        rest = np.setdiff1d(np.arange(n), sub, assume_unique=True)
        labels[rest] = nearest_labels(xyz[rest], emb[rest], xyz_sub, emb_sub, sub_labels, k=config.assign_k,
                                      lambda_c=config.lambda_c, lambda_e=config.lambda_e, metric=config.metric,
                                      workers=config.n_jobs)
    else:
        labels = sub_labels
    t_assign = time.perf_counter()

    clusters_before_merge = int(labels.max()) + 1 if len(labels) else 0
    labels = merge_close_centers(xyz, labels, config.merge_centers_m)
    clusters_before_filter = int(labels.max()) + 1 if len(labels) else 0
    if np.any(labels >= 0):
        sizes = np.bincount(labels[labels >= 0])
        labels = np.where((labels >= 0) & (sizes[np.maximum(labels, 0)] >= config.min_fruit_points), labels, -1)
    labels, n_split = split_oversized(xyz, emb, labels, config)
    clusters_before_agreeing = int(labels.max()) + 1 if len(labels) else 0
    labels = merge_agreeing_neighbours(xyz, emb, labels, config.merge_agreeing_m, config.merge_agreeing_cos)
    clusters_before_opposite = int(labels.max()) + 1 if len(labels) else 0
    if moved:
        labels = merge_opposite_caps(xyz, cloud.view_dir, labels, config.merge_opposite_m,
                                     config.opposite_facing_cos)
    final_labels, fruits = fruits_from_labels(np.asarray(cloud.xyz, np.float32), labels,
                                              centre_xyz=xyz if moved else None)
    t_end = time.perf_counter()
    exact = [r[1] for r in results]
    stats.update({
        'n_clustered': n_sub, 'partitions': len(parts.members), 'min_cluster_size_used': min_cluster_size,
        'partitions_in_executor': len(jobs) if parallel else 0,
        'clusters_before_merge': clusters_before_merge,
        'clusters_before_size_filter': clusters_before_filter, 'clusters_split': n_split,
        'clusters_joined_agreeing': clusters_before_agreeing - clusters_before_opposite,
        'clusters_joined_opposite': clusters_before_opposite - (int(labels.max()) + 1 if len(labels) else 0),
        'noise_points': int(np.count_nonzero(final_labels == 0)),
        'graph_exact_fraction': float(np.mean(exact)) if exact else 1.0,
        'time_partition_s': t_part - t0, 'time_hdbscan_s': t_hdb - t_part, 'time_assign_s': t_assign - t_hdb,
        'time_fruits_s': t_end - t_assign, 'time_total_s': t_end - started,
    })
    return CountResult(final_labels, fruits, stats)
