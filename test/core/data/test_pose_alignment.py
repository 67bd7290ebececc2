"""Feature-based pose alignment before training: tracks, the bundle adjustment, the gate, the trainer's use of it.

The accuracy figures (the suite's pose-noise row, the drift on exact poses) are in docs/results/pose_refinement.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.config_io import load_config, replace_nested
from fruitnerfpp_ros.core.data import pose_alignment
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.pass_registration import PassRegistration
from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignment, PoseAlignmentConfig, align_poses
from fruitnerfpp_ros.core.data.transforms_format import read_transforms
from fruitnerfpp_ros.core.evaluation.ground_truth import load_ground_truth
from fruitnerfpp_ros.core.evaluation.pose_errors import pose_errors
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.core.training import TrainConfig, train
from fruitnerfpp_ros.core.training.metrics import evaluate_views
from fruitnerfpp_ros.core.training.trained_scene import load_trained_scene
from fruitnerfpp_ros.errors import ConfigError
from test.core.training.stand_in_scene import make_sphere_scene
from test.core.training.test_trainer import MICRO

ROW = dict(fruit='apple', count=30, views=48, resolution=(240, 180), trajectory='row', seed=111, sparse_points=0)


@pytest.fixture(scope='module')
def twins(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A row drive with 2 cm / 1 deg odometry noise and its exact twin (same images, the true poses)."""
    root = tmp_path_factory.mktemp('pose_twins')
    generate_orchard(SynthConfig(**ROW, pose_noise_m=0.02, pose_noise_deg=1.0), root / 'noisy')
    generate_orchard(SynthConfig(**ROW), root / 'clean')
    return root / 'noisy', root / 'clean'


@pytest.fixture(scope='module')
def aligned(twins: tuple[Path, Path]) -> dict:
    """The noisy row aligned with every 8th view held out, and its training views aligned by themselves (the two
    alignments the tests below share: about 10 s each)."""
    noisy, clean = twins
    data = load_dataset(noisy, eval_every=0)
    T = data.T_world_camera.double().numpy()
    images = (data.images.numpy() * 255).round().astype(np.uint8)
    K = data.intrinsics.double().numpy()
    held = np.arange(len(T)) % 8 == 0
    config = PoseAlignmentConfig(enabled=True)
    return {'T': T, 'truth': load_dataset(clean, eval_every=0).T_world_camera.double().numpy(), 'held': held,
            'with_held_out': align_poses(images, K, T, config, held_out=held),
            'training_views': align_poses(images[~held], K[~held], T[~held], config)}


def _corrected(T: np.ndarray, correction: np.ndarray) -> np.ndarray:
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ Rotation.from_rotvec(correction[:, :3]).as_matrix()
    out[:, :3, 3] = T[:, :3, 3] + correction[:, 3:] - correction[:, 3:].mean(0)  # the gauge, as PoseRefinement
    return out


def _fruit_px(T: np.ndarray, truth: np.ndarray, dataset_dir: Path, views: np.ndarray) -> float:
    """Median distance (px) between the fruit centres projected into ``views`` with poses ``T`` [len(views)] and
    with the true poses."""
    transforms = read_transforms(dataset_dir)
    cameras = [frame.intrinsics or transforms.intrinsics for frame in transforms.frames]
    centres = np.asarray(load_ground_truth(dataset_dir / 'gt_fruits.json').centers)
    return pose_errors(T, truth[views], [cameras[v] for v in views], centres)['reprojection_px_median']


def test_the_alignment_undoes_most_of_the_odometry_noise(twins: tuple[Path, Path], aligned: dict) -> None:
    result, views = aligned['training_views'], np.flatnonzero(~aligned['held'])
    T = aligned['T'][views]
    before = _fruit_px(T, aligned['truth'], twins[0], views)
    after = _fruit_px(_corrected(T, result.correction), aligned['truth'], twins[0], views)
    assert result.report['applied'] and result.report['tracks'] >= 200
    assert result.report['reprojection_px_before'] > 1.0 > result.report['reprojection_px_after']
    assert before > 4.0 and after < 0.6 * before, (before, after, result.report)


