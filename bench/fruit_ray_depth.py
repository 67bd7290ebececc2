#!/usr/bin/env python3
"""Where the rays through a fruit's mask pixels end in a trained field: on the fruit, in front of it, or behind.

A fruit the count misses with "no points" (``bench/miss_kinds.py``) has no exported surface near its centre. This
script asks the trained field why: every training-view pixel of a seen fruit's instance mask (the synthetic masks
label a fruit by its ground-truth id; a scene with a segmenter's mask errors keeps the ids of the masks it kept) is
rendered from the run's poses, and its ray's median termination depth is compared with the camera's distance to
the fruit's centre: **front** more than one radius in front of the fruit's near surface, **on** within it,
**behind** beyond the centre plus a radius. Printed per scene for the matched and the missed fruits: the rays, and
the shares of front / on / behind, and the share of front rays whose rendered fruit probability is >= 0.5 (the
semantic head paints the fruit on whatever the ray ends on: a front termination labelled fruit is a fruit exported
at the wrong depth), and against the fruit masks' visual hull (``core/data/fruit_hull.py``, rendered from the
run's poses): the share of the rays that meet it, and of those the share whose termination lies more than
``HULL_MARGIN`` diameters in front of it (where session 49's rejected free-space term, commit ``0ef1f3c``, acted)::

    python bench/fruit_ray_depth.py SUITE_DIR/pear_row_30_b1 SUITE_DIR/mango_row_101_b3 ...

Session 48 (docs/results/accuracy_suite.md): on three rows the missed fruits' rays end in front 70-88 % of the
time, the matched fruits' 26-51 %. Session 49: on plum_row_120 and pear_row_far the missed fruits' rays meet the
hull 49-69 % of the time, and most of those end in front of it; a training term that empties that space
(rejected) did not bring those fruits back.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.benchmark.scene_run import scored_ground_truth
from fruitnerfpp_ros.core.data.dataset import SceneDataset, load_dataset
from fruitnerfpp_ros.core.data.fruit_hull import hull_depths
from fruitnerfpp_ros.core.data.rays import rays_for_pixels
from fruitnerfpp_ros.core.data.scene_scale import fruit_votes
from fruitnerfpp_ros.core.rendering.renderer import render_rays
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.scene_box import camera_box
from fruitnerfpp_ros.core.training.trained_scene import load_trained_scene

HULL_MARGIN = 0.5
"""How far in front of the hull's first voxel (fruit diameters) a ray's termination still counts as behind it."""


def hull_depth_images(config: TrainConfig, dataset: SceneDataset, poses: torch.Tensor) -> torch.Tensor:
    """[V, H, W]: the depth along the optical axis at which each training-view pixel's ray meets the fruit masks'
    visual hull (the scene measurement's vote from ``poses``: its fruit voxels and those placed by views spread
    wide); inf where it meets none, and on held-out views."""
    posed = dataclasses.replace(dataset, T_world_camera=poses)
    out = torch.full((dataset.num_views, dataset.height, dataset.width), math.inf)
    votes = fruit_votes(posed, camera_box(posed, config), config.scale)
    if votes is not None:
        out[dataset.train_indices] = hull_depths(posed, votes.votes.centres[votes.held], votes.votes.voxel,
                                                 dataset.train_indices)
    return out


def fruit_ray_depths(scene_dir: Path) -> dict[str, np.ndarray]:
    """Per kind ('matched', 'missed'): [F, 7] per seen fruit: rays, front, on, behind shares, front-fruit share,
    the share of its rays meeting the hull, and of those the share ending in front of the hull's bound."""
    data, run = scene_dir / 'data', scene_dir / 'run'
    trained = load_trained_scene(run, device='cpu')
    dataset = load_dataset(data, eval_every=trained.config.data.eval_every)
    gt = scored_ground_truth(data / 'gt_fruits.json', data, run, trained.config.data.eval_every)
    matched = np.zeros(len(gt.ids), bool)
    for _, g in json.loads((run / 'eval.json').read_text())['hungarian']['pairs']:
        matched[g] = True
    poses = trained.poses(dataset.T_world_camera).float()
    train = dataset.train_indices
    hull = hull_depth_images(trained.config, dataset, poses)
    margin = HULL_MARGIN * trained.scale.fruit_diameter_m
    out: dict[str, list] = {'matched': [], 'missed': []}
    for g in np.flatnonzero(gt.n_views_visible != 0):
        view, row, col = torch.nonzero(dataset.instance_masks[train] == int(gt.ids[g]), as_tuple=True)
        if len(view) == 0:
            continue
        view = train[view]
        rays = rays_for_pixels(poses, dataset.intrinsics, view, row, col)
        rendered = render_rays(trained.field, trained.occupancy, rays, trained.render_settings, semantic=True,
                               depth=True)
        radius = float(gt.diameters[g]) / 2.0
        distance = np.linalg.norm(poses[view][:, :3, 3].numpy() - np.asarray(gt.centers[g]), axis=1)
        depth = rendered.depth.numpy()
        front, behind = depth < distance - 2.0 * radius, depth > distance + radius
        fruit = rendered.fruit_prob.numpy() >= 0.5 * rendered.opacity.numpy()
        K = dataset.intrinsics[view]
        stretch = torch.sqrt(1 + ((col + 0.5 - K[:, 2]) / K[:, 0]) ** 2 + ((row + 0.5 - K[:, 3]) / K[:, 1]) ** 2)
        bound = (hull[view, row, col] * stretch).numpy()
        meets = np.isfinite(bound)
        out['matched' if matched[g] else 'missed'].append(
            (len(view), front.mean(), (~front & ~behind).mean(), behind.mean(),
             fruit[front].mean() if front.any() else np.nan, meets.mean(),
             (depth[meets] < bound[meets] - margin).mean() if meets.any() else np.nan))
    return {kind: np.asarray(rows, np.float64).reshape(-1, 7) for kind, rows in out.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('scenes', type=Path, nargs='+', help='suite scene directories (SCENE/data, SCENE/run)')
    args = parser.parse_args(argv)
    print('| scene | fruits | rays a fruit | front | on | behind | front rays labelled fruit | meet the hull | '
          'in front of it |')
    print('|---|---|---:|---:|---:|---:|---:|---:|---:|')
    for scene in args.scenes:
        for kind, rows in fruit_ray_depths(scene).items():
            if len(rows):
                mean = np.nanmean(rows, axis=0)
                print(f'| {scene.name} | {len(rows)} {kind} | {mean[0]:.0f} | {mean[1]:.2f} | {mean[2]:.2f} | '
                      f'{mean[3]:.2f} | {mean[4]:.2f} | {mean[5]:.2f} | {mean[6]:.2f} |', flush=True)
    return 0


if __name__ == '__main__':
    torch.set_grad_enabled(False)
    raise SystemExit(main())
