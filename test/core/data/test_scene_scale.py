"""Metric scale from masks and poses: the fruit diameter and region of the stand-in and the synthetic scenes."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.bounds import aabb_from_cameras
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.scene_scale import (ScaleConfig, dilate_square, estimate_scene_scale,
                                                   largest_eigenvalue_sym3)
from fruitnerfpp_ros.errors import ConfigError
from test.core.training.stand_in_scene import make_sphere_scene


def _search_box(dataset) -> np.ndarray:  # noqa: ANN001
    return aabb_from_cameras(dataset.T_world_camera.numpy(), dataset.intrinsics.numpy(), dataset.width,
                             dataset.height, min_view_fraction=0.1)


def _share_inside(centres: np.ndarray, region: np.ndarray) -> float:
    """Share of the true fruit centres [N, 3] inside the box ``region`` [2, 3]."""
    return float(np.all((centres >= region[0]) & (centres <= region[1]), axis=1).mean())


def test_the_synthetic_test_tree_measures_its_apples(tiny_apple_dataset: Path) -> None:
    dataset = load_dataset(tiny_apple_dataset, eval_every=8)
    scale = estimate_scene_scale(dataset, _search_box(dataset))
    fruits = json.loads((tiny_apple_dataset / 'gt_fruits.json').read_text())['fruits']
    truth = float(np.median([f['diameter'] for f in fruits]))
    assert scale.source == 'masks' and scale.n_masks_measured > 50
    assert abs(scale.fruit_diameter_m - truth) < 0.2 * truth
    centres = np.array([f['center'] for f in fruits])
    region = scale.fruit_region
    assert np.all((centres >= region[0] - 0.05) & (centres <= region[1] + 0.05))
    assert np.all(region[1] - region[0] < 1.5 * (centres.max(0) - centres.min(0)) + 0.3)  # not the camera box


def test_the_same_spheres_measure_alike_however_far_the_cameras_stand(tmp_path: Path) -> None:
    near = make_sphere_scene(tmp_path / 'near', views=20, size=64, fruits=8)
    far = make_sphere_scene(tmp_path / 'far', views=20, size=128, fruits=8, distance=6.4)
    measured = []
    for scene in (near, far):
        dataset = load_dataset(scene, eval_every=0)
        measured.append(estimate_scene_scale(dataset, _search_box(dataset)).fruit_diameter_m)
    radii = np.load(near / 'spheres.npz')['radii'][:8]
    assert measured[0] == pytest.approx(measured[1], rel=0.2)
    assert 1.4 * radii.mean() < measured[0] < 2.6 * radii.mean()


@pytest.fixture(scope='module')
def metric_spheres(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    """The sphere scene in metres and its measured scale (shared by the unit variants)."""
    dataset = load_dataset(make_sphere_scene(tmp_path_factory.mktemp('units') / 's', views=20, size=64, fruits=8),
                           eval_every=0)
    return dataset, estimate_scene_scale(dataset, _search_box(dataset))


@pytest.mark.parametrize('units', [0.05, 20.0])   # a pose unit of 20 m, of 5 cm
def test_poses_in_other_units_than_metres_measure_the_fruit_in_those_units(
        metric_spheres, units: float) -> None:  # noqa: ANN001
    """Poses not in metres (a COLMAP reconstruction, a scene modelled in centimetres) measure the fruit outside the
    metric range: the measurement is used as it is (every length follows it), and the scale says how many pose
    units make a metre; ``outside_range: clamp`` uses the range's end instead."""
    dataset, metric = metric_spheres
    assert metric.source == 'masks' and metric.units_per_metre == 1.0
    poses = dataset.T_world_camera.clone()
    poses[:, :3, 3] *= units
    scaled = dataclasses.replace(dataset, T_world_camera=poses)
    other = estimate_scene_scale(scaled, _search_box(scaled))
    assert other.source == 'pose_units'
    assert other.fruit_diameter_m == pytest.approx(units * metric.fruit_diameter_m, rel=0.1)
    assert other.units_per_metre == pytest.approx(other.fruit_diameter_m / ScaleConfig().default_diameter_m)
    np.testing.assert_allclose(other.fruit_region, units * metric.fruit_region, atol=0.15 * units)
    assert json.loads(json.dumps(other.to_json()))['units_per_metre'] == pytest.approx(other.units_per_metre, 1e-4)
    clamped = estimate_scene_scale(scaled, _search_box(scaled), ScaleConfig(outside_range='clamp'))
    assert clamped.source == 'clamped' and clamped.units_per_metre == 1.0
    assert clamped.fruit_diameter_m == (0.02 if units < 1 else 0.25)
    with pytest.raises(ConfigError, match='outside_range must be pose_units or clamp'):
        ScaleConfig(outside_range='metres')


