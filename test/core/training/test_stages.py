"""Training stages: learning-rate schedules per group, what each loss sees and moves (poses included)."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from fruitnerfpp_ros.core.config_io import replace_nested
from fruitnerfpp_ros.core.data.dataset import load_dataset
from fruitnerfpp_ros.core.data.rays import PixelBatch, pixels_crossing_box, rays_for_pixels
from fruitnerfpp_ros.core.data.samplers import mask_interior
from fruitnerfpp_ros.core.progress import ProgressEvent
from fruitnerfpp_ros.core.training import RunDir, train
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint
from fruitnerfpp_ros.core.training.model import FruitNeRFModel
from fruitnerfpp_ros.core.training.scene_box import measure_scene
from fruitnerfpp_ros.core.training.stages import build_stages
from fruitnerfpp_ros.core.training.trainer import _train_step, make_optimizer, _Progress
from fruitnerfpp_ros.errors import ConfigError
from test.core.training.stand_in_scene import make_sphere_scene
from test.core.training.test_trainer import MICRO

REFINED = replace_nested(MICRO, {'geometry': {'pose_lr': 1e-3, 'lr': 2e-2, 'lr_final_factor': 0.1},
                                 'semantic': {'lr': 5e-2, 'lr_final_factor': 0.2, 'fruit_fraction': 0.25},
                                 'instance': {'lr': 3e-2, 'lr_final_factor': 0.5}})


@pytest.fixture(scope='module')
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sphere_scene(tmp_path_factory.mktemp('spheres'), views=10, size=32, fruits=6, write_ply=True)


@pytest.fixture(scope='module')
def parts(scene: Path) -> tuple:
    dataset = load_dataset(scene, eval_every=REFINED.data.eval_every)
    aabb, scale = measure_scene(dataset, REFINED)
    model = FruitNeRFModel(REFINED, dataset, aabb, scale.fruit_diameter_m, torch.device('cpu'))
    return dataset, model, build_stages(REFINED, dataset)


def test_learning_rate_of_every_group_at_the_start_and_end_of_every_stage(parts: tuple) -> None:
    _, model, stages = parts
    g, s, i = REFINED.geometry, REFINED.semantic, REFINED.instance
    expected = {  # (stage, group): (lr at the first step, lr at the last step)
        ('geometry', 'geometry'): (g.lr, g.lr * g.lr_final_factor),
        ('geometry', 'poses'): (0.0, g.pose_lr * g.lr_final_factor),  # held for the first quarter
        ('semantic', 'semantic'): (s.lr, s.lr * s.lr_final_factor),
        ('semantic', 'geometry'): (g.lr * g.lr_final_factor,) * 2,   # constant at stage 1's final rate
        ('semantic', 'poses'): (g.pose_lr * g.lr_final_factor,) * 2,
        ('instance', 'instance'): (i.lr, i.lr * i.lr_final_factor),
    }
    seen = {}
    for stage in stages:
        for group in stage.param_groups(model):
            seen[(stage.name, group.name)] = (group.lr_at(0.0), group.lr_at(1.0))
    assert seen.keys() == expected.keys()
    for key, (start, end) in expected.items():
        assert seen[key][0] == pytest.approx(start, rel=1e-9) and seen[key][1] == pytest.approx(end, rel=1e-9), key
    poses = next(gr for gr in stages[0].param_groups(model) if gr.name == 'poses')
    assert poses.lr_at(g.pose_start_fraction - 1e-6) == 0.0 < poses.lr_at(g.pose_start_fraction)


def test_the_loop_sets_each_groups_rate_on_the_optimiser(parts: tuple) -> None:
    _, model, stages = parts
    stage = stages[1]
    groups = stage.param_groups(model)
    optimizer = make_optimizer(groups, REFINED)
    progress = _Progress(step=stage.iterations - 1, summaries=[])  # the last step of the stage
    _train_step(stage, model, groups, optimizer, progress, torch.Generator().manual_seed(0), REFINED)
    fraction = (stage.iterations - 1) / stage.iterations
    assert [pg['lr'] for pg in optimizer.param_groups] == pytest.approx([gr.lr_at(fraction) for gr in groups])


def test_the_optimiser_is_fused_on_the_cpu_and_takes_the_reference_adam_step(parts: tuple) -> None:
    """The fused update (one kernel over every parameter: 6x faster per step on the CPU) is still Adam: one step
    from the same gradients moves every parameter as torch's reference (per-tensor loop) Adam does."""
    _, model, stages = parts
    groups = stages[0].param_groups(model)
    optimizer = make_optimizer(groups, REFINED)
    assert optimizer.defaults['fused'] is True
    copied = [[torch.nn.Parameter(p.detach().clone()) for p in group['params']] for group in optimizer.param_groups]
    params = [p for group in optimizer.param_groups for p in group['params']]
    copies = [c for group in copied for c in group]
    o = REFINED.optimizer
    reference = torch.optim.Adam([{'params': group, 'lr': 0.01} for group in copied],
                                 betas=(o.beta1, o.beta2), eps=o.eps, foreach=False)
    gen = torch.Generator().manual_seed(3)
    for p, c in zip(params, copies):
        p.grad = torch.randn(p.shape, generator=gen)
        c.grad = p.grad.clone()
    for group in optimizer.param_groups:
        group['lr'] = 0.01
    before = [p.detach().clone() for p in params]
    optimizer.step()
    reference.step()
    for p, c, b in zip(params, copies, before):
        assert not torch.equal(p.detach(), b)
        torch.testing.assert_close(p.detach(), c.detach(), rtol=1e-5, atol=1e-6)
    with torch.no_grad():  # the module-scoped model is shared: put it back
        for p, b in zip(params, before):
            p.copy_(b)
            p.grad = None


