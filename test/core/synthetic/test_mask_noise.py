"""`fruitnerfpp synth --mask-noise`: instance masks as imperfect as a learned segmenter's, the ground truth exact."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from fruitnerfpp_ros.cli.main import main
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.synthetic.mask_noise import degrade_instances
from fruitnerfpp_ros.errors import SynthError


def _discs(n: int = 12, size: int = 120, radius: int = 6, seed: int = 0) -> np.ndarray:
    """[size, size] uint16: ``n`` separated discs with ids 1..n on a grid."""
    labels = np.zeros((size, size), np.uint16)
    step = size // 4
    for k in range(n):
        cv2.circle(labels, (step // 2 + step * (k % 4), step // 2 + step * (k // 4)), radius, k + 1, -1)
    return labels


def test_no_noise_is_the_masks_as_they_are() -> None:
    labels = _discs()
    assert np.array_equal(degrade_instances(labels, np.random.default_rng(0)), labels)


def test_missed_masks_are_removed_whole_and_the_rest_kept_exactly() -> None:
    labels = _discs()
    out = degrade_instances(labels, np.random.default_rng(1), missed=0.5)
    kept = set(np.unique(out[out > 0]).tolist())
    assert 0 < len(kept) < 12                                  # some missed, some kept (12 draws at 0.5)
    for i in range(1, 13):
        assert np.array_equal(out == i, labels == i) if i in kept else not (out == i).any()
    assert not degrade_instances(labels, np.random.default_rng(1), missed=1.0).any()


def test_boundaries_move_by_the_given_pixels_and_never_into_another_fruit() -> None:
    labels = _discs()
    labels[10:20, 14:24] = 13                                   # a fruit touching fruit 1
    out = degrade_instances(labels, np.random.default_rng(2), boundary_px=1)
    grown = shrunk = 0
    for i in range(1, 14):
        before, after = labels == i, out == i
        assert after.any()                                      # no mask eroded away
        if after.sum() > before.sum():
            grown += 1
            assert not (after & (labels > 0) & ~before).any()   # dilation only into the background
            assert np.array_equal(after, after & (cv2.dilate(before.astype(np.uint8), np.ones((3, 3))) > 0))
        elif after.sum() < before.sum():
            shrunk += 1
            assert np.array_equal(after, after & before)
            assert (cv2.erode(before.astype(np.uint8), np.ones((3, 3))) > 0)[before & ~after].sum() == 0
    assert grown and shrunk                                     # both happen among 13 fruits


def test_false_detections_are_new_fruit_sized_ids_on_the_background() -> None:
    labels = _discs()
    counts = []
    for seed in range(20):
        out = degrade_instances(labels, np.random.default_rng(seed), false_rate=0.25)
        assert np.array_equal(out[labels > 0], labels[labels > 0])   # the real masks stay on top
        new = np.unique(out[(out > 12)])
        counts.append(len(new))
        area = np.pi * 6 ** 2
        assert all(0.1 * area < (out == i).sum() < 1.5 * area for i in new)
    assert 1.5 < np.mean(counts) < 4.5                          # Binomial(12, 0.25): 3 a view


def test_synth_degrades_the_dataset_masks_and_keeps_the_truth(tmp_path: Path) -> None:
    args = ['synth', '--quiet', '--fruit', 'apple', '--count', '15', '--views', '6', '--resolution', '80x64',
            '--seed', '4', '--sparse-points', '0']
    assert main([*args, '--out', str(tmp_path / 'clean')]) == 0
    assert main([*args, '--out', str(tmp_path / 'noisy'), '--mask-noise', '0.3', '0.2', '1']) == 0
    clean, noisy = read_transforms(tmp_path / 'clean'), read_transforms(tmp_path / 'noisy')
    assert clean.extra['mask_source'] == 'ground_truth' and noisy.extra['mask_source'] == 'ground_truth_degraded'
    assert (tmp_path / 'clean' / 'gt_fruits.json').read_bytes() == (tmp_path / 'noisy' / 'gt_fruits.json').read_bytes()
    differ = 0
    for a, b in zip(clean.frames, noisy.frames):
        assert (tmp_path / 'clean' / a.file_path).read_bytes() == (tmp_path / 'noisy' / b.file_path).read_bytes()
        inst = cv2.imread(str(tmp_path / 'noisy' / b.instance_path), cv2.IMREAD_UNCHANGED)
        sem = cv2.imread(str(tmp_path / 'noisy' / b.semantic_path), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(sem > 0, inst > 0)               # the fruit mask is the union of the instances
        differ += not np.array_equal(inst, cv2.imread(str(tmp_path / 'clean' / a.instance_path),
                                                      cv2.IMREAD_UNCHANGED))
    assert differ == len(noisy.frames)


def test_bad_mask_noise_is_refused() -> None:
    from fruitnerfpp_ros.core.synthetic import SynthConfig
    with pytest.raises(SynthError, match='mask_missed'):
        SynthConfig(mask_missed=1.5)
    with pytest.raises(SynthError, match='mask_boundary_px'):
        SynthConfig(mask_boundary_px=-1)
    assert main(['synth', '--quiet', '--out', '/nonexistent/x', '--mask-noise', '0', '0', '1.5']) == 2
