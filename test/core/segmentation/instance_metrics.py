"""Scoring of predicted instance maps against ground truth: pixel IoU and per-view Hungarian instance matching."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment


class InstanceScores(NamedTuple):
    """Pooled over views: fruit-pixel IoU; instances matched at mask IoU > 0.5 (true positives), predicted
    instances, ground-truth instances of at least ``min_gt_area`` pixels."""

    pixel_iou: float
    true_positives: int
    predicted: int
    ground_truth: int

    @property
    def precision(self) -> float:
        return self.true_positives / max(self.predicted, 1)

    @property
    def recall(self) -> float:
        return self.true_positives / max(self.ground_truth, 1)

    @property
    def f1(self) -> float:
        return 2 * self.precision * self.recall / max(self.precision + self.recall, 1e-9)


def score_views(gt_views: list[np.ndarray], pred_views: list[np.ndarray], *, min_gt_area: int = 20) -> InstanceScores:
    """Score [H, W] predicted id maps against [H, W] ground-truth id maps, view by view.

    A ground-truth instance smaller than ``min_gt_area`` pixels (a sliver behind leaves) is not required; a
    prediction that lies mostly on such a sliver is neither a true nor a false positive.
    """
    inter = union = tp = n_pred = n_gt = 0
    for gt, pred in zip(gt_views, pred_views):
        inter += int(((gt > 0) & (pred > 0)).sum())
        union += int(((gt > 0) | (pred > 0)).sum())
        g_ids, g_inv = np.unique(gt, return_inverse=True)
        p_ids, p_inv = np.unique(pred, return_inverse=True)
        table = np.bincount(g_inv.ravel() * len(p_ids) + p_inv.ravel(),
                            minlength=len(g_ids) * len(p_ids)).reshape(len(g_ids), len(p_ids))
        g_area, p_area = table.sum(1), table.sum(0)
        big, small, real = (g_ids > 0) & (g_area >= min_gt_area), (g_ids > 0) & (g_area < min_gt_area), p_ids > 0
        overlap = table[np.ix_(big, real)]
        iou = overlap / (g_area[big][:, None] + p_area[real][None] - overlap)
        rows, cols = linear_sum_assignment(-iou)
        hit = iou[rows, cols] > 0.5
        matched = np.zeros(int(real.sum()), bool)
        matched[cols[hit]] = True
        on_sliver = table[np.ix_(small, real)].sum(0) > 0.5 * p_area[real]
        tp += int(hit.sum())
        n_gt += int(big.sum())
        n_pred += int((matched | ~on_sliver).sum())
    return InstanceScores(inter / max(union, 1), tp, n_pred, n_gt)
