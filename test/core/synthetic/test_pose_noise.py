"""`fruitnerfpp synth --pose-noise`: recorded poses carry odometry error, images stay rendered from the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.geometry import rotation_angle_deg
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.errors import SynthError


def test_noise_moves_the_recorded_poses_only(tmp_path: Path) -> None:
    base = SynthConfig(fruit='apple', count=6, views=12, resolution=(48, 48), seed=3, sparse_points=0)
    generate_orchard(base, tmp_path / 'clean')
    noisy = SynthConfig(**{**base.__dict__, 'pose_noise_m': 0.02, 'pose_noise_deg': 1.0})
    generate_orchard(noisy, tmp_path / 'noisy')
    clean_frames = read_transforms(tmp_path / 'clean').frames
    noisy_frames = read_transforms(tmp_path / 'noisy').frames
    shifts, angles = [], []
    for a, b in zip(clean_frames, noisy_frames):
        assert (tmp_path / 'clean' / a.file_path).read_bytes() == (tmp_path / 'noisy' / b.file_path).read_bytes()
        Ta, Tb = np.asarray(a.T_world_camera), np.asarray(b.T_world_camera)
        shifts.append(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]))
        angles.append(float(rotation_angle_deg(Ta[:3, :3], Tb[:3, :3])))
        np.testing.assert_allclose(Tb[:3, :3].T @ Tb[:3, :3], np.eye(3), atol=1e-9)  # still a rotation
    # per-axis std 2 cm / 1 deg: a 3-D error of about sqrt(3) times that on average
    assert 0.015 < np.mean(shifts) < 0.06 and 0.7 < np.mean(angles) < 3.0


def test_negative_noise_is_refused() -> None:
    with pytest.raises(SynthError, match='pose_noise_m must be a number >= 0'):
        SynthConfig(pose_noise_m=-0.1)


def test_the_return_pass_is_offset_rigidly(tmp_path: Path) -> None:
    """``--pass-offset``: the +y side's recorded poses move together (shift along x, turn about the vertical), the
    other side's stay true, the images stay rendered from the truth."""
    base = SynthConfig(fruit='apple', count=6, views=12, resolution=(48, 36), trajectory='row', seed=3, sparse_points=0)
    generate_orchard(base, tmp_path / 'clean')
    generate_orchard(SynthConfig(**{**base.__dict__, 'pass_offset_m': 0.05, 'pass_offset_deg': 2.0}),
                     tmp_path / 'drift')
    clean = [np.asarray(f.T_world_camera) for f in read_transforms(tmp_path / 'clean').frames]
    drift = [np.asarray(f.T_world_camera) for f in read_transforms(tmp_path / 'drift').frames]
    back = np.array([T[1, 3] > 0 for T in clean])
    assert 0 < back.sum() < len(back)  # both sides driven
    for a, b, moved in zip(clean, drift, back):
        if not moved:
            np.testing.assert_array_equal(a, b)
            continue
        assert rotation_angle_deg(a[:3, :3], b[:3, :3]) == pytest.approx(2.0, abs=1e-6)
    # rigid: distances within the moved side are kept; its mean position moved 5 cm along x, nothing else
    moved_a = np.array(clean)[back][:, :3, 3]
    moved_b = np.array(drift)[back][:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(moved_a[:, None] - moved_a[None], axis=-1),
                               np.linalg.norm(moved_b[:, None] - moved_b[None], axis=-1), atol=1e-9)
    np.testing.assert_allclose(moved_b.mean(0) - moved_a.mean(0), [0.05, 0.0, 0.0], atol=1e-9)
    clean_images = sorted((tmp_path / 'clean' / 'images').iterdir())
    assert [p.read_bytes() for p in clean_images] == \
        [(tmp_path / 'drift' / 'images' / p.name).read_bytes() for p in clean_images]
