"""``fruitnerfpp bench accuracy``: the accuracy suites of issue #11 (synthetic scenes with ground truth).

Example::

    fruitnerfpp bench accuracy --suite quick --out bench_quick --jobs 2
    fruitnerfpp bench accuracy --suite cpu --out bench_cpu --masks fallback --scenes apple_bag_odom,plum_row_120
    fruitnerfpp bench accuracy --suite gpu --out bench_gpu --device cuda --log docs/results/accuracy_suite.md

Each scene is generated under ``OUT/<scene>/data``, counted by the pipeline under ``OUT/<scene>/run`` (a bag
scene: written as a rosbag2 and counted by the bag replay, as ``fruitnerfpp replay`` does) and by the tracking
peer, scored against its ground truth and drawn as ``OUT/<scene>/count.png``. ``OUT/accuracy.json`` and
``OUT/accuracy.md`` hold the tables; ``--log FILE`` appends the run as a section of a running log. The suites
are defined in ``core/benchmark/suites.py``.
"""

from __future__ import annotations

import argparse
import shlex
import time
from pathlib import Path
from typing import Any

from fruitnerfpp_ros.core.benchmark.report import append_log_section, summary_lines
from fruitnerfpp_ros.core.benchmark.result import SceneResult
from fruitnerfpp_ros.core.benchmark.runner import ACCURACY_JSON, ACCURACY_MD, MASK_SOURCES, SuiteOptions, run_suite
from fruitnerfpp_ros.core.benchmark.scene_run import BagReplayOutcome, BagReplayRequest
from fruitnerfpp_ros.core.benchmark.suites import SUITE_NAMES, SUITES, suite_scenes
from fruitnerfpp_ros.core.preset_names import PRESET_NAMES

__all__ = ['register', 'run_accuracy', 'replay_scene_bag', 'scene_line', 'command_line']


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand (with its ``accuracy`` benchmark)."""
    parser = subparsers.add_parser('bench', help='benchmarks: the accuracy suites of synthetic scenes',
                                   description=__doc__.split('\n\n')[0])
    benches = parser.add_subparsers(dest='bench', metavar='BENCHMARK', required=True)
    acc = benches.add_parser(
        'accuracy', help='count every scene of a suite with the pipeline and the tracking peer, against ground truth',
        description='Generate each scene of the suite (with ground truth), count it with the pipeline (bag scenes: '
                    'through a rosbag2 and the bag replay) and with the tracking peer, score both, and write '
                    'OUT/accuracy.json, OUT/accuracy.md and OUT/<scene>/count.png. A failed scene is reported and '
                    'the suite goes on (exit code 1 when any failed).')
    acc.add_argument('--suite', choices=SUITE_NAMES, required=True,
                     help='; '.join(f'{s.name}: {len(s.scenes)} scenes, {s.description}' for s in SUITES.values()))
    acc.add_argument('--out', type=Path, required=True, help='output directory (OUT/<scene>/ is replaced)')
    acc.add_argument('--preset', choices=PRESET_NAMES, help="training preset (default: the suite's: tiny for smoke, "
                     'default for gpu, cpu for the others)')
    acc.add_argument('--masks', choices=MASK_SOURCES, default='gt',
                     help="instance masks of both counters: gt (the dataset's), fallback (the built-in segmenter's, "
                          'as `fruitnerfpp segment`; bag replay: mask_source fallback) or semantic (blobs of the '
                          'fruit masks, as `fruitnerfpp segment --method semantic`; bag replay: mask_source '
                          "semantic_topic) or noisy (the scene's masks degraded as a learned segmenter's: 15 %% "
                          'missed, 0.1 false detections per fruit, boundaries a pixel off)')
    acc.add_argument('--jobs', type=int, default=1, help='scenes run at once, one process each (default 1)')
    acc.add_argument('--scenes', metavar='NAME,NAME', help='run only these scenes of the suite')
    acc.add_argument('--draw', type=int, metavar='SEED',
                     help='blind suite only: eight other scenes drawn from this seed (names ..._dSEED_i), to check a '
                          'change again on scenes nobody has looked at')
    acc.add_argument('--config', type=Path, metavar='FILE.yaml',
                     help='pipeline YAML with optional sections train / export / clustering (as `fruitnerfpp run '
                          '--config`), applied on top of the preset')
    acc.add_argument('--device', default='auto', help='torch device: auto, cpu, cuda, cuda:N (default auto)')
    acc.add_argument('--log', type=Path, metavar='FILE.md', help='append the run as a section of this running log')
    acc.set_defaults(func=run_accuracy)


def command_line(args: argparse.Namespace, preset: str) -> str:
    """The ``fruitnerfpp bench accuracy`` command equivalent to ``args`` (every option spelled out)."""
    words = ['fruitnerfpp', 'bench', 'accuracy', '--suite', args.suite, '--out', str(args.out), '--preset', preset,
             '--masks', args.masks, '--jobs', str(args.jobs), '--device', args.device]
    if args.scenes:
        words += ['--scenes', args.scenes]
    if args.draw is not None:
        words += ['--draw', str(args.draw)]
    if args.config:
        words += ['--config', str(args.config)]
    return ' '.join(shlex.quote(w) for w in words)


def scene_line(result: SceneResult) -> str:
    """One line for a finished scene: our count and F1 beside the peer's, its time, or its error."""
    seconds = result.times_s.get('total', float('nan'))
    parts = [f'{result.name}:']
    if result.ours is not None:
        parts.append(f'count {result.ours.count}/{result.gt_count} F1 {result.ours.f1:.3f}')
    if result.peer is not None:
        parts.append(f'(peer {result.peer.count}, F1 {result.peer.f1:.3f})')
    parts.append(f'{seconds:.0f} s')
    if result.error:
        parts.append(f'FAILED: {result.error}')
    return ' '.join(parts)