def test_stage_two_keeps_the_geometry_rate_stage_one_ended_with(scene: Path, tmp_path: Path) -> None:
    """Read back from the optimiser state of a checkpoint taken at the end of stage 2."""
    stop = threading.Event()

    def stop_late(event: ProgressEvent) -> None:
        if event.phase == 'train:semantic' and event.step == REFINED.semantic.iterations - 2:
            stop.set()

    config = replace_nested(REFINED, {'geometry': {'pose_lr': 0.0}})
    train(scene, tmp_path / 'run', config, device='cpu', progress=stop_late, stop_event=stop)
    state = load_checkpoint(RunDir(tmp_path / 'run').latest_checkpoint)
    assert state['stage'] == 1
    rates = sorted(group['lr'] for group in state['optimizer']['param_groups'])
    g = config.geometry
    assert g.lr * g.lr_final_factor in [pytest.approx(r, rel=1e-9) for r in rates]


def _grad_norm(params: list[torch.nn.Parameter]) -> float:
    return sum(float(p.grad.abs().sum()) for p in params if p.grad is not None)


def test_only_the_photometric_loss_moves_the_poses(parts: tuple) -> None:
    dataset, model, stages = parts
    poses = list(model.pose_refinement.parameters())
    for p in model.parameters():
        p.requires_grad_(True)
    with torch.no_grad():  # a small correction, so the poses are not at the identity's special point
        model.pose_refinement.correction.add_(0.01)
    semantic_stage, instance_stage = stages[1], stages[2]
    pixels = semantic_stage.sampler.sample(256, torch.Generator().manual_seed(1))
    jitter = torch.rand(256, generator=torch.Generator().manual_seed(2))
    terms = {}
    for name in ('photometric', 'semantic', 'contrastive'):
        model.zero_grad(set_to_none=True)
        if name == 'contrastive':
            batch = instance_stage.sampler.sample(torch.Generator().manual_seed(3))
            out = model.render(batch, torch.rand(len(batch.view)), colour=False, instance=True)
            loss = model.contrastive_loss(out, batch)
        else:
            out = model.render(pixels, jitter, colour=True, semantic=True)
            loss = model.photometric_loss(out, pixels, 256) if name == 'photometric' else \
                model.semantic_loss(out, pixels)
        loss.backward()
        terms[name] = _grad_norm(poses)
    assert terms['photometric'] > 0.0
    assert terms['semantic'] == 0.0 and terms['contrastive'] == 0.0


def test_semantic_batches_hold_the_fruit_share_and_colour_sees_only_uniform_rays(parts: tuple) -> None:
    dataset, model, stages = parts
    stage = stages[1]
    pixels = stage.sampler.sample(400, torch.Generator().manual_seed(5))
    n_uniform = stage.sampler.num_uniform(400)
    assert n_uniform == 300
    fruit = dataset.semantic_masks[pixels.view, pixels.row, pixels.col]
    assert bool(fruit[n_uniform:].all())
    assert float(fruit[:n_uniform].float().mean()) < 0.5  # the uniform part is mostly not fruit
    jitter = torch.rand(400, generator=torch.Generator().manual_seed(6))
    with torch.no_grad():
        out = model.render(pixels, jitter, colour=True)
        before = float(model.photometric_loss(out, pixels, n_uniform))
        uniform = set(zip(pixels.view[:n_uniform].tolist(), pixels.row[:n_uniform].tolist(),
                          pixels.col[:n_uniform].tolist()))
        saved = model.images.clone()
        for v, r, c in zip(pixels.view[n_uniform:].tolist(), pixels.row[n_uniform:].tolist(),
                           pixels.col[n_uniform:].tolist()):
            if (v, r, c) not in uniform:
                model.images[v, r, c] = 1.0 - model.images[v, r, c]
        after = float(model.photometric_loss(out, pixels, n_uniform))
        model.images.copy_(saved)
    assert after == before


