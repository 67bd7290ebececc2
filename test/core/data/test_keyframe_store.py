"""Keyframe selection and persistence as a transforms.json dataset."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.core.data.keyframe_store import Keyframe, KeyframeConfig, KeyframeDecision, KeyframeStore
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, read_transforms
from fruitnerfpp_ros.core.geometry import opengl_from_optical

INTR = CameraIntrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)


def _kf(x: float, stamp: int, *, blurry: bool = False) -> Keyframe:
    rng = np.random.default_rng(stamp)
    rgb = np.full((24, 32, 3), 128, np.uint8) if blurry else rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
    instance = np.zeros((24, 32), np.uint16)
    instance[5:10, 5:10] = 3
    T = np.eye(4)
    T[0, 3] = x
    return Keyframe(stamp, rgb, instance, T, INTR)


def test_selection_and_files_on_disk(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf', KeyframeConfig(min_translation_m=0.1, min_rotation_deg=10,
                                                          max_keyframes=3, blur_threshold=50.0))
    decisions = [store.offer(_kf(x, i)) for i, x in enumerate([0.0, 0.05, 0.2, 0.4])]
    decisions.append(store.offer(_kf(0.8, 10, blurry=True)))
    assert decisions == [KeyframeDecision.ACCEPTED, KeyframeDecision.TOO_CLOSE, KeyframeDecision.ACCEPTED,
                         KeyframeDecision.ACCEPTED, KeyframeDecision.FULL]
    data = read_transforms(tmp_path / 'kf')
    assert [f.stamp_ns for f in data.frames] == [0, 2, 3]
    assert data.intrinsics == INTR
    assert np.allclose(data.frames[1].T_world_camera, opengl_from_optical(_kf(0.2, 2).T_world_optical))
    rgb = cv2.imread(str(tmp_path / 'kf' / data.frames[1].file_path))[..., ::-1]
    assert np.array_equal(rgb, _kf(0.2, 2).rgb)
    inst = cv2.imread(str(tmp_path / 'kf' / data.frames[1].instance_path), cv2.IMREAD_UNCHANGED)
    assert inst.dtype == np.uint16 and inst[7, 7] == 3
    sem = cv2.imread(str(tmp_path / 'kf' / data.frames[1].semantic_path), cv2.IMREAD_UNCHANGED)
    assert sem[7, 7] == 255 and sem[0, 0] == 0


def test_blur_rejection(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf', KeyframeConfig(blur_threshold=50.0))
    assert store.offer(_kf(0.0, 0, blurry=True)) is KeyframeDecision.BLURRY
    assert store.offer(_kf(0.0, 1)) is KeyframeDecision.ACCEPTED


def test_resume_snapshot_and_reset(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf')
    for i in range(3):
        store.offer(_kf(i * 1.0, i))
    resumed = KeyframeStore(tmp_path / 'kf')
    assert len(resumed) == 3
    assert resumed.offer(_kf(2.01, 9)) is KeyframeDecision.TOO_CLOSE  # compared with the last stored pose
    snapshot = resumed.snapshot(tmp_path / 'snap')
    snap = snapshot.dataset_dir
    assert snapshot.n_keyframes == 3 and snapshot.latest_stamp_ns == max(f.stamp_ns or 0 for f in resumed.frames)
    resumed.offer(_kf(5.0, 10))
    frames = read_transforms(snap).frames
    assert len(frames) == 3 and (snap / frames[0].file_path).exists()
    moved = resumed.reset()
    assert moved is not None and len(read_transforms(moved).frames) == 4 and len(resumed) == 0
    with pytest.raises(Exception, match='no keyframes'):
        resumed.snapshot(tmp_path / 'snap2')


def test_the_masks_source_is_recorded_and_joined_on_resume(tmp_path: Path) -> None:
    store = KeyframeStore(tmp_path / 'kf', mask_source='topic')
    store.offer(_kf(0.0, 0))
    assert read_transforms(tmp_path / 'kf').mask_source == 'topic'
    resumed = KeyframeStore(tmp_path / 'kf', mask_source='fallback')       # a second run, another source
    resumed.offer(_kf(1.0, 1))
    assert read_transforms(tmp_path / 'kf').mask_source == 'fallback+topic'
    assert read_transforms(resumed.snapshot(tmp_path / 'snap').dataset_dir).mask_source == 'fallback+topic'
    resumed.reset()
    resumed.offer(_kf(2.0, 2))
    assert read_transforms(tmp_path / 'kf').mask_source == 'fallback'
    assert KeyframeStore(tmp_path / 'kf').frames and read_transforms(tmp_path / 'kf').mask_source == 'fallback'


def test_a_keyframes_validity_mask_reaches_the_training_dataset(tmp_path: Path) -> None:
    """An undistorted keyframe's border is stored as nerfstudio's mask_path and loads as invalid pixels."""
    from fruitnerfpp_ros.core.data.dataset import load_dataset

    store = KeyframeStore(tmp_path / 'kf', KeyframeConfig(min_translation_m=0.0, min_rotation_deg=0.0))
    valid = np.ones((24, 32), bool)
    valid[:, :4] = False
    store.offer(_kf(0.0, 1)._replace(valid=valid))
    store.offer(_kf(0.5, 2))  # an undistorted camera: no mask
    frames = read_transforms(tmp_path / 'kf').frames
    assert frames[0].mask_path == 'masks/000000.png' and frames[1].mask_path is None
    snapshot = store.snapshot(tmp_path / 'snap')
    dataset = load_dataset(snapshot.dataset_dir, eval_every=0)
    assert dataset.valid_masks is not None
    assert not bool(dataset.valid_masks[0, :, :4].any()) and bool(dataset.valid_masks[0, :, 4:].all())
    assert bool(dataset.valid_masks[1].all())
