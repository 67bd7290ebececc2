"""Depth images in datasets: the keyframe store writes them with their unit, the loader reads, checks and undistorts
them, and the cross-view check tells real depth from garbage."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.depth_check import check_depth_views
from fruitnerfpp_ros.core.data.depth_image import depth_units_from_metres
from fruitnerfpp_ros.core.data.keyframe_store import Keyframe, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, read_transforms
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.errors import DatasetError

INTR = CameraIntrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)


def _depth_kf(x: float, stamp: int) -> Keyframe:
    rng = np.random.default_rng(stamp)
    depth = rng.uniform(0.5, 4.0, (24, 32)).astype(np.float32)
    depth[0, :4] = 0.0          # no return
    depth[1, 0] = np.nan        # no return (32FC1 drivers)
    T = np.eye(4)
    T[0, 3] = x
    return Keyframe(stamp, rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), np.zeros((24, 32), np.uint16), T,
                    INTR, depth=depth)


def test_depth_units() -> None:
    units = depth_units_from_metres(np.array([0.0, np.nan, -1.0, 1.2344, 65.535, 70.0, np.inf]))
    assert units.dtype == np.uint16 and units.tolist() == [0, 0, 0, 1234, 65535, 0, 0]


def test_depth_keyframe_round_trips_through_the_store_with_its_unit(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf')
    frames = [_depth_kf(float(i), i) for i in range(3)]
    for kf in frames:
        store.offer(kf)
    store.offer(frames[0]._replace(stamp_ns=7, T_world_optical=np.diag([1.0, 1, 1, 1]) + np.eye(4, k=3) * 9,
                                   depth=None))  # a frame without depth (a silent depth topic)
    raw = json.loads((tmp_path / 'kf' / 'transforms.json').read_text())
    assert raw['depth_unit_scale_factor'] == 0.001
    assert [f.get('depth_file_path') for f in raw['frames']] == [f'depths/{i:06d}.png' for i in range(3)] + [None]
    png = cv2.imread(str(tmp_path / 'kf' / 'depths' / '000001.png'), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png[0, 0] == 0
    for directory in (tmp_path / 'kf', store.snapshot(tmp_path / 'snap').dataset_dir):
        data = load_dataset(directory, eval_every=0)
        assert data.depths is not None and data.depths.shape == (4, 24, 32)
        for i, kf in enumerate(frames):
            expected = np.nan_to_num(kf.depth)
            np.testing.assert_allclose(data.depths[i].numpy(), expected, atol=5e-4)
        assert not data.depths[3].any()
    # A kill between two index writes: the journal alone brings the depth back.
    (tmp_path / 'kf' / 'transforms.json').unlink()
    assert [f.depth_path for f in KeyframeStore(tmp_path / 'kf').frames][:3] == \
        [f'depths/{i:06d}.png' for i in range(3)]


def test_store_refuses_depth_of_another_size(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf')
    with pytest.raises(DatasetError, match='depth is 16x12 but the image is 32x24'):
        store.offer(_depth_kf(0.0, 0)._replace(depth=np.ones((12, 16), np.float32)))
    assert len(store) == 0


@pytest.fixture(scope='module')
def rgbd_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('rgbd')
    generate_orchard(SynthConfig(count=6, views=12, resolution=(40, 32), depth='exact', sparse_points=0), out)
    return out


def test_loader_reads_unit_and_refuses_misaligned_depth(rgbd_scene: Path, tmp_path: Path) -> None:
    exact = load_dataset(rgbd_scene, eval_every=0).depths
    assert exact is not None and float(exact.max()) <= 6.0 and float((exact > 0).float().mean()) > 0.3
    data = json.loads((rgbd_scene / 'transforms.json').read_text())
    # The same depths in 0.1 mm steps, said so by depth_unit_scale_factor; one frame as a float TIFF in metres.
    (tmp_path / 'd').mkdir()
    for i, frame in enumerate(data['frames']):
        mm = cv2.imread(str(rgbd_scene / frame['depth_file_path']), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(tmp_path / 'd' / f'{i}.png'), np.round(mm * 10).clip(0, 65535).astype(np.uint16))
        frame['depth_file_path'] = str(tmp_path / 'd' / f'{i}.png')
        frame['file_path'] = str(rgbd_scene / frame['file_path'])
        frame['instance_path'] = str(rgbd_scene / frame['instance_path'])
        frame['semantic_path'] = str(rgbd_scene / frame['semantic_path'])
    data['depth_unit_scale_factor'] = 1e-4
    (tmp_path / 'transforms.json').write_text(json.dumps(data))
    assert read_transforms(tmp_path).depth_unit_m == 1e-4
    torch.testing.assert_close(load_dataset(tmp_path, eval_every=0).depths, exact)
    # A depth image of another size is refused, naming it and the image.
    cv2.imwrite(str(tmp_path / 'd' / '3.png'), np.ones((16, 20), np.uint16))
    with pytest.raises(DatasetError, match=r'3\.png: depth image is 20x16 but image .* is 40x32'):
        load_dataset(tmp_path)
    cv2.imwrite(str(tmp_path / 'd' / '3.png'), np.ones((32, 40, 3), np.uint8))
    with pytest.raises(DatasetError, match='3-channel uint8; expected one channel'):
        load_dataset(tmp_path)
    data['depth_unit_scale_factor'] = -1
    (tmp_path / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match='depth_unit_scale_factor must be a positive number'):
        read_transforms(tmp_path)


def test_distorted_depth_is_undistorted_nearest(tmp_path: Path) -> None:
    generate_orchard(SynthConfig(count=6, views=4, resolution=(40, 32), depth='exact', sparse_points=0,
                                 distortion=(0.25, 0.05, 0.0, 0.0, 0.0)), tmp_path)
    data = load_dataset(tmp_path, eval_every=0)
    assert data.valid_masks is not None and data.depths is not None
    assert not data.depths[~data.valid_masks].any()  # the border holds no depth
    for view, frame in enumerate(read_transforms(tmp_path).frames):
        raw = cv2.imread(str(tmp_path / frame.depth_path), cv2.IMREAD_UNCHANGED).astype(np.float32) * 1e-3
        loaded = data.depths[view].numpy()
        # nearest-neighbour remap: every depth is one the sensor measured, never a blend across an edge
        assert np.isin(loaded[loaded > 0], raw[raw > 0]).all()
        assert (loaded > 0).sum() > 0.5 * (raw > 0).sum()


def test_cross_view_check_keeps_real_and_drops_garbage_depth(rgbd_scene: Path) -> None:
    data = load_dataset(rgbd_scene, eval_every=0)
    assert data.depths is not None
    sigma = lambda z: 0.004 + 0.0025 * z * z  # noqa: E731
    real = check_depth_views(data.depths, data.T_world_camera, data.intrinsics, sigma)
    assert real.used.all() and float(np.nanmin(real.agreement)) > 0.8, real.summary()
    garbage = data.depths.clone()
    rng = torch.Generator().manual_seed(0)
    garbage[9:] = torch.where(garbage[9:] > 0, 0.2 + 5.8 * torch.rand(garbage[9:].shape, generator=rng), 0.0)
    check = check_depth_views(garbage, data.T_world_camera, data.intrinsics, sigma)
    assert check.rejected_views == [9, 10, 11], check.summary()  # a few broken views lose their depth
    assert 'trained without the depth of views 9, 10, 11' in check.summary()
    garbage = torch.where(data.depths > 0, 0.2 + 5.8 * torch.rand(data.depths.shape, generator=rng), 0.0)
    check = check_depth_views(garbage, data.T_world_camera, data.intrinsics, sigma)
    assert not check.used.any(), check.summary()  # a broken sensor loses all of it
