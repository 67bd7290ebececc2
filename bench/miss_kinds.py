#!/usr/bin/env python3
"""Where a suite run's missed fruits were lost: in the export (no cloud points near the fruit) or in the clustering.

For each scene directory of a suite run (``fruitnerfpp bench accuracy --out DIR``; bag replays score their
keyframes) the fruits some training view sees and that the run's Hungarian matching (``run/eval.json``, or the
suite's scoring where a bag replay wrote none) left unmatched are sorted into:

- ``no points``: fewer than 10 % of a fruit's points (``points_per_fruit`` of the run's count) lie within 0.7 ground
  truth diameters of its centre: the export kept no surface there, and no clustering can count it;
- ``merged``: it has points and a counted centre lies within 1.5 diameters (matched to another fruit): two fruits
  counted as one;
- ``other``: it has points and no counted centre near it (its cluster was too small, or noise).

Beside the kinds, what the training views showed of each fruit: a fruit's **shown** size is the most pixels its
ground-truth instance mask holds in one training view. ``shown < 12 px`` counts the misses no training view showed
with 12 pixels or more (a blob of about 4 x 3 pixels), and ``recall >= 12 px`` is the recall over the seen fruits
that some view showed that large: a miss of a fruit the views hardly show is a different problem from a miss of
a fruit in plain view. ``--types`` adds the recall per fruit type (the mixed scenes).

Usage::

    python bench/miss_kinds.py DIR/apple_hemi_200 DIR/mango_hemi_100 ...
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.benchmark.scene_run import scored_ground_truth
from fruitnerfpp_ros.core.data.dataset import split_indices
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import GroundTruth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.export.npz_io import read_cloud

#: a fruit some training view shows with at least this many mask pixels is "shown"
SHOWN_PX = 12


def largest_view_pixels(dataset_dir: Path, gt: GroundTruth, eval_every: int = 8) -> np.ndarray:
    """[G] the most pixels each fruit's instance mask holds in one training view of ``dataset_dir`` (the
    synthetic masks label a fruit by its ground-truth id)."""
    frames = read_transforms(dataset_dir).frames
    train, _ = split_indices(len(frames), eval_every)
    row = {int(fid): i for i, fid in enumerate(gt.ids)}
    largest = np.zeros(len(gt.ids), np.int64)
    for i in train:
        if frames[i].instance_path is None:
            continue
        mask = cv2.imread(str(dataset_dir / frames[i].instance_path), cv2.IMREAD_UNCHANGED)
        ids, pixels = np.unique(mask, return_counts=True)
        known = np.array([int(v) in row for v in ids], bool)
        where = np.array([row[int(v)] for v in ids[known]], np.int64)
        largest[where] = np.maximum(largest[where], pixels[known])
    return largest


def miss_kinds(scene_dir: Path, types: bool = False) -> dict[str, int | float]:
    """The counts of seen, missed, and each kind of miss in one scene directory."""
    run = scene_dir / 'run'
    dataset = run / 'keyframes' if (run / 'keyframes').is_dir() else scene_dir / 'data'
    gt = scored_ground_truth(scene_dir / 'data' / 'gt_fruits.json', dataset, run, 8)
    counts = json.loads((run / 'counts.json').read_text())
    centers = np.array([f['center'] for f in counts['fruits']]).reshape(-1, 3)
    evaluated = run / 'eval.json'  # the run's own scoring; a bag replay writes none: score it as the suite does
    pairs = (json.loads(evaluated.read_text())['hungarian']['pairs'] if evaluated.is_file()
             else evaluate_counts(centers, gt).hungarian.pairs)
    matched = np.zeros(len(gt.ids), bool)
    for _, g in pairs:
        matched[g] = True
    cloud, _ = read_cloud(scene_dir / 'run' / 'cloud.npz')
    near = np.asarray(cKDTree(cloud.xyz).query_ball_point(gt.centers, 0.7 * gt.diameters, return_length=True))
    nearest = cKDTree(centers).query(gt.centers)[0] if len(centers) else np.full(len(gt.ids), np.inf)
    miss = (gt.n_views_visible != 0) & ~matched
    empty = miss & (near < 0.1 * counts['stats']['points_per_fruit'])
    merged = miss & ~empty & (nearest < 1.5 * gt.diameters)
    shown = gt.seen & (largest_view_pixels(dataset, gt) >= SHOWN_PX)
    kinds: dict[str, int | float] = {
        'seen': int(gt.seen.sum()), 'missed': int(miss.sum()), 'no points': int(empty.sum()),
        'merged': int(merged.sum()), 'other': int((miss & ~empty & ~merged).sum()),
        f'shown < {SHOWN_PX} px': int((miss & ~shown).sum()),
        f'recall >= {SHOWN_PX} px': round(float(matched[shown].mean()) if shown.any() else float('nan'), 3)}
    if types:
        for name in sorted(set(gt.types)):
            of_type = gt.seen & (np.asarray(gt.types) == name)
            kinds[f'recall {name}'] = round(float(matched[of_type].mean()), 3)
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('scenes', type=Path, nargs='+', help='scene directories of a suite run')
    parser.add_argument('--types', action='store_true', help='also the recall per fruit type')
    args = parser.parse_args()
    rows = {scene.name: miss_kinds(scene, args.types) for scene in args.scenes}
    summed = ('seen', 'missed', 'no points', 'merged', 'other', f'shown < {SHOWN_PX} px')
    keys = list(dict.fromkeys(k for kinds in rows.values() for k in kinds))
    print('| scene | ' + ' | '.join(keys) + ' |\n|---|' + '---:|' * len(keys))
    for name, kinds in rows.items():
        print(f'| {name} | ' + ' | '.join(str(kinds.get(k, '')) for k in keys) + ' |')
    total = {k: sum(int(kinds[k]) for kinds in rows.values()) for k in summed}
    print('| **all** | ' + ' | '.join(f'**{total[k]}**' if k in total else '' for k in keys) + ' |')


if __name__ == '__main__':
    main()
