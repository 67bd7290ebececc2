"""Issue #12: throughput of a row count against the number of Ray workers (segments trained at once).

Runs ``fruitnerfpp orchard DATASET`` once per worker count on a fresh run directory (local Ray, one CPU thread
per worker unless ``--cpus-per-worker``) and tabulates the row's wall time, segments per hour, the segments' own
times and peak memory (``RUN/row.json``) and the row's F1 (``RUN/eval_row.json`` of a synthetic row):

    fruitnerfpp synth --scene row --trees 10 --count 20 --views 320 --resolution 200 150 --row-standoff 1.2 \\
        --camera-height 0.6 --camera-pitch 0 --gnss --seed 0 --out row10
    python bench/row_throughput.py --dataset row10 --out tp10 --workers 1 2 --preset tiny

Writes ``OUT/throughput.md`` and ``OUT/throughput.json``; the runs are ``OUT/w<N>/``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def run_row(dataset: Path, out: Path, workers: int, preset: str, cpus: int, config: Path | None) -> dict:
    """One ``fruitnerfpp orchard`` run; its wall time and what its row.json / eval_row.json say."""
    trees = next((p for p in (dataset / 'planting_map.geojson', dataset / 'planting_map.csv') if p.is_file()), None)
    cmd = [str(Path(sys.executable).parent / 'fruitnerfpp'), 'orchard', str(dataset), '--out', str(out),
           '--workers', str(workers), '--preset', preset, '--cpus-per-worker', str(cpus)]
    cmd += ['--trees', str(trees)] if trees else []
    cmd += ['--config', str(config)] if config else []
    started = time.perf_counter()
    with (out.parent / f'{out.name}.log').open('w') as log:
        code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy())
    wall = time.perf_counter() - started
    row = json.loads((out / 'row.json').read_text()) if (out / 'row.json').is_file() else {}
    outcomes = row.get('outcomes', [])
    evaluation = json.loads((out / 'eval_row.json').read_text()) if (out / 'eval_row.json').is_file() else {}
    return {'workers': workers, 'exit_code': code, 'wall_s': wall, 'segments': len(outcomes),
            'segments_ok': sum(1 for o in outcomes if o.get('ok')),
            'segment_s': [o.get('seconds') for o in outcomes],
            'peak_rss_mib': [o.get('peak_rss_mib') for o in outcomes],
            'row_f1': evaluation.get('row', {}).get('f1')}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True, help='a row dataset (synth --scene row)')
    parser.add_argument('--out', type=Path, required=True)
    parser.add_argument('--workers', type=int, nargs='+', default=[1, 2])
    parser.add_argument('--preset', default='tiny')
    parser.add_argument('--cpus-per-worker', type=int, default=1)
    parser.add_argument('--config', type=Path, help="YAML with sections 'train', 'export', 'clustering', 'orchard'")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for n in args.workers:
        run_dir = args.out / f'w{n}'
        if run_dir.exists():
            raise SystemExit(f'{run_dir} exists: a fresh run directory is needed (finished segments are reused)')
        runs.append(run_row(args.dataset.resolve(), run_dir.resolve(), n, args.preset, args.cpus_per_worker,
                            args.config))
        print(json.dumps(runs[-1]), flush=True)
    (args.out / 'throughput.json').write_text(json.dumps(runs, indent=1))
    lines = [f'# Row throughput ({args.dataset.name}, preset {args.preset}, {args.cpus_per_worker} CPU thread(s) per '
             f'worker, {os.cpu_count()} CPUs)', '',
             '| workers | segments ok | row wall s | segments per hour | segment s (mean) | peak RSS per worker MiB '
             '(max) | speed-up | row F1 |', '|---:|---:|---:|---:|---:|---:|---:|---:|']
    base = runs[0]['wall_s'] if runs else float('nan')
    for r in runs:
        seconds = [s for s in r['segment_s'] if s is not None]
        rss = [m for m in r['peak_rss_mib'] if m is not None]
        f1 = '-' if r['row_f1'] is None else f"{r['row_f1']:.3f}"
        lines.append(f"| {r['workers']} | {r['segments_ok']} / {r['segments']} | {r['wall_s']:.0f} | "
                     f"{3600.0 * r['segments_ok'] / r['wall_s']:.1f} | "
                     f"{sum(seconds) / max(len(seconds), 1):.0f} | {max(rss, default=0):.0f} | "
                     f"{base / r['wall_s']:.2f}x | {f1} |")
    (args.out / 'throughput.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0 if all(r['exit_code'] == 0 for r in runs) else 1


if __name__ == '__main__':
    sys.exit(main())
