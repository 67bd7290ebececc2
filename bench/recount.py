#!/usr/bin/env python3
"""Re-count finished runs with other clustering (or export) settings, on the same trained fields, and score them.

Export and clustering are the cheap end of the pipeline: trying a rule on the fields a suite or a row already
trained costs seconds per scene instead of a new training. A variant's keys are ClusterConfig fields, or
ExportConfig fields prefixed with ``export.`` (the cloud is then exported again from the run's checkpoint, into
OUT/clouds, e.g. ``--variant views3=export.min_views:3``), or MaskFruitConfig fields prefixed with ``masks.`` (the
fruit the training views' masks add to the clusters, as the pipeline counts: ``--variant nomasks=masks.enabled:0``).
The runs are read, never rewritten. A cloud exported before 2026-12-05 (session 27) lacks its points' viewing
directions, so the count cannot move its points to their fruits' centres: give such variants an export key
(``export.min_views:2``, the default, exports it again).

- A suite directory (``fruitnerfpp bench accuracy --out DIR``): every ``DIR/<scene>/run/cloud.npz`` is counted with
  each variant and scored as the suite scores it (Hungarian, one GT diameter, fruits no training view saw left
  out); writes ``OUT/recount.md`` and ``OUT/recount.json`` (F1 per scene and variant, the means). The variant
  ``base`` (the settings given, no overrides) reproduces the suite's own figures.
- An orchard row (``fruitnerfpp orchard ... --out RUN``) with ``--row-copy COPY``: each segment's cloud is counted
  with the one variant given, and COPY gets the row's layout with the segments' ``result.json`` rewritten, so that
  ``fruitnerfpp orchard DATASET --out COPY ...`` merges and reports the row again without training.

With ``--mask-noise DROPPED,FALSE`` every variant is counted against masks with that share of fruit missed and of
false detections added (``bench/mask_noise.py``); the training keeps its own masks.

Usage::

    python bench/recount.py SUITE_DIR... --out OUT --variant agree=merge_agreeing_m:0.1,merge_agreeing_cos:0.9
    python bench/recount.py RUN --row-copy RUN_AGREE --variant agree=merge_agreeing_m:0.1
    python bench/recount.py SUITE_DIR... --out OUT --mask-noise 0,0.1 --variant before=masks.chance_draws:0
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib.util
import json
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from fruitnerfpp_ros.cli.results import load_section
from fruitnerfpp_ros.core.benchmark.scene_run import scored_ground_truth
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import CountResult
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.export.config import ExportConfig
from fruitnerfpp_ros.core.export.npz_io import read_cloud
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.core.orchard.jobs import read_segment_result, segment_fruits, write_segment_result
from fruitnerfpp_ros.core.pipeline import RunViews, count_with_views, load_run_views
from fruitnerfpp_ros.core.training import TrainConfig


def _variant(text: str) -> tuple[str, dict[str, int | float | str]]:
    """``name=key:value,key:value`` -> (name, overrides)."""
    name, _, body = text.partition('=')
    overrides: dict[str, int | float | str] = {}
    for item in filter(None, body.split(',')):
        key, _, value = item.partition(':')
        for kind in (int, float, str):
            try:
                overrides[key] = kind(value)
                break
            except ValueError:
                continue
    return name, overrides


class Variant(NamedTuple):
    """A clustering config and the export overrides (none: the run's own cloud)."""

    cluster: ClusterConfig
    export: tuple[tuple[str, int | float | str], ...] = ()


def _variants(base: ClusterConfig, texts: list[str]) -> dict[str, Variant]:
    out = {'base': Variant(base)}
    for name, overrides in map(_variant, texts):
        export = tuple(sorted((k.removeprefix('export.'), v) for k, v in overrides.items() if k.startswith('export.')))
        masks = {k: type(getattr(base.masks, k))(v) for k, v in
                 ((k.removeprefix('masks.'), v) for k, v in overrides.items() if k.startswith('masks.'))}
        cluster = {k: v for k, v in overrides.items() if not k.startswith(('export.', 'masks.'))}
        out[name] = Variant(dataclasses.replace(base, **cluster, masks=dataclasses.replace(base.masks, **masks)),
                            export)
    return out


def _count(cloud: FruitPointCloud, config: ClusterConfig, views: Callable[[], RunViews]) -> CountResult:
    """The cloud's count as the pipeline makes it: the clusters checked against the run's training views' masks
    (``masks.enabled``; ``views`` loads them, once per run, only when needed)."""
    return count_with_views(cloud, config, views() if config.masks.enabled else None)


def _cloud(run_dir: Path, export: tuple[tuple[str, int | float | str], ...], scratch: Path) -> FruitPointCloud:
    """The run's exported cloud, or the cloud its checkpoint gives with the export overrides."""
    if not export:
        return read_cloud(run_dir / 'cloud.npz')[0]
    from fruitnerfpp_ros.core.pipeline import export_run
    config = dataclasses.replace(ExportConfig(), **dict(export))
    scratch.mkdir(parents=True, exist_ok=True)
    return export_run(run_dir, config, device='cpu', out=scratch / 'cloud.ply', write_cloud=False).cloud


@functools.cache
def _mask_noise() -> Any:
    """``bench/mask_noise.py`` (a sibling script, not a package), loaded once."""
    spec = importlib.util.spec_from_file_location('bench_mask_noise', Path(__file__).with_name('mask_noise.py'))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _views(run_dir: Path, dataset: Path, mask_noise: tuple[float, float] | None) -> Callable[[], RunViews]:
    """A loader, reading once, of the run's training views; their masks made noisy (``bench/mask_noise.py``)."""
    def load() -> RunViews:
        views = load_run_views(run_dir, dataset)
        if mask_noise is None:
            return views
        return dataclasses.replace(views, masks=_mask_noise().noisy_masks(views.masks, *mask_noise))
    return functools.cache(load)


def _scene_counts(scene_dir: Path, variants: dict[str, Variant], scratch: Path,
                  mask_noise: tuple[float, float] | None = None) -> dict[str, tuple[int, float]]:
    """{variant: (count, F1)} of one suite scene's cloud, scored as the suite scores it."""
    exports = dict.fromkeys(v.export for v in variants.values())   # each export variant exported once
    clouds = {e: _cloud(scene_dir / 'run', e, scratch / str(i)) for i, e in enumerate(exports)}
    keyframes = scene_dir / 'run' / 'keyframes'  # a bag scene trained on the replay's keyframes
    gt = scored_ground_truth(scene_dir / 'data' / 'gt_fruits.json', keyframes if keyframes.is_dir() else
                             scene_dir / 'data', scene_dir / 'run', TrainConfig().data.eval_every)
    dataset = keyframes if keyframes.is_dir() else scene_dir / 'data'
    views = _views(scene_dir / 'run', dataset, mask_noise)                           # one read for all variants
    counts = {name: _count(clouds[v.export], v.cluster, views) for name, v in variants.items()}
    return {name: (c.count, float(evaluate_counts(c.centers(), gt).f1)) for name, c in counts.items()}


def recount_suites(suite_dirs: list[Path], variants: dict[str, Variant], out: Path,
                   mask_noise: tuple[float, float] | None = None) -> None:
    scenes = sorted(p.parent.parent for d in suite_dirs for p in d.glob('*/run/cloud.npz'))
    table: dict[str, dict[str, tuple[int, float]]] = {}
    for scene in scenes:
        key = f'{scene.parent.name}/{scene.name}'
        table[key] = _scene_counts(scene, variants, out / 'clouds' / key, mask_noise)
        print(key, '  '.join(f'{n} {c} {f:.3f}' for n, (c, f) in table[key].items()), flush=True)
    means = {name: float(np.mean([row[name][1] for row in table.values()])) for name in variants}
    out.mkdir(parents=True, exist_ok=True)
    (out / 'recount.json').write_text(json.dumps({'scenes': table, 'mean_f1': means}, indent=1))
    lines = ['| scene | ' + ' | '.join(variants) + ' |', '|---|' + '---:|' * len(variants)]
    lines += [f'| {k} | ' + ' | '.join(f'{c} / {f:.3f}' for c, f in row.values()) + ' |' for k, row in table.items()]
    lines.append('| **mean F1** | ' + ' | '.join(f'**{m:.4f}**' for m in means.values()) + ' |')
    (out / 'recount.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


def recount_row(run: Path, copy: Path, variant: Variant, mask_noise: tuple[float, float] | None = None) -> None:
    for seg in sorted((run / 'segments').glob('seg_*')):
        done = read_segment_result(seg)
        if done is None:
            print(f'{seg.name}: no result, skipped', flush=True)
            continue
        fruits, record = done
        cloud = _cloud(seg / 'run', variant.export, copy / 'segments' / seg.name / 'cloud')
        count = _count(cloud, variant.cluster, _views(seg / 'run', seg / 'dataset', mask_noise))
        fruits = segment_fruits(fruits.segment, count, cloud)
        info = {k: v for k, v in record.items() if k not in ('segment', 'fruits', 'support')}
        (copy / 'segments' / seg.name).mkdir(parents=True, exist_ok=True)
        write_segment_result(copy / 'segments' / seg.name, fruits, **info)
        print(f'{seg.name}: {len(fruits.ids)} fruits', flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('runs', type=Path, nargs='+', help='suite directories, or one orchard run with --row-copy')
    parser.add_argument('--config', type=Path, help="YAML with a 'clustering' section (default: the defaults)")
    parser.add_argument('--variant', action='append', default=[], help='name=key:value,... (repeatable)')
    parser.add_argument('--out', type=Path, default=Path('recount'), help='suite mode: where the tables go')
    parser.add_argument('--row-copy', type=Path, help='row mode: the copy of the orchard run to write (with '
                        'the last --variant)')
    parser.add_argument('--mask-noise', metavar='DROPPED,FALSE', help='count against masks with this share of '
                        'fruit missed and of false detections added (bench/mask_noise.py)')
    args = parser.parse_args()
    noise = tuple(float(v) for v in args.mask_noise.split(',')) if args.mask_noise else None
    if noise is not None and len(noise) != 2:
        parser.error('--mask-noise takes two numbers: DROPPED,FALSE')
    base = load_section(ClusterConfig, args.config, 'clustering')
    variants = _variants(base, args.variant)
    if args.row_copy is not None:
        recount_row(args.runs[0], args.row_copy, list(variants.values())[-1], noise)
    else:
        recount_suites(args.runs, variants, args.out, noise)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
