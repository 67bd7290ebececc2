"""The live row (fruit_counter's row mode, ROS-free part): keyframes arrive one by one, a segment is due once the
robot has passed it, the running count joins the finished segments."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.orchard.config import OrchardConfig, SegmentConfig
from fruitnerfpp_ros.core.orchard.jobs import SegmentOutcome
from fruitnerfpp_ros.core.orchard.live import LiveRow, SegmentRequest
from fruitnerfpp_ros.core.orchard.merge import SegmentFruits
from fruitnerfpp_ros.core.orchard.trees import assign_to_trees, read_planting_map


def _count(request: SegmentRequest, gt: list[dict]) -> SegmentOutcome:
    """A perfect count: the ground-truth fruits >= 2 of the request's keyframes show."""
    frames = set(request.segment.frames)
    shown = [f for f in gt if len(frames & set(f['views_visible'])) >= 2]
    fruits = SegmentFruits(request.segment.index, np.array([f['center'] for f in shown]).reshape(-1, 3),
                           np.array([f['diameter'] for f in shown]), np.full(len(shown), 50),
                           np.array([f['id'] for f in shown]))
    return SegmentOutcome(request.segment.index, fruits)


def test_segments_are_due_as_the_robot_passes_them(row_dataset: Path, tmp_path: Path) -> None:
    transforms = read_transforms(row_dataset)
    gt = json.loads((row_dataset / 'gt_fruits.json').read_text())['fruits']
    trees = read_planting_map(row_dataset / 'planting_map.csv')
    # the tiny row is seen from 1.2 m (the node's row_standoff_m); one cell per tree of the planting map
    live = LiveRow(OrchardConfig(segments=SegmentConfig(standoff_m=1.2)), row_dataset, trees=trees)
    n = len(transforms.frames)
    due_at: dict[int, list[int]] = {}
    totals = []
    for i, frame in enumerate(transforms.frames):
        live.add([frame], [transforms.intrinsics_of(i)])
        for request in live.due():
            assert max(request.segment.frames) <= i            # trains only on keyframes it already has
            due_at.setdefault(request.segment.index, []).append(i)
            live.started(request.segment.index)
            live.record(request, _count(request, gt))
            result = live.result(tmp_path, None, frame_id='map', run_id='live', write_files=False)
            assert result is not None
            totals.append(len(result.fruits))
    assert live.frame is not None and abs(live.frame.axis[0]) > 0.99    # the row runs along x
    assert sorted(due_at) == [0, 1, 2]                                  # every tree's cell, while driving
    assert min(min(v) for v in due_at.values()) < n // 2                # the first before the robot turns
    assert totals == sorted(totals) and totals[0] < totals[-1]          # the count grows segment by segment
    for request in live.flush():                                        # the drive ended: the rest
        live.record(request, _count(request, gt))
    assert live.counts()['done'] == 3 and live.counts()['pending'] == 0
    result = live.result(tmp_path, None, frame_id='map', run_id='live')
    centers = np.array([f['center'] for f in gt])
    assert len(result.fruits) == len(gt)
    assert [t.count for t in result.tree_counts] == np.bincount(assign_to_trees(centers, trees),
                                                                minlength=3).tolist()
    assert all(t.complete for t in result.tree_counts)
    assert (tmp_path / 'trees.csv').is_file() and (tmp_path / 'row_report.json').is_file()


def test_a_failed_retraining_keeps_the_first_count(row_dataset: Path) -> None:
    transforms = read_transforms(row_dataset)
    live = LiveRow(OrchardConfig(segments=SegmentConfig(standoff_m=1.2)), row_dataset,
                   trees=read_planting_map(row_dataset / 'planting_map.csv'))
    live.add(transforms.frames, [transforms.intrinsics_of(i) for i in range(len(transforms.frames))])
    first = live.flush()
    assert [r.version for r in first] == [1, 1, 1] and live.flush() == []   # pending cells are not asked twice
    gt = json.loads((row_dataset / 'gt_fruits.json').read_text())['fruits']
    for request in first:
        live.record(request, _count(request, gt) if request.segment.index != 1 else
                    SegmentOutcome(1, None, 'out of memory'))
    assert live.counts() == {'collecting': 0, 'pending': 0, 'training': 0, 'done': 2, 'failed': 1}
    assert live.cells[1].failed == 'out of memory'


def _live(row_dataset: Path) -> LiveRow:
    return LiveRow(OrchardConfig(segments=SegmentConfig(standoff_m=1.2)), row_dataset,
                   trees=read_planting_map(row_dataset / 'planting_map.csv'))


def test_a_cell_waiting_for_training_is_trained_on_both_passes(row_dataset: Path) -> None:
    """Training slower than the drive: nothing starts before the robot is back. The request of the cell passed on
    the way out, still waiting, is replaced by one holding the way back's keyframes too (before: its first-pass
    keyframes only, for good); a cell training when the drive ends is asked for the rest once it is done."""
    transforms = read_transforms(row_dataset)
    n = len(transforms.frames)
    intrinsics = [transforms.intrinsics_of(i) for i in range(n)]
    live = _live(row_dataset)
    queue: dict[int, SegmentRequest] = {}
    out_pass = set()
    for i, frame in enumerate(transforms.frames):
        live.add([frame], [intrinsics[i]])
        for request in live.due():
            queue[request.segment.index] = request
            if i < n // 2:
                out_pass.add(request.segment.index)
    for request in live.flush():
        queue[request.segment.index] = request
    assert out_pass and sorted(queue) == [0, 1, 2]                     # a cell was passed on the way out
    assert all(min(r.segment.frames) < n // 2 <= max(r.segment.frames) for r in queue.values())  # both sides

    live = _live(row_dataset)                                          # the same drive, a cell trains meanwhile
    training = None
    for i, frame in enumerate(transforms.frames):
        live.add([frame], [intrinsics[i]])
        for request in live.due():
            if training is None:
                training = request
                live.started(request.segment.index)
    assert training is not None and max(training.segment.frames) < n // 2
    assert training.segment.index not in [r.segment.index for r in live.flush()]   # not asked while it trains
    gt = json.loads((row_dataset / 'gt_fruits.json').read_text())['fruits']
    live.record(training, _count(training, gt))
    again = live.flush()                                   # the node flushes after each segment once the drive ended
    assert [r.segment.index for r in again] == [training.segment.index] and again[0].version == 2
    assert max(again[0].segment.frames) >= n // 2
