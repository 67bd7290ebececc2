"""Quality of the shared tiny trained run (24-view 96 px synthetic apple tree, tiny preset, CPU).

Figures are held-out views (every 8th), compared with an untrained field of the same config and box.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.fields.fruit_field import FruitField
from fruitnerfpp_ros.core.training import RunDir, load_trained_scene
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint, save_checkpoint
from fruitnerfpp_ros.core.training.model import occupancy_grid
from fruitnerfpp_ros.core.training.metrics import eval_stride, evaluate_views, psnr_from_mse, render_view


def _untrained(run: Path) -> tuple[float, float]:
    scene = load_trained_scene(run, device='cpu')
    config = scene.config
    dataset = load_dataset(scene.dataset_dir, eval_every=config.data.eval_every)
    torch.manual_seed(0)
    field = FruitField(config.field, scene.aabb, scene.fruit_diameter_m)
    grid = occupancy_grid(config, scene.aabb, scene.fruit_diameter_m)
    settings = scene.render_settings
    views = [int(v) for v in dataset.eval_indices[:1]]  # one view: an untrained field renders every sample
    metrics = evaluate_views(field, grid, dataset, views, settings, config.render.chunk_rays)
    return metrics.psnr, metrics.semantic_iou


def test_tiny_run_beats_untrained_and_separates_fruit(tiny_trained_run: Path) -> None:
    final = [r for r in RunDir(tiny_trained_run).read_metrics() if r.get('event') == 'stage_end']
    assert [r['stage'] for r in final] == ['geometry', 'semantic', 'instance']
    last = final[-1]
    psnr0, iou0 = _untrained(tiny_trained_run)
    assert last['eval_psnr'] > psnr0 + 5.0
    assert last['eval_semantic_iou'] > iou0 + 0.05
    # views with >= 2 fruits only, ties split: a constant embedding scores eval_instance_chance (~0.06 here)
    assert last['eval_instance_acc'] >= 0.85 > 5 * last['eval_instance_chance']


def test_trained_scene_answers_queries_for_export(tiny_trained_run: Path) -> None:
    scene = load_trained_scene(tiny_trained_run, device='cpu')
    import json
    fruits = json.loads((scene.dataset_dir / 'gt_fruits.json').read_text())['fruits']
    centres = torch.tensor([f['center'] for f in fruits], dtype=torch.float32)
    assert np.all(centres.numpy() > scene.aabb[0]) and np.all(centres.numpy() < scene.aabb[1])
    radius = torch.tensor([f['diameter'] / 2 for f in fruits], dtype=torch.float32)
    # points on each fruit's surface, on the side facing up/out (seen by the hemisphere cameras)
    dirs = torch.nn.functional.normalize(torch.randn(len(fruits), 64, 3), dim=-1)
    surface = centres[:, None] + radius[:, None, None] * dirs * 0.9
    q = scene.field.query(surface.reshape(-1, 3))
    prob = q.fruit_prob.reshape(len(fruits), -1)
    assert float(prob.max(1).values.median()) > 0.5
    density_at_fruit = q.density.reshape(len(fruits), -1).max(1).values.median()
    lo, hi = torch.as_tensor(scene.aabb[0], dtype=torch.float32), torch.as_tensor(scene.aabb[1], dtype=torch.float32)
    anywhere = scene.field.query(lo + torch.rand(4000, 3, generator=torch.Generator().manual_seed(0)) * (hi - lo))
    assert float(density_at_fruit) > 5.0 * float(anywhere.density.median())
    assert float(anywhere.density.median()) < scene.surface_density < float(q.density.max())
    emb = torch.nn.functional.normalize(
        (q.embedding.reshape(len(fruits), -1, q.embedding.shape[-1]) * prob[..., None]).sum(1), dim=-1)
    cos = emb @ emb.T
    off = cos[~torch.eye(len(fruits), dtype=torch.bool)]
    assert float(off.mean()) < float(cos.diagonal().mean()) - 0.3  # different fruits, different embeddings


def test_the_heads_a_stage_has_not_trained_are_not_evaluated(tiny_trained_run: Path) -> None:
    """The geometry stage's evaluation renders colour only, the semantic stage's no embedding: their untrained
    heads would cost most of the evaluation and score nothing (NaN, null in metrics.jsonl)."""
    ends = {r['stage']: r for r in RunDir(tiny_trained_run).read_metrics() if r.get('event') == 'stage_end'}
    assert ends['geometry']['eval_semantic_iou'] is None and ends['geometry']['eval_instance_acc'] is None
    assert ends['semantic']['eval_semantic_iou'] > 0 and ends['semantic']['eval_instance_acc'] is None
    assert all(ends[s]['eval_psnr'] > 0 for s in ends)
    scene = load_trained_scene(tiny_trained_run, device='cpu')
    dataset = load_dataset(scene.dataset_dir, eval_every=scene.config.data.eval_every)
    view = [int(dataset.eval_indices[0])]
    colour = evaluate_views(scene.field, scene.occupancy, dataset, view, scene.render_settings, 4096,
                            semantic=False, instance=False)
    full = evaluate_views(scene.field, scene.occupancy, dataset, view, scene.render_settings, 4096)
    assert colour.psnr == full.psnr and math.isnan(colour.semantic_iou) and math.isnan(colour.instance_acc)
    assert full.semantic_iou > 0 and full.instance_acc > 0


def test_a_run_written_before_the_far_field_loads_and_renders_without_one(tiny_trained_run: Path,
                                                                          tmp_path: Path) -> None:
    """Checkpoints of older releases have no far-field weights and no ``far_field`` in their config: they load with
    the constant background they were trained with, instead of failing on the missing weights."""
    scene = load_trained_scene(tiny_trained_run, device='cpu')
    assert scene.field.far is not None  # today's runs have one
    old = tmp_path / 'old_run'
    shutil.copytree(tiny_trained_run, old)
    checkpoint = RunDir(old).latest_checkpoint
    state = load_checkpoint(checkpoint)
    state['config']['field'].pop('far_field')
    state['config']['data'].pop('box_around')      # nor the box option: their boxes held the cameras
    state['field'] = {k: v for k, v in state['field'].items() if not k.startswith('far.')}
    save_checkpoint(state, checkpoint)
    loaded = load_trained_scene(old, device='cpu')
    assert loaded.field.far is None and loaded.config.data.box_around == 'fruit_and_cameras'
    dataset = load_dataset(loaded.dataset_dir, eval_every=loaded.config.data.eval_every)
    view = [int(dataset.eval_indices[0])]
    metrics = evaluate_views(loaded.field, loaded.occupancy, dataset, view, loaded.render_settings,
                             loaded.config.render.chunk_rays, semantic=False, instance=False)
    assert math.isfinite(metrics.psnr) and metrics.psnr > 10.0


def test_large_views_are_scored_on_a_strided_grid_of_the_same_pixels(tiny_trained_run: Path) -> None:
    """A view over ``eval_max_pixels`` is scored on every k-th row and column: the rendered pixels are those of the
    whole view at those places, and the figures are the whole render's there (the evaluation of 1280 x 960 views
    renders a ninth of the rays)."""
    assert eval_stride(960, 1280, 262_144) == 3 and eval_stride(512, 512, 262_144) == 1
    assert eval_stride(96, 96, None) == 1 and eval_stride(96, 96, 96 * 96 // 4) == 2
    scene = load_trained_scene(tiny_trained_run, device='cpu')
    dataset = load_dataset(scene.dataset_dir, eval_every=scene.config.data.eval_every)
    view = int(dataset.eval_indices[0])
    whole = render_view(scene.field, scene.occupancy, dataset, view, scene.render_settings, 4096)
    strided = render_view(scene.field, scene.occupancy, dataset, view, scene.render_settings, 4096, stride=2)
    assert strided.rgb.shape == (48, 48, 3)
    torch.testing.assert_close(strided.rgb, whole.rgb[::2, ::2], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(strided.embedding, whole.embedding[::2, ::2], atol=1e-4, rtol=1e-4)
    metrics = evaluate_views(scene.field, scene.occupancy, dataset, [view], scene.render_settings, 4096,
                             max_pixels=96 * 96 // 4)
    expected = psnr_from_mse(float(((whole.rgb - dataset.images[view])[::2, ::2] ** 2).mean()))
    assert metrics.psnr == pytest.approx(expected, abs=1e-3)
    assert metrics.psnr != pytest.approx(evaluate_views(scene.field, scene.occupancy, dataset, [view],
                                                        scene.render_settings, 4096).psnr, abs=1e-3)
