#!/usr/bin/env python3
"""Issue #12's judge: per-tree counts on a suite of synthetic rows, not on one hand-picked row.

Each row of :data:`ROWS` varies what a real orchard varies: fruit type and size, fruit load per tree, the drive's
standoff, camera height and pitch, the odometry's drift on the return pass. Per row the script generates the data
(``fruitnerfpp synth --scene row ... --gnss``), counts it (``fruitnerfpp orchard DATA --out RUN --trees
DATA/planting_map.geojson``, one process per row, so a failed row is reported and the suite goes on) and reads its
evaluation (``RUN/eval_row.json``): the row's precision / recall / F1, double counts (across cuts), each tree's
count error against the fruit growing on it, the trunks' WGS84 error, wall time and the segments' peak memory.

Writes ``OUT/rows.md`` and ``OUT/rows.json``; the rows are ``OUT/<row>/data`` and ``OUT/<row>/run``. The summary
line is what issue 12 asks of every row: trees within 10 % of their truth (of all trees), the worst tree, the mean
and worst row F1, the doubles across cuts.

``--reuse OLD`` takes each row's finished segments from an earlier suite (their ``result.json`` and the row's
plan, no fields): the rows are merged, assigned to trees and scored again in seconds, so a merge or tree setting
(``--config`` with an ``orchard`` section) is judged on every row without training::

    python bench/row_suite.py --out rows_tiny --preset tiny --workers 2            # 8 rows, ~45 min on 2 cores
    python bench/row_suite.py --out rows_v --reuse rows_tiny --config variant.yaml --preset tiny
    python bench/row_suite.py --out rows_cpu --preset cpu --rows apple_s0,plum_s2   # the `cpu` preset: ~20 min a row
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple, Sequence

#: every row: 5 trees, 160 views of 200x150 (both sides), GNSS fixes
COMMON = ['--scene', 'row', '--trees', '5', '--views', '160', '--resolution', '200', '150', '--gnss',
          '--sparse-points', '0', '--quiet']


class Row(NamedTuple):
    """One row of the suite: its name, the ``fruitnerfpp synth`` arguments beyond :data:`COMMON`, what it covers."""

    name: str
    synth: tuple[str, ...]
    covers: str


def _drive(standoff: float, height: float, pitch: float) -> tuple[str, ...]:
    return ('--row-standoff', str(standoff), '--camera-height', str(height), '--camera-pitch', str(pitch))


ROWS: tuple[Row, ...] = (
    Row('apple_s0', ('--fruit', 'apple', '--count', '20', '--seed', '0', *_drive(1.2, 0.6, 0)),
        "issue 12's row (row5): apples, 20 a tree, standoff 1.2 m, camera 0.6 m, level"),
    Row('apple_s1', ('--fruit', 'apple', '--count', '20', '--seed', '1', *_drive(1.2, 0.6, 0)),
        'the same drive, another row (row5s1)'),
    Row('plum_s2', ('--fruit', 'plum', '--count', '20', '--seed', '2', *_drive(1.2, 0.6, 0)),
        'small fruit, canopies overlapping (row5p2)'),
    Row('peach_s11', ('--fruit', 'peach', '--count', '16', '--seed', '11', *_drive(1.5, 0.8, 0)),
        'peaches, lighter load, standoff 1.5 m, camera 0.8 m'),
    Row('lemon_s12', ('--fruit', 'lemon', '--count', '24', '--seed', '12', *_drive(1.2, 0.6, 5)),
        'lemons, camera pitched 5 deg up'),
    Row('mixed_s13', ('--fruit', 'mixed', '--count', '20', '--seed', '13', *_drive(1.4, 0.7, 0)),
        'all six fruit types, standoff 1.4 m'),
    Row('apple_s14_dense', ('--fruit', 'apple', '--count', '30', '--seed', '14', *_drive(1.2, 0.6, 0)),
        'apples, 30 a tree'),
    Row('apple_s15_drift', ('--fruit', 'apple', '--count', '20', '--seed', '15', *_drive(1.2, 0.6, 0),
                            '--pass-offset', '0.06', '0.5'),
        "the return pass's odometry 6 cm along the row and 0.5 deg off"),
)


def _cli() -> list[str]:
    """The package's command line in this interpreter (honours PYTHONPATH: a checkout or snapshot runs as is)."""
    return [sys.executable, '-m', 'fruitnerfpp_ros']


def _copy_finished(old_run: Path, run: Path) -> None:
    """The row plan and the segments' results of an earlier run, nothing else (no fields, no clouds)."""
    run.mkdir(parents=True)
    shutil.copy2(old_run / 'row.json', run / 'row.json')
    for result in sorted(old_run.glob('segments/*/result.json')):
        target = run / 'segments' / result.parent.name
        target.mkdir(parents=True)
        shutil.copy2(result, target / 'result.json')


