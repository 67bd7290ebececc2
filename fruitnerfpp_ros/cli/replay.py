"""``fruitnerfpp replay BAG --out RUN_DIR``: count fruit in a recorded rosbag2 (sqlite3 or MCAP) offline.

Also the ``bag_replay`` executable (``ros2 run fruitnerfpp_ros bag_replay BAG --out RUN_DIR``, see :func:`main`):
the command line calls the replay in ``nodes/bag_replay.py``, never the reverse.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fruitnerfpp_ros.nodes.params import CounterSettings

from fruitnerfpp_ros.core.preset_names import PRESET_CHOICES

__all__ = ['register', 'run', 'settings_from_args', 'main']


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        'replay', help='count fruit in a recorded rosbag2 (sqlite3 or MCAP)',
        description='Read images, instance masks, poses and camera_info from a rosbag2 with rosbags, collect '
                    'keyframes (RUN_DIR/keyframes), train, count, and write RUN_DIR/results.mcap with the '
                    "fruit_counter node's output topics plus RUN_DIR/fruit_report.json.")
    parser.add_argument('bag', type=Path, help='rosbag2 directory, or a single .mcap / .db3 file')
    parser.add_argument('--out', type=Path, required=True, help='run directory to create / fill')
    parser.add_argument('--params', type=Path, help='ROS 2 params file (e.g. config/fruit_counter.yaml): topics, '
                        'pose source, keyframe selection, preset')
    parser.add_argument('--preset', choices=PRESET_CHOICES,
                        help="training preset (overrides the params file; auto = default on CUDA, cpu on the CPU)")
    parser.add_argument('--device', help='torch device: auto, cpu, cuda, cuda:N')
    parser.add_argument('--no-train', action='store_true', help='only collect keyframes')
    parser.add_argument('--skip-training', action='store_true',
                        help='reuse the model already trained in RUN_DIR: re-export and recount only')
    parser.add_argument('--resume', action='store_true',
                        help='continue a replay into RUN_DIR that was killed or stopped: keep its keyframes (an '
                             'interrupted collection continues after the newest), train from the last checkpoint')
    parser.set_defaults(func=run)


def settings_from_args(args: argparse.Namespace) -> CounterSettings:
    """Settings from the params file, with --preset / --device on top."""
    from fruitnerfpp_ros.nodes.params import load_parameter_file, settings_from_parameters

    values = load_parameter_file(args.params) if args.params else {}
    if args.preset:
        values['preset'] = args.preset
    if args.device:
        values['device'] = args.device
    return settings_from_parameters(values)


def run(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.nodes.bag_replay import replay_bag
    settings = settings_from_args(args)
    result = replay_bag(args.bag, args.out, settings, train=not args.no_train, show_progress=True,
                        skip_training=args.skip_training, resume=args.resume)
    print(f'keyframes: {result.n_keyframes} in {result.keyframes_dir}')
    for recovery in result.recoveries:
        print(f'recovered: {recovery.messages} message(s) of the damaged {recovery.path}')
    if result.count is None:
        return 0
    print(f'fruit count: {result.count.count}')
    print(f'point cloud: {result.pipeline.paths.cloud_ply}')
    print(f'report:      {result.report_path}')
    print(f'results:     {result.results_mcap}')
    return 0


def main(argv: list[str] | None = None) -> int:
    """``ros2 run fruitnerfpp_ros bag_replay BAG --out RUN_DIR [...]``: ``fruitnerfpp replay`` with its options.

    ROS arguments that ``ros2 run`` / launch append (``--ros-args ...``) are dropped. Returns the exit code.
    """
    from fruitnerfpp_ros.cli.main import main as cli_main
    args = list(sys.argv[1:] if argv is None else argv)
    if '--ros-args' in args:
        args = args[:args.index('--ros-args')]
    return cli_main(['replay', *args])


if __name__ == '__main__':
    sys.exit(main())
