"""Combine per-partition clusters into one labelling, so a fruit cut by a partition boundary counts once.

Each partition clusters its cell plus an overlap margin and keeps only the clusters whose median lies in its own
cell (:func:`keep_owned_clusters`). Clusters kept by two partitions that still share most of their points (a
fruit larger than the margin, seen slightly differently from both sides) are merged (:func:`merge_clusters`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.clustering.count_result import label_groups
from fruitnerfpp_ros.core.clustering.partitions import assign_to_cells

__all__ = ['keep_owned_clusters', 'merge_clusters', 'merge_close_centers', 'merge_agreeing_neighbours',
           'merge_opposite_caps', 'close_pair_cosines', 'group_mean_directions']


def keep_owned_clusters(xyz: np.ndarray, members: np.ndarray, local_labels: np.ndarray, partition: int,
                        centers: np.ndarray) -> list[np.ndarray]:
    """Clusters of one partition whose median lies in the partition's own k-means cell.

    Args:
        xyz: [N, 3] all clustered positions (m).
        members: [M] indices of the partition's points into ``xyz``.
        local_labels: [M] HDBSCAN labels of those points (-1 noise).
        partition: index of this partition's cell.
        centers: [S, 3] cell centres.

    Returns:
        One sorted index array (into ``xyz``) per kept cluster.
    """
    _, groups = label_groups(local_labels, members)
    if not groups:
        return []
    medians = np.array([np.median(xyz[g], axis=0) for g in groups])
    owned = assign_to_cells(medians, centers) == partition if len(centers) > 1 else np.ones(len(groups), bool)
    return [np.sort(g) for g, keep in zip(groups, owned) if keep]


def merge_clusters(n_points: int, clusters: list[np.ndarray], *, min_shared: float = 0.5) -> np.ndarray:
    """One label per point from possibly overlapping clusters.

    Clusters sharing at least ``min_shared`` of the smaller one's points are merged; a point left in two
    unmerged clusters goes to the larger one.

    Returns:
        [n_points] int64 labels, -1 = noise, 0..K-1 in order of first appearance.
    """
    labels = np.full(n_points, -1, np.int64)
    if not clusters:
        return labels
    sizes = np.array([len(c) for c in clusters])
    point = np.concatenate(clusters)
    owner = np.repeat(np.arange(len(clusters)), sizes)
    order = np.lexsort((owner, point))
    point, owner = point[order], owner[order]
    dup = np.flatnonzero(point[1:] == point[:-1])
    n_clusters = len(clusters)
    if len(dup):
        a, b = owner[dup], owner[dup + 1]
        pair_keys, shared = np.unique(a * n_clusters + b, return_counts=True)
        pa, pb = pair_keys // n_clusters, pair_keys % n_clusters
        merge = shared >= min_shared * np.minimum(sizes[pa], sizes[pb])
        graph = scipy.sparse.coo_matrix((np.ones(int(merge.sum())), (pa[merge], pb[merge])),
                                        shape=(n_clusters, n_clusters))
        _, root = connected_components(graph, directed=False)
    else:
        root = np.arange(n_clusters)
    merged_size = np.bincount(root, weights=sizes)
    # larger (merged) clusters are written last, so they win the remaining conflicts
    rank = np.argsort(merged_size[root[owner]], kind='stable')
    labels[point[rank]] = root[owner[rank]]
    _, dense = np.unique(labels[labels >= 0], return_inverse=True)
    labels[labels >= 0] = dense
    return labels


def merge_close_centers(xyz: np.ndarray, labels: np.ndarray, distance_m: float) -> np.ndarray:
    """Merge clusters whose median centres lie closer than ``distance_m`` (transitively).

    Args:
        xyz: [N, 3] positions (m).
        labels: [N] labels, -1 noise, 0..K-1 clusters.
        distance_m: merge distance (m); <= 0 returns ``labels`` unchanged.

    Returns:
        [N] labels, -1 noise, 0..K'-1.
    """
    if distance_m <= 0 or not np.any(labels >= 0):
        return labels
    ids, _, _, pairs = _close_cluster_pairs(xyz, labels, distance_m)
    return _join_pairs(labels, ids[pairs[:, 0]], ids[pairs[:, 1]])


def merge_agreeing_neighbours(xyz: np.ndarray, embedding: np.ndarray, labels: np.ndarray, reach_m: float,
                              min_cosine: float) -> np.ndarray:
    """Merge clusters whose median centres lie within ``reach_m`` and whose mean embeddings agree (transitively).

    A fruit seen from both sides of a row is exported as two caps, its front and its back, with a gap between
    them where its sides were seen at grazing angles only: HDBSCAN splits the caps although the instance field
    gives them one embedding. Two touching fruits are told apart by the same field (the contrastive loss pushes
    apart masks of one image), so a pair is joined only when its clusters' mean embeddings have a cosine of at
    least ``min_cosine``.

    Args:
        xyz: [N, 3] positions (m); embedding: [N, D] embeddings (any norm).
        labels: [N] labels, -1 noise, 0..K-1 clusters.
        reach_m: largest distance between the two clusters' median centres (m); <= 0 returns ``labels``.
        min_cosine: smallest cosine between the clusters' mean unit embeddings.

    Returns:
        [N] labels, -1 noise, 0..K'-1.
    """
    if reach_m <= 0 or not np.any(labels >= 0):
        return labels
    ids, _, pairs, cosine = close_pair_cosines(xyz, embedding, labels, reach_m)
    pairs = pairs[cosine >= min_cosine]
    return _join_pairs(labels, ids[pairs[:, 0]], ids[pairs[:, 1]])


def merge_opposite_caps(xyz: np.ndarray, view_dir: np.ndarray, labels: np.ndarray, reach_m: float,
                        max_facing_cos: float) -> np.ndarray:
    """Merge clusters seen from opposite sides whose median centres lie within ``reach_m`` (transitively).

    Meant for points already moved towards their fruit's centre (``ClusterConfig.centre_shift_diameters``): a
    fruit seen from both sides of a row leaves a cap on each side, and moved inwards both caps' centres fall near
    the fruit's centre, while two fruits' centres stay about a diameter apart whatever side they were seen from.
    The instance field need not agree across the two sides (it is trained on one view at a time), so this test
    asks nothing of the embeddings.

    Args:
        xyz: [N, 3] (moved) positions (m).
        view_dir: [N, 3] each point's mean viewing direction (any length).
        labels: [N] labels, -1 noise, 0..K-1 clusters.
        reach_m: largest distance between the two clusters' median centres (m); <= 0 returns ``labels``.
        max_facing_cos: largest cosine between the clusters' mean viewing directions (e.g. -0.5: seen from
            directions more than 120 degrees apart).

    Returns:
        [N] labels, -1 noise, 0..K'-1.
    """
    if reach_m <= 0 or not np.any(labels >= 0):
        return labels
    ids, groups, _, pairs = _close_cluster_pairs(xyz, labels, reach_m)
    if len(pairs) == 0:
        return labels
    mean = group_mean_directions(view_dir, groups)
    facing = np.einsum('ij,ij->i', mean[pairs[:, 0]], mean[pairs[:, 1]])
    pairs = pairs[facing <= max_facing_cos]
    return _join_pairs(labels, ids[pairs[:, 0]], ids[pairs[:, 1]])


def close_pair_cosines(xyz: np.ndarray, embedding: np.ndarray, labels: np.ndarray,
                       reach_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cluster pairs :func:`merge_agreeing_neighbours` weighs: (the K cluster ids, their [K, 3] median centres,
    [P, 2] pairs of positions in the ids whose centres lie within ``reach_m``, [P] cosine of each pair's mean unit
    embeddings). ``labels``: [N], -1 noise; at least one cluster."""
    ids, groups, centers, pairs = _close_cluster_pairs(xyz, labels, reach_m)
    mean = group_mean_directions(_unit(embedding), groups)
    return ids, centers, pairs, np.einsum('ij,ij->i', mean[pairs[:, 0]], mean[pairs[:, 1]])


