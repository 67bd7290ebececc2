#!/usr/bin/env python3
"""Pairs of counted fruits near each other, on finished suite runs: where do both centres fall in the training views?

For every scene of the suite directories given (``fruitnerfpp bench accuracy --out DIR``), the run's cloud is counted
as the pipeline counts it with the pieces' join off (``clustering.masks.join_pieces: false``), and every pair of
counted fruits within ``--reach`` fruit diameters is labelled with the ground truth: ``two fruits`` (each matched to
its own ground-truth fruit) or ``a piece`` (one unmatched, nearest to the other's ground-truth fruit). Per label: the
number of training views in which both centres fall on one instance mask, and on two (the evidence
``core/clustering/mask_pieces.py`` joins on). This is the table of docs/results/accuracy_suite.md, "Pieces of one
fruit joined by the masks".

Usage::

    python bench/mask_pairs.py cpu30 ho31 q30 [--reach 2.0]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.benchmark.scene_run import scored_ground_truth
from fruitnerfpp_ros.core.clustering.config import ClusterConfig
from fruitnerfpp_ros.core.clustering.mask_pieces import mask_ids_at, shared_and_split_views
from fruitnerfpp_ros.core.evaluation.matching import hungarian_match
from fruitnerfpp_ros.core.export.npz_io import read_cloud
from fruitnerfpp_ros.core.pipeline import count_with_views, load_run_views
from fruitnerfpp_ros.core.training import TrainConfig


def scene_pairs(scene_dir: Path, reach: float) -> list[tuple[str, int, int]]:
    """(label, views on one mask, views on two masks) of each pair of the scene's counted fruits within reach."""
    keyframes = scene_dir / 'run' / 'keyframes'               # a bag scene trained on the replay's keyframes
    dataset = keyframes if keyframes.is_dir() else scene_dir / 'data'
    gt = scored_ground_truth(scene_dir / 'data' / 'gt_fruits.json', dataset, scene_dir / 'run',
                             TrainConfig().data.eval_every)
    config = ClusterConfig()
    config = dataclasses.replace(config, masks=dataclasses.replace(config.masks, join_pieces=False))
    views = load_run_views(scene_dir / 'run', dataset)
    count = count_with_views(read_cloud(scene_dir / 'run' / 'cloud.npz')[0], config, views)
    centers = count.centers()
    if len(centers) < 2:
        return []
    matched = dict(np.asarray(hungarian_match(centers, gt.centers, gt.diameters), np.int64).reshape(-1, 2).tolist())
    pairs = cKDTree(centers).query_pairs(reach * views.fruit_diameter_m, output_type='ndarray')
    if not len(pairs):
        return []
    shared, split = shared_and_split_views(mask_ids_at(views.masks, centers), pairs)
    out = []
    for (a, b), one, two in zip(pairs.tolist(), shared.tolist(), split.tolist()):
        if a in matched and b in matched:
            label = 'two fruits'
        elif (a in matched) != (b in matched):
            piece, whole = (b, a) if a in matched else (a, b)
            nearest = int(np.argmin(np.linalg.norm(gt.centers - centers[piece], axis=1)))
            label = 'a piece' if nearest == matched[whole] else 'a false fruit beside another'
        else:
            label = 'two false fruits'
        out.append((label, one, two))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('suites', nargs='+', type=Path, help='suite directories (fruitnerfpp bench accuracy --out)')
    parser.add_argument('--reach', type=float, default=2.0, help='pairs within this many fruit diameters')
    args = parser.parse_args()
    pairs: list[tuple[str, int, int]] = []
    for scene in sorted(p.parent.parent for d in args.suites for p in d.glob('*/run/cloud.npz')):
        pairs += scene_pairs(scene, args.reach)
        print(f'{scene}: {len(pairs)} pairs so far', flush=True)
    print('| pair | pairs | views on one mask: median (90 %) | on two masks: median (10 %) |')
    print('|---|---:|---|---|')
    for label in sorted({p[0] for p in pairs}):
        one = np.array([p[1] for p in pairs if p[0] == label])
        two = np.array([p[2] for p in pairs if p[0] == label])
        print(f'| {label} | {len(one)} | {np.median(one):g} ({np.quantile(one, 0.9):g}) | '
              f'{np.median(two):g} ({np.quantile(two, 0.1):g}) |')


if __name__ == '__main__':
    main()
