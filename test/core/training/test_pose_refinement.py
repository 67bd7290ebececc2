"""Per-view pose corrections: the rotation map, the identity start, training in stages 1-2 only, resume."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.config_io import replace_nested
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.core.training import RunDir, TrainConfig, train
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement, rotation_from_axis_angle
from test.core.training.stand_in_scene import make_sphere_scene
from test.core.training.test_trainer import MICRO

REFINED = replace_nested(MICRO, {'geometry': {'pose_lr': 1e-3, 'pose_refine_when': 'always'}})


@pytest.fixture(scope='module')
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sphere_scene(tmp_path_factory.mktemp('spheres'), views=10, size=32, fruits=6, write_ply=True)


def test_rotation_map_is_rodrigues_and_smooth_at_zero() -> None:
    rotvec = torch.randn(6, 3, dtype=torch.float64)
    rotvec[0] = 0.0
    rotvec[1] *= 1e-6
    expected = Rotation.from_rotvec(rotvec.numpy()).as_matrix()
    np.testing.assert_allclose(rotation_from_axis_angle(rotvec).numpy(), expected, atol=1e-12)
    rotvec.requires_grad_(True)
    rotation_from_axis_angle(rotvec).sum().backward()
    assert torch.isfinite(rotvec.grad).all()


def test_corrections_start_at_zero_keep_held_out_views_and_remove_the_mean_shift() -> None:
    poses = torch.eye(4).repeat(3, 1, 1)
    poses[:, :3, 3] = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.5]])
    refinement = PoseRefinement(torch.tensor([True, True, False]))
    assert torch.equal(refinement(poses), poses)
    with torch.no_grad():
        refinement.correction[0] = torch.tensor([0.0, 0.0, np.pi / 2, 0.1, 0.0, 0.0])
        refinement.correction[2] = torch.tensor([0.3, 0.0, 0.0, 1.0, 1.0, 1.0])  # held out: ignored
    corrected = refinement(poses).detach()
    # the trained views' mean shift (0.05 m along x) is the gauge, not a correction
    np.testing.assert_allclose(corrected[0, :3, 3].numpy(), [1.05, 2.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(corrected[1, :3, 3].numpy(), [-0.05, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(corrected[0, :3, 0].numpy(), [0.0, 1.0, 0.0], atol=1e-6)  # camera x turned to y
    assert torch.equal(corrected[1, :3, :3], poses[1, :3, :3]) and torch.equal(corrected[2], poses[2])


def test_the_start_is_applied_as_given_and_only_what_training_adds_is_under_the_gauge() -> None:
    """The pass registration moves the return pass alone: its start must not be spread over both passes (which
    shifted a drifted row's whole reconstruction by half the drift); a checkpoint without a start loads as before."""
    poses = torch.eye(4).repeat(3, 1, 1)
    start = np.zeros((3, 6))
    start[1, 3:] = [0.07, 0.0, 0.0]                       # the return pass's view moved 7 cm, the first left
    refinement = PoseRefinement(torch.tensor([True, True, False]), start)
    np.testing.assert_allclose(refinement(poses)[:, :3, 3].detach().numpy(), [[0, 0, 0], [0.07, 0, 0], [0, 0, 0]],
                               atol=1e-7)
    with torch.no_grad():
        refinement.correction[0, 3:] += torch.tensor([0.02, 0.0, 0.0])   # training adds 2 cm to one view
    np.testing.assert_allclose(refinement(poses)[:2, :3, 3].detach().numpy(), [[0.01, 0, 0], [0.06, 0, 0]],
                               atol=1e-7)
    old = {'trained': refinement.trained, 'correction': refinement.correction.detach().clone()}
    loaded = PoseRefinement(torch.tensor([True, True, False]))
    loaded.load_state_dict(old)                           # a run from before the start was kept
    np.testing.assert_allclose(loaded(poses)[:2, :3, 3].detach().numpy(), [[-0.025, 0, 0], [0.025, 0, 0]],
                               atol=1e-7)
    again = PoseRefinement(torch.tensor([True, True, False]))
    again.load_state_dict(refinement.state_dict())
    assert torch.equal(again(poses), refinement(poses))


def test_a_held_out_view_keeps_its_start_and_learns_nothing() -> None:
    """The pose alignment poses the held-out views on the training views' tracks (core/data/pose_resection.py):
    that start is applied, is not under the training views' gauge, and training moves nothing of it (before
    session 48 a held-out view's start was dropped: it was rendered from its recorded pose)."""
    poses = torch.eye(4).repeat(3, 1, 1)
    start = np.zeros((3, 6))
    start[2] = [0.0, 0.0, 0.01, 0.0, 0.03, 0.0]
    refinement = PoseRefinement(torch.tensor([True, True, False]), start)
    with torch.no_grad():
        refinement.correction[0, 3:] += torch.tensor([0.02, 0.0, 0.0])   # training adds 2 cm to one view ...
        refinement.correction[2] += 0.5                                  # ... and nothing to the held-out one
    corrected = refinement(poses).detach()
    np.testing.assert_allclose(corrected[2, :3, 3].numpy(), [0.0, 0.03, 0.0], atol=1e-7)
    np.testing.assert_allclose(corrected[2, :3, :3].numpy(),
                               rotation_from_axis_angle(torch.tensor([[0.0, 0.0, 0.01]]))[0].numpy(), atol=1e-7)
    np.testing.assert_allclose(corrected[:2, :3, 3].numpy(), [[0.01, 0, 0], [-0.01, 0, 0]], atol=1e-7)


def _corrections(run: Path) -> torch.Tensor:
    return load_checkpoint(RunDir(run).latest_checkpoint)['poses']['correction']


def test_poses_train_in_the_first_two_stages_and_resume_exactly(scene: Path, tmp_path: Path) -> None:
    stop = threading.Event()

    def stop_in_semantic(event: ProgressEvent) -> None:
        if event.phase == 'train:semantic' and event.step == 2:
            stop.set()

    train(scene, tmp_path / 'full', REFINED, device='cpu')
    assert train(scene, tmp_path / 'split', REFINED, device='cpu', progress=stop_in_semantic, stop_event=stop).stopped
    train(scene, tmp_path / 'split', None, device='cpu', resume=True)
    full = _corrections(tmp_path / 'full')
    assert torch.equal(full, _corrections(tmp_path / 'split'))   # resume is bit-exact with refinement on
    assert float(full.abs().max()) > 0                             # the photometric loss moved the poses
    one_instance_step = replace_nested(REFINED, {'instance': {'iterations': 1}})
    train(scene, tmp_path / 'short', one_instance_step, device='cpu')
    assert torch.equal(full, _corrections(tmp_path / 'short'))   # ... and the instance stage leaves them
    logged = {r['stage'] for r in RunDir(tmp_path / 'full').read_metrics() if 'pose_rot_deg' in r}
    assert logged == {'geometry', 'semantic'}
    report = json.loads(RunDir(tmp_path / 'full').refined_poses_path.read_text())
    assert len(report['views']) == 10 and report['views'][0]['file_path'].startswith('images/')
    held_out = [v for v in report['views'] if not v['refined']]
    assert held_out and all(v['rotation_deg'] == 0.0 and v['translation_m'] == 0.0 for v in held_out)
    assert 0.0 < report['max_rotation_deg'] < 5.0 and 0.0 < report['max_translation_m'] < 0.1


def _table_after(scene: Path, run: Path, steps: int, config: TrainConfig) -> torch.Tensor:
    """The geometry grid's table [F, L, T] after ``steps`` geometry steps."""
    stop = threading.Event()

    def stop_after(event: ProgressEvent) -> None:
        if event.phase == 'train:geometry' and event.step >= steps:
            stop.set()

    assert train(scene, run, config, device='cpu', progress=stop_after, stop_event=stop).stopped
    table = load_checkpoint(RunDir(run).latest_checkpoint)['field']['encoding.table']
    return table.view(table.shape[0], config.field.geometry_grid.num_levels, -1)


def test_coarse_to_fine_holds_the_fine_levels_of_the_geometry_grid_back(scene: Path, tmp_path: Path) -> None:
    opening = replace_nested(REFINED, {'geometry': {'coarse_to_fine_fraction': 1.0}, 'log_every': 1})
    one, two = (_table_after(scene, tmp_path / f'c2f{n}', n, opening) for n in (1, 2))
    # step 1 (fraction 1/6 of the 6-step stage) opens level 1 in part: levels 2+ get no gradient, level 0 learns
    assert torch.equal(one[:, 2:], two[:, 2:]) and not torch.equal(one[:, 0], two[:, 0])
    plain = replace_nested(REFINED, {'log_every': 1})
    one, two = (_table_after(scene, tmp_path / f'plain{n}', n, plain) for n in (1, 2))
    assert not torch.equal(one[:, -1], two[:, -1])           # without it every level learns from the start
