"""``fruitnerfpp export | count | eval | run``: from a trained run (or a dataset) to a scored fruit count.

- ``export RUN_DIR [--out cloud.ply]``: sample the trained field into a fruit point cloud (+ .npz, export.json).
- ``count RUN_DIR|cloud.ply [--out counts.json]``: cluster the cloud into fruits.
- ``eval counts.json --gt gt_fruits.json [--json] [--picture out.png [--dataset DATA_DIR]]``: precision / recall /
  F1 (Hungarian and greedy matching), optionally drawn.
- ``run DATA_DIR --out RUN_DIR [--preset auto]``: train -> export -> count (-> eval), then a result table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, TypeVar

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.config_io import (config_from_mapping, is_sectioned, load_yaml_mapping,
                                            pipeline_sections, replace_nested)
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.preset_names import AUTO, PRESET_CHOICES
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['register', 'load_section']

T = TypeVar('T')


def load_section(cls: type[T], path: Path | None, section: str) -> T:
    """``cls`` from a YAML file that is either that config's fields or a pipeline file holding it under
    ``section`` (strict: see :func:`load_pipeline_sections`)."""
    if path is None:
        return cls()
    data = load_yaml_mapping(path)
    if is_sectioned(data):
        data = pipeline_sections(data, path)[section]
    try:
        return config_from_mapping(cls, data)
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err


def _overrides(config: T, **values: Any) -> T:
    chosen = {k: v for k, v in values.items() if v is not None}
    return replace_nested(config, chosen) if chosen else config


def _export_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--density-threshold', type=float, help='minimum density in 1/m (default: the run\'s '
                        'surface density ln2/step)')
    parser.add_argument('--fruit-threshold', type=float, help='minimum fruit probability (default 0.9)')
    parser.add_argument('--grid-points', type=int,
                        help="grid samples over the scene box (default: a voxel of the run's ray-marching step)")
    parser.add_argument('--voxel-size', type=float, help='grid spacing in metres (overrides --grid-points)')


def _cluster_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--lambda-e', type=float, help='weight of the Euclidean term, 1/m')
    parser.add_argument('--metric', choices=('summed', 'concatenated'), help='clustering metric')
    parser.add_argument('--jobs', type=int, help='worker processes for the partitions')


def _export_config(args: argparse.Namespace, path: Path | None) -> ExportConfig:
    return _overrides(load_section(ExportConfig, path, 'export'), density_threshold=args.density_threshold,
                      fruit_threshold=args.fruit_threshold, grid_points=args.grid_points,
                      voxel_size_m=args.voxel_size)


def _cluster_config(args: argparse.Namespace, path: Path | None) -> ClusterConfig:
    return _overrides(load_section(ClusterConfig, path, 'clustering'), lambda_e=args.lambda_e, metric=args.metric,
                      n_jobs=args.jobs)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser('export', help='export the fruit point cloud of a trained run',
                              description='Sample the trained field on a grid over the scene box; keep points '
                                          'passing the density and fruit-probability thresholds.')
    p.add_argument('run_dir', type=Path, help='training run directory')
    p.add_argument('--out', type=Path, help='output .ply (default RUN_DIR/cloud.ply; a .npz is written beside)')
    p.add_argument('--dataset', type=Path, help='the dataset the run trained on, where it was moved (default: the '
                   'one its checkpoint names, or found beside the run)')
    p.add_argument('--config', type=Path, help='export YAML (e.g. config/export.yaml)')
    p.add_argument('--device', default='auto', help='auto, cpu, cuda, cuda:N')
    _export_args(p)
    p.set_defaults(func=_run_export)

    p = subparsers.add_parser('count', help='cluster a fruit point cloud into fruits',
                              description='k-means partitions + HDBSCAN with the summed embedding/Euclidean metric.')
    p.add_argument('source', type=Path, help='run directory (its cloud.npz / cloud.ply) or a .ply / .npz cloud')
    p.add_argument('--out', type=Path, help='counts.json path (default: next to the cloud)')
    p.add_argument('--config', type=Path, help='clustering YAML (e.g. config/clustering.yaml)')
    p.add_argument('--dataset', type=Path, help="a run directory's dataset, where it was moved: its training views' "
                   'masks check the count (default: the one its checkpoint names, or found beside the run)')
    _cluster_args(p)
    p.set_defaults(func=_run_count)

    p = subparsers.add_parser('eval', help='score a counts.json against gt_fruits.json',
                              description='One-to-one matching within one GT fruit diameter: Hungarian (headline) '
                                          "and the paper's greedy nearest-unmatched.")
    p.add_argument('counts', type=Path, help='run directory (its counts.json) or a counts.json')
    p.add_argument('--gt', type=Path, help="gt_fruits.json or the directory holding it (default: the one beside "
                   "the run's dataset)")
    p.add_argument('--json', action='store_true', help='print one JSON object (count, gt_count, precision, '
                   'recall, f1, ...)')
    p.add_argument('--out', type=Path, help='also write the metrics to this eval.json')
    p.add_argument('--tolerance', type=float, default=1.0, help='match reach in GT diameters (default 1)')
    p.add_argument('--include-unseen', action='store_true',
                   help="count GT fruits seen by no training view in the recall (excluded by default; the run's "
                        'dataset, or --dataset, tells which views trained)')
    p.add_argument('--picture', type=Path, help='also draw hits / misses / false counts to this PNG (top view)')
    p.add_argument('--dataset', type=Path, help="the dataset the count came from (default: the run's): its training "
                   'views decide which fruits were seen; with --picture, its view seeing most fruits is drawn')
    p.set_defaults(func=_run_eval)

    p = subparsers.add_parser('run', help='train -> export -> count (-> eval) on a dataset',
                              description='The whole pipeline on a transforms.json dataset; evaluates when the '
                                          'dataset has gt_fruits.json.')
    p.add_argument('data_dir', type=Path, help='transforms.json dataset directory')
    p.add_argument('--out', type=Path, required=True, help='run directory')
    p.add_argument('--preset', default=AUTO, choices=PRESET_CHOICES,
                   help='training preset (default auto: default on CUDA, cpu on the CPU)')
    p.add_argument('--device', default='auto', help='auto, cpu, cuda, cuda:N')
    p.add_argument('--config', type=Path, help='YAML with optional sections train / export / clustering')
    p.add_argument('--resume', action='store_true', help='continue training from RUN_DIR')
    p.add_argument('--skip-training', action='store_true', help='reuse the trained RUN_DIR as is')
    _export_args(p)
    _cluster_args(p)
    p.set_defaults(func=_run_pipeline)


def _run_export(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.core.pipeline import export_run

    result = export_run(args.run_dir, _export_config(args, args.config), device=args.device, out=args.out,
                        dataset_dir=args.dataset)
    out = args.out or args.run_dir / 'cloud.ply'
    print(result.report.explain())
    print(f'{len(result.cloud)} fruit points -> {out} (+ {Path(out).with_suffix(".npz").name})')
    return 0


def _run_count(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.core.clustering.workers import partition_pool
    from fruitnerfpp_ros.core.pipeline import count_run

    config = _cluster_config(args, args.config)
    with partition_pool(config.n_jobs) as pool:
        count, cloud, counts_path = count_run(args.source, config, out=args.out, executor=pool,
                                              dataset_dir=args.dataset)
    print(f'fruits: {count.count} (from {len(cloud)} points, {int((count.labels == 0).sum())} noise) -> '
          f'{counts_path}')
    return 0


def _run_eval(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.core.evaluation.run_inputs import run_eval_inputs
    from fruitnerfpp_ros.core.pipeline import evaluate_run

    inputs = run_eval_inputs(args.counts, args.gt, args.dataset)
    metrics = evaluate_run(inputs.counts_json, inputs.gt_json, out=args.out, tolerance=args.tolerance,
                           exclude_unseen=not args.include_unseen, train_views=inputs.train_views)
    print(json.dumps(metrics.to_json()) if args.json else metrics.table())
    if args.picture is not None:
        from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, load_predicted_centers
        from fruitnerfpp_ros.core.evaluation.picture import write_count_picture

        write_count_picture(args.picture, inputs.dataset_dir, load_predicted_centers(inputs.counts_json),
                            load_ground_truth(inputs.gt_json), metrics)
    return 0


def _run_pipeline(args: argparse.Namespace) -> int:
    from fruitnerfpp_ros.cli.train import resolve_preset, resolve_train_config
    from fruitnerfpp_ros.core.clustering.workers import partition_pool
    from fruitnerfpp_ros.core.pipeline import run_pipeline
    from fruitnerfpp_ros.core.training.pose_start import pose_start_lines

    from fruitnerfpp_ros.core.device import use_cpu_threads

    if args.resume:  # a kill or a full disk may have cut the last metrics line: resume reads the log again
        from fruitnerfpp_ros.core.atomic_io import trim_torn_line
        trim_torn_line(Path(args.out) / 'metrics.jsonl')
    train_config = resolve_train_config(resolve_preset(args.preset, args.device), args.config, section='train')
    use_cpu_threads(train_config.cpu_threads, args.device)
    cluster_config = _cluster_config(args, args.config)
    with partition_pool(cluster_config.n_jobs) as pool:
        result = run_pipeline(args.data_dir, args.out, train_config=train_config,
                              export_config=_export_config(args, args.config), cluster_config=cluster_config,
                              device=args.device, show_progress=True, resume=args.resume,
                              skip_training=args.skip_training, executor=pool)
    if result.stopped:
        print(f'stopped early; resume with: fruitnerfpp run {args.data_dir} --out {args.out} --resume')
        return 1
    for line in pose_start_lines(args.out):
        print(line)
    print(result.table())
    return 0
