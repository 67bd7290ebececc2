"""Scene bounds come from the data: cameras, or the sparse point cloud."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.bounds import aabb_from_cameras, read_ply_points, scene_aabb
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.errors import DatasetError
from test.core.training.stand_in_scene import make_sphere_scene


def _inside(points: np.ndarray, box: np.ndarray) -> bool:
    return bool(np.all(points >= box[0]) and np.all(points <= box[1]))


def test_camera_box_holds_the_tree_not_the_cameras(tmp_path: Path) -> None:
    data = make_sphere_scene(tmp_path, views=12, size=32, fruits=6)
    ds = load_dataset(data)
    fruits = np.load(data / 'fruit_centres.npy')
    box = aabb_from_cameras(ds.T_world_camera.numpy(), ds.intrinsics.numpy(), 32, 32, min_view_fraction=0.75)
    assert _inside(fruits, box)
    cameras = ds.T_world_camera[:, :3, 3].numpy()
    assert not _inside(cameras, box)  # the cameras (3.2 m out) are not part of the scene
    assert np.all(box[1] - box[0] < 5.0)


def test_point_cloud_bounds_the_camera_box(tmp_path: Path) -> None:
    data = make_sphere_scene(tmp_path, views=12, size=32, fruits=6, write_ply=True)
    ds = load_dataset(data)
    assert ds.ply_path is not None
    points = read_ply_points(ds.ply_path)
    cameras_only = scene_aabb(ds.T_world_camera, ds.intrinsics, 32, 32)
    box = scene_aabb(ds.T_world_camera, ds.intrinsics, 32, 32, ply_path=ds.ply_path, points_growth=2.0)
    fruits = np.load(data / 'fruit_centres.npy')
    assert _inside(fruits, box) and _inside(points, box)
    extent = points.max(0) - points.min(0)
    assert np.all(box[1] - box[0] <= 2.0 * extent * 1.2)               # at most the grown point box
    assert np.all(box[1] - box[0] < cameras_only[1] - cameras_only[0])  # tighter than cameras alone


def test_ply_binary_and_errors(tmp_path: Path) -> None:
    pts = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    header = ('ply\nformat binary_little_endian 1.0\nelement vertex 50\nproperty float x\nproperty float y\n'
              'property float z\nproperty uchar red\nend_header\n').encode()
    body = np.zeros(50, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('r', 'u1')])
    body['x'], body['y'], body['z'] = pts.T
    (tmp_path / 'a.ply').write_bytes(header + body.tobytes())
    assert np.allclose(read_ply_points(tmp_path / 'a.ply'), pts)
    (tmp_path / 'b.ply').write_text('not a ply')
    with pytest.raises(DatasetError, match='b.ply'):
        read_ply_points(tmp_path / 'b.ply')
