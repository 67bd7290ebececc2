"""``fruitnerfpp orchard BAG_OR_DATASET --out RUN``: count a whole row per tree, georeferenced, segments on Ray.

Examples::

    fruitnerfpp synth --scene row --trees 5 --count 20 --views 160 --resolution 240 180 --row-standoff 1.2 \\
        --camera-height 0.6 --camera-pitch 0 --gnss --out row5 --bag row5_bag
    fruitnerfpp orchard row5 --out run5 --preset cpu --workers 2          # a dataset, a local Ray with 2 workers
    fruitnerfpp orchard row5_bag --out run5b --params config/fruit_counter.yaml --params config/orchard_row.yaml \
        --trees row5/planting_map.geojson
    fruitnerfpp orchard row5 --out run5c --ray-address ray://head:10001   # a Ray cluster (one GPU per job)

The params file is the node's (topics, pose source, world frame, preset) plus the row parameters (``gnss_topic``,
``datum``, ``segment_length_m``... see ``config/orchard_row.yaml``). Outputs: ``RUN/trees.csv``,
``RUN/trees.geojson``, ``RUN/fruits.geojson``, ``RUN/row_report.json`` and, for a synthetic row, ``RUN/eval_row.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from fruitnerfpp_ros.core.preset_names import PRESET_CHOICES
from fruitnerfpp_ros.errors import ConfigError

__all__ = ['register', 'run', 'make_runner']


def register(subparsers: Any) -> None:
    """Add the ``orchard`` subcommand."""
    parser = subparsers.add_parser(
        'orchard', help='count a whole row per tree (segments, trees, GeoJSON; Ray)',
        description='Cut a row (a transforms.json dataset or a rosbag2) into overlapping segments, train, export and '
                    'count each on its own (Ray tasks, or one after the other without Ray), count every fruit once, '
                    'give each to its tree and write trees.csv, trees.geojson, fruits.geojson and row_report.json.')
    parser.add_argument('source', type=Path,
                        help='transforms.json dataset directory, or a rosbag2 (directory, .mcap or .db3)')
    parser.add_argument('--out', type=Path, required=True, help='run directory')
    parser.add_argument('--params', type=Path, action='append',
                        help="ROS 2 params file(s), read in order: the node's parameters (config/fruit_counter.yaml) "
                             'and the row ones (config/orchard_row.yaml: gnss_topic, datum, segments...)')
    parser.add_argument('--trees', type=Path, help='planting map: CSV (tree_id,x,y or tree_id,latitude,longitude) or '
                        'GeoJSON points of the trunks (default: trees found from the fruit)')
    parser.add_argument('--workers', type=int, default=1, help='segments trained at once on a local Ray (default 1)')
    parser.add_argument('--cpus-per-worker', type=int,
                        help='CPU threads per segment job (default: the CPUs divided by --workers)')
    parser.add_argument('--ray-address', help='address of a running Ray cluster (e.g. ray://head:10001 or auto)')
    parser.add_argument('--no-ray', action='store_true', help='run the segments in this process, one after another')
    parser.add_argument('--preset', choices=PRESET_CHOICES, help='training preset of every segment')
    parser.add_argument('--device', help='torch device of in-process jobs: auto, cpu, cuda, cuda:N')
    parser.add_argument('--config', type=Path, help="YAML with sections 'train', 'export', 'clustering', 'orchard'")
    parser.add_argument('--gt', type=Path, help='ground truth directory (gt_fruits.json + gt_trees.json; default: '
                        'the dataset when it has them)')
    parser.set_defaults(func=run)


def _settings(args: argparse.Namespace) -> tuple[Any, Any, dict[str, Any]]:
    """(counter settings, row settings, the --config file's ``orchard`` section); its train / export / clustering
    sections go to ``RUN/pipeline_config.yaml``, which the segments' pipelines read as the node's config_file."""
    import yaml

    from fruitnerfpp_ros.core.config_io import load_yaml_mapping, pipeline_sections
    from fruitnerfpp_ros.nodes.params import load_parameter_file, settings_from_parameters
    from fruitnerfpp_ros.nodes.row_params import row_settings_from_parameters, split_parameters

    values: dict[str, Any] = {}
    for path in args.params or ():
        values.update(load_parameter_file(path))
    counter, row = split_parameters(values)
    if args.preset:
        counter['preset'] = args.preset
    if args.device:
        counter['device'] = args.device
    orchard: dict[str, Any] = {}
    if args.config:
        data = dict(load_yaml_mapping(args.config, kind='--config'))
        orchard = dict(data.pop('orchard', None) or {})
        sections = pipeline_sections(data, args.config, kind='--config')
        if any(sections.values()):
            args.out.mkdir(parents=True, exist_ok=True)
            resolved = args.out / 'pipeline_config.yaml'
            resolved.write_text(yaml.safe_dump({k: v for k, v in sections.items() if v}, sort_keys=False))
            counter['config_file'] = str(resolved)
    return settings_from_parameters(counter), row_settings_from_parameters(row), orchard


def make_runner(args: argparse.Namespace, log: Any = print) -> tuple[Any, Any]:
    """(runner, ray module or None): a RayRunner on a Ray this command starts (local, ``--workers`` x
    ``--cpus-per-worker`` CPUs and the local GPUs) or joins (``--ray-address``), else the in-process runner."""
    from fruitnerfpp_ros.core.orchard.jobs import InProcessRunner, RayRunner

    if args.no_ray:
        return InProcessRunner(), None
    try:
        import ray
    except ImportError:
        log("ray is not installed (pip install ray, or the package's [scale] extra): the segments run in this "
            'process one after the other')
        return InProcessRunner(), None
    import torch

    from fruitnerfpp_ros.core.device import available_cores
    if args.workers < 1:
        raise ConfigError(f'--workers must be >= 1, got {args.workers}')
    cpus = args.cpus_per_worker or max(1, available_cores() // args.workers)
    if args.ray_address:
        ray.init(address=args.ray_address, log_to_driver=True)
        gpus = 1 if ray.cluster_resources().get('GPU', 0) > 0 else 0
    else:
        n_gpu = torch.cuda.device_count()
        ray.init(num_cpus=args.workers * cpus, num_gpus=n_gpu, include_dashboard=False, log_to_driver=True,
                 configure_logging=False)
        gpus = 1 if n_gpu else 0
    where = args.ray_address or f'a local Ray with {args.workers} worker(s) of {cpus} CPU(s)'
    log(f'segment jobs on {where}' + (', one GPU per job' if gpus else ', CPU workers'))
    return RayRunner(ray, num_cpus=0 if gpus else cpus, num_gpus=gpus), ray


def run(args: argparse.Namespace) -> int:
    """Run ``orchard`` from parsed arguments; returns the exit code."""
    from fruitnerfpp_ros.cli.orchard_source import prepare_source
    from fruitnerfpp_ros.core.device import use_cpu_threads
    from fruitnerfpp_ros.core.orchard.row_run import run_row
    from fruitnerfpp_ros.nodes.params import pipeline_configs
    from fruitnerfpp_ros.nodes.row_params import orchard_config

    settings, row, orchard_section = _settings(args)
    configs = pipeline_configs(settings)
    for note in configs.notes:
        print(f'[INFO] {note}')
    orchard = orchard_config(row, orchard_section)
    source = prepare_source(args.source, args.out, settings, row)
    planting_map = args.trees or (Path(row.planting_map) if row.planting_map else None)
    from tqdm import tqdm

    runner, ray = make_runner(args)
    if ray is None:
        use_cpu_threads(configs.train.cpu_threads, settings.device)  # this process owns its threads
    bar = tqdm(desc='orchard', unit='segment', total=0)

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    try:
        result = run_row(source.dataset_dir, args.out, runner, config=orchard, train_config=configs.train,
                         export_config=configs.export, cluster_config=configs.cluster,
                         device=settings.device if ray is None else 'auto', planting_map=planting_map,
                         fixes=source.fixes, antenna_in_camera_m=source.antenna, frame_id=settings.world_frame,
                         extra={'keyframes': source.n_keyframes, 'preset': configs.preset, 'source': str(args.source)},
                         log=tqdm.write, progress=progress)
    finally:
        bar.close()
        if ray is not None:
            ray.shutdown()
    _print_result(result)
    gt_dir = args.gt or (source.dataset_dir if (source.dataset_dir / 'gt_trees.json').is_file() else None)
    if gt_dir is not None:
        _evaluate(gt_dir, result, args.out)
    return 0 if any(o.ok for o in result.outcomes) else 1


def _print_result(result: Any) -> None:
    failed = [o for o in result.outcomes if not o.ok]
    print(f'fruits: {len(result.fruits)} on {len(result.trees)} tree(s) ({result.trees.source}); '
          f'{int(result.fruits.matched.sum())} counted by two segments kept once')
    for t in result.tree_counts:
        print(f'  tree {t.id:>3}: {t.count:>4} fruits  at {t.along_m:6.2f} m  diameter {100 * t.diameter_mean_m:.1f} '
              f'+- {100 * t.diameter_std_m:.1f} cm')
    for o in failed:
        print(f'  segment {o.index} not counted: {o.error}')
    if result.georef is not None:
        g = result.georef
        residual = '' if g.residual_rms_m is None else f', residual {g.residual_rms_m:.3f} m'
        print(f'georeferencing: {g.source}{residual}')
    for name, path in sorted(result.paths.items()):
        print(f'{name:<15} {path}')


def _evaluate(gt_dir: Path, result: Any, out: Path) -> None:
    import numpy as np

    from fruitnerfpp_ros.core.orchard.evaluation import evaluate_row, row_eval_table
    from fruitnerfpp_ros.core.orchard.report import write_json

    evaluation = evaluate_row(gt_dir, result.fruits.centers, result.fruits.segments, result.fruit_trees,
                              result.trees.ids, result.trees.positions,
                              np.array([t.count for t in result.tree_counts]), result.paths.get('trees_geojson'))
    write_json(out / 'eval_row.json', evaluation)
    print(row_eval_table(evaluation))
