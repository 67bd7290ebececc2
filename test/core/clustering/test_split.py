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
    config = ClusterConfig(n_jobs=1).for_spacing(synth.cloud.spacing_m)
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
    config = ClusterConfig(n_jobs=1).for_spacing(synth.cloud.spacing_m)
    labels, n_split = split_oversized(synth.cloud.xyz, synth.cloud.embedding, synth.labels, config)
    assert n_split == 0 and np.array_equal(labels, synth.labels)
    merged = np.where(synth.labels == 1, 0, synth.labels)
    off = ClusterConfig(n_jobs=1, split_diameter_factor=0.0)
    assert split_oversized(synth.cloud.xyz, synth.cloud.embedding, merged, off) == (merged, 0)
    assert count_fruits(synth.cloud, ClusterConfig(n_jobs=1)).stats['clusters_split'] == 0
