"""The fruit masks' visual hull along every pixel's ray: a lower bound on where a fruit pixel's fruit is."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.data.bounds import aabb_from_cameras
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.fruit_hull import hull_depths
from fruitnerfpp_ros.core.data.scene_scale import fruit_votes
from test.core.training.stand_in_scene import make_sphere_scene


def _fruit_distances(dataset, centres: np.ndarray, radii: np.ndarray, view: int) -> np.ndarray:  # noqa: ANN001
    """[H, W] distance along each pixel's unit ray to the nearest fruit sphere (inf where none)."""
    T = dataset.T_world_camera[view].double().numpy()
    fx, fy, cx, cy = dataset.intrinsics[view].double().numpy()
    v, u = np.meshgrid(np.arange(dataset.height), np.arange(dataset.width), indexing='ij')
    d = np.stack([(u + 0.5 - cx) / fx, -(v + 0.5 - cy) / fy, -np.ones(u.shape)], -1).reshape(-1, 3) @ T[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    oc = T[:3, 3][None] - centres
    b = d @ oc.T
    disc = b ** 2 - ((oc ** 2).sum(-1) - radii ** 2)[None]
    t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    return np.where(t > 0, t, np.inf).min(1).reshape(dataset.height, dataset.width)


def test_a_fruit_pixel_meets_the_hull_in_front_of_its_fruit_and_close_to_it(tmp_path: Path) -> None:
    """Every fruit pixel's ray meets the hull no later than its fruit's surface (the bound never empties a fruit),
    half of them within two fruit diameters of it (the bound says something; 64 px views of a 3.2 m hemisphere
    carve a hull a few centimetres wide of each sphere); rays past every fruit mostly meet none."""
    scene = make_sphere_scene(tmp_path / 's', views=20, size=64, fruits=8)
    dataset = load_dataset(scene, eval_every=0)
    box = aabb_from_cameras(dataset.T_world_camera.numpy(), dataset.intrinsics.numpy(), dataset.width,
                            dataset.height, min_view_fraction=0.1)
    votes = fruit_votes(dataset, box)
    assert votes is not None
    views = dataset.train_indices
    depth = hull_depths(dataset, votes.votes.centres[votes.held], votes.votes.voxel, views)
    spheres = np.load(scene / 'spheres.npz')
    fruit = spheres['is_fruit']
    centres, radii = spheres['centres'][fruit], spheres['radii'][fruit]
    gaps, far_met = [], []
    for i, view in enumerate(views.tolist()):
        K = dataset.intrinsics[view].numpy()
        v, u = np.meshgrid(np.arange(dataset.height), np.arange(dataset.width), indexing='ij')
        stretch = np.sqrt(1 + ((u + 0.5 - K[2]) / K[0]) ** 2 + ((v + 0.5 - K[3]) / K[1]) ** 2)
        hull = depth[i].numpy() * stretch
        truth = _fruit_distances(dataset, centres, radii, view)
        on_fruit = dataset.semantic_masks[view].numpy()
        gaps.append(truth[on_fruit] - hull[on_fruit])
        far_met.append(np.isfinite(hull[~np.isfinite(truth)]))
    gap = np.concatenate(gaps)
    diameter = 2 * float(radii.mean())
    assert np.isfinite(gap).mean() > 0.9                          # the hull holds the fruit the masks show
    met = gap[np.isfinite(gap)]
    assert (met >= -0.5 * votes.votes.voxel).mean() > 0.99        # never behind the fruit's surface
    assert np.median(met) < 2 * diameter                          # ... nor far in front of it
    assert np.concatenate(far_met).mean() < 0.25                  # rays that pass every fruit mostly meet none


def test_an_empty_hull_leaves_every_ray_unbounded(tmp_path: Path) -> None:
    dataset = load_dataset(make_sphere_scene(tmp_path / 's', views=4, size=32, fruits=2), eval_every=0)
    depth = hull_depths(dataset, torch.zeros(0, 3), 0.02, dataset.train_indices)
    assert depth.shape == (4, 32, 32) and bool(torch.isinf(depth).all())
