"""Depth supervision: the line-of-sight split and loss, the measured depth of a batch, and training on RGB-D data
(its loss logged, garbage depth detected before it trains anything)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from fruitnerfpp_ros.core.config_io import replace_nested
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.rays import PixelBatch, RayBundle
from fruitnerfpp_ros.core.rendering.depth_loss import DepthTarget, line_of_sight, line_of_sight_loss
from fruitnerfpp_ros.core.rendering.marching import march_rays
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.volume import render_weights
from fruitnerfpp_ros.core.synthetic import SynthConfig, generate_orchard
from fruitnerfpp_ros.core.training import RunDir, TrainConfig, train
from fruitnerfpp_ros.core.training.model import FruitNeRFModel

AABB = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
MICRO = replace_nested(TrainConfig.preset('tiny'), {
    'geometry': {'iterations': 4, 'batch_rays': 128},
    'semantic': {'iterations': 2, 'batch_rays': 128},
    'instance': {'iterations': 2, 'groups': 2, 'group_size': 3, 'pixels_per_fruit': 8},
    'render': {'occupancy_update_every': 2, 'chunk_rays': 2048},
    'data': {'eval_every': 5},
    'checkpoint_every': 100, 'log_every': 1, 'eval_max_views': 1})


def _slab(n: int = 4) -> tuple[RayBundle, torch.Tensor, object]:
    """n rays straight down from z = 2 through the unit box, an opaque slab at z in [0.4, 0.6] (its top at t = 1.4);
    returns the rays, weights (with a graph to the density) and samples."""
    origins = torch.stack([torch.linspace(0.2, 0.8, n), torch.full((n,), 0.5), torch.full((n,), 2.0)], -1)
    rays = RayBundle(origins, torch.tensor([[0.0, 0.0, -1.0]]).repeat(n, 1))
    samples = march_rays(rays, OccupancyGrid(AABB, resolution=4, threshold=0.01, decay=0.95), 0.01)
    density = torch.where((samples.positions[:, 2] > 0.4) & (samples.positions[:, 2] < 0.6), 500.0, 0.01)
    density.requires_grad_(True)
    return rays, render_weights(samples, density), (samples, density)


def _target(distance: list[float], weight: list[float], window: float = 0.02) -> DepthTarget:
    return DepthTarget(torch.tensor(distance), torch.full((len(distance),), window), torch.tensor(weight))


def test_line_of_sight_splits_the_weight_at_the_measured_depth() -> None:
    rays, weights, (samples, _) = _slab()
    # at the slab's top, behind it (the ray stops in front: its weight is in the sensor's free space), beyond the
    # box (no surface term: the ray cannot end there), and where the measured surface is exactly the slab again
    los = line_of_sight(samples, rays, weights, _target([1.4, 1.8, 5.0, 1.41], [1, 1, 1, 1]), AABB, 0.0)
    assert los.surface[0] > 0.99 and los.free[0] < 0.01
    assert los.surface[1] < 0.01 and los.free[1] > 0.99
    assert los.reachable.tolist() == [True, True, False, True]
    loss = line_of_sight_loss(los, _target([1.4, 1.8, 5.0, 1.41], [1, 1, 1, 1]), free_space_weight=0.5)
    expected = (0.5 * los.free + torch.where(los.reachable, 1 - los.surface, torch.zeros(4))).mean()
    torch.testing.assert_close(loss, expected)


def test_depth_loss_is_zero_where_depth_is_missing() -> None:
    rays, weights, (samples, density) = _slab()
    none = _target([0.0, 0.0, 0.0, 0.0], [0, 0, 0, 0])
    loss = line_of_sight_loss(line_of_sight(samples, rays, weights, none, AABB, 0.0), none)
    assert loss.item() == 0.0
    loss.backward()
    assert density.grad is not None and not density.grad.any()
    # rays without depth neither add to the loss nor dilute its mean
    rays, weights, (samples, density) = _slab()
    some = _target([1.8, 0.0, 1.8, 0.0], [1, 0, 0.5, 0])
    loss = line_of_sight_loss(line_of_sight(samples, rays, weights, some, AABB, 0.0), some)
    free = line_of_sight(samples, rays, weights, some, AABB, 0.0).free
    torch.testing.assert_close(loss, (free[0] + 1.0 + 0.5 * (free[2] + 1.0)) / 2)
    loss.backward()
    on_missing = (samples.ray_index == 1) | (samples.ray_index == 3)
    assert not density.grad[on_missing].any() and density.grad[~on_missing].any()


def _scene(root: Path, depth: str) -> Path:
    generate_orchard(SynthConfig(count=6, views=12, resolution=(40, 32), depth=depth, sparse_points=200), root)
    return root


@pytest.fixture(scope='module')
def rgbd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _scene(tmp_path_factory.mktemp('rgbd'), 'stereo')


def test_measured_depth_of_a_batch(rgbd: Path) -> None:
    dataset = load_dataset(rgbd, eval_every=5)
    model = FruitNeRFModel(MICRO, dataset, torch.tensor([[-2.0, -2.0, 0.0], [2.0, 2.0, 3.0]]).numpy(), 0.075,
                           torch.device('cpu'))
    assert model.depth_check is not None and model.depth_check.used.all()
    assert model.depths is not None and not model.depths[dataset.eval_indices].any()  # held-out depth unused
    view, row, col = torch.nonzero(model.depths > 0)[:64].T
    pixels = PixelBatch(view, row, col)
    target = model.depth_target(pixels, 48)
    assert target is not None
    z = model.depths[view, row, col]
    K = dataset.intrinsics[view]
    stretch = torch.sqrt(1 + ((col + 0.5 - K[:, 2]) / K[:, 0]) ** 2 + ((row + 0.5 - K[:, 3]) / K[:, 1]) ** 2)
    torch.testing.assert_close(target.distance[:48], (z * stretch)[:48])
    assert (target.weight[:48] > 0).all() and not target.weight[48:].any()  # only the uniform part of a batch
    assert (target.window >= model.depth_window_min_m - 1e-7).all() and (target.weight <= 1.0).all()
    far = target.window > model.depth_window_min_m  # uncertain (far) depth counts less
    torch.testing.assert_close(target.weight[:48][far[:48]], model.depth_window_min_m / target.window[:48][far[:48]])


def test_training_with_depth_logs_the_depth_loss(rgbd: Path, tmp_path: Path) -> None:
    summary = train(rgbd, tmp_path / 'run', MICRO, device='cpu')
    assert summary.completed
    records = [r for r in RunDir(tmp_path / 'run').read_metrics() if 'event' not in r]
    with_depth = {r['stage'] for r in records if 'depth_loss' in r}
    assert with_depth == {'geometry', 'semantic'}  # the instance stage trains its head only
    assert all(r['depth_loss'] > 0 and 0 < r['depth_rays'] <= 1 for r in records if 'depth_loss' in r)
    check = json.loads((tmp_path / 'run' / 'depth_check.json').read_text())
    assert all(check['used']) and 'agrees' in check['summary']


def test_garbage_depth_is_detected_and_not_trained(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    scene = _scene(tmp_path / 'garbage', 'random')
    with caplog.at_level('WARNING'):
        train(scene, tmp_path / 'run', MICRO, device='cpu')
    check = json.loads((tmp_path / 'run' / 'depth_check.json').read_text())
    assert not any(check['used'])
    assert 'training without depth' in caplog.text
    assert not any('depth_loss' in r for r in RunDir(tmp_path / 'run').read_metrics())
