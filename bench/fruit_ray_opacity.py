#!/usr/bin/env python3
"""How opaque a trained field is along the rays of its training views' fruit pixels.

A fruit pixel sees a solid fruit inside the scene box, so its ray's opacity through the box should be 1. Each run
directory given (``fruitnerfpp run`` / ``bench accuracy``'s ``<scene>/run``) is loaded from its checkpoint, up to
``--per-view`` fruit pixels of every training view are drawn (seeded), their rays' opacity through the box rendered
(what stage 1's transparency term sees), and its distribution printed:
mean (1 - opacity)^2 (the training term ``geometry.fruit_opacity_weight`` weighs), the share below 0.5 and 0.9, and
the median. One thread; about a minute per run on the CPU.

Usage::

    python bench/fruit_ray_opacity.py SUITE_DIR/mango_hemi_40/run SUITE_DIR/plum_row_120/run
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.rays import RayBundle, rays_for_pixels
from fruitnerfpp_ros.core.rendering.renderer import render_rays
from fruitnerfpp_ros.core.training import load_trained_scene


def fruit_ray_opacity(run: Path, per_view: int, seed: int) -> np.ndarray:
    """Box opacity [N] of up to ``per_view`` random fruit pixels' rays in every training view of ``run``."""
    scene = load_trained_scene(run, device='cpu')
    dataset = load_dataset(scene.dataset_dir, eval_every=scene.config.data.eval_every)
    poses = scene.poses(dataset.T_world_camera).float()
    generator = torch.Generator().manual_seed(seed)
    views, rows, cols = [], [], []
    for view in dataset.train_indices.tolist():
        pixels = torch.nonzero(dataset.semantic_masks[view])
        pick = pixels[torch.randperm(len(pixels), generator=generator)[:per_view]]
        views.append(torch.full((len(pick),), view))
        rows.append(pick[:, 0])
        cols.append(pick[:, 1])
    rays = rays_for_pixels(poses, dataset.intrinsics.float(), torch.cat(views), torch.cat(rows), torch.cat(cols))
    chunk = scene.config.render.chunk_rays
    opacity = []
    with torch.no_grad():  # the opacity through the box; no colour (nor what lies behind the box) needed
        for start in range(0, len(rays.origins), chunk):
            part = RayBundle(rays.origins[start:start + chunk], rays.directions[start:start + chunk])
            opacity.append(render_rays(scene.field, scene.occupancy, part, scene.render_settings,
                                       colour=False).opacity.float())
    return torch.cat(opacity).numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('runs', type=Path, nargs='+', help='run directories (with checkpoints/)')
    parser.add_argument('--per-view', type=int, default=300, help='fruit pixels drawn per training view')
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print('| run | fruit rays | mean (1 - o)^2 | o < 0.5 | o < 0.9 | median o |')
    print('|---|---:|---:|---:|---:|---:|')
    for run in args.runs:
        o = fruit_ray_opacity(run, args.per_view, args.seed)
        print(f'| {run} | {len(o)} | {np.mean((1 - o) ** 2):.4f} | {np.mean(o < 0.5):.3f} | {np.mean(o < 0.9):.3f} '
              f'| {np.median(o):.3f} |')


if __name__ == '__main__':
    main()
