"""Sparse neighbour graph under the paper's multi-modal metric, without any dense N x N matrix.

``d_kl = lambda_c (1 - cos(i_k, i_l)) + lambda_e |x_k - x_l|``. Because ``1 - cos >= 0``, ``d >= lambda_e |dx|``:
every point closer than r in the metric lies within ``r / lambda_e`` in space, so a KD-tree on xyz yields the
candidates, the metric is evaluated on those pairs only, and each point keeps its ``knn_k`` smallest values.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from fruitnerfpp_ros.errors import ClusteringError

__all__ = ['NeighbourGraph', 'pair_metric', 'build_graph', 'nearest_labels']

_CHUNK = 32768


class NeighbourGraph(NamedTuple):
    """A kNN graph under the clustering metric.

    Attributes:
        matrix: [N, N] scipy CSR matrix of metric values (knn_k stored entries per row).
        exact_fraction: share of rows whose knn_k neighbours are provably the exact ones under the metric.
    """

    matrix: scipy.sparse.csr_matrix
    exact_fraction: float


def pair_metric(cos: np.ndarray, dist_m: np.ndarray, *, lambda_c: float, lambda_e: float,
                metric: str = 'summed') -> np.ndarray:
    """The clustering distance from cosine similarities and Euclidean distances (m) of the same shape.

    ``summed`` is the paper's ``lambda_c (1 - cos) + lambda_e |dx|``; ``concatenated`` the approximation
    ``sqrt(lambda_e^2 |dx|^2 + lambda_c (1 - cos))`` (distance of concatenated scaled features).

    Raises:
        ClusteringError: an unknown ``metric``.
    """
    cos_gap = np.clip(1.0 - cos, 0.0, 2.0)
    if metric == 'summed':
        return lambda_c * cos_gap + lambda_e * dist_m
    if metric == 'concatenated':
        return np.sqrt((lambda_e * dist_m) ** 2 + lambda_c * cos_gap)
    raise ClusteringError(f"unknown clustering metric {metric!r} (expected 'summed' or 'concatenated')")


def _row_cosines(emb_rows: np.ndarray, emb_all: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """[R, K] cosine between each row embedding [R, D] and its K neighbours ``emb_all[idx]``."""
    return np.einsum('rd,rkd->rk', emb_rows, emb_all[idx], optimize=False)


def build_graph(xyz: np.ndarray, embedding: np.ndarray, *, knn_k: int, candidate_factor: float, lambda_c: float,
                lambda_e: float, metric: str = 'summed', workers: int = 1) -> NeighbourGraph:
    """kNN graph of ``xyz`` [N, 3] (m) with unit ``embedding`` [N, D] under the clustering metric.

    Returns:
        The graph; each row holds its ``min(knn_k, N-1)`` smallest metric values among the
        ``candidate_factor * knn_k`` spatial nearest neighbours.
    """
    n = len(xyz)
    k = min(knn_k, n - 1)
    n_cand = min(n - 1, max(k, int(round(candidate_factor * knn_k))))
    if k < 1:
        return NeighbourGraph(scipy.sparse.csr_matrix((n, n), dtype=np.float64), 1.0)
    tree = cKDTree(xyz)
    dist, idx = tree.query(xyz, k=n_cand + 1, workers=workers)
    dist, idx = dist[:, 1:], idx[:, 1:]  # drop self (duplicates may swap order; harmless: distance 0)
    emb = np.ascontiguousarray(embedding, dtype=np.float32)
    values = np.empty((n, k), np.float64)
    cols = np.empty((n, k), np.int32)
    exact = 0
    for start in range(0, n, _CHUNK):
        stop = min(n, start + _CHUNK)
        cos = _row_cosines(emb[start:stop], emb, idx[start:stop])
        d = pair_metric(cos, dist[start:stop], lambda_c=lambda_c, lambda_e=lambda_e, metric=metric)
        if k < n_cand:
            keep = np.argpartition(d, k - 1, axis=1)[:, :k]
            d = np.take_along_axis(d, keep, axis=1)
            chunk_cols = np.take_along_axis(idx[start:stop], keep, axis=1)
        else:
            chunk_cols = idx[start:stop]
        values[start:stop] = d
        cols[start:stop] = chunk_cols
        # exact when the k-th metric value cannot be beaten by any point outside the candidate ball
        exact += int(np.count_nonzero(d.max(axis=1) <= lambda_e * dist[start:stop, -1]))
    if n_cand >= n - 1:
        exact = n
    indptr = np.arange(0, n * k + 1, k, dtype=np.int64)
    matrix = scipy.sparse.csr_matrix((values.ravel(), cols.ravel(), indptr), shape=(n, n))
    return NeighbourGraph(matrix, exact / n)


def nearest_labels(query_xyz: np.ndarray, query_embedding: np.ndarray, ref_xyz: np.ndarray,
                   ref_embedding: np.ndarray, ref_labels: np.ndarray, *, k: int, lambda_c: float, lambda_e: float,
                   metric: str = 'summed', workers: int = 1) -> np.ndarray:
    """Label of the reference point nearest to each query point under the clustering metric.

    Candidates are the ``k`` spatially nearest reference points; returns [M] labels from ``ref_labels`` [N].
    """
    m = len(query_xyz)
    if m == 0 or len(ref_xyz) == 0:
        return np.zeros(m, ref_labels.dtype)
    k = min(k, len(ref_xyz))
    tree = cKDTree(ref_xyz)
    dist, idx = tree.query(query_xyz, k=k, workers=workers)
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    ref_emb = np.ascontiguousarray(ref_embedding, dtype=np.float32)
    q_emb = np.ascontiguousarray(query_embedding, dtype=np.float32)
    out = np.empty(m, ref_labels.dtype)
    for start in range(0, m, _CHUNK):
        stop = min(m, start + _CHUNK)
        cos = _row_cosines(q_emb[start:stop], ref_emb, idx[start:stop])
        d = pair_metric(cos, dist[start:stop], lambda_c=lambda_c, lambda_e=lambda_e, metric=metric)
        best = np.take_along_axis(idx[start:stop], np.argmin(d, axis=1)[:, None], axis=1)[:, 0]
        out[start:stop] = ref_labels[best]
    return out