def replay_scene_bag(request: BagReplayRequest) -> BagReplayOutcome:
    """``fruitnerfpp replay BAG --out RUN_DIR`` with the scene's parameters (runs in the scene's process).

    The ROS layer is imported here, in the command line, never by the core.
    """
    from fruitnerfpp_ros.nodes.bag_replay import replay_bag
    from fruitnerfpp_ros.nodes.params import settings_from_parameters

    settings = settings_from_parameters(request.parameters)
    started = time.perf_counter()
    first_event: list[float] = []

    def on_progress(event: Any) -> None:
        if not first_event:
            first_event.append(time.perf_counter() - started)

    result = replay_bag(request.bag_path, request.run_dir, settings, progress=on_progress)
    return BagReplayOutcome(result.keyframes_dir, result.pipeline,
                            first_event[0] if first_event else time.perf_counter() - started)


def _configs(preset: str, config_file: Path | None) -> tuple[Any, Any, Any]:
    """(TrainConfig, ExportConfig, ClusterConfig) as ``fruitnerfpp run --preset P --config FILE`` resolves them."""
    from fruitnerfpp_ros.cli.results import load_section
    from fruitnerfpp_ros.cli.train import resolve_train_config
    from fruitnerfpp_ros.core.clustering.config import ClusterConfig
    from fruitnerfpp_ros.core.export.config import ExportConfig

    return (resolve_train_config(preset, config_file, section='train'),
            load_section(ExportConfig, config_file, 'export'), load_section(ClusterConfig, config_file, 'clustering'))


def run_accuracy(args: argparse.Namespace) -> int:
    """Run ``bench accuracy`` from parsed arguments; returns 0, or 1 when a scene failed."""
    from tqdm import tqdm

    from fruitnerfpp_ros.core.device import resolve_device

    scenes = suite_scenes(args.suite, args.scenes, draw=args.draw)
    preset = args.preset or SUITES[args.suite].preset
    resolve_device(args.device)  # an unknown or missing device fails here, not in every scene
    train, export, cluster = _configs(preset, args.config)
    options = SuiteOptions(preset, train, export, cluster, masks=args.masks, device=args.device, jobs=args.jobs,
                           config_file=str(args.config.resolve()) if args.config else '')
    print(f'{args.suite} suite: {len(scenes)} scene(s), preset {preset}, masks {args.masks}, device {args.device}, '
          f'{args.jobs} at once -> {args.out}', flush=True)
    with tqdm(total=len(scenes), desc=f'bench {args.suite}', unit='scene') as bar:
        def done(result: SceneResult) -> None:
            bar.write(scene_line(result))
            bar.update(1)

        suite = run_suite(args.suite, scenes, args.out, options, bag_runner=replay_scene_bag, on_scene_done=done,
                          command=command_line(args, preset))
    print('\n'.join(summary_lines(suite)).replace('**', ''))
    print(f'tables: {args.out / ACCURACY_MD}, {args.out / ACCURACY_JSON}')
    if args.log:
        print(f'log:    {append_log_section(args.log, suite)}')
    return 1 if suite.failed else 0
