"""bench/miss_kinds.py on a suite-shaped scene built by hand: three missed fruits, one of each kind by construction,
and every other fruit matched."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.dataset import split_indices
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.export.npz_io import write_npz
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from test.bench_scripts import load_bench_script


def _surface(center: np.ndarray, radius: float, n: int, rng: np.random.Generator) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    return center + radius * direction / np.linalg.norm(direction, axis=1, keepdims=True)


def test_each_kind_of_miss_is_told_apart(tiny_apple_dataset: Path, tmp_path: Path) -> None:
    scene = tmp_path / 'suite' / 'apple'
    shutil.copytree(tiny_apple_dataset, scene / 'data')
    (scene / 'run').mkdir()
    gt = load_ground_truth(scene / 'data' / 'gt_fruits.json')
    assert len(gt.ids) >= 8 and np.all(gt.n_views_visible != 0)  # every fruit seen (no run config: all views)
    gaps = np.linalg.norm(gt.centers[:, None] - gt.centers[None], axis=2) / gt.diameters[:, None]
    np.fill_diagonal(gaps, np.inf)
    other = int(np.argmax(gaps.min(axis=1)))                     # the loneliest fruit: no centre near it
    assert gaps[other].min() > 2.5
    no_points, merged = [g for g in range(len(gt.ids)) if g != other and gaps[other, g] > 2.5][:2]
    counted = [g for g in range(len(gt.ids)) if g not in (no_points, merged, other)]
    centers = [gt.centers[g] for g in counted] + [gt.centers[merged] + [0.5 * gt.diameters[merged], 0.0, 0.0]]
    pairs = [[p, g] for p, g in enumerate(counted)]              # the extra centre near `merged` matched nothing
    rng = np.random.default_rng(0)
    xyz = np.concatenate([_surface(gt.centers[g], 0.5 * gt.diameters[g], 60, rng)
                          for g in range(len(gt.ids)) if g != no_points])
    n = len(xyz)
    write_npz(scene / 'run' / 'cloud.npz', FruitPointCloud(
        xyz.astype(np.float32), np.zeros((n, 3), np.uint8), np.ones(n, np.float32),
        np.tile(np.eye(1, 8, dtype=np.float32), (n, 1)), spacing_m=0.01, fruit_diameter_m=0.075))
    (scene / 'run' / 'counts.json').write_text(json.dumps(
        {'fruits': [{'center': list(map(float, c))} for c in centers], 'stats': {'points_per_fruit': 60.0}}))
    (scene / 'run' / 'eval.json').write_text(json.dumps({'hungarian': {'pairs': pairs}}))

    # the loneliest fruit shows at most 5 pixels in any view: a miss no view showed with 12
    frames = read_transforms(scene / 'data').frames
    for frame in frames:
        path = scene / 'data' / frame.instance_path
        mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        mask.reshape(-1)[np.flatnonzero(mask == gt.ids[other])[5:]] = 0
        cv2.imwrite(str(path), mask)
    train, _ = split_indices(len(frames), 8)
    largest = np.zeros(len(gt.ids), np.int64)
    for view in train:
        mask = cv2.imread(str(scene / 'data' / frames[view].instance_path), cv2.IMREAD_UNCHANGED)
        for g, fid in enumerate(gt.ids):
            largest[g] = max(largest[g], int(np.count_nonzero(mask == fid)))
    shown = largest >= 12
    assert not shown[other] and shown[counted].all()

    kinds = load_bench_script('miss_kinds').miss_kinds(scene)

    missed = [no_points, merged, other]
    assert kinds == {'seen': len(gt.ids), 'missed': 3, 'no points': 1, 'merged': 1, 'other': 1,
                     'shown < 12 px': int(np.count_nonzero(~shown[missed])),
                     'recall >= 12 px': round(len(counted) / int(shown.sum()), 3)}
