"""Train the three stages on a dataset and print per-stage wall-clock and held-out figures.

Usage::

    python bench/train_bench.py DATASET_DIR RUN_DIR [--preset tiny] [--device cpu]
    python bench/train_bench.py --synthetic RUN_DIR        # generates the 24-view 96 px apple scene first
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from fruitnerfpp_ros.core.training import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('dataset', nargs='?', help='transforms.json dataset directory')
    parser.add_argument('run_dir', help='output run directory (replaced)')
    parser.add_argument('--synthetic', action='store_true', help='generate the tiny apple scene first')
    parser.add_argument('--preset', default='tiny')
    parser.add_argument('--device', default='auto')
    args = parser.parse_args()
    dataset = args.dataset
    if args.synthetic or dataset is None:
        from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
        dataset = tempfile.mkdtemp(prefix='tiny_apple_')
        generate_orchard(SynthConfig(fruit='apple', count=20, views=24, resolution=(96, 96),
                                     trajectory='hemisphere', seed=0), Path(dataset))
    shutil.rmtree(args.run_dir, ignore_errors=True)
    started = time.perf_counter()
    summary = train(dataset, args.run_dir, TrainConfig.preset(args.preset), device=args.device)
    total = time.perf_counter() - started
    print(f'device {summary.device}  total wall-clock {total:.1f} s (incl. loading and evaluation)')
    for stage in summary.stages:
        print(f'{stage.name:9s} steps {stage.steps:6d}  train {stage.wall_s:7.1f} s  '
              f'eval psnr {stage.eval.psnr:6.2f} dB  semantic IoU {stage.eval.semantic_iou:.3f}  '
              f'instance acc {stage.eval.instance_acc:.3f}')


if __name__ == '__main__':
    main()