def test_distortion_loss_covers_the_uniform_rays_only(parts: tuple) -> None:
    _, model, stages = parts
    stage = stages[1]
    pixels = stage.sampler.sample(200, torch.Generator().manual_seed(7))
    n_uniform = stage.sampler.num_uniform(200)
    jitter = torch.rand(200, generator=torch.Generator().manual_seed(8))
    full = model.render(pixels, jitter, distortion_rays=n_uniform).distortion.item()
    head = PixelBatch(pixels.view[:n_uniform], pixels.row[:n_uniform], pixels.col[:n_uniform])
    alone = model.render(head, jitter[:n_uniform]).distortion.item()
    assert full == pytest.approx(alone, rel=1e-5)
    assert model.render(pixels, jitter).distortion.item() != pytest.approx(alone, rel=1e-5)


def test_opacity_entropy_is_logged_and_weighted_only_when_asked(parts: tuple) -> None:
    dataset, model, stages = parts
    off = stages[0].losses(model, torch.Generator().manual_seed(3))
    assert 'opacity_entropy' not in off.logged
    weighted = replace_nested(REFINED, {'geometry': {'opacity_entropy_weight': 0.5}})
    on = build_stages(weighted, dataset)[0].losses(model, torch.Generator().manual_seed(3))
    expected = off.total + 0.5 * on.logged['opacity_entropy']
    assert float(on.total) == pytest.approx(float(expected), rel=1e-4)


def test_geometry_fruit_share_is_drawn_from_fruit_pixels_and_trains_colour(parts: tuple) -> None:
    dataset, model, stages = parts
    assert stages[0].sampler.num_uniform(400) == 320  # the default share, 0.2
    uniform = build_stages(replace_nested(REFINED, {'geometry': {'fruit_fraction': 0.0}}), dataset)[0]
    assert uniform.sampler.num_uniform(400) == 400
    biased = build_stages(replace_nested(REFINED, {'geometry': {'fruit_fraction': 0.25}}), dataset)[0]
    assert biased.sampler.num_uniform(400) == 300
    generator = torch.Generator().manual_seed(11)
    pixels = biased.sampler.sample(biased.batch_rays, generator)
    jitter = torch.rand(len(pixels.view), generator=generator)
    n_uniform = biased.sampler.num_uniform(len(pixels.view))
    assert bool(dataset.semantic_masks[pixels.view, pixels.row, pixels.col][n_uniform:].all())
    with torch.no_grad():
        out = model.render(pixels, jitter, colour=True, far_field_rays=n_uniform)  # fruit rays: no far field
        every_ray = float(model.photometric_loss(out, pixels, len(pixels.view)))
        uniform_only = float(model.photometric_loss(out, pixels, n_uniform))
        logged = float(biased.losses(model, torch.Generator().manual_seed(11)).logged['photo'])
    assert logged == pytest.approx(every_ray, rel=1e-4)
    assert logged != pytest.approx(uniform_only, rel=1e-4)


def test_fruit_fraction_outside_zero_to_one_is_refused() -> None:
    for stage, value in (('geometry', 1.0), ('geometry', -0.1), ('semantic', 1.5)):
        with pytest.raises(ConfigError, match=f'{stage}.fruit_fraction'):
            replace_nested(MICRO, {stage: {'fruit_fraction': value}})