def test_exact_poses_are_kept(twins: tuple[Path, Path]) -> None:
    data = load_dataset(twins[1], eval_every=0)
    result = align_poses((data.images.numpy() * 255).round().astype(np.uint8), data.intrinsics.double().numpy(),
                         data.T_world_camera.double().numpy(), PoseAlignmentConfig(enabled=True))
    assert not result.report['applied'] and result.report['reason'] == 'the recorded poses agree with the images'
    assert result.report['reprojection_px_before'] < 0.5 and not result.correction.any()


def test_a_track_with_two_features_in_one_view_is_dropped() -> None:
    # features 0, 1 in view 0, 2 and 4 in view 1, 3 in view 2: the matches join {0, 1, 2} (two of view 0) and {3, 4}
    view_of = np.array([0, 0, 1, 2, 1])
    points = np.arange(10, dtype=np.float64).reshape(5, 2)
    edges = np.array([[0, 2], [2, 1], [3, 4]])
    track, view, uv, feature = pose_alignment._tracks(edges, view_of, points, 3)
    assert track.tolist() == [0, 0] and sorted(view.tolist()) == [1, 2] and feature.tolist() == [3, 4]
    np.testing.assert_array_equal(uv, points[[3, 4]])


def test_held_out_views_are_posed_on_the_training_views_tracks_and_shape_none(twins: tuple[Path, Path],
                                                                              aligned: dict) -> None:
    """Every 8th view held out: its pose is solved on the training views' adjusted tracks (before session 48 it
    kept the odometry's, and its held-out figures measured the noise); the training views' corrections are what
    the alignment of the training views alone gives (a held-out image adds no track)."""
    T, held, result = aligned['T'], aligned['held'], aligned['with_held_out']
    np.testing.assert_array_equal(result.correction[~held], aligned['training_views'].correction)
    figures = result.report['held_out']
    assert figures['views'] == held.sum() and figures['posed'] >= held.sum() - 1, figures
    assert figures['reprojection_px_after'] < figures['reprojection_px_before'], figures
    correction = result.correction.copy()
    correction[:, 3:] -= correction[~held, 3:].mean(0)  # the gauge of aligned_poses: the training views' mean
    posed = T.copy()
    posed[:, :3, :3] = T[:, :3, :3] @ Rotation.from_rotvec(correction[:, :3]).as_matrix()
    posed[:, :3, 3] = T[:, :3, 3] + correction[:, 3:]
    views = np.flatnonzero(held)
    before = _fruit_px(T[views], aligned['truth'], twins[0], views)
    after = _fruit_px(posed[views], aligned['truth'], twins[0], views)
    assert before > 4.0 and after < 0.6 * before, (before, after, figures)


