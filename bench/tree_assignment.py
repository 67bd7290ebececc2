#!/usr/bin/env python3
"""Which tree a fruit hangs on: the nearest trunk against the nearest crown shell, on many synthetic rows.

No training: each row's layout is built as ``fruitnerfpp synth --scene row`` builds it (trunks jittered off the
nominal planting grid, crowns of varied size that overlap their neighbours), its true fruit centres are "detected"
with a centre error (``--noise-m``) and a share missed (``--miss``), and every fruit is given to a tree of the
nominal planting map by each rule of ``TreeConfig.assign`` (and by the nearest *true* trunk, the best the trunk
rule can do); the last column gives each fruit to the nearest shell of the *true* crowns (the generator's crown
ellipsoids, semi-axes r, r, 0.85 r, the shell at 0.9 of them, where the fruit hang): the bound of a better crown
estimate, e.g. one fitted to the canopy rather than to the fruit. Per case: the share of fruits on the right tree,
the share of rows with some tree's count off by more than 10 % of its truth (issue 12's target) and the share of
trees off by more than 10 %.

Usage::

    python bench/tree_assignment.py --seeds 40 [--out bench/results/tree_assignment.md]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fruitnerfpp_ros.core.synthetic.row_scene import RowScene

#: (fruit, mean fruits per tree, trees, share missed)
CASES = [('apple', 8, 5, 0.15), ('apple', 20, 5, 0.0), ('apple', 20, 5, 0.15), ('apple', 20, 10, 0.15),
         ('apple', 60, 5, 0.15), ('plum', 40, 5, 0.15), ('mango', 20, 5, 0.15), ('mixed', 30, 5, 0.15),
         ('pear', 20, 5, 0.3), ('lemon', 12, 5, 0.15)]


def _scores(truth: np.ndarray, labels: np.ndarray, trees: int) -> tuple[float, float, float]:
    """(share right, worst tree's |count error| / truth, share of trees off by > 10 %)."""
    true, got = np.bincount(truth, minlength=trees), np.bincount(labels, minlength=trees)
    error = np.abs(got - true) / np.maximum(true, 1)
    return float((labels == truth).mean()), float(error.max()), float((error > 0.10).mean())


def _true_crowns(counted: np.ndarray, row: RowScene) -> np.ndarray:
    """[N] the tree whose true crown shell (0.9 of the ellipsoid r, r, 0.85 r) each centre lies nearest to."""
    semi = np.c_[row.crown_radii, row.crown_radii, 0.85 * row.crown_radii]
    radius = np.linalg.norm((counted[:, None] - row.crown_centers[None]) / semi[None], axis=2)
    return np.argmin(np.abs(radius - 0.9), axis=1)


def main() -> int:
    from fruitnerfpp_ros.core.orchard.config import TreeConfig
    from fruitnerfpp_ros.core.orchard.trees import TreeMap, assign_to_trees
    from fruitnerfpp_ros.core.synthetic.config import SynthConfig
    from fruitnerfpp_ros.core.synthetic.row_scene import RowSceneConfig, build_row_scene

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--seeds', type=int, default=40, help='rows per case')
    parser.add_argument('--noise-m', type=float, default=0.01, help='standard deviation of a counted centre (m)')
    parser.add_argument('--miss', type=float, default=None, help='share of fruits missed (default: per case)')
    parser.add_argument('--out', type=Path, help='also write the table (markdown) here')
    args = parser.parse_args()

    rules = {'nearest true trunk': None, 'trunk': TreeConfig(assign='trunk'), 'crown': TreeConfig(assign='crown')}
    columns = [*rules, 'true crowns (bound)']
    lines = ['| fruit | per tree | trees | missed | ' + ' | '.join(columns) + ' |',
             '|---|---:|---:|---:|' + '---|' * len(columns)]
    for fruit, count, n_trees, miss in CASES:
        miss = miss if args.miss is None else args.miss
        scores: dict[str, list[tuple[float, float, float]]] = {name: [] for name in columns}
        for seed in range(args.seeds):
            row = build_row_scene(SynthConfig(fruit=fruit, count=count, trajectory='row', seed=seed),
                                  RowSceneConfig(trees=n_trees))
            centers = np.array([f.center for f in row.scene.fruits])
            truth = np.array([f.tree_id for f in row.scene.fruits]) - 1
            rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7EE]))
            seen = rng.random(len(centers)) >= miss
            counted = centers[seen] + rng.normal(scale=args.noise_m, size=(int(seen.sum()), 3))
            ids = np.arange(1, n_trees + 1)
            for name, config in rules.items():
                trunks = row.trunks if config is None else row.planted
                labels = assign_to_trees(counted, TreeMap(ids, trunks, 'planting_map'), config or rules['trunk'])
                scores[name].append(_scores(truth[seen], labels, n_trees))
            scores[columns[-1]].append(_scores(truth[seen], _true_crowns(counted, row), n_trees))
        cells = []
        for name in columns:
            s = np.array(scores[name])
            cells.append(f'{s[:, 0].mean():.3f} / {(s[:, 1] > 0.10).mean():.2f} / {s[:, 2].mean():.3f}')
        lines.append(f'| {fruit} | {count} | {n_trees} | {miss:.2f} | ' + ' | '.join(cells) + ' |')
        print(lines[-1], flush=True)
    if args.out:
        header = (f'Per rule: share of fruits on the right tree / share of rows with a tree off by > 10 % / share of '
                  f'trees off by > 10 % ({args.seeds} rows per case, centre error {args.noise_m} m; trees of the '
                  f'nominal planting map, except the first column).\n\n')
        args.out.write_text(header + '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
