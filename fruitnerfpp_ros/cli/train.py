"""``fruitnerfpp train``: cascaded FruitNeRF++ training of a transforms.json dataset into a run directory."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fruitnerfpp_ros.core.config_io import load_pipeline_sections, load_yaml_mapping, replace_nested
from fruitnerfpp_ros.core.preset_names import AUTO, PRESET_CHOICES
from fruitnerfpp_ros.errors import ConfigError

if TYPE_CHECKING:  # torch is imported only by the commands that train (``fruitnerfpp --help`` stays fast)
    from fruitnerfpp_ros.core.training import TrainConfig

__all__ = ['register', 'run', 'resolve_preset', 'resolve_train_config']


def resolve_preset(name: str, device: str) -> str:
    """The preset ``name`` stands for on ``device`` (``core.device.device_preset``); the CPU's note for ``auto``
    goes to stderr, as the node logs it."""
    from fruitnerfpp_ros.core.device import device_preset
    preset, note = device_preset(name, device)
    if note:
        print(f'note: {note}', file=sys.stderr)
    return preset


def resolve_train_config(preset: str, config_file: str | Path | None, *, section: str | None = None
                         ) -> TrainConfig:
    """The preset, with the values of an optional YAML file (full or partial TrainConfig) applied on top.

    ``section``: the file is a pipeline file (``fruitnerfpp run --config``: sections train / export /
    clustering, read by :func:`load_pipeline_sections`) and the TrainConfig values are under this key.

    Raises:
        ConfigError: unknown preset, unreadable YAML or unknown key (naming the file).
    """
    from fruitnerfpp_ros.core.training import TrainConfig

    config = TrainConfig.preset(preset)
    if config_file is None:
        return config
    path = Path(config_file)
    data = load_yaml_mapping(path) if section is None else load_pipeline_sections(path)[section]
    try:
        return replace_nested(config, data)
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err


def run(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.core.device import use_cpu_threads
    from fruitnerfpp_ros.core.training import train
    from fruitnerfpp_ros.core.training.pose_start import pose_start_lines

    config = resolve_train_config(resolve_preset(args.preset, args.device), args.config)
    use_cpu_threads(config.cpu_threads, args.device)
    summary = train(args.dataset, args.out, config, device=args.device, resume=args.resume, show_progress=True)
    for stage in summary.stages:
        print(f'{stage.name:9s} {stage.steps:6d} steps  {stage.wall_s:7.1f} s  '
              f'held-out PSNR {stage.eval.psnr:6.2f} dB  semantic IoU {stage.eval.semantic_iou:.3f}  '
              f'instance acc {stage.eval.instance_acc:.3f}')
    for line in pose_start_lines(summary.run_dir):
        print(line)
    stopped = '  (stopped early; continue with --resume)' if summary.stopped else ''
    print(f'run directory: {summary.run_dir}{stopped}')
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser('train', help='train the FruitNeRF++ fields on a transforms.json dataset',
                                   description=__doc__)
    parser.add_argument('dataset', metavar='DATA_DIR', help='dataset directory holding transforms.json')
    parser.add_argument('--out', required=True, metavar='RUN_DIR', help='run directory (config, checkpoints, metrics)')
    parser.add_argument('--preset', default=AUTO, choices=PRESET_CHOICES,
                        help='hyper-parameter preset: tiny (CPU tests), cpu (a real tree on a CPU), default (GPU), '
                             'paper (long schedule); auto (the default): default on CUDA, cpu on the CPU')
    parser.add_argument('--device', default='auto', help='auto, cpu or cuda[:N] (default: auto)')
    parser.add_argument('--resume', action='store_true', help='continue from RUN_DIR/checkpoints/latest.pt')
    parser.add_argument('--config', metavar='FILE.yaml', help='YAML with TrainConfig values overriding the preset')
    parser.set_defaults(func=run)
