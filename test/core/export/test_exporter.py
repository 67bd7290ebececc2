"""Volumetric export against an analytic sphere field."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.exporter import export_fruit_cloud, export_grid
from fruitnerfpp_ros.core.fields.query import FieldQuery
from fruitnerfpp_ros.errors import ConfigError, ExportError
from test.core.export.analytic_field import SphereField

AABB = np.array([[0.0, 0.0, 0.0], [0.4, 0.4, 0.2]])
FRUITS = np.array([[0.1, 0.1, 0.1], [0.3, 0.1, 0.1], [0.1, 0.3, 0.1], [0.3, 0.3, 0.1]])
LEAVES = np.array([[0.2, 0.2, 0.1]])
R = 0.035


def _field() -> SphereField:
    return SphereField(FRUITS, R, leaf_centers=LEAVES)


def test_export_keeps_dense_fruit_points_with_their_features() -> None:
    field = _field()
    result = export_fruit_cloud(field, AABB, ExportConfig(voxel_size_m=0.005, density_threshold=100.0,
                                                          coarse_factor=1))
    cloud, report = result
    voxel = report.voxel_size_m
    sphere_samples = 4 / 3 * np.pi * R ** 3 / voxel ** 3
    assert report.grid_shape == (80, 80, 40)
    assert report.n_grid == 80 * 80 * 40
    assert abs(report.n_kept - 4 * sphere_samples) < 0.05 * 4 * sphere_samples
    assert abs(report.n_dense - 5 * sphere_samples) < 0.05 * 5 * sphere_samples  # the leaf is dense, not fruit
    assert len(cloud) == report.n_kept
    d = np.linalg.norm(cloud.xyz[:, None, :] - FRUITS[None], axis=-1).min(axis=1)
    assert d.max() <= R + 1e-6  # only points inside fruit spheres
    np.testing.assert_allclose(cloud.semantic, 0.95, atol=1e-6)
    assert np.all(cloud.rgb == np.array([204, 26, 26], np.uint8))
    np.testing.assert_allclose(np.linalg.norm(cloud.embedding, axis=1), 1.0, atol=1e-5)
    owner = np.linalg.norm(cloud.xyz[:, None, :] - FRUITS[None], axis=-1).argmin(axis=1)
    np.testing.assert_allclose(cloud.embedding, field.embeddings[torch.as_tensor(owner)].numpy(), atol=1e-6)
    # the coarse-to-fine pass finds the same points and skips the leaf and the empty space
    coarse = export_fruit_cloud(field, AABB, ExportConfig(voxel_size_m=0.005, density_threshold=100.0))
    np.testing.assert_array_equal(np.unique(coarse.cloud.xyz, axis=0), np.unique(cloud.xyz, axis=0))
    assert coarse.report.n_evaluated < 0.25 * report.n_evaluated
    assert coarse.report.n_coarse == 20 * 20 * 10


def test_batches_do_not_change_the_result() -> None:
    config = ExportConfig(voxel_size_m=0.01, density_threshold=100.0, coarse_factor=1)
    whole = export_fruit_cloud(_field(), AABB, config).cloud
    field = _field()
    batched = export_fruit_cloud(field, AABB, ExportConfig(voxel_size_m=0.01, density_threshold=100.0,
                                                           batch_size=4001, coarse_factor=1)).cloud
    n_batches = int(np.ceil(40 * 40 * 20 / 4001))
    assert n_batches <= field.calls <= 2 * n_batches  # a density pass per batch, a full query where kept
    np.testing.assert_array_equal(whole.xyz, batched.xyz)
    np.testing.assert_array_equal(whole.embedding, batched.embedding)


def test_grid_points_target_and_crop_box() -> None:
    box, voxel, shape = export_grid(AABB, ExportConfig(grid_points=32_000))
    assert abs(np.prod(shape) - 32_000) < 0.1 * 32_000
    box, voxel, shape = export_grid(AABB, ExportConfig(voxel_size_m=0.01, aabb=(0.0, 0.0, 0.0, 0.2, 0.2, 0.2)))
    assert shape == (20, 20, 20)
    with pytest.raises(ExportError, match='empty'):
        export_grid(AABB, ExportConfig(aabb=(1.0, 1.0, 1.0, 2.0, 2.0, 2.0)))


def test_automatic_density_threshold_uses_the_surface_density() -> None:
    result = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01), surface_density=30.0)
    assert result.report.density_threshold == 30.0
    assert result.report.n_kept > 0
    with pytest.raises(ExportError, match='density_threshold'):
        export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01))


def test_empty_export_says_which_threshold_removed_what() -> None:
    too_dense = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01, density_threshold=1e4))
    assert too_dense.report.n_kept == 0 and too_dense.report.n_dense == 0 and len(too_dense.cloud) == 0
    assert 'density threshold removed everything' in too_dense.report.explain()
    assert 'max density 500' in too_dense.report.explain()
    too_sure = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01, density_threshold=100.0,
                                                               fruit_threshold=0.99, coarse_factor=1))
    assert too_sure.report.n_dense > 0 and too_sure.report.n_kept == 0
    assert 'fruit threshold removed all' in too_sure.report.explain()
    assert 'max fruit probability among them 0.95' in too_sure.report.explain()
    pruned_coarse = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01, density_threshold=100.0,
                                                                    fruit_threshold=0.99, coarse_factor=4,
                                                                    coarse_fruit_fraction=1.0))
    assert pruned_coarse.report.n_evaluated == 0  # nothing to refine: the coarse pass explains the empty cloud
    assert 'fruit threshold removed all' in pruned_coarse.report.explain()
    assert too_sure.report.to_json()['explanation'] == too_sure.report.explain()


def test_stop_event_ends_the_export_early() -> None:
    import threading
    stop = threading.Event()
    stop.set()
    result = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.01, density_threshold=100.0),
                                stop_event=stop)
    assert result.report.stopped and len(result.cloud) == 0


class _BrokenField(SphereField):
    def query(self, xyz: torch.Tensor) -> FieldQuery:
        q = super().query(xyz)
        return q._replace(embedding=q.embedding[:, :3])


def test_wrong_field_shapes_and_bad_config_are_errors() -> None:
    with pytest.raises(ExportError, match='embedding'):
        export_fruit_cloud(_BrokenField(FRUITS, R), AABB, ExportConfig(voxel_size_m=0.02, density_threshold=1.0))
    with pytest.raises(ConfigError, match='fruit_threshold'):
        ExportConfig(fruit_threshold=1.5)
    with pytest.raises(ExportError, match='max_points'):
        export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.005, density_threshold=1.0, max_points=1000))


def test_exported_spheres_are_counted_one_fruit_each() -> None:
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.clustering.counter import count_fruits

    cloud = export_fruit_cloud(_field(), AABB, ExportConfig(voxel_size_m=0.006, density_threshold=100.0)).cloud
    result = count_fruits(cloud, ClusterConfig(n_jobs=1))
    assert result.count == 4
    np.testing.assert_allclose(result.centers(), FRUITS[np.lexsort((FRUITS[:, 2], FRUITS[:, 1], FRUITS[:, 0]))],
                               atol=0.004)
    assert all(abs(f.diameter_m - 2 * R) < 0.012 for f in result.fruits)
