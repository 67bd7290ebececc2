#!/usr/bin/env python3
"""Where a suite run's missed fruits were lost: in the export (no cloud points near the fruit) or in the clustering.

For each scene directory of a suite run (``fruitnerfpp bench accuracy --out DIR``; dataset scenes, not bag replays)
the fruits some training view sees and that the run's Hungarian matching (``run/eval.json``) left unmatched are
sorted into:

- ``no points``: fewer than 10 % of a fruit's points (``points_per_fruit`` of the run's count) lie within 0.7 ground
  truth diameters of its centre: the export kept no surface there, and no clustering can count it;
- ``merged``: it has points and a counted centre lies within 1.5 diameters (matched to another fruit): two fruits
  counted as one;
- ``other``: it has points and no counted centre near it (its cluster was too small, or noise).

Usage::

    python bench/miss_kinds.py DIR/apple_hemi_200 DIR/mango_hemi_100 ...
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from fruitnerfpp_ros.core.benchmark.scene_run import scored_ground_truth
from fruitnerfpp_ros.core.export.npz_io import read_cloud


def miss_kinds(scene_dir: Path) -> dict[str, int]:
    """The counts of seen, missed, and each kind of miss in one scene directory."""
    gt = scored_ground_truth(scene_dir / 'data' / 'gt_fruits.json', scene_dir / 'data', scene_dir / 'run', 8)
    counts = json.loads((scene_dir / 'run' / 'counts.json').read_text())
    matched = np.zeros(len(gt.ids), bool)
    for _, g in json.loads((scene_dir / 'run' / 'eval.json').read_text())['hungarian']['pairs']:
        matched[g] = True
    cloud, _ = read_cloud(scene_dir / 'run' / 'cloud.npz')
    near = np.asarray(cKDTree(cloud.xyz).query_ball_point(gt.centers, 0.7 * gt.diameters, return_length=True))
    centers = np.array([f['center'] for f in counts['fruits']]).reshape(-1, 3)
    nearest = cKDTree(centers).query(gt.centers)[0] if len(centers) else np.full(len(gt.ids), np.inf)
    miss = (gt.n_views_visible != 0) & ~matched
    empty = miss & (near < 0.1 * counts['stats']['points_per_fruit'])
    merged = miss & ~empty & (nearest < 1.5 * gt.diameters)
    return {'seen': int(np.count_nonzero(gt.n_views_visible != 0)), 'missed': int(miss.sum()),
            'no points': int(empty.sum()), 'merged': int(merged.sum()), 'other': int((miss & ~empty & ~merged).sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('scenes', type=Path, nargs='+', help='scene directories of a suite run')
    args = parser.parse_args()
    keys = ('seen', 'missed', 'no points', 'merged', 'other')
    print('| scene | ' + ' | '.join(keys) + ' |\n|---|' + '---:|' * len(keys))
    total = dict.fromkeys(keys, 0)
    for scene in args.scenes:
        kinds = miss_kinds(scene)
        total = {k: total[k] + kinds[k] for k in keys}
        print(f'| {scene.name} | ' + ' | '.join(str(kinds[k]) for k in keys) + ' |')
    print('| **all** | ' + ' | '.join(f'**{total[k]}**' for k in keys) + ' |')


if __name__ == '__main__':
    main()
