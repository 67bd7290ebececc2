"""Distorted datasets: undistorted on load, with validity masks that no sampler or metric ever crosses."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.samplers import UniformPixelSampler
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.data.undistortion import LensUndistorter
from fruitnerfpp_ros.errors import DatasetError
from test.core.training.stand_in_scene import make_sphere_scene


def _distort(dataset: Path, coefficients: dict[str, float]) -> Path:
    path = dataset / 'transforms.json'
    data = json.loads(path.read_text())
    data.update(coefficients)
    path.write_text(json.dumps(data))
    return dataset


@pytest.fixture(scope='module')
def distorted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    scene = make_sphere_scene(tmp_path_factory.mktemp('distorted'), views=6, size=48, fruits=6)
    # strong pincushion distortion: the undistorted image's corners map outside the sensor and hold no data
    return _distort(scene, {'k1': 0.45, 'k2': 0.12})


def test_a_strongly_distorted_camera_has_invalid_borders_and_no_fruit_there(distorted: Path) -> None:
    dataset = load_dataset(distorted, eval_every=0)
    assert dataset.valid_masks is not None and dataset.valid_masks.shape == dataset.instance_masks.shape
    valid = dataset.valid_masks
    assert not bool(valid[:, 0, 0].any()) and bool(valid[:, 24, 24].all())  # corners invalid, centre valid
    assert 0.5 < float(valid.float().mean()) < 0.98
    assert not bool(dataset.semantic_masks[~valid].any()) and not bool((dataset.instance_masks[~valid] > 0).any())


def test_no_sampled_ray_comes_from_outside_the_valid_region(distorted: Path) -> None:
    dataset = load_dataset(distorted, eval_every=0)
    sampler = UniformPixelSampler(dataset.train_indices, dataset.height, dataset.width,
                                  fruit_masks=dataset.semantic_masks, fruit_fraction=0.2,
                                  valid_masks=dataset.valid_masks)
    batch = sampler.sample(20000, torch.Generator().manual_seed(0))
    assert len(batch.view) == 20000
    assert bool(dataset.valid_masks[batch.view, batch.row, batch.col].all())


def test_undistortion_moves_a_point_to_its_pinhole_projection() -> None:
    K = np.array([[40.0, 0.0, 31.5], [0.0, 40.0, 23.5], [0.0, 0.0, 1.0]])
    D = np.array([-0.3, 0.05, 0.0, 0.0, 0.0])
    undistorter = LensUndistorter(K, D, 'plumb_bob', (64, 48))
    point = np.array([[0.5, 0.3, 1.0]])                          # a ray in the camera frame (z forward)
    pinhole = (K @ point[0])[:2]
    distorted_px, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), K, D)
    image = np.zeros((48, 64), np.uint8)
    u, v = np.round(distorted_px[0, 0]).astype(int)
    image[v - 1:v + 2, u - 1:u + 2] = 255
    out = undistorter.image(image)
    vs, us = np.nonzero(out > 64)
    assert np.hypot(us.mean() - pinhole[0], vs.mean() - pinhole[1]) < 1.0


def test_a_frame_pixel_mask_marks_pixels_invalid(tmp_path: Path) -> None:
    scene = make_sphere_scene(tmp_path / 'masked', views=4, size=32, fruits=4)
    data = json.loads((scene / 'transforms.json').read_text())
    mask = np.full((32, 32), 255, np.uint8)
    mask[:, :8] = 0
    (scene / 'masks').mkdir()
    cv2.imwrite(str(scene / 'masks' / 'm.png'), mask)
    for frame in data['frames']:
        frame['mask_path'] = 'masks/m.png'
    (scene / 'transforms.json').write_text(json.dumps(data))
    dataset = load_dataset(scene, eval_every=0)
    assert dataset.valid_masks is not None and not bool(dataset.valid_masks[:, :, :8].any())
    assert bool(dataset.valid_masks[:, :, 8:].all())


def test_unknown_camera_models_and_bad_matrices_are_refused(tmp_path: Path) -> None:
    scene = make_sphere_scene(tmp_path / 'fisheye', views=2, size=16, fruits=2)
    data = json.loads((scene / 'transforms.json').read_text())
    data['camera_model'] = 'THIN_PRISM_FISHEYE'
    (scene / 'transforms.json').write_text(json.dumps(data))
    with pytest.raises(DatasetError, match='THIN_PRISM_FISHEYE'):
        load_dataset(scene, require_instances=False)
    with pytest.raises(DatasetError, match='pinhole'):
        LensUndistorter(np.zeros((3, 3)), np.zeros(5), 'plumb_bob', (16, 16))
    assert LensUndistorter.for_intrinsics(CameraIntrinsics(10.0, 10.0, 8.0, 8.0, 16, 16)) is None
