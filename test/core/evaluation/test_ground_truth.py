"""Visibility in gt_fruits.json: views_visible lists all views; evaluation counts only the training views."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth, parse_ground_truth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.errors import EvaluationError

#: Held-out rule of the trainer (core.data.dataset.split_indices, eval_every = 8): views 0 and 8 are held out.
TRAIN_VIEWS = [v for v in range(10) if v % 8 != 0]


def _write(path: Path, views: list[list[int]], **extra: object) -> Path:
    fruits = [{'id': i + 1, 'type': 'apple', 'center': [float(i), 0.0, 1.0], 'radius': 0.04, 'views_visible': v,
               'n_views_visible': len(v)} for i, v in enumerate(views)]
    path.write_text(json.dumps({'fruits': fruits, 'n_views': 10, **extra}))
    return path


def test_a_fruit_seen_only_by_a_held_out_view_is_unseen(tmp_path: Path) -> None:
    path = _write(tmp_path / 'gt.json', [[0, 3, 4], [0], [8], []])
    everything = load_ground_truth(path)
    assert everything.n_views_visible.tolist() == [3, 1, 1, 0]  # all views, as written
    assert everything.seen.tolist() == [True, True, True, False]
    gt = load_ground_truth(path, train_views=TRAIN_VIEWS)
    assert gt.n_views_visible.tolist() == [2, 0, 0, 0] and gt.seen.tolist() == [True, False, False, False]
    assert [v.tolist() for v in gt.views_visible] == [[3, 4], [], [], []]
    assert everything.seen_by(TRAIN_VIEWS).tolist() == gt.seen.tolist()
    # Recall over the fruits the training views saw: one found of one seen, not one of three.
    metrics = evaluate_counts(np.array([[0.0, 0.0, 1.0]]), gt)
    assert (metrics.gt_unseen, metrics.recall) == (3, 1.0)
    assert evaluate_counts(np.array([[0.0, 0.0, 1.0]]), everything).recall == pytest.approx(1 / 3)


def test_files_without_view_lists_keep_their_counts(tmp_path: Path) -> None:
    path = tmp_path / 'old.json'
    path.write_text(json.dumps({'fruits': [{'center': [0, 0, 0], 'radius': 0.04, 'n_views_visible': n}
                                           for n in (5, 0)] + [{'center': [1, 0, 0], 'radius': 0.04}]}))
    gt = load_ground_truth(path)
    assert gt.views_visible is None and gt.n_views_visible.tolist() == [5, 0, -1]
    # Per-view visibility unknown: never seen stays unseen, anything else is unknown (counted as seen).
    restricted = load_ground_truth(path, train_views=TRAIN_VIEWS)
    assert restricted.n_views_visible.tolist() == [-1, 0, -1] and restricted.seen.tolist() == [True, False, True]


def test_views_of_keyframe_stamps(tmp_path: Path) -> None:
    stamps = [1_000 + 100 * v for v in range(10)]
    gt = load_ground_truth(_write(tmp_path / 'gt.json', [[0, 2], [5]], view_stamps_ns=stamps))
    assert gt.views_at_stamps([1_200, 1_500, 99]).tolist() == [2, 5]
    assert gt.seen_by(gt.views_at_stamps([1_200])).tolist() == [True, False]
    with pytest.raises(EvaluationError, match='no view_stamps_ns'):
        load_ground_truth(_write(tmp_path / 'nostamps.json', [[0]])).views_at_stamps([1])


@pytest.mark.parametrize('fruits, message', [
    ([{'views_visible': [1, 2], 'n_views_visible': 3}], r'"n_views_visible" 3 disagrees with 2 "views_visible"'),
    ([{'views_visible': [2, 1]}], 'distinct view indices >= 0 in increasing order'),
    ([{'views_visible': [-1]}], 'distinct view indices >= 0'),
    ([{'views_visible': 'all'}], '"views_visible" must be a list of integers'),
    ([{'views_visible': [1]}, {}], 'must be given for every fruit or for none'),
])
def test_malformed_view_lists(fruits: list[dict], message: str) -> None:
    data = {'fruits': [{'center': [0, 0, 0], 'radius': 0.04, **f} for f in fruits]}
    with pytest.raises(EvaluationError, match=message):
        parse_ground_truth(data, 'gt.json')