def _unit(vectors: np.ndarray) -> np.ndarray:
    vectors = np.asarray(vectors, np.float64)
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


def group_mean_directions(vectors: np.ndarray, groups: list[np.ndarray]) -> np.ndarray:
    """[K, D] the unit direction of each group's mean vector (``vectors`` [N, D], ``groups`` index arrays)."""
    return _unit(np.array([np.asarray(vectors[g], np.float64).mean(axis=0) for g in groups]))


def _close_cluster_pairs(xyz: np.ndarray, labels: np.ndarray,
                         reach_m: float) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    """(cluster ids, each cluster's point indices, their [K, 3] median centres, [P, 2] pairs of positions in
    ``ids`` whose clusters' median centres lie within ``reach_m``)."""
    ids, groups = label_groups(labels)
    centers = np.array([np.median(xyz[g], axis=0) for g in groups])
    return ids, groups, centers, cKDTree(centers).query_pairs(reach_m, output_type='ndarray')


def _join_pairs(labels: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``labels`` with the clusters of every pair (a[i], b[i]) joined, transitively; renumbered 0..K'-1."""
    if len(a) == 0:
        return labels
    valid = labels >= 0
    n_clusters = int(labels.max()) + 1
    graph = scipy.sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_clusters, n_clusters))
    _, root = connected_components(graph, directed=False)
    out = np.where(valid, root[np.maximum(labels, 0)], -1)
    _, dense = np.unique(out[valid], return_inverse=True)
    out[valid] = dense
    return out
