"""The sparse metric graph, partitions and cluster merging."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.graph import build_graph, nearest_labels, pair_metric
from fruitnerfpp_ros.core.clustering.merge import merge_agreeing_neighbours, merge_close_centers, merge_clusters
from fruitnerfpp_ros.core.clustering.partitions import make_partitions
from fruitnerfpp_ros.errors import ClusteringError


def _random_cloud(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(0, 0.3, (n, 3)).astype(np.float32)
    emb = rng.normal(size=(n, 8)).astype(np.float32)
    return xyz, emb / np.linalg.norm(emb, axis=1, keepdims=True)


def test_graph_holds_the_exact_summed_metric_and_exact_rows_are_true_knn() -> None:
    xyz, emb = _random_cloud(300)
    lambda_c, lambda_e, k = 1.0, 10.0, 6
    graph = build_graph(xyz, emb, knn_k=k, candidate_factor=3.0, lambda_c=lambda_c, lambda_e=lambda_e)
    dense = lambda_c * (1 - emb @ emb.T) + lambda_e * np.linalg.norm(xyz[:, None] - xyz[None], axis=-1)
    np.fill_diagonal(dense, np.inf)
    m = graph.matrix
    rows = np.repeat(np.arange(300), np.diff(m.indptr))
    np.testing.assert_allclose(m.data, dense[rows, m.indices], rtol=1e-5, atol=1e-6)
    assert np.all(np.diff(m.indptr) == k)
    # with lambda_e large the spatial candidates contain the true metric kNN for most rows
    graph = build_graph(xyz, emb, knn_k=k, candidate_factor=3.0, lambda_c=lambda_c, lambda_e=100.0)
    dense = lambda_c * (1 - emb @ emb.T) + 100.0 * np.linalg.norm(xyz[:, None] - xyz[None], axis=-1)
    np.fill_diagonal(dense, np.inf)
    true_kth = np.sort(dense, axis=1)[:, k - 1]
    got_kth = graph.matrix.max(axis=1).toarray().ravel()
    assert graph.exact_fraction > 0.5
    assert np.mean(np.isclose(got_kth, true_kth, rtol=1e-5)) >= graph.exact_fraction - 1e-9


def test_concatenated_metric_formula() -> None:
    cos, dist = np.array([1.0, 0.0]), np.array([0.1, 0.0])
    np.testing.assert_allclose(pair_metric(cos, dist, lambda_c=1, lambda_e=10), [1.0, 1.0])
    np.testing.assert_allclose(pair_metric(cos, dist, lambda_c=1, lambda_e=10, metric='concatenated'), [1.0, 1.0])
    np.testing.assert_allclose(pair_metric(np.array([0.5]), np.array([0.03]), lambda_c=1, lambda_e=10,
                                           metric='concatenated'), [np.sqrt(0.09 + 0.5)])


def test_unknown_metric_raises_clustering_error() -> None:
    with pytest.raises(ClusteringError, match="unknown clustering metric 'cosine'"):
        pair_metric(np.array([1.0]), np.array([0.1]), lambda_c=1, lambda_e=2, metric='cosine')
    xyz, emb = _random_cloud(50)
    with pytest.raises(ClusteringError, match='unknown clustering metric'):
        build_graph(xyz, emb, knn_k=4, candidate_factor=2, lambda_c=1, lambda_e=2, metric='manhattan')


def test_nearest_labels_prefers_the_matching_embedding() -> None:
    ref_xyz = np.array([[0, 0, 0], [0.01, 0, 0]], np.float32)
    ref_emb = np.array([[1, 0], [0, 1]], np.float32)
    query_xyz = np.array([[0.004, 0, 0]], np.float32)  # spatially nearer the first reference point
    query_emb = np.array([[0, 1]], np.float32)  # but with the second one's embedding
    labels = nearest_labels(query_xyz, query_emb, ref_xyz, ref_emb, np.array([1, 2]), k=2, lambda_c=1.0,
                            lambda_e=10.0)
    assert labels.tolist() == [2]


def test_partitions_are_balanced_and_overlap() -> None:
    xyz, _ = _random_cloud(4000, seed=1)
    parts = make_partitions(xyz, 4, overlap_m=0.02, seed=0)
    own_sizes = np.bincount(parts.owner, minlength=4)
    assert own_sizes.min() > 0.5 * own_sizes.max()
    for p, members in enumerate(parts.members):
        assert set(np.flatnonzero(parts.owner == p)) <= set(members)
        assert len(members) > own_sizes[p]  # the overlap margin adds neighbours' points
    no_overlap = make_partitions(xyz, 4, overlap_m=0.0, seed=0)
    assert sum(len(m) for m in no_overlap.members) == 4000


def test_merge_clusters_joins_duplicates_and_keeps_distinct() -> None:
    a = np.arange(0, 100)
    a_seen_twice = np.arange(10, 100)  # the same fruit found by a second partition
    b = np.arange(200, 250)
    labels = merge_clusters(300, [a, a_seen_twice, b])
    assert len(np.unique(labels[labels >= 0])) == 2
    assert np.all(labels[a] == labels[0]) and np.all(labels[b] == labels[200]) and labels[0] != labels[200]
    assert np.all(labels[100:200] == -1)


def test_merge_close_centers_joins_a_split_fruit_only() -> None:
    rng = np.random.default_rng(0)
    half_a = rng.normal([0.0, 0, 0], 0.01, (50, 3))
    half_b = rng.normal([0.03, 0, 0], 0.01, (50, 3))  # the other half of the same fruit
    other = rng.normal([0.08, 0, 0], 0.01, (50, 3))  # a touching neighbour, 8 cm away
    xyz = np.concatenate([half_a, half_b, other])
    labels = np.repeat([0, 1, 2], 50)
    merged = merge_close_centers(xyz, labels, 0.04)
    assert merged[0] == merged[50] != merged[100]
    assert np.array_equal(merge_close_centers(xyz, labels, 0.0), labels)


def test_merge_agreeing_neighbours_joins_the_caps_of_one_fruit_only() -> None:
    rng = np.random.default_rng(0)
    front = rng.normal([0.0, -0.03, 0], 0.008, (40, 3))
    back = rng.normal([0.0, 0.03, 0], 0.008, (40, 3))  # the same fruit's back cap, 6 cm away
    neighbour = rng.normal([0.07, 0.0, 0], 0.008, (40, 3))  # a touching fruit, 7 cm away
    far = rng.normal([0.3, 0.0, 0], 0.008, (40, 3))  # same embedding as the fruit, 30 cm away
    xyz = np.concatenate([front, back, neighbour, far])
    fruit, other = np.eye(8)[0], np.eye(8)[1]
    embedding = np.concatenate([np.tile(fruit, (80, 1)), np.tile(other, (40, 1)), np.tile(fruit, (40, 1))])
    embedding += rng.normal(0, 0.05, embedding.shape)
    labels = np.repeat([0, 1, 2, 3], 40)
    merged = merge_agreeing_neighbours(xyz, embedding, labels, 0.1, 0.9)
    assert merged[0] == merged[40] and len({merged[0], merged[80], merged[120]}) == 3
    assert np.array_equal(merge_agreeing_neighbours(xyz, embedding, labels, 0.0, 0.9), labels)
    assert np.array_equal(merge_agreeing_neighbours(xyz, embedding, labels, 0.05, 0.9), labels)  # caps 6 cm apart
    assert np.array_equal(merge_agreeing_neighbours(xyz, -embedding, np.full(160, -1), 0.1, 0.9), np.full(160, -1))