def test_a_given_diameter_is_used_and_nothing_measurable_falls_back(tmp_path: Path) -> None:
    scene = make_sphere_scene(tmp_path / 's', views=6, size=32, fruits=4)
    dataset = load_dataset(scene, eval_every=0)
    given = estimate_scene_scale(dataset, _search_box(dataset), ScaleConfig(fruit_diameter_m=0.09))
    assert given.fruit_diameter_m == 0.09 and given.source == 'config'
    empty = dataset.__class__(**{**dataset.__dict__, 'semantic_masks': dataset.semantic_masks & False})
    fallback = estimate_scene_scale(empty, _search_box(dataset), ScaleConfig(default_diameter_m=0.06))
    assert fallback.source == 'default' and fallback.fruit_diameter_m == 0.06 and fallback.fruit_region is None
    with pytest.raises(ConfigError, match='diameter_range_m'):
        ScaleConfig(fruit_diameter_m=0.5)
    with pytest.raises(ConfigError, match='refine_min_share'):
        ScaleConfig(refine_min_share=1.5)


def test_a_far_row_drive_measures_its_fruit_and_region_near_the_truth(tmp_path: Path) -> None:
    """Views of a row drive from 3 m stretch the coarse vote along the viewing direction (3 m for a 0.7 m crown):
    one fine vote over it had voxels larger than the fruit and measured 1.45x the diameter; the refining votes
    bring region and diameter to the crown and the fruit."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    generate_orchard(SynthConfig(fruit='pear', count=30, views=32, resolution=(240, 180), trajectory='row',
                                 sparse_points=0, row_standoff_m=3.0, camera_height_m=2.0, camera_pitch_deg=0.0,
                                 seed=5, device='cpu'), tmp_path / 'row')
    dataset = load_dataset(tmp_path / 'row', eval_every=0)
    fruits = json.loads((tmp_path / 'row' / 'gt_fruits.json').read_text())['fruits']
    truth = float(np.median([f['diameter'] for f in fruits]))
    centres = np.array([f['center'] for f in fruits])
    scale = estimate_scene_scale(dataset, _search_box(dataset))
    assert scale.source == 'masks' and abs(scale.fruit_diameter_m - truth) < 0.25 * truth
    region = scale.fruit_region
    assert np.all(region[1] - region[0] < centres.max(0) - centres.min(0) + 0.5)   # before: 2.4 m too wide
    inside = np.all((centres >= region[0] - truth) & (centres <= region[1] + truth), axis=1)
    assert inside.mean() >= 0.9


def test_fruit_hidden_in_foliage_stays_inside_the_region(tmp_path: Path) -> None:
    """Mangoes inside dense foliage agree with few of the views that see them: the voxels >= 70 % of them agree with
    held one side of the crown, and a fifth of the suite's mangoes fell outside the scene box. The region also
    holds the voxels fewer views agree with from directions spread wide enough; a row drive's region stays as it
    was (its views through a fruit lie along one line: checked by the row test above)."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    generate_orchard(SynthConfig(fruit='mango', count=40, views=48, resolution=(128, 128), seed=11, device='cpu'),
                     tmp_path / 'mango')
    dataset = load_dataset(tmp_path / 'mango', eval_every=8)
    centres = np.array([f['center'] for f in json.loads((tmp_path / 'mango' / 'gt_fruits.json').read_text())['fruits']])
    strict = estimate_scene_scale(dataset, _search_box(dataset), ScaleConfig(region_fraction=None))
    held = estimate_scene_scale(dataset, _search_box(dataset))
    assert _share_inside(centres, held.fruit_region) >= 0.95
    assert _share_inside(centres, strict.fruit_region) < _share_inside(centres, held.fruit_region)
    assert np.all(held.fruit_region[1] - held.fruit_region[0] < centres.max(0) - centres.min(0) + 0.6)
    assert held.fruit_diameter_m == pytest.approx(strict.fruit_diameter_m, rel=0.1)


