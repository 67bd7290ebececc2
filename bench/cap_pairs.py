#!/usr/bin/env python3
"""How far apart, and how alike in embedding, are the counted clusters that halve one true fruit, against pairs of
two true fruits: the evidence behind the caps' join (``merge_agreeing_m`` / ``merge_agreeing_cos``).

For every pair of counted clusters (a run's labelled cloud) whose median centres lie within ``--reach`` median true
diameters of each other and each within one diameter of a true fruit: the cosine of the two clusters' mean unit
embeddings (the pairs and cosines the join itself weighs), filed under "halves of one fruit" when both are nearest
the same true fruit, else "two fruits". Reads suite directories
(``DIR/<scene>/run`` with ``DIR/<scene>/data/gt_fruits.json``) and orchard runs (``RUN/segments/seg_*/run``, with
``--gt DATASET/gt_fruits.json``).

When the clouds keep their points' viewing directions (runs from 2026-12-05 session 27 on), the pairs are also
split by the sides they were seen from (mean viewing directions' cosine <= -0.5: opposite) with the distance of
their centres after the points moved to their fruits' centres (``ClusterConfig.centre_shift_diameters``): the
evidence behind the opposite caps' join (``merge_opposite_m``).

Usage::

    python bench/cap_pairs.py SUITE_DIR... [--reach 1.5]
    python bench/cap_pairs.py RUN --gt row5/gt_fruits.json
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Iterator

import numpy as np

from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.count_result import label_groups
from fruitnerfpp_ros.core.clustering.counter import centre_positions
from fruitnerfpp_ros.core.clustering.merge import close_pair_cosines, group_mean_directions
from fruitnerfpp_ros.core.evaluation.ground_truth import GroundTruth, load_ground_truth
from fruitnerfpp_ros.core.export.npz_io import read_cloud
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud


def _runs(paths: list[Path], gt: Path | None) -> Iterator[tuple[Path, Path]]:
    for path in paths:
        if (path / 'segments').is_dir():
            if gt is None:
                raise SystemExit(f'{path}: an orchard run needs --gt')
            yield from ((seg / 'run', gt) for seg in sorted((path / 'segments').glob('seg_*')))
        else:
            yield from ((run, run.parent / 'data' / 'gt_fruits.json') for run in sorted(path.glob('*/run')))


def _nearest_true(centres: np.ndarray, gt: GroundTruth) -> tuple[np.ndarray, np.ndarray]:
    """Per counted centre [K, 3]: the nearest true fruit, and whether it lies within that fruit's diameter."""
    dist = np.linalg.norm(centres[:, None] - gt.centers[None], axis=2)
    nearest = dist.argmin(1)
    return nearest, dist[np.arange(len(centres)), nearest] <= gt.diameters[nearest]


def _pair_cosines(run: Path, gt_path: Path, reach: float) -> tuple[list[float], list[float], list[tuple]]:
    """(cosines of the pairs halving one true fruit, of the pairs of two fruits) in one run's counted cloud, the
    pairs and cosines being those the caps' join weighs (:func:`close_pair_cosines`); and, for a cloud with viewing
    directions, per pair within ``reach`` of each other after the move (halves?, opposite sides?, distance of the
    moved centres in median true diameters)."""
    gt = load_ground_truth(gt_path)
    cloud, labels = read_cloud(run / 'cloud.npz')
    if labels is None or not np.any(labels > 0):
        return [], [], []
    _, centres, pairs, cosine = close_pair_cosines(cloud.xyz, cloud.embedding, labels.astype(np.int64) - 1,
                                                   reach * float(np.median(gt.diameters)))
    nearest, near = _nearest_true(centres, gt)
    both = near[pairs[:, 0]] & near[pairs[:, 1]]
    same = nearest[pairs[:, 0]] == nearest[pairs[:, 1]]
    return cosine[both & same].tolist(), cosine[both & ~same].tolist(), _moved_pairs(cloud, labels, gt, reach)


def _moved_pairs(cloud: FruitPointCloud, labels: np.ndarray, gt: GroundTruth, reach: float) -> list[tuple]:
    """(halves of one fruit?, seen from opposite sides?, moved-centre distance in diameters) per pair of counted
    clusters whose moved centres lie within ``reach`` diameters, both within a diameter of a true fruit."""
    if cloud.view_dir is None:
        return []
    moved = centre_positions(cloud, ClusterConfig())
    _, groups = label_groups(labels.astype(np.int64) - 1)
    centres = np.array([np.median(moved[g], axis=0) for g in groups])
    facing = group_mean_directions(cloud.view_dir, groups)
    nearest, near = _nearest_true(centres, gt)
    diameter = float(np.median(gt.diameters))
    pairs = cKDTree(centres).query_pairs(reach * diameter, output_type='ndarray')
    return [(bool(nearest[i] == nearest[j]), bool(facing[i] @ facing[j] <= -0.5),
             float(np.linalg.norm(centres[i] - centres[j])) / diameter) for i, j in pairs if near[i] and near[j]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('runs', type=Path, nargs='+')
    parser.add_argument('--gt', type=Path, help="an orchard run's gt_fruits.json")
    parser.add_argument('--reach', type=float, default=1.5, help='pair reach in median true diameters')
    args = parser.parse_args()
    halves: list[float] = []
    two: list[float] = []
    moved: list[tuple] = []
    for run, gt in _runs(args.runs, args.gt):
        if (run / 'cloud.npz').is_file() and gt.is_file():
            same, other, pairs = _pair_cosines(run, gt, args.reach)
            halves += same
            two += other
            moved += pairs
    for name, values in (('halves of one fruit', halves), ('two fruits', two)):
        v = np.asarray(values)
        quantiles = np.round(np.percentile(v, [10, 50, 90, 95]), 2).tolist() if len(v) else []
        print(f'{name}: {len(v)} pairs, cosine 10/50/90/95th percentiles {quantiles}')
    for threshold in (0.9, 0.8, 0.7, 0.6):
        print(f'cosine >= {threshold}: halves {np.mean(np.asarray(halves) >= threshold) if halves else 0:.2f}, '
              f'two fruits {int((np.asarray(two) >= threshold).sum())} of {len(two)}')
    for sides in (True, False):
        for kind in (True, False):
            d = np.array([m[2] for m in moved if m[1] == sides and m[0] == kind])
            within = ', '.join(f'< {t} d: {int((d < t).sum())}' for t in (0.4, 0.5, 0.6, 0.7, 0.8))
            print(f'moved centres, {"opposite sides" if sides else "one side"}, '
                  f'{"halves of one fruit" if kind else "two fruits"}: {len(d)} pairs; {within}')


if __name__ == '__main__':
    main()
