"""Spatial partitions of the fruit cloud: k-means cells, each widened by an overlap margin.

The partitions only bound the cost of the per-partition HDBSCAN. A fruit cut by a cell boundary is handled by
overlap: a partition clusters every point within ``overlap_m`` of its cell and keeps only the clusters whose
median falls inside its own cell, so the fruit is seen whole by the partition owning its centre.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from sklearn.cluster import MiniBatchKMeans
from threadpoolctl import threadpool_limits

__all__ = ['Partitions', 'make_partitions', 'assign_to_cells']


class Partitions(NamedTuple):
    """S spatial partitions of N points.

    Attributes:
        centers: [S, 3] k-means cell centres (m).
        owner: [N] int index of the cell each point lies in.
        members: S index arrays into the N points: the cell's points plus those within the overlap margin.
    """

    centers: np.ndarray
    owner: np.ndarray
    members: list[np.ndarray]


def assign_to_cells(xyz: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """[N] index of the nearest centre (the Voronoi cell) of each point of ``xyz`` [N, 3]."""
    d2 = ((xyz[:, None, :].astype(np.float64) - centers[None, :, :]) ** 2).sum(-1)
    return np.argmin(d2, axis=1)


def make_partitions(xyz: np.ndarray, n_partitions: int, *, overlap_m: float, seed: int = 0) -> Partitions:
    """Split ``xyz`` [N, 3] (m) into ``n_partitions`` k-means cells of similar size, widened by ``overlap_m``.

    A point owned by cell q joins partition p when its distance to the p/q bisector plane,
    ``(|x - c_p|^2 - |x - c_q|^2) / (2 |c_p - c_q|)``, is at most ``overlap_m``.
    """
    n = len(xyz)
    n_partitions = max(1, min(int(n_partitions), n))
    if n_partitions == 1:
        return Partitions(xyz.mean(0, keepdims=True).astype(np.float64) if n else np.zeros((1, 3)),
                          np.zeros(n, np.int64), [np.arange(n)])
    kmeans = MiniBatchKMeans(n_clusters=n_partitions, random_state=seed, n_init=1, batch_size=min(1024, n),
                             max_iter=20, compute_labels=False)
    with threadpool_limits(1):  # tiny problem: OpenMP threads only add spin-wait overhead on a busy machine
        kmeans.fit(xyz.astype(np.float64))
    centers = kmeans.cluster_centers_
    d2 = ((xyz[:, None, :].astype(np.float64) - centers[None, :, :]) ** 2).sum(-1)  # [N, S]
    owner = np.argmin(d2, axis=1)
    own_d2 = d2[np.arange(n), owner][:, None]
    center_gap = np.linalg.norm(centers[:, None, :] - centers[None, :, :], axis=-1)  # [S, S]
    denom = 2.0 * np.maximum(center_gap[owner], 1e-12)  # [N, S]
    near = (d2 - own_d2) / denom <= overlap_m
    near[np.arange(n), owner] = True
    members = [np.flatnonzero(near[:, p]) for p in range(n_partitions)]
    return Partitions(centers, owner, members)
