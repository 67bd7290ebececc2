"""Oversized clusters (two fruits kept together by HDBSCAN's excess of mass) are clustered again and split."""

from __future__ import annotations

import numpy as np
from sklearn.metrics import adjusted_rand_score

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.clustering.split import cluster_diameters, split_oversized
from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud


def test_a_cluster_holding_two_fruits_is_split_and_normal_ones_are_kept() -> None:
    synth = make_fruit_cloud(3000, 6, seed=4)
    config = ClusterConfig(n_jobs=1).for_cloud(synth.cloud.spacing_m)
    merged = synth.labels.copy()
    merged[merged == 1] = 0  # as if 'eom' had kept fruits 0 and 1 together
    diameters = {label: d for label, (d, _) in cluster_diameters(synth.cloud.xyz, merged).items()}
    assert diameters[0] > 1.5 * np.median(list(diameters.values()))
    labels, n_split = split_oversized(synth.cloud.xyz, synth.cloud.embedding, merged, config)
    assert n_split == 1
    assert len(np.unique(labels[labels >= 0])) == 6
    assert adjusted_rand_score(synth.labels, labels) > 0.95
    untouched = np.isin(synth.labels, [2, 3, 4, 5])
    np.testing.assert_array_equal(labels[untouched], merged[untouched])


def test_even_sized_clusters_are_left_alone_and_the_split_can_be_switched_off() -> None:
    synth = make_fruit_cloud(3000, 6, seed=5)
    config = ClusterConfig(n_jobs=1).for_cloud(synth.cloud.spacing_m)
    labels, n_split = split_oversized(synth.cloud.xyz, synth.cloud.embedding, synth.labels, config)
    assert n_split == 0 and np.array_equal(labels, synth.labels)
    merged = np.where(synth.labels == 1, 0, synth.labels)
    off = ClusterConfig(n_jobs=1, split_diameter_factor=0.0)
    assert split_oversized(synth.cloud.xyz, synth.cloud.embedding, merged, off) == (merged, 0)
    assert count_fruits(synth.cloud, ClusterConfig(n_jobs=1)).stats['clusters_split'] == 0


def test_one_giant_cluster_without_a_typical_fruit_is_split_into_its_fruits() -> None:
    synth = make_fruit_cloud(3000, 6, seed=4)
    config = ClusterConfig(n_jobs=1).for_cloud(synth.cloud.spacing_m)
    giant = np.where(synth.labels == 5, 1, 0)  # fruits 0-4 as one cluster, fruit 5 alone: no median to trust
    labels, n_split = split_oversized(synth.cloud.xyz, synth.cloud.embedding, giant, config)
    assert n_split == 1 and len(np.unique(labels[labels >= 0])) == 6
    assert adjusted_rand_score(synth.labels, labels) > 0.95


def test_a_lone_fruit_with_two_embeddings_is_not_cut_in_halves() -> None:
    """A leaf across a fruit pulls its embedding apart (the paper's failure case): leaf selection then finds two
    hemispheres, each as wide as the fruit, so without a typical fruit to compare with the split is refused."""
    rng = np.random.default_rng(0)
    direction = rng.normal(size=(2000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    embedding = np.zeros((2000, 32))
    embedding[:, 0] = direction[:, 0] > 0
    embedding[:, 1] = direction[:, 0] <= 0
    embedding += 0.05 * rng.normal(size=embedding.shape)
    embedding /= np.linalg.norm(embedding, axis=1, keepdims=True)
    labels = np.zeros(2000, np.int64)
    out, n_split = split_oversized((0.04 * direction).astype(np.float32), embedding.astype(np.float32), labels,
                                   ClusterConfig(n_jobs=1))
    assert n_split == 0 and np.array_equal(out, labels)
