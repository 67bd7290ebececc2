"""A segment's result: its fruits and where its fruit cloud has points (the merge's support) survive result.json,
and a result written before the support was kept reads as "not known"."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.orchard.jobs import (RESULT_NAME, read_segment_result, segment_fruits, support_voxel_m,
                                               write_segment_result)


def _cloud(xyz: np.ndarray, diameter: float | None, spacing: float | None) -> FruitPointCloud:
    n = len(xyz)
    return FruitPointCloud(xyz.astype(np.float32), np.zeros((n, 3), np.uint8), np.ones(n, np.float32),
                           np.zeros((n, 4), np.float32), spacing, diameter)


def test_the_support_travels_with_the_fruits_through_result_json(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    xyz = np.concatenate([c + 0.035 * rng.uniform(-1, 1, size=(2000, 3)) for c in ([0, 0, 1], [0.3, 0.1, 1.2])])
    cloud = _cloud(xyz, 0.07, 0.008)
    count = CountResult(np.ones(len(xyz), np.int32),
                        [Fruit(1, np.array([0.0, 0.0, 1.0]), 0.07, np.full(3, 0.07), 2000, 'cloud'),
                         Fruit(2, np.array([0.3, 0.1, 1.2]), 0.068, np.full(3, 0.07), 2000, 'cloud')])
    fruits = segment_fruits(3, count, cloud)
    voxel = support_voxel_m(cloud)
    assert voxel == np.float64(0.2 * 0.07)
    # one point per occupied voxel: every cloud point within half a voxel diagonal of a support point
    assert len(fruits.support) < len(xyz) / 3
    gap = np.linalg.norm(xyz[:, None] - fruits.support[None], axis=2).min(axis=1)
    assert gap.max() <= 0.5 * np.sqrt(3) * voxel + 1e-6
    write_segment_result(tmp_path, fruits, seconds=1.5, worker='w')
    read, record = read_segment_result(tmp_path)
    assert record['seconds'] == 1.5 and read.segment == 3 and read.ids.tolist() == [1, 2]
    assert np.allclose(read.centers, fruits.centers) and np.allclose(read.support, fruits.support, atol=1e-4)
    assert len((tmp_path / RESULT_NAME).read_text().splitlines()) < 40      # the support on one line


def test_a_result_without_support_reads_as_unknown(tmp_path: Path) -> None:
    fruit = {'id': 1, 'center': [0, 0, 1], 'diameter': 0.07, 'n_points': 30}
    record = {'segment': 0, 'seconds': 2.0, 'fruits': [fruit]}
    (tmp_path / RESULT_NAME).write_text(json.dumps(record))
    fruits, _ = read_segment_result(tmp_path)
    assert fruits.support is None and len(fruits.ids) == 1


def test_the_support_voxel_follows_the_fruit_and_never_undercuts_the_cloud() -> None:
    xyz = np.zeros((1, 3))
    assert support_voxel_m(_cloud(xyz, 0.04, 0.005)) == 0.2 * 0.04
    assert support_voxel_m(_cloud(xyz, 0.04, 0.012)) == 0.012                # the cloud is coarser than a fifth
    assert support_voxel_m(_cloud(xyz, None, None)) == 0.2 * 0.05            # unknown scale: a 5 cm fruit


def test_an_unreadable_support_keeps_the_fruits(tmp_path: Path) -> None:
    record = {'segment': 0, 'fruits': [{'id': 1, 'center': [0, 0, 1], 'diameter': 0.07, 'n_points': 30}],
              'support': [0.1, 0.2]}                                       # not x, y, z triples
    (tmp_path / RESULT_NAME).write_text(json.dumps(record))
    fruits, _ = read_segment_result(tmp_path)
    assert fruits.support is None and fruits.ids.tolist() == [1]