def run_row(row: Row, out: Path, preset: str, workers: int, config: Path | None, reuse: Path | None) -> dict:
    """Generate (unless present), count and score one row; the record of ``rows.json``."""
    data, run, log = out / row.name / 'data', out / row.name / 'run', out / row.name / 'orchard.log'
    if reuse is not None and (reuse / row.name / 'data' / 'transforms.json').is_file():
        data = reuse / row.name / 'data'
    started = time.perf_counter()
    record: dict[str, Any] = {'row': row.name, 'covers': row.covers, 'synth': list(row.synth), 'error': ''}
    if reuse is not None and not (reuse / row.name / 'run' / 'row.json').is_file():
        return {**record, 'error': f'nothing to reuse: no {reuse / row.name / "run" / "row.json"}'}
    if not (data / 'transforms.json').is_file():
        done = subprocess.run([*_cli(), 'synth', *COMMON, *row.synth, '--out', str(data)], capture_output=True,
                              text=True)
        if done.returncode:
            return {**record, 'error': f'synth failed: {done.stderr.strip()[-300:]}'}
    if run.exists():
        shutil.rmtree(run)
    run.parent.mkdir(parents=True, exist_ok=True)
    if reuse is not None:
        _copy_finished(reuse / row.name / 'run', run)
    command = [*_cli(), 'orchard', str(data), '--out', str(run), '--preset', preset, '--workers', str(workers),
               '--trees', str(data / 'planting_map.geojson')]
    command += ['--no-ray'] if reuse is not None else []
    command += ['--config', str(config)] if config else []
    with log.open('w') as stream:
        code = subprocess.call(command, stdout=stream, stderr=subprocess.STDOUT, env=os.environ.copy())
    record['wall_s'] = round(time.perf_counter() - started, 1)
    evaluation = run / 'eval_row.json'
    if code or not evaluation.is_file():
        return {**record, 'error': f'orchard exited {code} (see {log})'}
    plan = json.loads((run / 'row.json').read_text())
    record['peak_rss_mib'] = max((o.get('peak_rss_mib') or 0.0 for o in plan.get('outcomes', [])), default=0.0)
    record['evaluation'] = json.loads(evaluation.read_text())
    return record


def row_figures(evaluation: dict, within: float = 10.0) -> dict:
    """What the table shows of one ``eval_row.json``: the row's scores, the trees' errors (%, against the fruit
    growing on each), how many are within ``within`` %, the worst, the doubles and the trunks' WGS84 error."""
    row, trees = evaluation['row'], evaluation['trees']
    errors = [float(t['error_pct']) for t in trees]
    return {'count': row['count'], 'gt': row['gt_count'], 'precision': row['precision'], 'recall': row['recall'],
            'f1': row['f1'], 'doubles': evaluation['double_counts']['total'],
            'doubles_across_cuts': evaluation['double_counts']['across_cuts'], 'tree_errors_pct': errors,
            'trees_within': sum(abs(e) <= within for e in errors), 'trees': len(errors),
            'trees_true': evaluation.get('trees_true', len(errors)),
            'worst_tree_pct': max((abs(e) for e in errors), default=0.0),
            'geo_max_m': evaluation.get('geo', {}).get('max_error_m')}


def table(records: Sequence[dict], title: str) -> list[str]:
    """The Markdown of ``rows.md``: one line per row, then the summary."""
    lines = [f'# {title}', '',
             '| row | count / GT | P | R | F1 | doubles (across cuts) | trees within 10 % | tree errors (%) | '
             'trunks (m) | s | peak MiB |', '|---|---:|---:|---:|---:|---|---:|---|---:|---:|---:|']
    figures = []
    for record in records:
        if record.get('error'):
            lines.append(f"| {record['row']} | failed: {record['error']} | | | | | | | | | |")
            continue
        f = row_figures(record['evaluation'])
        figures.append(f)
        geo = '-' if f['geo_max_m'] is None else f"{f['geo_max_m']:.3f}"
        lines.append(f"| {record['row']} | {f['count']} / {f['gt']} | {f['precision']:.3f} | {f['recall']:.3f} | "
                     f"{f['f1']:.3f} | {f['doubles']} ({f['doubles_across_cuts']}) | {f['trees_within']} / "
                     f"{f['trees']} | {' / '.join(f'{e:+.0f}' for e in f['tree_errors_pct'])} | {geo} | "
                     f"{record['wall_s']:.0f} | {record['peak_rss_mib']:.0f} |")
    if figures:
        f1 = [f['f1'] for f in figures]
        lines += ['', f"Rows: {len(figures)} of {len(records)} counted; mean F1 **{sum(f1) / len(f1):.3f}**, worst "
                  f"{min(f1):.3f}; trees within 10 % of their truth: **{sum(f['trees_within'] for f in figures)} of "
                  f"{sum(f['trees'] for f in figures)}**, worst tree {max(f['worst_tree_pct'] for f in figures):.0f} "
                  f"%; doubles across cuts {sum(f['doubles_across_cuts'] for f in figures)}; rows with every tree "
                  f"within 10 %: {sum(f['trees_within'] == f['trees'] == f['trees_true'] for f in figures)}."]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, required=True, help='suite directory (OUT/<row>/run is replaced)')
    parser.add_argument('--preset', default='tiny', help='training preset of every segment (default tiny)')
    parser.add_argument('--workers', type=int, default=2, help='segments trained at once (local Ray; default 2)')
    parser.add_argument('--rows', metavar='NAME,NAME', help='only these rows')
    parser.add_argument('--config', type=Path, help="YAML with sections 'train', 'export', 'clustering', 'orchard'")
    parser.add_argument('--reuse', type=Path, metavar='OLD', help="an earlier suite's directory: merge, assign and "
                        'score its finished segments again (no training)')
    args = parser.parse_args(argv)
    known = {row.name: row for row in ROWS}
    names = args.rows.split(',') if args.rows else list(known)
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"unknown row(s) {', '.join(unknown)}; the rows: {', '.join(known)}")
    args.out.mkdir(parents=True, exist_ok=True)
    records = []
    for name in names:
        record = run_row(known[name], args.out.resolve(), args.preset, args.workers,
                         args.config.resolve() if args.config else None, args.reuse.resolve() if args.reuse else None)
        records.append(record)
        print(table([record], name)[4], flush=True)
    title = f'Row suite: preset {args.preset}, {args.workers} worker(s)'
    title += f', config {args.config}' if args.config else ''
    (args.out / 'rows.json').write_text(json.dumps(records, indent=1))
    lines = table(records, title)
    (args.out / 'rows.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 1 if any(r.get('error') for r in records) else 0


if __name__ == '__main__':
    sys.exit(main())
