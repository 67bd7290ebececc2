"""Counting metrics (count, precision, recall, F1) under both matchings, as in the paper's Table II."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fruitnerfpp_ros.core.evaluation.ground_truth import GroundTruth
from fruitnerfpp_ros.core.evaluation.matching import greedy_match, hungarian_match

__all__ = ['MatchScores', 'EvalMetrics', 'evaluate_counts', 'EVAL_FORMAT_VERSION']

EVAL_FORMAT_VERSION = 1


@dataclass(frozen=True)
class MatchScores:
    """Scores of one matching.

    Attributes:
        tp: matched predictions.
        tp_seen: matches to ground-truth fruits seen by at least one view.
        precision: tp / count (1 when nothing was predicted).
        recall: tp / gt_count, or tp_seen / gt_seen when unseen fruits are excluded.
        f1: harmonic mean of precision and recall.
        pairs: (prediction index, ground-truth index) of each match.
    """

    tp: int
    tp_seen: int
    precision: float
    recall: float
    f1: float
    pairs: list[list[int]]


@dataclass(frozen=True)
class EvalMetrics:
    """Count evaluation against ground truth.

    Attributes:
        count: predicted fruits.
        gt_count: ground-truth fruits (all).
        gt_unseen: ground-truth fruits that no training view saw (``n_views_visible == 0``).
        exclude_unseen: whether recall ignores the unseen fruits.
        tolerance: match reach, in ground-truth diameters.
        hungarian: scores of the optimal one-to-one matching (the headline figures).
        greedy: scores of the paper's greedy nearest-unmatched matching.
    """

    count: int
    gt_count: int
    gt_unseen: int
    exclude_unseen: bool
    tolerance: float
    hungarian: MatchScores
    greedy: MatchScores

    @property
    def precision(self) -> float:
        return self.hungarian.precision

    @property
    def recall(self) -> float:
        return self.hungarian.recall

    @property
    def f1(self) -> float:
        return self.hungarian.f1

    def to_json(self) -> dict[str, Any]:
        """Flat headline figures (Hungarian) plus both matchings in full."""
        data = asdict(self)
        return {'version': EVAL_FORMAT_VERSION, 'count': self.count, 'gt_count': self.gt_count,
                'gt_unseen': self.gt_unseen, 'exclude_unseen': self.exclude_unseen, 'tolerance': self.tolerance,
                'tp': self.hungarian.tp, 'precision': self.precision, 'recall': self.recall, 'f1': self.f1,
                'hungarian': data['hungarian'], 'greedy': data['greedy']}

    def table(self) -> str:
        """A small text table of both matchings."""
        lines = [f'count {self.count}   gt {self.gt_count}'
                 + (f' ({self.gt_unseen} unseen, {"excluded from" if self.exclude_unseen else "included in"} '
                    'recall)' if self.gt_unseen else ''),
                 f'{"matching":<10} {"TP":>5} {"precision":>9} {"recall":>7} {"F1":>6}']
        for name, s in (('hungarian', self.hungarian), ('greedy', self.greedy)):
            lines.append(f'{name:<10} {s.tp:>5} {s.precision:>9.3f} {s.recall:>7.3f} {s.f1:>6.3f}')
        return '\n'.join(lines)


def _scores(pairs: np.ndarray, count: int, gt: GroundTruth, exclude_unseen: bool) -> MatchScores:
    tp = len(pairs)
    tp_seen = int(gt.seen[pairs[:, 1]].sum()) if tp else 0
    precision = tp / count if count else 1.0
    if exclude_unseen:
        n_seen = int(gt.seen.sum())
        recall = tp_seen / n_seen if n_seen else 1.0
    else:
        recall = tp / len(gt) if len(gt) else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return MatchScores(tp, tp_seen, float(precision), float(recall), float(f1), pairs.tolist())


def evaluate_counts(pred_centers: np.ndarray, gt: GroundTruth, *, tolerance: float = 1.0,
                    exclude_unseen: bool = True) -> EvalMetrics:
    """Score predicted fruit centres [P, 3] (m) against the ground truth.

    Args:
        pred_centers: predicted centres.
        gt: ground truth.
        tolerance: a match needs centres closer than ``tolerance`` GT diameters.
        exclude_unseen: recall over the fruits seen by at least one view only (predictions matched to unseen
            fruits still count as true positives for precision).
    """
    pred = np.asarray(pred_centers, np.float64).reshape(-1, 3)
    hungarian = _scores(hungarian_match(pred, gt.centers, gt.diameters, tolerance=tolerance), len(pred), gt,
                        exclude_unseen)
    greedy = _scores(greedy_match(pred, gt.centers, gt.diameters, tolerance=tolerance), len(pred), gt,
                     exclude_unseen)
    return EvalMetrics(count=len(pred), gt_count=len(gt), gt_unseen=int((~gt.seen).sum()),
                       exclude_unseen=exclude_unseen, tolerance=tolerance, hungarian=hungarian, greedy=greedy)
