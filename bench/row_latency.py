"""Issue #12: the live node on a row replayed in real time -- how long after the robot passes a tree is its count out?

Runs two processes as a robot would: ``orchard_sim`` replays a synthetic row bag (``fruitnerfpp synth --scene row
--gnss --bag``) at ``--rate`` frames per second, and ``fruit_counter`` in row mode (``config/fruit_counter.yaml`` +
``config/orchard_row.yaml``) trains each segment in the background once the robot has passed it. When every
segment queued has been trained and published, the counter is stopped and ``RUN/row/events.jsonl`` gives per segment
the time from being passed to its first count and from being passed again (both sides) to its final count
(:func:`fruitnerfpp_ros.core.orchard.latency.segment_latencies`); the final row report is scored against the truth.

    python bench/row_latency.py --dataset row5 --bag row5_bag --out lat5 --preset tiny --standoff 1.2 \\
        --planting-map row5/planting_map.csv

Writes ``OUT/latency.md`` (the tables) and ``OUT/latency.json``; the node's run directory is ``OUT/run``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _wait_done(events_path: Path, sim: subprocess.Popen, sim_log: Path, timeout_s: float, settle_s: float) -> str:
    """Poll the events until the drive is over and every queued segment version is trained and published."""
    from fruitnerfpp_ros.core.orchard.latency import read_events
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        time.sleep(5.0)
        if not events_path.is_file() or (sim.poll() is None and 'published all' not in sim_log.read_text()):
            continue
        events = read_events(events_path)
        newest: dict[int, int] = {}  # a waiting request replaced by a newer one is never trained: the newest counts
        for e in events:
            if e['event'] == 'queued':
                newest[e['segment']] = max(newest.get(e['segment'], 0), e['version'])
        trained = {(e['segment'], e['version']) for e in events if e['event'] == 'trained'}
        last = events[-1] if events else {}
        if newest and set(newest.items()) <= trained and last.get('event') == 'published' \
                and time.time() - float(last['time_unix_s']) > settle_s:
            return 'done'
    return 'timed out'


def _score(dataset: Path, report: dict) -> dict:
    from fruitnerfpp_ros.core.orchard.evaluation import evaluate_row
    fruits, trees = report['fruits'], report['trees']
    return evaluate_row(dataset, np.array([f['center'] for f in fruits]).reshape(-1, 3),
                        np.array([f.get('segment', -1) for f in fruits]),
                        np.array([f.get('tree_id', 0) for f in fruits]), np.array([t['id'] for t in trees]),
                        np.array([t['position'] for t in trees]).reshape(-1, 3),
                        np.array([t['count'] for t in trees]))


def _drive(args: argparse.Namespace, out: Path) -> str:
    """Replay the bag into the node until every segment's newest request is trained and published."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(random.randint(1, 200)), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    bindir = Path(sys.executable).parent
    counter_cmd = [str(bindir / 'fruit_counter'), '--ros-args',
                   '--params-file', str(ROOT / 'config/fruit_counter.yaml'),
                   '--params-file', str(ROOT / 'config/orchard_row.yaml'), '-p', f'output_dir:={out / "run"}',
                   '-p', f'preset:={args.preset}', '-p', f'device:={args.device}',
                   '-p', f'row_standoff_m:={args.standoff}', '-p', f'planting_map:={args.planting_map}']
    sim_cmd = [str(bindir / 'orchard_sim'), '--ros-args', '-p', f'source:={args.bag.resolve()}',
               '-p', f'rate_hz:={args.rate}', '-p', 'wait_for_subscribers_s:=60.0']
    with (out / 'counter.log').open('w') as counter_log, (out / 'sim.log').open('w') as sim_log:
        counter = subprocess.Popen(counter_cmd, stdout=counter_log, stderr=subprocess.STDOUT, env=env)
        sim = subprocess.Popen(sim_cmd, stdout=sim_log, stderr=subprocess.STDOUT, env=env)
        try:
            state = _wait_done(out / 'run' / 'row' / 'events.jsonl', sim, out / 'sim.log', args.timeout, settle_s=15.0)
        finally:
            for proc in (sim, counter):
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
            for proc in (sim, counter):
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()

    return state


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True, help='the row dataset (ground truth)')
    parser.add_argument('--bag', type=Path, required=True, help='its rosbag2 (synth --bag)')
    parser.add_argument('--out', type=Path, required=True)
    parser.add_argument('--preset', default='tiny')
    parser.add_argument('--device', default='cpu')
    parser.add_argument('--rate', type=float, default=5.0, help='frames per second of the replay')
    parser.add_argument('--standoff', type=float, default=0.0, help='row_standoff_m (0: the node decides)')
    parser.add_argument('--planting-map', default='', help='planting_map parameter (CSV / GeoJSON)')
    parser.add_argument('--timeout', type=float, default=7200.0, help='seconds before giving up')
    parser.add_argument('--report-only', action='store_true', help='only tabulate the events of an earlier OUT/run')
    args = parser.parse_args(argv)

    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    state = 'report only' if args.report_only else _drive(args, out)
    from fruitnerfpp_ros.core.orchard.latency import read_events, segment_latencies
    events = read_events(out / 'run' / 'row' / 'events.jsonl')
    lags = segment_latencies(events)
    keyframes = [e for e in events if e['event'] == 'keyframe']
    drive_s = float(keyframes[-1]['time_unix_s']) - float(keyframes[0]['time_unix_s'])
    report = json.loads((out / 'run' / 'row' / 'row_report.json').read_text())
    score = _score(args.dataset, report)
    last_s = float(events[-1]['time_unix_s']) - float(keyframes[0]['time_unix_s'])
    result = {'state': state, 'preset': args.preset, 'device': args.device, 'rate_hz': args.rate,
              'keyframes': len(keyframes), 'drive_s': drive_s, 'last_event_s': last_s,
              'segments': [lag._asdict() for lag in lags], 'evaluation': score}
    (out / 'latency.json').write_text(json.dumps(result, indent=1, default=float))

    def fmt(v: float | None) -> str:
        return '-' if v is None else f'{v:.0f}'

    lines = [f'# Live row latency ({args.preset} preset, {args.device}, replay at {args.rate:g} Hz: {state})', '',
             f'{len(keyframes)} keyframes over a {drive_s:.0f} s drive; the last count published {last_s:.0f} s '
             f'after the first keyframe.', '',
             '| segment | passed at (s) | to first count (s) | last asked at (s) | to final count (s) | versions '
             '| training (s) |', '|---:|---:|---:|---:|---:|---:|---:|']
    lines += [f'| {g.segment} | {g.passed_s:.0f} | {fmt(g.first_count_s)} | {g.last_passed_s:.0f} | '
              f'{fmt(g.final_count_s)} | {g.versions} | {g.training_s:.0f} |' for g in lags]
    row = score['row']
    lines += ['', f"Final row count: {row['count']} / {row['gt_count']}, precision {row['precision']:.3f}, "
              f"recall {row['recall']:.3f}, F1 {row['f1']:.3f}; double counts {score['double_counts']['total']} "
              f"({score['double_counts']['across_cuts']} across cuts)", '',
              '| tree | truth | counted | error |', '|---:|---:|---:|---:|']
    lines += [f"| {t['tree']} | {t['truth']} | {t.get('count', '-')} | {t.get('error_pct', '-')} % |"
              for t in score['trees']]
    (out / 'latency.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0 if state in ('done', 'report only') else 1


if __name__ == '__main__':
    sys.exit(main())
