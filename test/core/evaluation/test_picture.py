"""The count picture: size, keyframe choice, marker colours at hit / miss / false-count positions, errors, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.evaluation.ground_truth import parse_ground_truth
from fruitnerfpp_ros.core.evaluation.metrics import evaluate_counts
from fruitnerfpp_ros.core.evaluation.picture import MARKER_BGR, MarkerKind, write_count_picture
from fruitnerfpp_ros.errors import EvaluationError
from test.core.tracking.scenes import render, row_pose, write_scene

GT_CENTERS = np.array([[-0.15, 0.0, 0.0], [0.0, 0.05, 0.1], [0.15, -0.05, -0.05], [0.1, 0.1, -0.15]])
# a hit on GT 0 (1 cm off), a hit on GT 2, a false count far from every fruit; GT 1 is missed, GT 3 unseen
COUNTED = np.array([[-0.14, 0.0, 0.0], [0.15, -0.05, -0.04], [0.0, -0.1, -0.15]])


def _gt(views: list[int]) -> dict:
    return {'fruits': [{'id': i + 1, 'center': c.tolist(), 'radius': 0.0375, 'n_views_visible': v}
                       for i, (c, v) in enumerate(zip(GT_CENTERS, views))]}


@pytest.fixture
def scene(tmp_path: Path) -> Path:
    """Four views along a row; the third sees all three visible fruits, the others fewer."""
    poses = [row_pose(x, -1.0) for x in (-0.6, -0.4, 0.0, 0.4)]
    masks = [render(T, GT_CENTERS[:3]) for T in poses]
    dataset = write_scene(tmp_path / 'scene', poses, masks)
    (dataset / 'gt_fruits.json').write_text(json.dumps(_gt([3, 3, 3, 0])))
    return dataset


def _colour_at(image: np.ndarray, xy: tuple[int, int]) -> tuple[int, ...]:
    return tuple(int(v) for v in image[xy[1], xy[0]])


def test_markers_carry_their_colours(scene: Path, tmp_path: Path) -> None:
    gt = parse_ground_truth(_gt([3, 3, 3, 0]))
    metrics = evaluate_counts(COUNTED, gt)
    assert (metrics.hungarian.tp, metrics.count) == (2, 3)
    picture = write_count_picture(tmp_path / 'pics' / 'count.png', scene, COUNTED, gt, metrics)
    image = cv2.imread(str(picture.path))
    assert image.shape == (picture.height, picture.width, 3) == (480 + 77, 480 + 480, 3)
    assert picture.keyframe == 2
    kinds = {(m.panel, m.kind, m.index) for m in picture.markers}
    assert kinds == {('keyframe', MarkerKind.HIT, 0), ('keyframe', MarkerKind.HIT, 1), ('keyframe', MarkerKind.MISS, 1),
                     ('keyframe', MarkerKind.FALSE, 2), ('keyframe', MarkerKind.UNSEEN, 3),
                     ('top', MarkerKind.HIT, 0), ('top', MarkerKind.HIT, 1), ('top', MarkerKind.MISS, 1),
                     ('top', MarkerKind.FALSE, 2), ('top', MarkerKind.UNSEEN, 3)}
    for marker in picture.markers:
        assert _colour_at(image, marker.xy_px) == MARKER_BGR[marker.kind], marker
        assert (marker.xy_px[0] < 480) == (marker.panel == 'keyframe')
    top = {(m.kind, m.index): m.xy_px for m in picture.markers if m.panel == 'top'}
    # the top view keeps the world's layout: x to the right, y up
    assert top[MarkerKind.HIT, 0][0] < top[MarkerKind.MISS, 1][0] < top[MarkerKind.HIT, 1][0]
    assert top[MarkerKind.FALSE, 2][1] > top[MarkerKind.HIT, 1][1] > top[MarkerKind.MISS, 1][1]
    # the camera looks along +y from y = -1: in the keyframe, world x is right and z is up
    key = {(m.kind, m.index): m.xy_px for m in picture.markers if m.panel == 'keyframe'}
    assert key[MarkerKind.HIT, 0][0] < key[MarkerKind.MISS, 1][0] < key[MarkerKind.HIT, 1][0]
    assert key[MarkerKind.MISS, 1][1] < key[MarkerKind.HIT, 0][1] < key[MarkerKind.FALSE, 2][1]


def test_top_view_only_and_default_match(tmp_path: Path) -> None:
    gt = parse_ground_truth(_gt([3, 3, 3, 3]))
    picture = write_count_picture(tmp_path / 'top.jpg', None, COUNTED, gt)
    image = cv2.imread(str(picture.path))
    assert image.shape[:2] == (picture.height, picture.width) == (557, 480) and picture.keyframe is None
    assert {m.panel for m in picture.markers} == {'top'}
    assert sorted(m.kind.value for m in picture.markers) == ['false count', 'hit', 'hit', 'miss', 'miss']
    small = write_count_picture(tmp_path / 'small.png', None, np.zeros((0, 3)), gt, panel_px=200)
    assert (small.width, small.height) == (200, 232) and len(small.markers) == 4  # four misses


def test_errors(tmp_path: Path) -> None:
    gt = parse_ground_truth(_gt([3, 3, 3, 3]))
    with pytest.raises(EvaluationError, match=r'finite \[K, 3\]'):
        write_count_picture(tmp_path / 'a.png', None, np.zeros((2, 2)), gt)
    other = evaluate_counts(np.vstack([COUNTED, GT_CENTERS]), gt)
    with pytest.raises(EvaluationError, match='computed for other inputs'):
        write_count_picture(tmp_path / 'a.png', None, COUNTED[:1], gt, other)
    with pytest.raises(EvaluationError, match='cannot write picture'):
        write_count_picture(tmp_path / 'a.unknown', None, COUNTED, gt)
    assert not list(tmp_path.iterdir())


def test_eval_command_draws_the_picture(scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    counts = tmp_path / 'counts.json'
    counts.write_text(json.dumps({'total': 3, 'fruits': [{'id': i + 1, 'center': c.tolist()}
                                                         for i, c in enumerate(COUNTED)]}))
    out = tmp_path / 'eval' / 'picture.png'
    args = ['eval', str(counts), '--gt', str(scene / 'gt_fruits.json'), '--picture', str(out)]
    assert main(args + ['--dataset', str(scene)]) == 0
    assert cv2.imread(str(out)).shape == (557, 960, 3)
    assert 'hungarian' in capsys.readouterr().out
    assert main(args) == 0 and cv2.imread(str(out)).shape == (557, 480, 3)
    assert main(args + ['--dataset', str(tmp_path / 'nowhere')]) == 2
    assert capsys.readouterr().err.startswith('fruitnerfpp eval: error: ')