def test_training_starts_from_the_alignment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The geometry stage's pose corrections start at the alignment's; with pose_lr 0 they stay there."""
    scene = make_sphere_scene(tmp_path / 'spheres', views=10, size=32, fruits=6, write_ply=True)
    data = load_dataset(scene, eval_every=MICRO.data.eval_every)
    views = data.train_indices.numpy()
    wanted = np.zeros((len(views), 6))
    wanted[:, 2] = np.deg2rad(0.5) * np.linspace(-1, 1, len(views))
    wanted[:, 3] = np.linspace(-0.01, 0.01, len(views))
    calls = []

    held_out = np.setdiff1d(np.arange(data.num_views), views)
    resected = np.zeros((len(held_out), 6))
    resected[:, 0] = np.deg2rad(0.3)
    resected[:, 4] = 0.02
    every = np.zeros((data.num_views, 6))
    every[views], every[held_out] = wanted, resected

    def stub(images: np.ndarray, intrinsics: np.ndarray, T: np.ndarray, config: PoseAlignmentConfig,
             valid: np.ndarray | None = None, held: np.ndarray | None = None) -> PoseAlignment:
        calls.append((len(images), np.flatnonzero(held).tolist()))
        return PoseAlignment(every, {'applied': True})

    monkeypatch.setattr('fruitnerfpp_ros.core.training.pose_start.align_poses', stub)
    evaluated = []

    def evaluate(field, grid, dataset, views, *args, **kwargs):
        evaluated.append((views, dataset.T_world_camera.clone()))
        return evaluate_views(field, grid, dataset, views, *args, **kwargs)

    monkeypatch.setattr('fruitnerfpp_ros.core.training.trainer.evaluate_views', evaluate)
    config = replace_nested(MICRO, {'pose_alignment': {'enabled': True}, 'geometry': {'pose_lr': 0.0}})
    train(scene, tmp_path / 'run', config, device='cpu')
    assert calls == [(data.num_views, held_out.tolist())]  # every view; the held-out ones named
    assert json.loads((tmp_path / 'run' / 'pose_alignment.json').read_text()) == {'applied': True}
    trained = load_trained_scene(tmp_path / 'run', device='cpu')
    corrections = trained.pose_corrections.correction.detach().double().numpy()
    np.testing.assert_allclose(corrections[views], wanted, atol=1e-7)
    poses = trained.poses(data.T_world_camera).double().numpy()
    # the held-out views are where the alignment posed them, under the training views' gauge (a mean of 0 here)
    recorded = data.T_world_camera.double().numpy()
    np.testing.assert_allclose(poses[held_out, :3, 3], recorded[held_out, :3, 3] + resected[:, 3:], atol=1e-6)
    np.testing.assert_allclose(poses[held_out, :3, :3], recorded[held_out, :3, :3]
                               @ Rotation.from_rotvec(resected[:, :3]).as_matrix(), atol=1e-6)
    expected = _corrected(recorded[views], wanted)
    np.testing.assert_allclose(poses[views], expected, atol=1e-5)
    # the held-out figures are rendered from those poses (before session 48 from the recorded ones)
    assert len(evaluated) == 3 and all(v and set(v) <= set(held_out.tolist()) for v, _ in evaluated)
    for _, rendered in evaluated:
        np.testing.assert_allclose(rendered[held_out].double().numpy(), poses[held_out], atol=1e-6)


@pytest.mark.parametrize('aligned, registered', [(False, False), (True, False), (False, True)])
def test_poses_are_refined_where_the_alignment_or_the_registration_found_them_off(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, aligned: bool, registered: bool) -> None:
    """``pose_refine_when: aligned`` (the tiny, default and paper presets): the photometric refinement runs only
    when the alignment corrected the poses or the pass registration moved a return pass (a drift grown along the
    drive is more than its one rigid move); poses that agree with the images stay as recorded (``always``, the
    ``cpu`` preset's, refines them anyway: test_pose_refinement.py). Before session 41 the gate read only the
    alignment, so a moved pass was not refined (the third case failed)."""
    scene = make_sphere_scene(tmp_path / 'spheres', views=10, size=32, fruits=6, write_ply=True)
    views = load_dataset(scene, eval_every=MICRO.data.eval_every).train_indices.numpy()
    start = np.zeros((len(load_dataset(scene).images), 6))
    if aligned:
        start[views, 3] = np.linspace(-0.01, 0.01, len(views))
    aligned_start = start.copy()
    monkeypatch.setattr('fruitnerfpp_ros.core.training.pose_start.align_poses',
                        lambda images, *args, **kwargs: PoseAlignment(aligned_start, {'applied': aligned}))
    later = views[len(views) // 2:]
    shift = np.eye(4)
    shift[0, 3] = 0.005 if registered else 0.0
    monkeypatch.setattr('fruitnerfpp_ros.core.training.pose_start.register_passes',
                        lambda *args, **kwargs: PassRegistration(later, shift, {'applied': registered}))
    if registered:
        start[later, 3] += 0.005
    config = replace_nested(MICRO, {'pose_alignment': {'enabled': True}, 'pass_registration': {'enabled': True},
                                    'geometry': {'pose_lr': 1e-2, 'pose_start_fraction': 0.0,
                                                 'pose_refine_when': 'aligned'}})
    train(scene, tmp_path / 'run', config, device='cpu')
    refined = aligned or registered
    stored = load_config(TrainConfig, tmp_path / 'run' / 'config.yaml')
    assert stored.geometry.pose_lr == (1e-2 if refined else 0.0)  # what ran: a resume reads the same
    corrections = load_trained_scene(tmp_path / 'run', device='cpu').pose_corrections.correction.detach().numpy()
    moved = np.abs(corrections[views] - start[views]).max()
    assert (moved > 1e-4) if refined else (moved == 0.0)


def test_a_config_that_cannot_work_is_refused() -> None:
    with pytest.raises(ConfigError, match='min_tracks and rounds must be >= 1'):
        PoseAlignmentConfig(min_tracks=0)
    with pytest.raises(ConfigError, match='check_neighbours <= neighbours'):
        PoseAlignmentConfig(check_neighbours=9, neighbours=8)
