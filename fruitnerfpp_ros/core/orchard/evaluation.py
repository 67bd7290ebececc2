"""A row count against a synthetic row's ground truth (``gt_fruits.json`` with ``tree_id``, ``gt_trees.json``).

- the row: precision / recall / F1 of every fruit (Hungarian matching within one fruit diameter, as the single-tree
  evaluation; fruits no view saw are left out of recall);
- double counts: predictions left unmatched within one diameter of a ground-truth fruit that another prediction
  matched (``across_cuts``: the two came from different segments);
- per tree: the counted trees are paired with the true trunks (Hungarian, horizontal distance); each tree's count
  against its truth, two ways: the fruit growing on it (``truth``) and the fruit whose nearest trunk it is
  (``truth_nearest``: the rule the count applies where canopies overlap);
- positions: each counted trunk against the true one (world, m) and, from ``trees.geojson``, the WGS84 point
  against the true trunk's latitude / longitude (m, on the true datum's tangent plane).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.orchard.geodesy import Datum, enu_from_geodetic
from fruitnerfpp_ros.errors import EvaluationError

__all__ = ['evaluate_row', 'row_eval_table']


def _gt_tree_ids(gt_path: Path) -> np.ndarray:
    data = json.loads(gt_path.read_text())
    try:
        return np.array([int(f['tree_id']) for f in data['fruits']], np.int64)
    except KeyError as err:
        raise EvaluationError(f'{gt_path}: fruits carry no tree_id (not a row of trees)') from err


def _pair(a: np.ndarray, b: np.ndarray, reach: float) -> list[tuple[int, int]]:
    if len(a) == 0 or len(b) == 0:
        return []
    d = np.linalg.norm(a[:, None, :2] - b[None, :, :2], axis=2)
    rows, cols = linear_sum_assignment(np.where(d <= reach, d, 1e6))
    return [(int(r), int(c)) for r, c in zip(rows, cols) if d[r, c] <= reach]


def evaluate_row(gt_dir: str | Path, centers: np.ndarray, segments: np.ndarray, fruit_tree_ids: np.ndarray,
                 tree_ids: np.ndarray, tree_positions: np.ndarray, tree_counts: np.ndarray,
                 trees_geojson: str | Path | None = None, tolerance: float = 1.0) -> dict[str, Any]:
    """Score a row count (see the module docstring).

    Args:
        gt_dir: the synthetic row's dataset directory.
        centers: [M, 3] counted fruit centres; segments: [M] their segments; fruit_tree_ids: [M] their trees.
        tree_ids / tree_positions / tree_counts: the counted trees ([T], [T, 3], [T]).
        trees_geojson: the written trees.geojson (positions checked against the truth's WGS84 trunks).

    Raises:
        EvaluationError: missing or malformed ground truth.
    """
    gt_dir = Path(gt_dir)
    gt = load_ground_truth(gt_dir / 'gt_fruits.json')
    gt_tree = _gt_tree_ids(gt_dir / 'gt_fruits.json')
    try:
        truth_trees = json.loads((gt_dir / 'gt_trees.json').read_text())
    except (OSError, ValueError) as err:
        raise EvaluationError(f'{gt_dir}/gt_trees.json: {err}') from err
    trunks = np.array([t['trunk'] for t in truth_trees['trees']], np.float64)
    true_ids = np.array([t['id'] for t in truth_trees['trees']], np.int64)
    centers = np.asarray(centers, np.float64).reshape(-1, 3)
    metrics = evaluate_counts(centers, gt, tolerance=tolerance)
    pairs = np.asarray(metrics.hungarian.pairs, np.int64).reshape(-1, 2)
    matched_pred = set(pairs[:, 0].tolist())
    owner = dict(zip(pairs[:, 1].tolist(), pairs[:, 0].tolist()))
    duplicates = across = 0
    for p in range(len(centers)):
        if p in matched_pred:
            continue
        d = np.linalg.norm(gt.centers - centers[p], axis=1)
        near = [g for g in np.flatnonzero(d <= tolerance * gt.diameters) if g in owner]
        if near:
            duplicates += 1
            across += int(segments[owner[near[0]]] != segments[p])
    nearest = np.argmin(np.linalg.norm(gt.centers[:, None, :2] - trunks[None, :, :2], axis=2), axis=1)
    spacing = float(truth_trees.get('spacing_m') or 1.0)
    pairing = _pair(np.asarray(tree_positions, np.float64).reshape(-1, 3), trunks, 0.5 * spacing)
    rows = []
    for k, true_id in enumerate(true_ids):
        found = [p for p, t in pairing if t == k]
        seen = gt.seen & (gt_tree == true_id)
        truth = int(seen.sum())
        truth_nearest = int((gt.seen & (nearest == k)).sum())
        row: dict[str, Any] = {'tree': int(true_id), 'truth': truth, 'truth_nearest': truth_nearest,
                               'truth_all': int((gt_tree == true_id).sum())}
        if found:
            p = found[0]
            count = int(tree_counts[p])
            row.update({'counted_as': int(tree_ids[p]), 'count': count,
                        'error_pct': round(100.0 * (count - truth) / max(truth, 1), 1),
                        'error_nearest_pct': round(100.0 * (count - truth_nearest) / max(truth_nearest, 1), 1),
                        'trunk_error_m': round(float(np.linalg.norm(tree_positions[p][:2] - trunks[k][:2])), 3)})
        rows.append(row)
    result: dict[str, Any] = {
        'row': {'count': metrics.count, 'gt_count': metrics.gt_count, 'gt_unseen': metrics.gt_unseen,
                'tp': metrics.hungarian.tp, 'precision': round(metrics.precision, 4),
                'recall': round(metrics.recall, 4), 'f1': round(metrics.f1, 4)},
        'double_counts': {'total': duplicates, 'across_cuts': across},
        'trees_found': len(tree_ids), 'trees_true': len(true_ids), 'trees': rows,
        'grown_on_other_nearest_trunk': int((true_ids[nearest] != gt_tree).sum())}
    if trees_geojson is not None and Path(trees_geojson).is_file():
        result['geo'] = _geo_errors(Path(trees_geojson), truth_trees, pairing, tree_ids)
    return result


def _geo_errors(path: Path, truth: dict[str, Any], pairing: list[tuple[int, int]],
                tree_ids: np.ndarray) -> dict[str, Any]:
    """Horizontal distance (m) of each tree's GeoJSON point from its true trunk (both on the true datum's plane)."""
    datum = Datum(truth['datum']['latitude'], truth['datum']['longitude'], truth['datum']['altitude'])
    features = {int(f['properties']['tree_id']): f['geometry']['coordinates']
                for f in json.loads(path.read_text())['features']}
    errors = []
    for p, k in pairing:
        if int(tree_ids[p]) not in features:
            continue
        lon, lat = features[int(tree_ids[p])][:2]
        t = truth['trees'][k]
        a = enu_from_geodetic(np.array([[lat, lon, datum.altitude_m]]), datum)[0]
        b = enu_from_geodetic(np.array([[t['latitude'], t['longitude'], datum.altitude_m]]), datum)[0]
        errors.append(float(np.linalg.norm(a[:2] - b[:2])))
    return {'trees_checked': len(errors), 'max_error_m': round(max(errors), 3) if errors else None,
            'mean_error_m': round(float(np.mean(errors)), 3) if errors else None}


def row_eval_table(result: dict[str, Any]) -> str:
    """Text table of :func:`evaluate_row`'s result."""
    r = result['row']
    lines = [f"row: {r['count']} counted, {r['gt_count']} true ({r['gt_unseen']} unseen); P {r['precision']:.3f} "
             f"R {r['recall']:.3f} F1 {r['f1']:.3f}; double counts {result['double_counts']['total']} "
             f"({result['double_counts']['across_cuts']} across cuts); trees found {result['trees_found']} of "
             f"{result['trees_true']}",
             f"{'tree':>4} {'truth':>6} {'nearest':>8} {'count':>6} {'error':>7} {'trunk m':>8}"]
    for t in result['trees']:
        count = t.get('count', '-')
        error = f"{t['error_pct']:+.0f}%" if 'error_pct' in t else '-'
        lines.append(f"{t['tree']:>4} {t['truth']:>6} {t['truth_nearest']:>8} {count:>6} {error:>7} "
                     f"{t.get('trunk_error_m', '-'):>8}")
    if 'geo' in result:
        g = result['geo']
        lines.append(f"trees.geojson vs true trunks: max {g['max_error_m']} m, mean {g['mean_error_m']} m "
                     f"({g['trees_checked']} trees)")
    return '\n'.join(lines)
