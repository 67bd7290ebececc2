"""count_fruits on synthetic fruit clouds with known instances."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.clustering.partitions import make_partitions
from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud
from fruitnerfpp_ros.core.clustering.workers import partition_pool
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ClusteringError, ConfigError


def _center_errors(result, centers: np.ndarray) -> np.ndarray:
    found = result.centers()
    return np.linalg.norm(found[:, None, :] - centers[None, :, :], axis=-1).min(axis=1)


def test_separated_fruits_counted_with_centres_and_diameters() -> None:
    synth = make_fruit_cloud(6000, 24, seed=3)
    result = count_fruits(synth.cloud, ClusterConfig(n_jobs=1))
    assert result.count == 24
    assert adjusted_rand_score(synth.labels, result.labels) > 0.99
    assert [f.id for f in result.fruits] == list(range(1, 25))
    assert set(np.unique(result.labels)) <= set(range(0, 25))
    assert _center_errors(result, synth.centers).max() < 0.01  # median of a shell sits at its centre (m)
    diameters = np.array([f.diameter_m for f in result.fruits])
    assert np.all(np.abs(diameters - 2 * synth.radius_m) < 0.015)
    assert sum(f.n_points for f in result.fruits) == np.count_nonzero(result.labels)


def test_touching_fruits_need_the_embedding_term() -> None:
    """Groups of three overlapping fruits: one blob in space, three fruits by embedding."""
    synth = make_fruit_cloud(6000, 24, touching=True, seed=4)
    combined = count_fruits(synth.cloud, ClusterConfig(n_jobs=1))
    euclidean_only = count_fruits(synth.cloud, ClusterConfig(lambda_c=0.0, n_jobs=1))
    assert combined.count == 24
    assert adjusted_rand_score(synth.labels, combined.labels) > 0.95
    assert euclidean_only.count <= 12  # the groups of three merge
    assert adjusted_rand_score(synth.labels, euclidean_only.labels) < 0.7


def test_fruit_straddling_a_partition_boundary_is_counted_once() -> None:
    synth = make_fruit_cloud(8000, 27, seed=5)
    config = ClusterConfig(partitions=4, n_jobs=1)
    parts = make_partitions(synth.cloud.xyz, 4, overlap_m=config.overlap_m, seed=config.seed)
    owners_per_fruit = [len(np.unique(parts.owner[synth.labels == f])) for f in range(27)]
    assert max(owners_per_fruit) > 1, 'scene must have a fruit cut by a partition boundary'
    result = count_fruits(synth.cloud, config)
    assert result.count == 27
    assert adjusted_rand_score(synth.labels, result.labels) > 0.99
    # without overlap the cut fruits are counted twice: the mechanism matters (the merge of agreeing neighbours,
    # which would join the two pieces afterwards, off)
    no_overlap = count_fruits(synth.cloud, ClusterConfig(partitions=4, overlap_m=0.0, n_jobs=1, merge_agreeing_m=0.0,
                                                         min_cluster_size=5, min_fruit_points=5))
    assert no_overlap.count > 27


def test_subsample_and_assign_matches_full_clustering() -> None:
    synth = make_fruit_cloud(12000, 30, touching=True, seed=6)
    result = count_fruits(synth.cloud, ClusterConfig(subsample_size=3000, n_jobs=1))
    assert result.stats['n_clustered'] == 3000
    assert result.count == 30
    assert adjusted_rand_score(synth.labels, result.labels) > 0.95


def test_partitions_in_a_caller_owned_pool_give_the_in_process_labels() -> None:
    synth = make_fruit_cloud(6000, 24, seed=7)
    config = ClusterConfig(partitions=2, n_jobs=2, parallel_min_points=1000)
    in_process = count_fruits(synth.cloud, config)
    with partition_pool(config.n_jobs) as pool:
        pooled = count_fruits(synth.cloud, config, executor=pool)
        assert pool.submit(int, 7).result() == 7  # the count leaves the caller's pool running
    assert in_process.stats['partitions_in_executor'] == 0
    assert pooled.stats['partitions_in_executor'] == 2, pooled.stats.get('parallel_error')
    assert pooled.count == in_process.count == 24
    assert np.array_equal(pooled.labels, in_process.labels)


def test_concatenated_metric_is_available_as_an_option() -> None:
    synth = make_fruit_cloud(4000, 16, seed=8)
    result = count_fruits(synth.cloud, ClusterConfig(metric='concatenated', n_jobs=1))
    assert result.stats['metric'] == 'concatenated'
    assert result.count == 16


def test_clutter_creates_no_fruit_and_small_clusters_are_dropped() -> None:
    synth = make_fruit_cloud(5000, 16, clutter_fraction=0.02, seed=9)
    result = count_fruits(synth.cloud, ClusterConfig(n_jobs=1))
    assert result.count == 16
    assert _center_errors(result, synth.centers).max() < 0.01
    strict = count_fruits(synth.cloud, ClusterConfig(n_jobs=1, min_fruit_points=10_000))
    assert strict.count == 0 and np.all(strict.labels == 0)


def test_empty_cloud_counts_zero() -> None:
    result = count_fruits(FruitPointCloud.empty(32))
    assert result.count == 0
    assert result.labels.shape == (0,)
    assert 'empty' in result.stats['note']


def test_tiny_cloud_is_all_noise_not_a_crash() -> None:
    synth = make_fruit_cloud(40, 4, seed=1)
    result = count_fruits(synth.cloud.subset(np.arange(5)), ClusterConfig(n_jobs=1))
    assert result.count == 0
    assert np.all(result.labels == 0)


def test_bad_cloud_raises_clustering_error() -> None:
    synth = make_fruit_cloud(200, 2, seed=1)
    xyz = synth.cloud.xyz.copy()
    xyz[3] = np.nan
    bad = FruitPointCloud(xyz, synth.cloud.rgb, synth.cloud.semantic, synth.cloud.embedding)
    with pytest.raises(ClusteringError, match='NaN'):
        count_fruits(bad)
    with pytest.raises(ClusteringError, match='FruitPointCloud'):
        count_fruits(xyz)  # type: ignore[arg-type]


def test_cluster_sizes_follow_the_point_spacing() -> None:
    """Sizes are given for 2 cm spacing; a finer export has ~(2 cm / s)^2 more points per fruit."""
    config = ClusterConfig(min_cluster_size=15, min_samples=8, min_fruit_points=20, knn_k=24)
    assert config.for_cloud(None) is config and config.for_cloud(0.02) == config
    fine = config.for_cloud(0.01)
    assert (fine.min_cluster_size, fine.min_samples, fine.min_fruit_points) == (60, 8, 80)  # min_samples is local
    coarse = config.for_cloud(0.04)
    assert (coarse.min_cluster_size, coarse.min_samples, coarse.min_fruit_points) == (4, 8, 5)
    assert ClusterConfig(reference_spacing_m=None).for_cloud(0.01) == ClusterConfig(reference_spacing_m=None)
    # count_fruits takes the spacing from the cloud: 8 fruits of ~50 points survive at 2 cm spacing, not at 5 mm
    synth = make_fruit_cloud(400, 8, seed=3)
    cloud = synth.cloud
    at = {s: count_fruits(FruitPointCloud(cloud.xyz, cloud.rgb, cloud.semantic, cloud.embedding, spacing_m=s),
                          ClusterConfig(n_jobs=1)) for s in (0.02, 0.005)}
    assert at[0.02].count == 8 and at[0.02].stats['min_fruit_points'] == 20
    assert at[0.005].count == 0 and at[0.005].stats['min_fruit_points'] == 320


def test_config_rejects_impossible_values() -> None:
    with pytest.raises(ConfigError, match='lambda_e'):
        ClusterConfig(lambda_e=0.0)
    with pytest.raises(ConfigError, match='min_samples'):
        ClusterConfig(min_samples=50, knn_k=10)
    with pytest.raises(ConfigError, match='merge_agreeing_m'):
        ClusterConfig(merge_agreeing_m=-0.1)
    with pytest.raises(ConfigError, match='merge_agreeing_cos'):
        ClusterConfig(merge_agreeing_cos=1.5)
    for bad in ({'centre_shift_diameters': 1.5}, {'merge_opposite_m': -0.01}, {'opposite_facing_cos': 0.5}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            ClusterConfig(**bad)


def test_lengths_and_sizes_follow_the_fruit_not_the_metre() -> None:
    config = ClusterConfig(lambda_e=2.0, overlap_m=0.12, reference_fruit_diameter_m=0.075, fruit_share_cluster=0.3,
                           fruit_share_keep=0.35)
    big = config.for_cloud(0.02, 0.15, fruit_points=100.0)
    assert big.lambda_e == pytest.approx(1.0) and big.overlap_m == pytest.approx(0.24)
    assert ClusterConfig(merge_agreeing_m=0.1).for_cloud(0.02, 0.15).merge_agreeing_m == pytest.approx(0.2)
    assert (big.min_cluster_size, big.min_fruit_points) == (30, 35)
    assert config.for_cloud(0.02, None, None).lambda_e == 2.0  # unknown fruit size: as given


def test_a_scaled_copy_of_a_cloud_counts_the_same() -> None:
    """Touching fruits of 3.5 cm radius, and the same cloud three times larger (10.5 cm fruits): same labels."""
    synth = make_fruit_cloud(2400, 12, touching=True, seed=5)
    c = synth.cloud
    small = FruitPointCloud(c.xyz, c.rgb, c.semantic, c.embedding, spacing_m=0.01, fruit_diameter_m=0.07)
    large = FruitPointCloud(c.xyz * 3.0, c.rgb, c.semantic, c.embedding, spacing_m=0.03, fruit_diameter_m=0.21)
    a, b = (count_fruits(cloud, ClusterConfig(n_jobs=1)) for cloud in (small, large))
    assert a.count == b.count >= 10 and np.array_equal(a.labels, b.labels)
    assert b.stats['points_per_fruit'] == a.stats['points_per_fruit']


def _two_sided(touching: bool, view_dir: bool = False) -> tuple[FruitPointCloud, np.ndarray, np.ndarray]:
    """Fruit seen from both sides of a row (along y): each fruit's front and back cap, its sides missing; with
    ``view_dir`` the cloud knows each point's viewing direction (cameras far off on the cap's side). Returns
    (cloud, each point's true fruit, the true centres)."""
    synth = make_fruit_cloud(6000, 12, touching=touching, seed=3)
    cloud = synth.cloud
    across = (cloud.xyz[:, 1] - synth.centers[synth.labels, 1]) / synth.radius_m
    keep = np.abs(across) > 0.5
    direction = np.zeros((int(keep.sum()), 3), np.float32)
    direction[:, 1] = -np.sign(across[keep])   # a ray from the +y side runs towards -y
    caps = FruitPointCloud(cloud.xyz[keep], cloud.rgb[keep], cloud.semantic[keep], cloud.embedding[keep],
                           spacing_m=cloud.spacing_m, fruit_diameter_m=2 * synth.radius_m,
                           view_dir=direction if view_dir else None)
    return caps, synth.labels[keep], synth.centers


def _back_caps_disagreeing(caps: FruitPointCloud, truth: np.ndarray, cosine: float) -> FruitPointCloud:
    """The caps with each back cap's embedding turned away from its front cap's (to ``cosine``), as an instance
    field trained one view at a time leaves a fruit seen from the two sides of a row."""
    rng = np.random.default_rng(1)
    emb = caps.embedding.astype(np.float64)
    back = caps.view_dir[:, 1] > 0
    away = rng.normal(size=(int(truth.max()) + 1, emb.shape[1]))[truth[back]]
    away -= np.einsum('ij,ij->i', away, emb[back])[:, None] * emb[back]
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    emb[back] = cosine * emb[back] + np.sqrt(1 - cosine ** 2) * away
    return dataclasses.replace(caps, embedding=emb.astype(np.float32))


@pytest.mark.parametrize('touching', [False, True])
def test_a_fruit_seen_from_both_sides_counts_once_and_touching_fruit_stay_apart(touching: bool) -> None:
    caps, truth, _ = _two_sided(touching)
    split = count_fruits(caps, ClusterConfig(n_jobs=1, merge_agreeing_m=0.0))
    assert split.count == 24  # the defect: each cap a fruit of its own
    joined = count_fruits(caps, ClusterConfig(n_jobs=1))  # the default joins them
    assert joined.count == 12 and joined.stats['clusters_joined_agreeing'] == 12
    assert 'viewing directions' in joined.stats['centre_shift_note']   # this cloud cannot move its points
    assert adjusted_rand_score(truth, joined.labels) > 0.99


def _centre_error(result: CountResult, centres: np.ndarray, radius_m: float) -> float:
    """Median distance of the counted centres from their nearest true centre, in fruit radii."""
    dist = np.linalg.norm(result.centers()[:, None] - centres[None], axis=2)
    return float(np.median(dist.min(1))) / radius_m


@pytest.mark.parametrize('touching', [False, True])
def test_points_moved_along_their_viewing_direction_put_a_fruit_on_its_centre(touching: bool) -> None:
    """A cap's median lies about 0.7 radii in front of its fruit's centre; moved a third of a diameter along the
    rays that saw them, both caps' points meet on the centre: one cluster without the caps' join, and the centre
    where the fruit is (the distance the evaluation and the row's cross-segment match measure)."""
    caps, truth, centres = _two_sided(touching, view_dir=True)
    radius = 0.5 * float(caps.fruit_diameter_m)
    unmoved = count_fruits(caps, ClusterConfig(n_jobs=1, merge_agreeing_m=0.0, centre_shift_diameters=0.0))
    assert unmoved.count == 24 and _centre_error(unmoved, centres, radius) > 0.4
    moved = count_fruits(caps, ClusterConfig(n_jobs=1, merge_agreeing_m=0.0))   # the default moves them
    assert moved.count == 12 and moved.stats['clusters_joined_agreeing'] == 0 and 'centre_shift_note' not in moved.stats
    assert adjusted_rand_score(truth, moved.labels) > 0.99
    assert _centre_error(moved, centres, radius) < 0.15
    assert moved.stats['mean_centre_shift_m'] == pytest.approx(2 * radius / 3, rel=1e-3)
    # diameters stay those of the surface points (about the true diameter, not the moved points' spread)
    assert np.median([f.diameter_m for f in moved.fruits]) == pytest.approx(2 * radius, rel=0.15)


@pytest.mark.parametrize('touching', [False, True])
def test_caps_seen_from_opposite_sides_join_though_their_embeddings_disagree(touching: bool) -> None:
    caps, truth, _ = _two_sided(touching, view_dir=True)
    caps = _back_caps_disagreeing(caps, truth, cosine=0.3)
    split = count_fruits(caps, ClusterConfig(n_jobs=1, merge_opposite_m=0.0))
    assert split.count == 24   # moved onto one place, the caps still differ in embedding
    joined = count_fruits(caps, ClusterConfig(n_jobs=1))   # the default joins caps seen from opposite sides
    assert joined.count == 12 and joined.stats['clusters_joined_opposite'] == 12
    assert adjusted_rand_score(truth, joined.labels) > 0.99   # touching fruits stay apart
    same_side = dataclasses.replace(caps, view_dir=np.abs(caps.view_dir))   # as if both were seen from one side
    assert count_fruits(same_side, ClusterConfig(n_jobs=1)).stats['clusters_joined_opposite'] == 0
