"""``fruitnerfpp demo --out DIR``: synthetic orchard bag -> bag replay on this machine -> count vs ground truth.

What ``make demo`` runs. Steps: generate a small synthetic tree and record it as a rosbag2 (the topics a robot
would record), replay the bag through the same keyframe collector as the live node, train (the ``tiny``
preset: the demo takes minutes), count, and print the count beside the ground truth plus the output paths.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.preset_names import PRESET_CHOICES

__all__ = ['register', 'run', 'render_instance_cloud']


def _median_spacing(xyz: np.ndarray) -> float:
    """Median nearest-neighbour distance of (a sample of) the points; 0 for fewer than two."""
    from scipy.spatial import cKDTree
    if len(xyz) < 2:
        return 0.0
    sample = xyz[np.random.default_rng(0).choice(len(xyz), min(len(xyz), 5000), replace=False)]
    return float(np.median(cKDTree(sample).query(sample, k=2)[0][:, 1]))


def render_instance_cloud(xyz: np.ndarray, labels: np.ndarray, path: str | Path, size: int = 480) -> Path:
    """PNG of a fruit cloud coloured by instance id (grey = noise): front (x-z) and top (x-y) orthographic views.

    Args:
        xyz: [N, 3] points, metres.
        labels: [N] cluster ids (0 = noise).
        path: PNG to write.
        size: height of each view in pixels.
    """
    import cv2
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    labels = np.asarray(labels).reshape(-1)
    palette = np.random.default_rng(7).integers(60, 256, (int(labels.max(initial=0)) + 1, 3), dtype=np.uint8)
    palette[0] = 110
    colours = palette[labels]
    views = []
    spacing = _median_spacing(xyz)
    for axes in ((0, 2), (0, 1)):
        canvas = np.full((size, size, 3), 255, np.uint8)
        if len(xyz):
            pts = xyz[:, axes]
            lo, hi = pts.min(0), pts.max(0)
            scale = (size - 20) / max(float((hi - lo).max()), 1e-6)
            uv = ((pts - lo) * scale + 10).astype(int)
            uv[:, 1] = size - 1 - uv[:, 1]
            order = np.argsort(labels > 0, kind='stable')  # noise first, fruit drawn over it
            uv, bgr = uv[order], colours[order][:, ::-1]
            r = int(np.clip(round(0.45 * spacing * scale), 1, 6))  # dots ~0.45 x the point spacing, 1-6 px
            for dv in range(-r, r + 1):  # square dots about as wide as the point spacing
                for du in range(-r, r + 1):
                    canvas[np.clip(uv[:, 1] + dv, 0, size - 1), np.clip(uv[:, 0] + du, 0, size - 1)] = bgr
        views.append(canvas)
    image = np.concatenate([views[0], np.full((size, 4, 3), 0, np.uint8), views[1]], axis=1)
    cv2.putText(image, 'front (x-z)', (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
    cv2.putText(image, 'top (x-y)', (size + 12, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
    path = Path(path)
    cv2.imwrite(str(path), image)
    return path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        'demo', help='synthetic orchard bag -> replay -> count vs ground truth (a few minutes on a CPU)',
        description='Generate a small synthetic orchard recording (rosbag2), replay it through the fruit '
                    'counter on this machine and compare the count with the ground truth.')
    parser.add_argument('--out', type=Path, required=True, help='output directory (scene/, orchard_bag/, run/)')
    parser.add_argument('--fruit', default='apple', help='fruit type (apple, plum, lemon, pear, peach, mango)')
    parser.add_argument('--count', type=int, default=20, help='fruits on the tree')
    parser.add_argument('--views', type=int, default=48, help='camera views in the drive')
    parser.add_argument('--resolution', type=int, default=96, help='square image size, px')
    parser.add_argument('--trajectory', choices=('hemisphere', 'row'), default='hemisphere')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap', help='rosbag2 storage')
    parser.add_argument('--preset', choices=PRESET_CHOICES, default='tiny',
                        help='training preset (default tiny: the demo takes minutes; auto = default on CUDA, cpu '
                             'on the CPU)')
    parser.add_argument('--device', default='auto', help='torch device: auto, cpu, cuda, cuda:N')
    parser.add_argument('--seed', type=int, default=0)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.core.pipeline import evaluate_run
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
    from fruitnerfpp_ros.nodes.bag_replay import replay_bag
    from fruitnerfpp_ros.nodes.params import settings_from_parameters

    started = time.perf_counter()
    out = Path(args.out)
    if (out / 'run').exists():  # the demo owns its output directory: start from a clean run
        import shutil
        shutil.rmtree(out / 'run')
    config = SynthConfig(fruit=args.fruit, count=args.count, views=args.views,
                         resolution=(args.resolution, args.resolution), trajectory=args.trajectory, seed=args.seed)
    print(f'[1/3] synthetic {args.fruit} tree, {args.views} views at {args.resolution} px, {args.trajectory} '
          f'trajectory -> rosbag2 ({args.storage})', flush=True)
    synth = generate_orchard(config, out / 'scene', bag=out / 'orchard_bag', bag_storage=args.storage)
    print(f'[2/3] replaying {synth.bag_path} (keyframes, training, counting)', flush=True)
    settings = settings_from_parameters({'preset': args.preset, 'device': args.device})
    result = replay_bag(synth.bag_path, out / 'run', settings, show_progress=True)
    print('[3/3] comparing with the ground truth', flush=True)
    metrics = evaluate_run(result.pipeline.paths.counts_json, synth.gt_path, out=out / 'run' / 'eval.json',
                           centers=result.count.centers())
    counted, visible = result.count.count, synth.n_fruits_visible
    error = 100.0 * (counted - visible) / max(visible, 1)
    print()
    print(f'ground truth: {synth.n_fruits} fruits ({visible} seen by the cameras)')
    print(f'counted:      {counted} fruits ({error:+.1f} % vs seen)')
    print(metrics.table())
    print(f'keyframes:    {result.keyframes_dir} ({result.n_keyframes})')
    picture = render_instance_cloud(result.pipeline.cloud.xyz, result.count.labels, out / 'run' / 'instance_cloud.png')
    print(f'point cloud:  {result.pipeline.paths.cloud_ply} (picture: {picture})')
    print(f'report:       {result.report_path}')
    print(f'results:      {result.results_mcap}')
    print(f'time:         {time.perf_counter() - started:.0f} s')
    return 0
