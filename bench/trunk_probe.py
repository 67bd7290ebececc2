#!/usr/bin/env python3
"""A lead for issue 12's per-tree counts: trunks found in a row run's trained segments, crowns centred on them.

``bench/tree_assignment.py`` shows that the trees' errors, where the count is right, come mostly from the crowns'
estimate (a sphere per tree fitted to 10-50 fruits), and that crowns centred on the *true* trunks would leave fewer
trees off. This probe asks whether the trained fields show the trunks: per segment of a finished ``fruitnerfpp
orchard`` run (``RUN/segments/seg_*/run``, checkpoints kept) the density is sampled on a 1 cm grid in a slab from
5 cm above the world's ground plane (z = 0 in the synthetic rows) to 5 cm below the lowest fruit (5th percentile of
the counted fruit's heights); the slab's optical depth per column, smoothed over 1.5 cm, has a peak at each trunk.
Peaks of at least two segments within 10 cm are one trunk; each planting-map tree takes the trunk found within 0.3
spacings of it. Then the run's fruit are given to crowns fitted as ``TreeConfig.assign: crown`` fits them, with each
crown's centre held over its trunk, and the per-tree counts are scored against ``gt_trees.json`` beside the run's
own (``eval_row.json``).

Usage (a row of ``bench/row_suite.py``: ``OUT/<row>`` holds ``data`` and ``run``)::

    python bench/trunk_probe.py OUT/apple_s0 [OUT/plum_s2 ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage
from scipy.cluster.hierarchy import fcluster, linkage


def trunk_peaks(run: Path, top_z: float) -> np.ndarray:
    """[P, 4] (segment, x, y, optical depth) of the slab's column peaks in every segment of ``run``."""
    from fruitnerfpp_ros.core.training import load_trained_scene

    peaks = []
    for k, seg in enumerate(sorted((run / 'segments').glob('seg_*'))):
        scene = load_trained_scene(seg / 'run', device='cpu')
        lo, hi = scene.aabb
        xs, ys = np.arange(lo[0], hi[0], 0.01), np.arange(lo[1], hi[1], 0.01)
        zs = np.arange(max(lo[2], 0.05), top_z, 0.02)
        X, Y, Z = np.meshgrid(xs, ys, zs, indexing='ij')
        points = torch.tensor(np.c_[X.ravel(), Y.ravel(), Z.ravel()], dtype=torch.float32)
        with torch.no_grad():
            density = torch.cat([scene.field.query(points[i:i + 200000]).density
                                 for i in range(0, len(points), 200000)]).numpy()
        depth = ndimage.gaussian_filter(density.reshape(X.shape).sum(axis=2) * 0.02, 1.5)
        peak = (depth == ndimage.maximum_filter(depth, size=15)) & (depth > 0.3 * depth.max())
        inside = ((xs[:, None] > lo[0] + 0.05) & (xs[:, None] < hi[0] - 0.05)
                  & (ys[None] > lo[1] + 0.05) & (ys[None] < hi[1] - 0.05))
        i, j = np.nonzero(peak & inside)
        peaks.append(np.c_[np.full(len(i), k), xs[i], ys[j], depth[i, j]])
    return np.concatenate(peaks) if peaks else np.zeros((0, 4))


def trunks_from_peaks(peaks: np.ndarray) -> np.ndarray:
    """[T, 2] trunks: peaks within 10 cm of each other, seen by at least two segments, averaged."""
    if len(peaks) < 2:
        return np.zeros((0, 2))
    groups = fcluster(linkage(peaks[:, 1:3], 'single'), 0.1, 'distance')
    found = [peaks[groups == g, 1:3].mean(axis=0) for g in np.unique(groups)
             if len(np.unique(peaks[groups == g, 0])) >= 2]
    return np.array(found).reshape(-1, 2)


