"""Issue #11: how far the pose refinement undoes odometry noise, without counting (geometry stage only).

Trains the first stage (density + colour + pose corrections) on a dataset with noisy poses, then projects the
ground-truth fruit centres into every training view with the exact poses and with the refined ones: the median /
90th percentile distance in pixels is what the masks of two views disagree by (a fruit is 5-10 px across in the
suite's 240x180 rows). The clean twin is the same scene generated without ``--pose-noise`` (the noise has its own
random stream, so images and fruit are identical)::

    fruitnerfpp synth --fruit apple --count 60 --views 64 --resolution 240 180 --trajectory row --sparse-points 0 \\
        --seed 111 --pose-noise 0.02 1.0 --out noisy
    fruitnerfpp synth ... (the same without --pose-noise) --out clean
    python bench/pose_refinement.py --dataset noisy --clean clean --out pr_run --preset cpu [--config over.yaml]

A run on the clean twin itself (``--dataset clean --clean clean``) measures the drift the refinement adds to exact
poses. Prints one line per pose set (the training views', and the held-out views': those the alignment posed on
the training views' tracks, core/data/pose_resection.py) and writes ``OUT/pose_errors.json``.
"""

from __future__ import annotations

import argparse
import json
import threading
from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.config_io import load_yaml_mapping, replace_nested
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.pose_errors import pose_errors
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.core.training import RunDir, TrainConfig, train
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement


def _clean_views(clean_dir: Path, file_paths: list[str]) -> tuple[np.ndarray, list[CameraIntrinsics]]:
    """The exact poses [V, 4, 4] and intrinsics of ``file_paths``, from the clean twin's transforms.json."""
    transforms = read_transforms(clean_dir)
    by_name = {f.file_path: f for f in transforms.frames}
    frames = [by_name[p] for p in file_paths]
    return np.stack([f.T_world_camera for f in frames]), [f.intrinsics or transforms.intrinsics for f in frames]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True, help='dataset with the recorded (noisy) poses')
    parser.add_argument('--clean', type=Path, required=True, help='the same scene with exact poses')
    parser.add_argument('--out', type=Path, required=True, help='fresh run directory')
    parser.add_argument('--preset', default='cpu')
    parser.add_argument('--config', type=Path, help="YAML of TrainConfig overrides (the 'train' section's keys)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    config = TrainConfig.preset(args.preset)
    if args.config is not None:
        config = replace_nested(config, load_yaml_mapping(args.config))
    stop = threading.Event()

    def stop_in_semantic(event: ProgressEvent) -> None:  # the poses are (nearly) final after stage 1
        if event.phase == 'train:semantic':
            stop.set()

    train(args.dataset, args.out, config, device='cpu', progress=stop_in_semantic, stop_event=stop)
    dataset = load_dataset(args.dataset, eval_every=config.data.eval_every)
    recorded = dataset.T_world_camera.double().numpy()
    poses = load_checkpoint(RunDir(args.out).latest_checkpoint)['poses']
    if poses is None:
        refined = recorded
        trained = np.asarray(dataset.train_indices)
    else:
        refinement = PoseRefinement(poses['trained'])
        refinement.load_state_dict(poses)
        refined = refinement(dataset.T_world_camera.float()).detach().double().numpy()
        trained = np.flatnonzero(poses['trained'].numpy())
    truth, cameras = _clean_views(args.clean, list(dataset.file_paths))
    X = load_ground_truth(args.dataset / 'gt_fruits.json').centers
    held = np.setdiff1d(np.arange(len(recorded)), trained)
    report = {f'{kind}{name}': pose_errors(T[views], truth[views], [cameras[i] for i in views], X)
              for kind, views in (('', trained), ('held-out ', held)) if len(views)
              for name, T in (('recorded', recorded), ('refined', refined))}
    for name, e in report.items():
        print(f"{name:18s} rotation {e['rotation_deg_median']:.2f} deg, position {e['position_m_median']:.3f} m, "
              f"fruit reprojection {e['reprojection_px_median']:.1f} px median, {e['reprojection_px_p90']:.1f} p90")
    (args.out / 'pose_errors.json').write_text(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
