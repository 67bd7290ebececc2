"""``fruitnerfpp synth``: generate a synthetic orchard tree (transforms.json dataset, ground truth, optional bag).

Example::

    fruitnerfpp synth --fruit apple --count 30 --views 32 --resolution 128 --out synth_apple \\
        --bag synth_apple_bag --preview synth_apple/preview.png
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.errors import ConfigError, SynthError

__all__ = ['register', 'run', 'parse_resolution']


def parse_resolution(text: str) -> tuple[int, int]:
    """``'128'`` -> (128, 128); ``'160x120'`` -> (160, 120) (width x height).

    Raises:
        SynthError: not a size.
    """
    parts = text.lower().split('x')
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2:
        raise SynthError(f'--resolution: expected a size like 128 or 160x120, got {text!r}')
    return values[0], values[1]


def _int(text: str | None, flag: str) -> int | None:
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        raise SynthError(f'{flag}: expected an integer, got {text!r}') from None


def register(subparsers: Any) -> None:
    """Add the ``synth`` subcommand."""
    parser = subparsers.add_parser(
        'synth', help='generate a synthetic fruit tree with ground truth',
        description='Render a procedural fruit tree to a transforms.json dataset (RGB, instance and semantic '
                    'masks), gt_fruits.json and sparse_pc.ply; optionally a rosbag2 recording and a preview.')
    parser.add_argument('--fruit', help='apple, plum, lemon, pear, peach, mango or mixed (default apple)')
    parser.add_argument('--count', help="number of fruits (default: the type's paper count, e.g. apple 283)")
    parser.add_argument('--views', help='number of camera views (default 32)')
    parser.add_argument('--resolution', help='image size: 128 (square) or WxH like 160x120 (default 128)')
    parser.add_argument('--trajectory', help='hemisphere (default) or row')
    parser.add_argument('--seed', help='random seed (default 0)')
    parser.add_argument('--device', help='auto (default), cpu or cuda')
    parser.add_argument('--pose-noise', nargs=2, metavar=('METRES', 'DEGREES'),
                        help='odometry error: per-axis standard deviations of noise on the recorded camera positions '
                             'and orientations (images stay rendered from the true poses)')
    parser.add_argument('--out', required=True, help='output dataset directory')
    parser.add_argument('--bag', help='also write a rosbag2 directory here')
    parser.add_argument('--bag-storage', default='mcap', help='mcap (default) or sqlite3')
    parser.add_argument('--preview', help='write a contact sheet PNG (RGB | instance | semantic)')
    parser.add_argument('--config', help='YAML file with SynthConfig defaults (e.g. config/synth.yaml)')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``synth`` from parsed arguments; returns the exit code."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    if args.config is not None:
        try:
            base = load_config(SynthConfig, args.config)
        except ConfigError as err:
            raise SynthError(str(err)) from err
    else:
        base = SynthConfig()
    overrides: dict[str, Any] = {}
    if args.fruit is not None:
        overrides['fruit'] = args.fruit
    if args.count is not None:
        overrides['count'] = _int(args.count, '--count')
    if args.views is not None:
        overrides['views'] = _int(args.views, '--views')
    if args.resolution is not None:
        overrides['resolution'] = parse_resolution(args.resolution)
    if args.trajectory is not None:
        overrides['trajectory'] = args.trajectory
    if args.seed is not None:
        overrides['seed'] = _int(args.seed, '--seed')
    if args.device is not None:
        overrides['device'] = args.device
    if args.pose_noise is not None:
        try:
            overrides['pose_noise_m'], overrides['pose_noise_deg'] = (float(v) for v in args.pose_noise)
        except ValueError:
            raise SynthError(f'--pose-noise: expected two numbers (metres, degrees), got {args.pose_noise}') from None
    config = dataclasses.replace(base, **overrides)

    bar: Any = None

    def on_progress(event: ProgressEvent) -> None:
        nonlocal bar
        if args.quiet:
            return
        if bar is None:  # created on the first event, so input errors print one line only
            from tqdm import tqdm
            bar = tqdm(total=event.total, desc='synth', unit='view')
        bar.n = event.step
        if event.message:
            bar.set_postfix_str(event.message, refresh=False)
        bar.refresh()

    try:
        result = generate_orchard(config, Path(args.out), bag=args.bag, bag_storage=args.bag_storage,
                                  preview=args.preview, progress=on_progress)
    finally:
        if bar is not None:
            bar.close()
    print(f'wrote {result.n_views} views of {result.n_fruits} fruits ({result.n_fruits_visible} visible) to '
          f'{result.dataset_dir} in {result.seconds:.1f} s'
          + (f'; bag {result.bag_path}' if result.bag_path else '')
          + (f'; preview {result.preview_path}' if result.preview_path else ''))
    return 0