def test_a_refining_vote_that_loses_the_fruit_is_not_kept(tmp_path: Path) -> None:
    """A row drive past mangoes in foliage 1.3x denser (the holdout suite's mango_row_80, fewer views): the second
    refining vote's 14 mm cells agree with few of the views that see them, and the region it left held a corner of
    the crown (the run counted 41 of 80, F1 0.35). A refining vote that holds under half the voxels of the vote
    before it is not kept; every other suite scene measures as before (docs/results/accuracy_suite.md)."""
    from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard

    generate_orchard(SynthConfig(fruit='mango', count=80, views=48, resolution=(240, 180), seed=202, leaf_scale=1.3,
                                 trajectory='row', sparse_points=0, device='cpu'), tmp_path / 'row')
    dataset = load_dataset(tmp_path / 'row', eval_every=8)
    fruits = json.loads((tmp_path / 'row' / 'gt_fruits.json').read_text())['fruits']
    centres = np.array([f['center'] for f in fruits])
    every_vote = estimate_scene_scale(dataset, _search_box(dataset), ScaleConfig(refine_min_share=0.0))
    scale = estimate_scene_scale(dataset, _search_box(dataset))
    assert _share_inside(centres, every_vote.fruit_region) < 0.5  # the defect this guards against
    assert _share_inside(centres, scale.fruit_region) >= 0.95
    assert np.all(scale.fruit_region[1] - scale.fruit_region[0] < centres.max(0) - centres.min(0) + 0.6)
    truth = float(np.median([f['diameter'] for f in fruits]))
    assert abs(scale.fruit_diameter_m - truth) < 0.2 * truth


def test_the_closed_form_largest_eigenvalue_matches_lapack_on_every_kind_of_matrix() -> None:
    """Mean outer products of unit directions (what the view-spread test feeds it) and the degenerate cases: all
    views on one line (rank 1, eigenvalue 1), a plane (rank 2), isotropic (a multiple of the identity)."""
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(500, 7, 3))
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    dirs[:100] = dirs[:100, :1]                               # one line
    dirs[100:200, :, 2] = 0.0                                 # one plane
    dirs[100:200] /= np.linalg.norm(dirs[100:200], axis=2, keepdims=True)
    matrices = np.einsum('nki,nkj->nij', dirs, dirs) / dirs.shape[1]
    matrices = np.concatenate([matrices, np.eye(3)[None] / 3.0, np.zeros((1, 3, 3)), 2.0 * rng.normal(size=(50, 3, 3))])
    matrices[-50:] = matrices[-50:] + matrices[-50:].transpose(0, 2, 1)   # symmetric, indefinite
    six = torch.as_tensor(matrices[:, [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]], dtype=torch.float32)
    got = largest_eigenvalue_sym3(six).double().numpy()
    assert got.dtype == np.float64 and largest_eigenvalue_sym3(six).dtype == torch.float32
    np.testing.assert_allclose(got, np.linalg.eigvalsh(matrices)[:, -1], atol=2e-5)
    np.testing.assert_allclose(got[:100], 1.0, atol=2e-5)


def test_the_view_spread_needs_no_batched_solver(tiny_apple_dataset: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """On CUDA the batched ``torch.linalg.eigvalsh`` over a 300-view 512 px scene's voxels raised a cusolver
    internal error before any training (the `gpu` suite, 2026-12-04): the estimate must not depend on it."""
    dataset = load_dataset(tiny_apple_dataset, eval_every=8)
    expected = estimate_scene_scale(dataset, _search_box(dataset))

    def cusolver_failure(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise RuntimeError('cusolver error: CUSOLVER_STATUS_INTERNAL_ERROR')

    monkeypatch.setattr(torch.linalg, 'eigvalsh', cusolver_failure)
    monkeypatch.setattr(torch.linalg, 'eigh', cusolver_failure)
    scale = estimate_scene_scale(dataset, _search_box(dataset))
    assert scale.source == 'masks' and scale.n_fruit_voxels == expected.n_fruit_voxels
    np.testing.assert_allclose(scale.fruit_region, expected.fruit_region)


@pytest.mark.parametrize('radius', [1, 4, 17])
def test_the_row_and_column_dilation_is_the_square_max_pool(radius: int) -> None:
    masks = (torch.rand(3, 1, 45, 61, generator=torch.Generator().manual_seed(radius)) > 0.97).float()
    masks[0, 0, 0, 0] = masks[1, 0, -1, -1] = 1.0  # the borders too
    square = torch.nn.functional.max_pool2d(masks, 2 * radius + 1, stride=1, padding=radius)
    assert torch.equal(dilate_square(masks, radius), square) and square.sum() > masks.sum()
