#!/usr/bin/env python3
"""The pose alignment's time and accuracy on noisy twins of synthetic scenes (no training).

Each scene is generated twice from one seed: with odometry noise (``pose_noise_m`` / ``pose_noise_deg``) and
without (the true poses). The alignment (``core/data/pose_alignment.py``) runs on the noisy one; the ground-truth
fruit centres are projected into every view with the recorded, the aligned and the true poses, and the median /
90th percentile of the distance to the true projection (px) is reported with the alignment's wall time (SIFT,
matching, bundle adjustment). The twins are kept in ``--root`` and reused.

Usage::

    python bench/pose_alignment_bench.py --root /tmp/twins [--scenes row48,row64_suite,plum56_320,hemi48]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignmentConfig, align_poses
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.pose_errors import pose_errors
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.core.training.pose_start import corrected_poses

NOISE = dict(pose_noise_m=0.02, pose_noise_deg=1.0)
#: name -> the synth settings of the noisy twin (row48: test_pose_alignment's scene; row64_suite: the cpu suite's
#: apple_row_pose_noise)
SCENES = {
    'row48': dict(fruit='apple', count=30, views=48, resolution=(240, 180), trajectory='row', seed=111,
                  sparse_points=0, **NOISE),
    'row64_suite': dict(fruit='apple', count=60, views=64, resolution=(240, 180), trajectory='row', seed=111, **NOISE),
    'plum56_320': dict(fruit='plum', count=60, views=56, resolution=(320, 240), trajectory='row', seed=5,
                       pose_noise_m=0.03, pose_noise_deg=1.5),
    'hemi48': dict(fruit='apple', count=40, views=48, resolution=(160, 160), trajectory='hemisphere', seed=9, **NOISE),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--root', type=Path, required=True, help='where the twins are generated (and reused)')
    parser.add_argument('--scenes', default=','.join(SCENES), help='comma-separated names of SCENES')
    args = parser.parse_args()
    print('| scene | tracks | alignment s | fruit px recorded (median / p90) | aligned |')
    print('|---|---:|---:|---|---|')
    for name in args.scenes.split(','):
        settings = SCENES[name]
        noisy, clean = args.root / name / 'noisy', args.root / name / 'clean'
        if not (noisy / 'transforms.json').is_file():
            generate_orchard(SynthConfig(**settings), noisy)
            generate_orchard(SynthConfig(**{k: v for k, v in settings.items() if not k.startswith('pose_noise')}),
                             clean)
        data = load_dataset(noisy, eval_every=0)
        T = data.T_world_camera.double().numpy()
        truth = load_dataset(clean, eval_every=0).T_world_camera.double().numpy()
        transforms = read_transforms(noisy)
        cameras = [frame.intrinsics or transforms.intrinsics for frame in transforms.frames]
        centres = np.asarray(load_ground_truth(noisy / 'gt_fruits.json').centers)
        start = time.perf_counter()
        result = align_poses((data.images.numpy() * 255).round().astype(np.uint8), data.intrinsics.double().numpy(),
                             T, PoseAlignmentConfig(enabled=True))
        seconds = time.perf_counter() - start
        before = pose_errors(T, truth, cameras, centres)
        after = pose_errors(corrected_poses(data, result.correction).double().numpy(), truth, cameras, centres)
        print(f"| {name} | {result.report['tracks']} | {seconds:.1f} | {before['reprojection_px_median']:.3f} / "
              f"{before['reprojection_px_p90']:.3f} | {after['reprojection_px_median']:.3f} / "
              f"{after['reprojection_px_p90']:.3f} |", flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