@pytest.mark.parametrize('see_far_field', [True, False])
def test_fruit_rays_see_the_far_field_only_when_asked(parts: tuple, see_far_field: bool,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    dataset, model, _ = parts
    config = replace_nested(REFINED, {'geometry': {'fruit_fraction': 0.25, 'fruit_rays_far_field': see_far_field}})
    geometry, semantic = build_stages(config, dataset)[:2]
    seen: list = []
    render = model.render
    monkeypatch.setattr(model, 'render', lambda *a, **k: seen.append(k.get('far_field_rays')) or render(*a, **k))
    geometry.losses(model, torch.Generator().manual_seed(2))
    semantic.losses(model, torch.Generator().manual_seed(2))
    n_uniform = geometry.sampler.num_uniform(geometry.batch_rays)
    assert seen == [None if see_far_field else n_uniform, None]  # stage 2's fruit rays train no colour


def test_fruit_transparency_is_the_fruit_rays_mean_squared_transparency_and_weighted_only_when_asked(
        parts: tuple) -> None:
    dataset, model, stages = parts
    assert REFINED.geometry.fruit_opacity_weight == 0.02  # on by default
    off = build_stages(replace_nested(REFINED, {'geometry': {'fruit_opacity_weight': 0.0}}), dataset)[0].losses(
        model, torch.Generator().manual_seed(4))
    assert 'fruit_transparency' not in off.logged
    weighted = replace_nested(REFINED, {'geometry': {'fruit_opacity_weight': 0.5}})
    geometry = build_stages(weighted, dataset)[0]
    on = geometry.losses(model, torch.Generator().manual_seed(4))
    assert float(on.total) == pytest.approx(float(off.total + 0.5 * on.logged['fruit_transparency']), rel=1e-4)
    generator = torch.Generator().manual_seed(4)  # the same draw as the stage's, rendered here
    pixels = geometry.sampler.sample(geometry.batch_rays, generator)
    jitter = torch.rand(len(pixels.view), generator=generator)
    n_uniform = geometry.sampler.num_uniform(len(pixels.view))
    with torch.no_grad():
        opacity = model.render(pixels, jitter, colour=True, far_field_rays=n_uniform).opacity
    expected = float(((1.0 - opacity[n_uniform:]) ** 2).mean())
    assert expected > 1e-3  # an untrained field: the fruit rays are far from opaque
    assert float(on.logged['fruit_transparency']) == pytest.approx(expected, rel=1e-3)
    assert float(on.logged['fruit_transparency']) != pytest.approx(float(((1.0 - opacity) ** 2).mean()), rel=1e-3)


def test_fruit_transparency_moves_the_density_towards_opaque_fruit_rays(parts: tuple) -> None:
    dataset, model, _ = parts
    geometry = build_stages(replace_nested(REFINED, {'geometry': {'fruit_opacity_weight': 1.0}}), dataset)[0]
    params = list(model.field.geometry_parameters())
    for p in params:
        p.requires_grad_(True)
    model.zero_grad(set_to_none=True)
    before = geometry.losses(model, torch.Generator().manual_seed(9)).logged['fruit_transparency']
    saved = [p.detach().clone() for p in params]
    for _ in range(3):  # three signed-gradient steps of the transparency term alone (distortion: tiny, same way)
        model.zero_grad(set_to_none=True)
        step = geometry.losses(model, torch.Generator().manual_seed(9))
        (step.total - step.logged['photo']).backward()
        with torch.no_grad():
            for p in params:
                if p.grad is not None:
                    p.sub_(1e-2 * p.grad.sign())
    with torch.no_grad():
        after = geometry.losses(model, torch.Generator().manual_seed(9)).logged['fruit_transparency']
        for p, s in zip(params, saved):
            p.copy_(s)
    model.zero_grad(set_to_none=True)
    assert float(after) < 0.9 * float(before)


def test_fruit_transparency_on_the_interior_covers_only_interior_fruit_rays(parts: tuple) -> None:
    dataset, model, _ = parts
    config = replace_nested(REFINED, {'geometry': {'fruit_opacity_weight': 0.5, 'fruit_opacity_interior': True}})
    geometry = build_stages(config, dataset)[0]
    assert torch.equal(geometry.opaque_fruit, mask_interior(dataset.instance_masks, dataset.semantic_masks))
    assert build_stages(REFINED, dataset)[0].opaque_fruit is None
    # the sphere scene's fruits are a few pixels wide (no interior: all kept), so the term's selection is checked
    # with a chequerboard of the fruit pixels in its place
    rows, cols = torch.meshgrid(torch.arange(dataset.height), torch.arange(dataset.width), indexing='ij')
    geometry.opaque_fruit = dataset.semantic_masks & ((rows + cols) % 2 == 0)[None]
    generator = torch.Generator().manual_seed(12)
    pixels = geometry.sampler.sample(geometry.batch_rays, generator)
    jitter = torch.rand(len(pixels.view), generator=generator)
    n_uniform = geometry.sampler.num_uniform(len(pixels.view))
    kept = ((pixels.row[n_uniform:] + pixels.col[n_uniform:]) % 2 == 0)
    assert 0 < int(kept.sum()) < len(kept)
    with torch.no_grad():
        opacity = model.render(pixels, jitter, colour=True, far_field_rays=n_uniform).opacity[n_uniform:]
    expected = float(((1.0 - opacity[kept]) ** 2).mean())
    logged = float(geometry.losses(model, torch.Generator().manual_seed(12)).logged['fruit_transparency'])
    assert logged == pytest.approx(expected, rel=1e-3)
    assert logged != pytest.approx(float(((1.0 - opacity) ** 2).mean()), rel=1e-3)


def test_photometric_stages_draw_their_rays_through_the_scene_box_only(parts: tuple) -> None:
    dataset, model, _ = parts
    aabb = model.grid.aabb.numpy()
    centre, half = (aabb[0] + aabb[1]) / 2, (aabb[1] - aabb[0]) / 8
    small = np.stack([centre - half, centre + half])  # a box most pixels' rays miss
    crossing = pixels_crossing_box(dataset.T_world_camera, dataset.intrinsics, dataset.height, dataset.width,
                                   torch.as_tensor(small, dtype=torch.float32))
    assert 0.02 < float(crossing.float().mean()) < 0.8
    # the mask against points marched along a few rays of each kind (1 mm steps to 20 m)
    picks = [torch.tensor(v) for v in torch.nonzero(crossing)[::97].T.tolist()]
    misses = [torch.tensor(v) for v in torch.nonzero(~crossing)[::997].T.tolist()]
    for (v, r, c), expected in ((picks, True), (misses, False)):
        rays = rays_for_pixels(dataset.T_world_camera, dataset.intrinsics, v, r, c)
        t = torch.arange(0.0, 20.0, 1e-3)
        points = rays.origins[:, None] + t[None, :, None] * rays.directions[:, None]
        inside = ((points > torch.as_tensor(small[0])) & (points < torch.as_tensor(small[1]))).all(-1).any(-1)
        assert bool((inside == expected).all())
    box_config = replace_nested(REFINED, {'semantic': {'fruit_fraction': 0.0}, 'geometry': {'fruit_fraction': 0.0},
                                          'data': {'outside_box_fraction': 0.1}})
    for stage in build_stages(box_config, dataset, small)[:2]:
        drawn = stage.sampler.sample(4000, torch.Generator().manual_seed(5))
        through = crossing[drawn.view, drawn.row, drawn.col]
        assert bool(through[:3600].all()) and not bool(through[3600:].any())  # the last tenth: the backdrop
    stage = build_stages(replace_nested(box_config, {'data': {'rays_through_box': False}}), dataset, small)[0]
    drawn = stage.sampler.sample(4000, torch.Generator().manual_seed(5))
    assert float(crossing[drawn.view, drawn.row, drawn.col].float().mean()) < 0.8  # uniform over the image
    # a box every pixel's ray crosses: the draws are the ones without the test
    huge = np.stack([aabb[0] - 100.0, aabb[1] + 100.0])
    for with_box, without in zip(build_stages(box_config, dataset, huge)[:2], build_stages(box_config, dataset)[:2]):
        a, b = (s.sampler.sample(500, torch.Generator().manual_seed(2)) for s in (with_box, without))
        assert torch.equal(a.view, b.view) and torch.equal(a.row, b.row) and torch.equal(a.col, b.col)


def test_the_instance_stage_draws_from_the_masks_interior_only_when_asked() -> None:
    """``instance.interior``: no pixel on a fruit mask's boundary is drawn (a segmenter's boundary a pixel off
    labels the neighbour's surface); a fruit with no interior keeps its pixels."""
    from types import SimpleNamespace

    from fruitnerfpp_ros.core.training.stages import InstanceStage
    masks = torch.zeros(2, 24, 24, dtype=torch.int64)
    masks[:, 2:10, 2:10], masks[:, 2:10, 10:18], masks[:, 14:16, 3:5] = 1, 2, 3  # two touching fruits, a 2x2 one
    dataset = SimpleNamespace(train_indices=torch.arange(2), instance_masks=masks)
    boundary = masks.bool() & ~mask_interior(masks, masks.bool())
    drawn = {}
    for interior in (False, True):
        stage = InstanceStage(replace_nested(REFINED, {'instance': {'interior': interior, 'groups': 3}}), dataset)
        generator = torch.Generator().manual_seed(3)
        batches = [stage.sampler.sample(generator) for _ in range(20)]
        drawn[interior] = torch.cat([boundary[b.view, b.row, b.col] for b in batches])
        labels = torch.cat([masks[b.view, b.row, b.col] for b in batches])
        # every fruit drawn (the 2x2 one has no interior: it keeps its pixels), none of the background
        assert set(labels.tolist()) == {1, 2, 3}
    assert drawn[False].any() and not drawn[True].any()
