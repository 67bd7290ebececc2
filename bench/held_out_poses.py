#!/usr/bin/env python3
"""The held-out figures of trained runs rendered from the recorded poses and from the poses the run used.

Since session 48 the pose alignment poses the held-out views on the training views' tracks
(core/data/pose_resection.py) and the pass registration moves a return pass's held-out views with it; the
stage-end evaluation renders them from those poses. This script renders the same fields (a finished run's latest
checkpoint) from both pose sets, so that the difference is the poses' alone::

    python bench/held_out_poses.py SUITE_DIR/apple_row_pose_noise/run SUITE_DIR/mango_row_101_b3/run ...

Prints a markdown row per run: held-out PSNR (dB), semantic IoU and instance accuracy from the recorded poses ->
from the run's, and how far the run's poses moved the held-out views (median rotation, translation).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.geometry import rotation_angle_deg
from fruitnerfpp_ros.core.training.metrics import evaluate_views, spread_views
from fruitnerfpp_ros.core.training.trained_scene import load_trained_scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('runs', type=Path, nargs='+', help='finished run directories (RUN/checkpoints)')
    args = parser.parse_args(argv)
    print('| run | held-out views | PSNR (dB) | semantic IoU | instance acc. | moved (deg / cm, median) |')
    print('|---|---:|---|---|---|---|')
    for run in args.runs:
        trained = load_trained_scene(run, device='cpu')
        dataset = load_dataset(trained.dataset_dir, eval_every=trained.config.data.eval_every)
        views = spread_views(dataset.eval_indices, trained.config.eval_max_views)
        recorded = dataset.T_world_camera
        used = trained.poses(recorded).detach().to('cpu', recorded.dtype)
        figures = []
        for poses in (recorded, used):
            posed = dataclasses.replace(dataset, T_world_camera=poses)
            figures.append(evaluate_views(trained.field, trained.occupancy, posed, views, trained.render_settings,
                                          trained.config.render.chunk_rays, max_pixels=trained.config.eval_max_pixels))
        a, b = recorded[views].double().numpy(), used[views].double().numpy()
        turn = float(np.median(rotation_angle_deg(a[:, :3, :3], b[:, :3, :3])))
        shift = 100.0 * float(np.median(np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)))
        before, after = figures
        print(f'| {run} | {len(views)} | {before.psnr:.2f} -> {after.psnr:.2f} | {before.semantic_iou:.3f} -> '
              f'{after.semantic_iou:.3f} | {before.instance_acc:.3f} -> {after.instance_acc:.3f} | '
              f'{turn:.2f} / {shift:.1f} |', flush=True)
    return 0


if __name__ == '__main__':
    torch.set_grad_enabled(False)
    raise SystemExit(main())
