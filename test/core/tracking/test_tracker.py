"""The tracker on hand-made scenes: one fruit, two fruits, a fruit seen from both sides of a row."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.config_io import load_config
from fruitnerfpp_ros.core.tracking import FruitTracker, PinholeView, TrackConfig, detect_blobs, track_dataset
from fruitnerfpp_ros.errors import ConfigError
from test.core.tracking.scenes import INTRINSICS, look_at, render, row_pose, write_scene


def _track(poses: list[np.ndarray], masks: list[np.ndarray], config: TrackConfig | None = None) -> FruitTracker:
    tracker = FruitTracker(config)
    for i, (pose, mask) in enumerate(zip(poses, masks)):
        tracker.update(i, PinholeView.from_intrinsics(pose, INTRINSICS), detect_blobs(mask))
    return tracker


def test_one_fruit_in_consecutive_frames_is_one_track() -> None:
    fruit = np.array([[0.05, 0.1, 0.02]])
    poses = [row_pose(x, -1.0) for x in np.linspace(-0.25, 0.25, 10)]
    masks = [render(T, fruit, ids=[7 + i]) for i, T in enumerate(poses)]  # per-image ids change every frame
    result = _track(poses, masks).result()
    assert result.count == 1 and result.n_tracks == 1
    fruit_record = result.fruits[0]
    assert (fruit_record.n_detections, fruit_record.first_frame, fruit_record.last_frame) == (10, 0, 9)
    np.testing.assert_allclose(fruit_record.center, fruit[0], atol=0.01)  # triangulated, not the size prior
    assert fruit_record.diameter_m == pytest.approx(0.075, rel=0.15)


def test_two_fruits_are_two_tracks_and_short_blips_are_not_counted() -> None:
    fruits = np.array([[-0.1, 0.0, 0.0], [0.12, 0.05, 0.08]])
    poses = [row_pose(x, -1.0) for x in np.linspace(-0.2, 0.2, 8)]
    masks = [render(T, fruits, ids=[2, 1] if i % 2 else [1, 2]) for i, T in enumerate(poses)]
    blip = np.array([[0.0, 0.0, -0.2]])
    masks[3] = np.where(render(poses[3], blip, ids=[9]) > 0, 9, masks[3])  # seen in one frame only
    result = _track(poses, masks).result()
    assert result.count == 2 and result.n_tracks == 3
    centers = result.centers()[np.argsort(result.centers()[:, 0])]
    np.testing.assert_allclose(centers, fruits, atol=0.01)
    assert _track(poses, masks, TrackConfig(min_hits=1)).result().count == 3


def _both_sides(gap_frames: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A fruit seen on a drive along one side of a row, then ``gap_frames`` frames of the turn at the row's end
    (the fruit out of view), then the drive back on the other side."""
    fruit = np.array([[0.0, 0.0, 0.0]])
    xs = np.linspace(-0.2, 0.2, 6)
    out = [row_pose(x, -1.0) for x in xs]
    turn = [look_at(np.array([1.5, -1.0 + 2.0 * (i + 0.5) / gap_frames, 0.0]), np.array([3.0, 0.0, 0.0]))
            for i in range(gap_frames)]
    back = [row_pose(x, 1.0) for x in xs[::-1]]
    poses = out + turn + back
    return poses, [render(T, fruit) for T in poses]


def test_a_fruit_seen_from_both_sides_after_a_long_turn_is_counted_twice() -> None:
    """The known weakness of tracking counters, which the accuracy benchmark explains: a track ends after
    ``max_age`` frames without its fruit, so the drive back on the other side of the row starts a new track."""
    config = TrackConfig(max_age=8)
    poses, masks = _both_sides(gap_frames=config.max_age + 1)
    assert sum(bool(m.any()) for m in masks) == 12
    long_turn = _track(poses, masks, config).result()
    assert long_turn.count == 2
    assert [(f.first_frame, f.last_frame) for f in long_turn.fruits] == [(0, 5), (15, 20)]
    np.testing.assert_allclose(long_turn.centers(), np.zeros((2, 3)), atol=0.02)  # both right, one fruit
    # the same drive with a turn shorter than max_age: the 3D motion model carries the track over
    poses, masks = _both_sides(gap_frames=config.max_age - 2)
    assert _track(poses, masks, config).result().count == 1


def test_frames_are_processed_in_time_order(tmp_path: Path) -> None:
    fruits = np.array([[-0.1, 0.0, 0.0], [0.12, 0.05, 0.08]])
    poses = [row_pose(x, -1.0) for x in np.linspace(-0.2, 0.2, 8)]
    masks = [render(T, fruits) for T in poses]
    shuffled = np.random.default_rng(0).permutation(8)
    dataset = write_scene(tmp_path / 'shuffled', [poses[i] for i in shuffled], [masks[i] for i in shuffled])
    data = json.loads((dataset / 'transforms.json').read_text())
    for frame, i in zip(data['frames'], shuffled):  # the stamps keep the recording order
        frame['stamp_ns'] = 1_000_000_000 + 100_000_000 * int(i)
    (dataset / 'transforms.json').write_text(json.dumps(data))
    result = track_dataset(dataset)
    assert result.count == 2 and result.stats['frame_order'] == np.argsort(shuffled).tolist()
    # first and last frame are file indices: the first recorded frame is the one stored at argsort(shuffled)[0]
    assert {f.first_frame for f in result.fruits} == {int(np.argsort(shuffled)[0])}


def test_config_checks_and_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match='min_hits'):
        TrackConfig(min_hits=0)
    with pytest.raises(ConfigError, match='iou_threshold'):
        TrackConfig(iou_threshold=0.0)
    path = tmp_path / 'track.yaml'
    path.write_text('max_age: 3\nfruit_diameter_m: 0.05\nframe_order: file\n')
    assert load_config(TrackConfig, path) == TrackConfig(max_age=3, fruit_diameter_m=0.05, frame_order='file')
    path.write_text('max_ages: 3\n')
    with pytest.raises(ConfigError, match='max_ages'):
        load_config(TrackConfig, path)
