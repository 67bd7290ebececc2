"""Row frame from a drive, what each camera sees, the cut into segments and their datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.orchard.config import OrchardConfig, SegmentConfig
from fruitnerfpp_ros.core.orchard.row_frame import estimate_row_frame, viewed_intervals
from fruitnerfpp_ros.core.orchard.row_run import plan_row
from fruitnerfpp_ros.core.orchard.segments import (edges_between_trees, plan_segments, search_box, segment_edges,
                                                   write_segment_dataset)
from fruitnerfpp_ros.core.synthetic.cameras import look_at
from fruitnerfpp_ros.errors import OrchardError


def _drive(yaw: float = 0.4, n: int = 40, standoff: float = 1.5, both: bool = True) -> np.ndarray:
    """Camera poses of a drive along a row through (3, -2) heading ``yaw``: out on the right, back on the left."""
    axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    normal = np.array([-axis[1], axis[0], 0.0])
    origin = np.array([3.0, -2.0, 0.0])
    poses = []
    for i in range(n):
        out = i < n // 2 or not both
        s = (i if out else n - 1 - i) * 6.0 / (n // 2)
        side = -1.0 if out else 1.0
        eye = origin + s * axis + side * standoff * normal + [0, 0, 0.8]
        poses.append(look_at(eye, eye - side * normal))
    return np.stack(poses)


def test_row_frame_from_both_sides_and_one() -> None:
    T = _drive()
    frame = estimate_row_frame(T)
    assert np.allclose(frame.axis, [np.cos(0.4), np.sin(0.4)], atol=1e-6)
    assert abs(frame.across(np.array([[3.0, -2.0]]))[0]) < 1e-6   # the centre line, midway between the passes
    assert abs(frame.along(T[:1, :3, 3])[0]) < 1e-6               # s = 0 where the drive starts
    one_side = estimate_row_frame(_drive(both=False), standoff_m=1.5)
    assert abs(one_side.across(np.array([[3.0, -2.0]]))[0]) < 1e-6
    with pytest.raises(OrchardError, match='move'):
        estimate_row_frame(np.tile(np.eye(4), (3, 1, 1)))


def test_viewed_intervals_centre_on_the_camera() -> None:
    T = _drive()
    frame = estimate_row_frame(T)
    iv = viewed_intervals(frame, T, np.full(len(T), 100.0), np.full(len(T), 200), crown_half_depth_m=0.5)
    s_cam = frame.along(T[:, :3, 3])
    assert np.allclose(iv.mean(axis=1), s_cam, atol=1e-6)
    # half width at the far side of the canopy: (standoff + depth) * (w / 2) / f = 2.0
    assert np.allclose(iv[:, 1] - s_cam, 2.0, atol=1e-6)


def test_plan_tiles_the_row_with_overlapping_views() -> None:
    T = _drive(n=60)
    frame = estimate_row_frame(T)
    iv = viewed_intervals(frame, T, np.full(len(T), 100.0), np.full(len(T), 200))
    edges = segment_edges(1.0, 5.0, 1.5)
    assert len(edges) == 4 and np.isinf(edges[[0, -1]]).all()
    config = SegmentConfig(margin_m=0.5, max_views=30)
    segments = plan_segments(iv, edges, config)
    assert [s.index for s in segments] == [0, 1, 2]
    for a, b in zip(segments[:-1], segments[1:]):
        assert a.core[1] == b.core[0] and a.trust[1] > b.trust[0]    # cores tile, trusted stretches overlap
    assert all(0 < len(s.frames) <= 30 for s in segments)
    box = search_box(frame, segments[1], T, config)
    assert box.shape == (2, 3) and np.all(box[1] > box[0])
    assert np.allclose(edges_between_trees(np.array([2.0, 0.0, 1.0]))[1:-1], [0.5, 1.5])


def test_segment_dataset_points_at_the_row_images(row_dataset: Path, tmp_path: Path) -> None:
    transforms = read_transforms(row_dataset)
    plan = plan_row(row_dataset, transforms, OrchardConfig(segments=SegmentConfig(length_m=0.6)), None)
    assert len(plan.segments) >= 2 and plan.extent[1] - plan.extent[0] > 1.0
    out = tmp_path / 'seg' / 'dataset'
    write_segment_dataset(transforms, row_dataset, plan.segments[0].frames, out, plan.segments[0].to_json())
    written = read_transforms(out)
    assert len(written.frames) == len(plan.segments[0].frames) and written.ply_file_path is None
    assert written.extra['segment']['index'] == 0
    dataset = load_dataset(out, eval_every=0)
    assert len(dataset.T_world_camera) == len(plan.segments[0].frames)
    with pytest.raises(OrchardError, match='without keyframes'):
        write_segment_dataset(transforms, row_dataset, [], tmp_path / 'empty')
