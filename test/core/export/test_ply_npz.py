"""PLY and NPZ round trips and read errors."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud
from fruitnerfpp_ros.core.export.npz_io import read_cloud, read_npz, write_npz
from fruitnerfpp_ros.core.export.ply import read_ply, write_ply
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ExportError


def _assert_same(a: FruitPointCloud, b: FruitPointCloud) -> None:
    for name in ('xyz', 'rgb', 'semantic', 'embedding'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert getattr(a, name).dtype == getattr(b, name).dtype


def test_ply_round_trip_with_labels_and_a_standard_header(tmp_path: Path) -> None:
    synth = make_fruit_cloud(500, 5, dim=8, seed=0)
    labels = (synth.labels + 1).astype(np.int32)
    path = write_ply(tmp_path / 'cloud.ply', synth.cloud, labels)
    cloud, read_labels = read_ply(path)
    _assert_same(cloud, synth.cloud)
    np.testing.assert_array_equal(read_labels, labels)
    raw = path.read_bytes()
    header = raw[:raw.index(b'end_header\n')].decode().splitlines()
    assert header[:2] == ['ply', 'format binary_little_endian 1.0']
    assert 'element vertex 500' in header
    props = [line.split()[-1] for line in header if line.startswith('property')]
    assert props == ['x', 'y', 'z', 'red', 'green', 'blue', 'semantic'] + [f'emb_{i}' for i in range(8)] + ['cluster']
    assert len(raw) - raw.index(b'end_header\n') - len('end_header\n') == 500 * (4 * 3 + 3 + 4 + 4 * 8 + 4)
    cloud, read_labels = read_ply(write_ply(tmp_path / 'nolabels.ply', synth.cloud))
    assert read_labels is None and cloud.embedding_dim == 8


def test_empty_cloud_round_trips(tmp_path: Path) -> None:
    cloud, labels = read_ply(write_ply(tmp_path / 'e.ply', FruitPointCloud.empty(4)))
    assert len(cloud) == 0 and cloud.embedding_dim == 4
    cloud, labels = read_npz(write_npz(tmp_path / 'e.npz', FruitPointCloud.empty(4)))
    assert len(cloud) == 0 and cloud.embedding_dim == 4


def test_npz_round_trip(tmp_path: Path) -> None:
    synth = make_fruit_cloud(300, 3, seed=1)
    cloud, labels = read_cloud(write_npz(tmp_path / 'c.npz', synth.cloud, synth.labels))
    _assert_same(cloud, synth.cloud)
    np.testing.assert_array_equal(labels, synth.labels)


def test_the_viewing_directions_travel_with_the_cloud(tmp_path: Path) -> None:
    cloud = make_fruit_cloud(200, 2, dim=4, seed=2).cloud
    directed = dataclasses.replace(cloud, view_dir=np.tile(np.float32([[0, -1, 0]]), (len(cloud), 1)))
    np.testing.assert_array_equal(read_npz(write_npz(tmp_path / 'd.npz', directed))[0].view_dir, directed.view_dir)
    np.testing.assert_array_equal(read_ply(write_ply(tmp_path / 'd.ply', directed))[0].view_dir, directed.view_dir)
    assert read_npz(write_npz(tmp_path / 'n.npz', cloud))[0].view_dir is None
    assert read_ply(write_ply(tmp_path / 'n.ply', cloud))[0].view_dir is None
    assert directed.subset(np.arange(10)).view_dir.shape == (10, 3)
    with pytest.raises(ExportError, match='view_dir'):
        dataclasses.replace(cloud, view_dir=np.zeros((3, 3), np.float32))


def test_the_export_spacing_travels_with_the_cloud(tmp_path: Path) -> None:
    """Counting a copied cloud file must scale cluster sizes like the pipeline did: the voxel is in the file."""
    spaced = dataclasses.replace(make_fruit_cloud(200, 2, dim=4, seed=2).cloud, spacing_m=0.0143)
    cloud = dataclasses.replace(spaced, spacing_m=None)
    assert read_ply(write_ply(tmp_path / 'c.ply', spaced))[0].spacing_m == 0.0143
    assert read_npz(write_npz(tmp_path / 'c.npz', spaced))[0].spacing_m == 0.0143
    assert spaced.subset(np.arange(10)).spacing_m == 0.0143
    assert read_ply(write_ply(tmp_path / 'n.ply', cloud))[0].spacing_m is None
    assert read_npz(write_npz(tmp_path / 'n.npz', cloud))[0].spacing_m is None


def test_read_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match='missing.ply: point cloud file not found'):
        read_ply(tmp_path / 'missing.ply')
    (tmp_path / 'bad.ply').write_bytes(b'not a ply')
    with pytest.raises(ExportError, match='bad.ply: not a PLY'):
        read_ply(tmp_path / 'bad.ply')
    (tmp_path / 'ascii.ply').write_bytes(b'ply\nformat ascii 1.0\nelement vertex 0\nend_header\n')
    with pytest.raises(ExportError, match='binary_little_endian'):
        read_ply(tmp_path / 'ascii.ply')
    (tmp_path / 'bad.npz').write_bytes(b'garbage')
    with pytest.raises(ExportError, match='bad.npz'):
        read_npz(tmp_path / 'bad.npz')
    with pytest.raises(ExportError, match='unknown point cloud format'):
        read_cloud(tmp_path / 'cloud.xyz')
    synth = make_fruit_cloud(100, 2, seed=1)
    path = write_ply(tmp_path / 'trunc.ply', synth.cloud)
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(ExportError, match='truncated'):
        read_ply(path)


def test_inconsistent_cloud_arrays_raise_export_error_naming_the_file(tmp_path: Path) -> None:
    good = make_fruit_cloud(50, 2, dim=4, seed=3).cloud
    with pytest.raises(ExportError, match=r'inconsistent FruitPointCloud shapes: xyz \(50, 3\), rgb \(49, 3\)'):
        FruitPointCloud(good.xyz, good.rgb[:49], good.semantic, good.embedding)
    with pytest.raises(ExportError, match='inconsistent FruitPointCloud shapes'):
        FruitPointCloud(good.xyz, good.rgb, good.semantic, good.embedding[:, 0])
    np.savez(tmp_path / 'short.npz', xyz=good.xyz, rgb=good.rgb, semantic=good.semantic[:10],
             embedding=good.embedding)
    with pytest.raises(ExportError, match=r'short\.npz: inconsistent FruitPointCloud shapes'):
        read_npz(tmp_path / 'short.npz')
