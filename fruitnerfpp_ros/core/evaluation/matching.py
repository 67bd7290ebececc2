"""One-to-one matching of predicted fruit centres to ground-truth centres.

A pair can match when the centres are closer than the ground-truth fruit's diameter (times ``tolerance``).
``hungarian_match`` maximises the number of matches, then minimises their total distance (scipy
linear_sum_assignment); ``greedy_match`` is the paper's / FruitNeRF's rule: each prediction in turn takes the
nearest still-unmatched ground-truth fruit within reach.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

__all__ = ['hungarian_match', 'greedy_match']


def _reach(pred: np.ndarray, gt: np.ndarray, gt_diameters: np.ndarray, tolerance: float) -> tuple[np.ndarray, ...]:
    dist = cdist(np.asarray(pred, np.float64).reshape(-1, 3), np.asarray(gt, np.float64).reshape(-1, 3))
    return dist, dist <= tolerance * np.asarray(gt_diameters, np.float64)[None, :]


def hungarian_match(pred: np.ndarray, gt: np.ndarray, gt_diameters: np.ndarray, *,
                    tolerance: float = 1.0) -> np.ndarray:
    """Maximum one-to-one matching within reach.

    Args:
        pred: [P, 3] predicted centres (m).
        gt: [G, 3] ground-truth centres (m).
        gt_diameters: [G] ground-truth diameters (m).
        tolerance: reach in ground-truth diameters.

    Returns:
        [M, 2] int pairs (prediction index, ground-truth index).
    """
    if len(pred) == 0 or len(gt) == 0:
        return np.zeros((0, 2), np.int64)
    dist, ok = _reach(pred, gt, gt_diameters, tolerance)
    # an out-of-reach pair costs more than any sum of in-reach ones: cardinality first, then distance
    big = 1.0 + float(dist[ok].sum()) if ok.any() else 1.0
    cost = np.where(ok, dist, big + dist)
    rows, cols = linear_sum_assignment(cost)
    keep = ok[rows, cols]
    return np.stack([rows[keep], cols[keep]], 1).astype(np.int64)


def greedy_match(pred: np.ndarray, gt: np.ndarray, gt_diameters: np.ndarray, *,
                 tolerance: float = 1.0) -> np.ndarray:
    """The paper's greedy matching: predictions in order, each to its nearest unmatched ground truth in reach.

    Returns:
        [M, 2] int pairs (prediction index, ground-truth index).
    """
    if len(pred) == 0 or len(gt) == 0:
        return np.zeros((0, 2), np.int64)
    dist, ok = _reach(pred, gt, gt_diameters, tolerance)
    dist = np.where(ok, dist, np.inf)
    taken = np.zeros(len(gt), bool)
    pairs = []
    for p in range(len(pred)):  # one step per predicted fruit (hundreds), not per point
        row = np.where(taken, np.inf, dist[p])
        g = int(np.argmin(row))
        if np.isfinite(row[g]):
            taken[g] = True
            pairs.append((p, g))
    return np.asarray(pairs, np.int64).reshape(-1, 2)