def crowns_on_trunks(fruit: np.ndarray, trunks: np.ndarray, min_fruits: int = 12, iterations: int = 25
                     ) -> np.ndarray:
    """[N] tree index of each fruit: the crown shell it lies nearest to, crowns fitted from their fruit with the
    centre's xy held on the trunk (height and radius fitted; trees with too few fruit take the median radius)."""
    from fruitnerfpp_ros.core.orchard.trees import _nearest_trunks

    k = len(trunks)
    candidates = _nearest_trunks(fruit, trunks, 3)  # the crown rule's candidates: the three nearest trunks
    labels = candidates[:, 0]
    for _ in range(iterations):
        centres, radii = np.c_[trunks, np.zeros(k)], np.zeros(k)
        fitted = np.bincount(labels, minlength=k) >= min_fruits
        for j in np.flatnonzero(fitted):
            p = fruit[labels == j]
            # sphere through p with its centre on the vertical through the trunk: |p - (x0, y0, z)|^2 = r^2,
            # linear in (z, r^2 - z^2)
            h = ((p[:, :2] - trunks[j]) ** 2).sum(axis=1)
            A = np.c_[2.0 * p[:, 2], np.ones(len(p))]
            (z, c), *_ = np.linalg.lstsq(A, h + p[:, 2] ** 2, rcond=None)
            centres[j, 2], radii[j] = z, np.sqrt(max(c + z * z, 1e-6))
        if not fitted.any():
            return labels
        median = float(np.median(radii[fitted]))
        radii[fitted] = np.clip(radii[fitted], 0.8 * median, 1.25 * median)
        radii[~fitted] = median
        centres[~fitted, 2] = float(np.median(centres[fitted, 2]))
        residual = np.abs(np.linalg.norm(fruit[:, None] - centres[candidates], axis=2) - radii[candidates])
        new = candidates[np.arange(len(fruit)), np.argmin(residual, axis=1)]
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


def probe(row: Path) -> str:
    report = json.loads((row / 'run' / 'row_report.json').read_text())
    fruit = np.array([f['center'] for f in report['fruits']])
    truth_trees = json.loads((row / 'data' / 'gt_trees.json').read_text())['trees']
    true_xy = np.array([t['trunk'][:2] for t in truth_trees])
    plan = np.loadtxt(row / 'data' / 'planting_map.csv', delimiter=',', skiprows=1, ndmin=2)[:, 1:3]
    found = trunks_from_peaks(trunk_peaks(row / 'run', float(np.percentile(fruit[:, 2], 5)) - 0.05))
    spacing = float(np.median(np.diff(plan[:, 0]))) if len(plan) > 1 else 1.0
    snapped = plan.copy()
    for t in range(len(plan)):
        d = np.linalg.norm(found - plan[t], axis=1) if len(found) else np.full(1, np.inf)
        if d.min() < 0.3 * spacing:
            snapped[t] = found[int(np.argmin(d))]
    evaluation = json.loads((row / 'run' / 'eval_row.json').read_text())
    truth = np.array([t['truth'] for t in evaluation['trees']])
    today = np.array([t.get('count', 0) for t in evaluation['trees']])
    probe_counts = np.bincount(crowns_on_trunks(fruit, snapped), minlength=len(plan))

    def cells(counts: np.ndarray) -> str:
        error = (counts - truth) / np.maximum(truth, 1)
        return (' / '.join(f'{100 * e:+.0f}' for e in error) + f' ({int((np.abs(error) <= 0.1).sum())} / '
                f'{len(truth)})')

    def cm(xy: np.ndarray) -> str:
        return ' / '.join(f'{100 * d:.1f}' for d in np.linalg.norm(xy - true_xy, axis=1))
    return (f'| {row.name} | {len(found)} | {cm(snapped)} | {cm(plan)} | {cells(today)} | '
            f'{cells(probe_counts)} |')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('rows', type=Path, nargs='+', help='row directories (data/, run/)')
    args = parser.parse_args()
    torch.set_num_threads(1)
    print('| row | trunks found | trunk error, snapped map (cm) | map error (cm) | trees today (%, within 10 %) | '
          'crowns on the trunks |')
    print('|---|---:|---|---|---|---|')
    for row in args.rows:
        print(probe(row), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
