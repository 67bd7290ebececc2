"""Experiment: a visibility-weighted export (rejected; kept to reproduce docs/results/tiny_preset.md).

Instead of raw density, a voxel counts as surface when some training ray gives it a render weight >= W
(weights are scale-free: W = 0.4 means "this voxel makes 40 % of that pixel's colour"). Voxels that pass W and
fruit probability >= 0.9 are clustered and scored like `fruitnerfpp count` + `eval`.

Usage: [VOXEL=0.01] python bench/visibility_export_experiment.py RUN_DIR DATASET_DIR W [W ...]
"""

from __future__ import annotations

import os
import sys

import numpy as np
import torch

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.rays import rays_for_pixels
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.volume import render_weights
from fruitnerfpp_ros.core.training import TrainedScene, load_trained_scene


def max_training_weight(scene: TrainedScene, data: str, voxel: float,
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(largest render weight per voxel [X*Y*Z], voxels per axis [3], box corner [3]) over all training rays."""
    dataset = load_dataset(data)
    aabb = torch.as_tensor(scene.aabb, dtype=torch.float32)
    res = torch.ceil((aabb[1] - aabb[0]) / voxel).long()
    best = torch.zeros(int(res.prod()))
    height, width = dataset.images.shape[1:3]
    rows, cols = torch.meshgrid(torch.arange(height), torch.arange(width), indexing='ij')
    for view in dataset.train_indices.tolist():
        rays = rays_for_pixels(dataset.T_world_camera, dataset.intrinsics, torch.full((height * width,), view),
                               rows.reshape(-1), cols.reshape(-1))
        with torch.no_grad():
            samples = march_rays(rays, scene.occupancy, scene.march_step, near=scene.config.render.near)
            weights = render_weights(samples, scene.field.geometry(samples.positions).density)
        ijk = torch.minimum(((samples.positions - aabb[0]) / voxel).long().clamp(min=0), res - 1)
        best.scatter_reduce_(0, (ijk[:, 0] * res[1] + ijk[:, 1]) * res[2] + ijk[:, 2], weights, reduce='amax')
    return best, res, aabb[0]


def main() -> None:
    torch.set_num_threads(1)
    run, data, thresholds = sys.argv[1], sys.argv[2], [float(a) for a in sys.argv[3:]]
    voxel = float(os.environ.get('VOXEL', '0.01'))
    scene = load_trained_scene(run, 'cpu')
    best, res, corner = max_training_weight(scene, data, voxel)
    seen = torch.nonzero(best > 0).squeeze(1)
    print('grid', res.tolist(), 'voxels with weight', len(seen))
    ijk = torch.stack([seen // (res[1] * res[2]), (seen // res[2]) % res[1], seen % res[2]], 1)
    centres = corner + (ijk.float() + 0.5) * voxel
    query = scene.field.query(centres)
    gt = load_ground_truth(f'{data}/gt_fruits.json')
    for threshold in thresholds:
        keep = (best[seen] >= threshold) & (query.fruit_prob >= 0.9)
        cloud = FruitPointCloud(centres[keep].numpy().astype(np.float32),
                                (query.rgb[keep].numpy() * 255).astype(np.uint8),
                                query.fruit_prob[keep].numpy().astype(np.float32),
                                query.embedding[keep].numpy().astype(np.float32), spacing_m=voxel)
        result = count_fruits(cloud, ClusterConfig(n_jobs=1))
        m = evaluate_counts(result.centers(), gt)
        print(f'W >= {threshold}: points {len(cloud)}  count {result.count}  precision {m.precision:.3f}  '
              f'recall {m.recall:.3f}  F1 {m.f1:.3f}')


if __name__ == '__main__':
    main()
