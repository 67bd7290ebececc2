"""Ground truth loading, Hungarian / greedy matching and P/R/F1."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, load_predicted_centers, parse_ground_truth
from fruitnerfpp_ros.core.evaluation.matching import greedy_match, hungarian_match
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.errors import EvaluationError


def _gt(centers: list[list[float]], radius: float = 0.04, views: list[int] | None = None) -> dict:
    views = views or [5] * len(centers)
    return {'fruits': [{'id': i + 1, 'type': 'apple', 'center': c, 'radius': radius, 'n_views_visible': v}
                       for i, (c, v) in enumerate(zip(centers, views))]}


def test_perfect_and_partial_predictions() -> None:
    gt = parse_ground_truth(_gt([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]))
    perfect = evaluate_counts(gt.centers + 0.01, gt)
    assert (perfect.count, perfect.gt_count, perfect.hungarian.tp) == (4, 4, 4)
    assert perfect.precision == perfect.recall == perfect.f1 == 1.0
    # one missed, one far-off false positive, one within a diameter (0.08 m) but off by 0.07
    pred = np.array([[0, 0, 0], [1.07, 0, 0], [2, 0, 0], [5, 5, 5]], float)
    m = evaluate_counts(pred, gt)
    assert m.hungarian.tp == 3
    assert m.precision == pytest.approx(0.75) and m.recall == pytest.approx(0.75) and m.f1 == pytest.approx(0.75)
    far = evaluate_counts(np.array([[1.09, 0, 0]]), gt)  # beyond one diameter
    assert far.hungarian.tp == 0 and far.f1 == 0.0
    none = evaluate_counts(np.zeros((0, 3)), gt)
    assert none.count == 0 and none.recall == 0.0 and none.precision == 1.0


def test_hungarian_beats_greedy_where_greedy_is_suboptimal() -> None:
    gt = np.array([[0.0, 0, 0], [0.09, 0, 0]])
    diam = np.array([0.1, 0.1])
    pred = np.array([[0.04, 0, 0], [-0.06, 0, 0]])  # the first is nearest GT0 but could take GT1
    assert len(greedy_match(pred, gt, diam)) == 1
    pairs = hungarian_match(pred, gt, diam)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 1), (1, 0)]
    metrics = evaluate_counts(pred, parse_ground_truth(_gt(gt.tolist(), radius=0.05)))
    assert metrics.hungarian.tp == 2 and metrics.greedy.tp == 1
    assert 'greedy' in metrics.table() and 'hungarian' in metrics.table()


def test_unseen_fruits_are_reported_apart_and_excluded_from_recall_by_flag() -> None:
    gt = parse_ground_truth(_gt([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], views=[3, 3, 3, 0]))
    pred = gt.centers[:3]
    excluded = evaluate_counts(pred, gt)
    assert excluded.gt_unseen == 1 and excluded.exclude_unseen
    assert excluded.recall == 1.0 and excluded.f1 == 1.0
    included = evaluate_counts(pred, gt, exclude_unseen=False)
    assert included.recall == pytest.approx(0.75)
    data = excluded.to_json()
    assert {'count', 'gt_count', 'precision', 'recall', 'f1', 'gt_unseen', 'greedy', 'hungarian'} <= set(data)


def test_radii_use_the_largest_semi_axis(tmp_path: Path) -> None:
    path = tmp_path / 'gt_fruits.json'
    pear = {'id': 7, 'type': 'pear', 'center': [0, 0, 0], 'radii': [0.03, 0.03, 0.05]}
    path.write_text(json.dumps({'fruits': [pear]}))
    gt = load_ground_truth(path)
    assert gt.ids.tolist() == [7] and gt.diameters.tolist() == [0.1] and gt.n_views_visible.tolist() == [-1]
    assert gt.seen.tolist() == [True]


def test_malformed_inputs_raise_evaluation_errors(tmp_path: Path) -> None:
    with pytest.raises(EvaluationError, match='nothere.json: ground truth file not found'):
        load_ground_truth(tmp_path / 'nothere.json')
    bad = tmp_path / 'bad.json'
    bad.write_text('{not json')
    with pytest.raises(EvaluationError, match='bad.json: not valid JSON'):
        load_ground_truth(bad)
    with pytest.raises(EvaluationError, match='"fruits" list'):
        parse_ground_truth({'apples': []})
    with pytest.raises(EvaluationError, match=r'fruits\[1\]: "center"'):
        parse_ground_truth({'fruits': [{'center': [0, 0, 0], 'radius': 0.1}, {'center': [0, 0], 'radius': 0.1}]})
    with pytest.raises(EvaluationError, match='radius'):
        parse_ground_truth({'fruits': [{'center': [0, 0, 0]}]})
    with pytest.raises(EvaluationError, match='positive'):
        parse_ground_truth({'fruits': [{'center': [0, 0, 0], 'radius': -1}]})
    counts = tmp_path / 'counts.json'
    counts.write_text(json.dumps({'total': 3, 'fruits': [{'id': 1, 'center': [0, 0, 0]}]}))
    with pytest.raises(EvaluationError, match='"total" 3 disagrees with 1'):
        load_predicted_centers(counts)
    counts.write_text(json.dumps({'total': 1, 'fruits': [{'id': 1}]}))
    with pytest.raises(EvaluationError, match=r'fruits\[0\] has no "center"'):
        load_predicted_centers(counts)
    with pytest.raises(EvaluationError, match='counts file not found'):
        load_predicted_centers(tmp_path / 'none.json')
