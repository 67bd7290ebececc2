"""Experiment: a visibility-weighted export (not part of the package yet).

Instead of raw density, a 1 cm voxel counts as surface when some training ray gives it a render weight >= W
(weights are scale-free: W = 0.4 means "this voxel makes 40 % of that pixel's colour"). Voxels that pass W and
fruit probability >= 0.9 are clustered and scored like `fruitnerfpp count` + `eval`.

Usage: [VOXEL=0.01] python bench/visibility_export_experiment.py RUN_DIR DATASET_DIR W [W ...]
Findings: docs/results/tiny_preset.md.
"""
import os
import sys

import numpy as np
import torch

torch.set_num_threads(1)
from fruitnerfpp_ros.core.training import load_trained_scene
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.rays import rays_for_pixels
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.volume import render_weights
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
run, data = sys.argv[1], sys.argv[2]
s = load_trained_scene(run, 'cpu'); ds = load_dataset(data)
f = s.field; aabb = torch.as_tensor(s.aabb, dtype=torch.float32)
diag = float((aabb[1]-aabb[0]).norm()); step = s.config.render.step_size(diag)
vox = float(os.environ.get('VOXEL', '0.01')); res = torch.ceil((aabb[1]-aabb[0])/vox).long(); print('grid', res.tolist())
maxw = torch.zeros(int(res.prod()))
V, H, W = ds.images.shape[:3]
for v in ds.train_indices.tolist():
    rr, cc = torch.meshgrid(torch.arange(H), torch.arange(W), indexing='ij')
    view = torch.full((H*W,), v)
    rays = rays_for_pixels(ds.T_world_camera, ds.intrinsics, view, rr.reshape(-1), cc.reshape(-1))
    with torch.no_grad():
        smp = march_rays(rays, s.occupancy, step, near=s.config.render.near)
        w = render_weights(smp, f.geometry(smp.positions).density)
    idx3 = ((smp.positions - aabb[0]) / vox).long().clamp(min=0)
    idx3 = torch.minimum(idx3, res-1)
    lin = (idx3[:,0]*res[1]+idx3[:,1])*res[2]+idx3[:,2]
    maxw.scatter_reduce_(0, lin, w, reduce='amax')
occ = torch.nonzero(maxw > 0).squeeze(1)
print('voxels with weight', len(occ))
zi = occ % res[2]; yi = (occ // res[2]) % res[1]; xi = occ // (res[1]*res[2])
centres = aabb[0] + (torch.stack([xi, yi, zi], 1).float() + 0.5) * vox
q = f.query(centres)
gt = load_ground_truth(f'{data}/gt_fruits.json')
for wt in [float(a) for a in sys.argv[3:]]:
    keep = (maxw[occ] >= wt) & (q.fruit_prob >= 0.9)
    cloud = FruitPointCloud(centres[keep].numpy().astype(np.float32), (q.rgb[keep].numpy()*255).astype(np.uint8),
                            q.fruit_prob[keep].numpy().astype(np.float32), q.embedding[keep].numpy().astype(np.float32),
                            spacing_m=vox)
    res_ = count_fruits(cloud, ClusterConfig(n_jobs=1))
    m = evaluate_counts(res_.centers(), gt)
    print(f'W >= {wt}: points {len(cloud)}  count {res_.count}  precision {m.precision:.3f}  '
          f'recall {m.recall:.3f}  F1 {m.f1:.3f}')
