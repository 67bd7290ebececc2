"""``fruitnerfpp track DATA_DIR --out counts.json``: the tracking-by-detection peer counter (issue #11).

Tracks the dataset's instance masks from frame to frame (pose-driven 3D motion model, mask-IoU + Mahalanobis
association, Hungarian) and counts one fruit per confirmed track; the counts.json it writes is scored by
``fruitnerfpp eval`` like the pipeline's. No training, CPU only, seconds per scene. Example::

    fruitnerfpp track synth_apple --out synth_apple/track_counts.json --max-age 8
    fruitnerfpp eval synth_apple/track_counts.json --gt synth_apple/gt_fruits.json
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

__all__ = ['register', 'run']


def register(subparsers: Any) -> None:
    """Add the ``track`` subcommand."""
    parser = subparsers.add_parser(
        'track', help='count fruits by tracking instance masks from frame to frame (baseline)',
        description='Multi-object tracking of the instance masks of a transforms.json dataset (frames in time '
                    'order, 3D motion model from the poses, Hungarian association by mask IoU then distance); '
                    'one fruit per track with enough detections. Writes counts.json.')
    parser.add_argument('data_dir', type=Path, help='transforms.json dataset with instance masks')
    parser.add_argument('--out', type=Path, required=True, help='counts.json to write')
    parser.add_argument('--config', type=Path, help='YAML with TrackConfig fields')
    parser.add_argument('--max-age', type=int, help='frames a track survives unmatched (default 8)')
    parser.add_argument('--min-hits', type=int, help='detections a track needs to be counted (default 3)')
    parser.add_argument('--fruit-diameter', type=float, help='prior fruit diameter in metres (default 0.075)')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``track`` from parsed arguments; returns the exit code."""
    from fruitnerfpp_ros.core.config_io import load_config
    from fruitnerfpp_ros.core.tracking import TrackConfig, track_dataset, write_track_counts

    config = load_config(TrackConfig, args.config) if args.config is not None else TrackConfig()
    overrides = {name: value for name, value in (('max_age', args.max_age), ('min_hits', args.min_hits),
                                                 ('fruit_diameter_m', args.fruit_diameter)) if value is not None}
    if overrides:
        config = dataclasses.replace(config, **overrides)
    result = track_dataset(args.data_dir, config)
    out = write_track_counts(args.out, result, config, source=str(args.data_dir))
    print(f'fruits: {result.count} ({result.n_tracks} tracks over {result.n_frames} frames, '
          f'{result.stats["seconds"]:.2f} s) -> {out}')
    gt_path = args.data_dir / 'gt_fruits.json'
    if gt_path.is_file():
        from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
        from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts

        print(evaluate_counts(result.centers(), load_ground_truth(gt_path)).table())
    return 0
