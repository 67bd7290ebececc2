#!/usr/bin/env python3
"""Clustering benchmark: time and adjusted Rand index of ``count_fruits`` on synthetic fruit clouds.

Clouds of 50k / 200k / 600k fruit-surface points (32-D embeddings, ~600 points per 7 cm fruit), separated fruits
and touching triples (one blob in space, three fruits by embedding). One-time costs (numba JIT load / compile of
fast_hdbscan, the partition worker pool) are measured apart. Writes the table to bench/results/cluster_bench.md.

Usage::

    python bench/cluster_bench.py                 # the table (about a minute on 2 cores)
    python bench/cluster_bench.py --full          # also without the subsample shortcut (exact route, slower)
    python bench/cluster_bench.py --sweep         # lambda_e sweep on touching fruit
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
from concurrent.futures import Executor
from pathlib import Path

from sklearn.metrics import adjusted_rand_score

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.counter import count_fruits
from fruitnerfpp_ros.core.clustering.hdbscan_cluster import warm_up
from fruitnerfpp_ros.core.clustering.synthetic_cloud import make_fruit_cloud
from fruitnerfpp_ros.core.clustering.workers import partition_pool

POINTS_PER_FRUIT = 600


def _row(n: int, touching: bool, config: ClusterConfig, label: str, pool: Executor | None, seed: int = 0) -> dict:
    synth = make_fruit_cloud(n, max(3, n // POINTS_PER_FRUIT), touching=touching, dim=32, seed=seed)
    start = time.perf_counter()
    result = count_fruits(synth.cloud, config, executor=pool)
    seconds = time.perf_counter() - start
    return {'points': len(synth.cloud), 'scene': 'touching' if touching else 'separated', 'route': label,
            'fruits': int(synth.labels.max() + 1), 'count': result.count, 'seconds': seconds,
            'ari': adjusted_rand_score(synth.labels, result.labels), 'stats': result.stats}


def _table(rows: list[dict]) -> str:
    lines = ['| points | scene | route | GT fruits | counted | time (s) | ARI | partitions | clustered | in pool |',
             '|---:|---|---|---:|---:|---:|---:|---:|---:|---:|']
    for r in rows:
        s = r['stats']
        lines.append(f"| {r['points']:,} | {r['scene']} | {r['route']} | {r['fruits']} | {r['count']} | "
                     f"{r['seconds']:.2f} | {r['ari']:.4f} | {s['partitions']} | {s['n_clustered']:,} | "
                     f"{'yes' if s['partitions_in_executor'] else 'no'} |")
    return '\n'.join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', type=int, nargs='+', default=[50_000, 200_000, 600_000])
    parser.add_argument('--full', action='store_true', help='also cluster every point (no subsample)')
    parser.add_argument('--sweep', action='store_true', help='lambda_e sweep on touching fruit (50k points)')
    parser.add_argument('--out', type=Path, default=Path(__file__).parent / 'results' / 'cluster_bench.md')
    args = parser.parse_args()

    config = ClusterConfig()
    rows = []
    sweep_rows = []
    with partition_pool(config.n_jobs) as pool:
        t0 = time.perf_counter()
        jit_s = warm_up()
        t1 = time.perf_counter()
        # start the worker pool (spawn + JIT load in each worker) on a small cloud: a one-time cost as well
        count_fruits(make_fruit_cloud(4000, 8, seed=99).cloud, ClusterConfig(partitions=2, parallel_min_points=0),
                     executor=pool)
        pool_s = time.perf_counter() - t1
        print(f'one-time: fast_hdbscan JIT warm-up {jit_s:.1f} s (process import+JIT {t1 - t0:.1f} s), '
              f'worker pool start {pool_s:.1f} s', flush=True)
        for n in args.sizes:
            for touching in (False, True):
                rows.append(_row(n, touching, config, f'subsample {config.subsample_size // 1000}k + assign', pool))
                print(_table(rows[-1:]).splitlines()[-1], flush=True)
                if args.full and n > config.subsample_size:
                    full = dataclasses.replace(config, subsample_size=0)
                    rows.append(_row(n, touching, full, 'all points', pool))
                    print(_table(rows[-1:]).splitlines()[-1], flush=True)
        if args.sweep:
            for lam in (0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 20.0):
                r = _row(50_000, True, dataclasses.replace(config, lambda_e=lam), f'lambda_e {lam:g}/m', pool)
                sweep_rows.append(r)
                print(_table([r]).splitlines()[-1], flush=True)

    header = (f'# Clustering benchmark\n\n`python bench/cluster_bench.py{" --full" if args.full else ""}'
              f'{" --sweep" if args.sweep else ""}` on {platform.machine()} with {os.cpu_count()} CPU cores '
              f'({time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}). Timings are wall seconds of '
              '`count_fruits` on a shared, busy machine (other jobs running): noisy.\n\n'
              f'One-time costs, excluded below: fast_hdbscan JIT warm-up {jit_s:.1f} s (numba disk cache warm; '
              f'a cold cache compiles for 20-80 s), partition worker pool start {pool_s:.1f} s.\n\n'
              f'Config: lambda_c {config.lambda_c}, lambda_e {config.lambda_e}/m, summed metric, kNN {config.knn_k}, '
              f'min_samples {config.min_samples}, subsample {config.subsample_size}, n_jobs {config.n_jobs}. '
              f'Scenes: ~{POINTS_PER_FRUIT} points per fruit (7 cm), 32-D embeddings; touching = triples of '
              'overlapping fruits.\n\n')
    text = header + _table(rows) + '\n'
    if sweep_rows:
        text += '\n## lambda_e sweep (touching fruit, 50k points)\n\n' + _table(sweep_rows) + '\n'
    print()
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)


if __name__ == '__main__':
    main()
