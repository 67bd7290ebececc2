"""Cascaded FruitNeRF++ training: geometry -> + semantics -> instance field only.

All randomness after model initialisation comes from one CPU ``torch.Generator`` saved in every checkpoint, with
the optimiser, occupancy grid and step, so ``resume=True`` ends bit-exactly where an uninterrupted run ends on the
CPU (on CUDA within a small tolerance: the hash-grid backward uses atomic adds).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from fruitnerfpp_ros.core.config_io import config_from_mapping, config_to_mapping, save_config
from fruitnerfpp_ros.core.data.bounds import scene_aabb
from fruitnerfpp_ros.core.data.dataset import SceneDataset, load_dataset
from fruitnerfpp_ros.core.data.rays import rays_for_pixels
from fruitnerfpp_ros.core.data.samplers import GroupInstanceSampler, UniformPixelSampler
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.fields.fruit_field import FruitField, GeometryOutput
from fruitnerfpp_ros.core.progress import Phase, ProgressCallback, ProgressEvent
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderSettings, render_rays
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint, save_checkpoint
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.losses import photometric_loss, prototype_infonce, semantic_loss
from fruitnerfpp_ros.core.training.metrics import EvalMetrics, evaluate_views, psnr_from_mse
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement, write_refined_poses
from fruitnerfpp_ros.core.training.run_dir import RunDir
from fruitnerfpp_ros.errors import CheckpointError, DatasetError, TrainingError

__all__ = ['STAGES', 'StageSummary', 'TrainSummary', 'TrainedScene', 'train', 'load_trained_scene',
           'build_scene_box']

log = logging.getLogger(__name__)

#: Stage names, in order; progress phases are ``train:<name>``.
STAGES = ('geometry', 'semantic', 'instance')
_CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class StageSummary:
    """What one stage did.

    Attributes:
        name: ``geometry``, ``semantic`` or ``instance``.
        steps: steps trained.
        wall_s: wall-clock seconds spent training the stage (summed over resumed runs, evaluation excluded).
        final_loss: loss of the last logged step.
        eval: held-out figures at the stage end.
    """

    name: str
    steps: int
    wall_s: float
    final_loss: float
    eval: EvalMetrics


@dataclass(frozen=True)
class TrainSummary:
    """Result of :func:`train`.

    Attributes:
        run_dir: the run directory.
        device: torch device used.
        stages: completed stages in order.
        stopped: True when ``stop_event`` ended training early (a checkpoint holds the state).
        aabb: [2, 3] scene box, metres.
    """

    run_dir: Path
    device: str
    stages: tuple[StageSummary, ...]
    stopped: bool
    aabb: np.ndarray

    @property
    def completed(self) -> bool:
        return len(self.stages) == len(STAGES) and not self.stopped


@dataclass(frozen=True)
class TrainedScene:
    """A trained field ready for export.

    Attributes:
        field: the field (eval mode, no grad needed); satisfies ``QueryableField``.
        aabb: [2, 3] float64 scene box, metres (world frame of the dataset).
        config: the resolved training config.
        dataset_dir: the dataset it was trained on.
        completed_stages: stages finished (3 for a complete run).
        occupancy: the final occupancy grid (cells with density), on the field's device.
    """

    field: FruitField
    aabb: np.ndarray
    config: TrainConfig
    dataset_dir: Path
    completed_stages: int
    occupancy: OccupancyGrid

    @property
    def march_step(self) -> float:
        """Ray-marching step (m) of the scene box: the default export voxel size."""
        return self.config.render.step_size(float(np.linalg.norm(self.aabb[1] - self.aabb[0])))

    @property
    def surface_density(self) -> float:
        """Density threshold (1/m) separating surfaces from empty space, for the export.

        The smaller of ``ln 2 / step`` (one marching step half opaque: right for a converged, opaque field) and
        the 90th percentile of the occupancy grid's densities (right for briefly trained, semi-transparent
        fields such as the tiny preset's, whose fruit surfaces reach a few 1/m only).
        """
        opaque = self.config.surface_density(float(np.linalg.norm(self.aabb[1] - self.aabb[0])))
        grid = float(torch.quantile(self.occupancy.values.float().cpu(), 0.9)) / self.march_step
        return min(opaque, grid) if grid > 0 else opaque


def build_scene_box(dataset: SceneDataset, config: TrainConfig) -> np.ndarray:
    """The scene box [2, 3]: ``config.data.aabb`` when set, else derived from cameras and sparse points."""
    if config.data.aabb is not None:
        box = np.asarray(config.data.aabb, dtype=np.float64).reshape(2, 3)
        if not np.all(box[1] > box[0]):
            raise DatasetError(f'data.aabb {config.data.aabb}: max must exceed min on every axis')
        return box
    return scene_aabb(dataset.T_world_camera, dataset.intrinsics, dataset.width, dataset.height,
                      ply_path=dataset.ply_path, min_view_fraction=config.data.min_view_fraction,
                      padding=config.data.aabb_padding, points_growth=config.data.points_growth)


class _GuardedCompile:
    """A torch.compile'd callable that falls back to eager mode, once and for good, when compiling fails."""

    def __init__(self, fn: Callable[[torch.Tensor], GeometryOutput]) -> None:
        self._eager = fn
        self._compiled: Callable[[torch.Tensor], GeometryOutput] | None = torch.compile(fn, dynamic=True)

    def __call__(self, xyz: torch.Tensor) -> GeometryOutput:
        if self._compiled is not None:
            try:
                return self._compiled(xyz)
            except Exception as err:  # compiler back-ends raise many types
                warnings.warn(f'torch.compile failed ({type(err).__name__}: {err}); running eagerly')
                self._compiled = None
        return self._eager(xyz)


class _Session:
    """Mutable state of one training run (field, grid, optimiser, generator, counters)."""

    def __init__(self, dataset: SceneDataset, config: TrainConfig, device: torch.device, aabb: np.ndarray,
                 run: RunDir) -> None:
        self.dataset = dataset
        self.config = config
        self.device = device
        self.aabb = aabb
        self.run = run
        diagonal = float(np.linalg.norm(aabb[1] - aabb[0]))
        self.settings = RenderSettings(step=config.render.step_size(diagonal), near=config.render.near,
                                       mixed_precision=config.render.mixed_precision,
                                       weight_threshold=config.instance.weight_threshold)
        field_config = config.field
        if field_config.density_bias is None:
            # Start just below the occupancy threshold (as instant-NGP does at its scale): the first occupancy
            # update then keeps only cells whose density training raised, never cells no ray constrains.
            field_config = dataclasses.replace(field_config, density_bias=math.log(
                0.5 * config.render.occupancy_threshold / self.settings.step))
        torch.manual_seed(config.seed)
        np.random.seed(config.seed)
        self.field = FruitField(field_config, aabb).to(device)
        self.grid = OccupancyGrid(torch.as_tensor(aabb, dtype=torch.float32),
                                  resolution=config.render.occupancy_resolution,
                                  threshold=config.render.occupancy_threshold,
                                  decay=config.render.occupancy_decay).to(device)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.geometry_fn: Callable[[torch.Tensor], GeometryOutput] = self.field.geometry
        if device.type == 'cuda' and config.render.compile and hasattr(torch, 'compile'):
            self.geometry_fn = _GuardedCompile(self.field.geometry)
        self.images = dataset.images.to(device)
        self.semantics = dataset.semantic_masks.to(device)
        self.poses = dataset.T_world_camera.to(device)
        trained = torch.zeros(len(self.poses), dtype=torch.bool)
        trained[dataset.train_indices] = True
        self.pose_refinement = PoseRefinement(trained).to(device) if config.geometry.pose_lr > 0 else None
        self.intrinsics = dataset.intrinsics.to(device)
        self.stage = 0
        self.step = 0
        self.global_step = 0
        self.stage_wall = 0.0
        self.summaries: list[StageSummary] = []
        self.optimizer: torch.optim.Optimizer | None = None
        self.last_loss = float('nan')

    # -- checkpoints --------------------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            'version': _CHECKPOINT_VERSION,
            'config': config_to_mapping(self.config),
            'dataset_dir': str(self.dataset.dataset_dir),
            'aabb': self.aabb,
            'stage': self.stage, 'step': self.step, 'global_step': self.global_step,
            'stage_wall': self.stage_wall, 'last_loss': self.last_loss,
            'summaries': [(s.name, s.steps, s.wall_s, s.final_loss, tuple(s.eval)) for s in self.summaries],
            'field': self.field.state_dict(),
            'grid': self.grid.state_dict(),
            'poses': None if self.pose_refinement is None else self.pose_refinement.state_dict(),
            'optimizer': None if self.optimizer is None else self.optimizer.state_dict(),
            'generator': self.generator.get_state(),
            'torch_rng': torch.get_rng_state(),
            'numpy_rng': np.random.get_state(),
        }

    def save(self) -> None:
        save_checkpoint(self.state(), self.run.latest_checkpoint)

    def restore(self, state: dict[str, Any]) -> None:
        self.field.load_state_dict(state['field'])
        self.grid.load_state_dict(state['grid'])
        if self.pose_refinement is not None:
            self.pose_refinement.load_state_dict(state['poses'])
        self.generator.set_state(state['generator'])
        torch.set_rng_state(state['torch_rng'])
        np.random.set_state(state['numpy_rng'])
        self.stage, self.step, self.global_step = state['stage'], state['step'], state['global_step']
        self.stage_wall, self.last_loss = state['stage_wall'], state['last_loss']
        self.summaries = [StageSummary(n, st, w, fl, EvalMetrics(*ev)) for n, st, w, fl, ev in state['summaries']]
        if self.stage < len(STAGES):
            self.optimizer = self.make_optimizer(self.stage)
            if state['optimizer'] is not None:
                self.optimizer.load_state_dict(state['optimizer'])

    # -- stages -------------------------------------------------------------------------------------------------
    def stage_config(self, stage: int) -> Any:
        return (self.config.geometry, self.config.semantic, self.config.instance)[stage]

    def make_optimizer(self, stage: int) -> torch.optim.Optimizer:
        geometry = self.config.geometry
        poses = [] if self.pose_refinement is None else list(self.pose_refinement.parameters())
        if stage == 0:
            groups = [{'params': list(self.field.geometry_parameters()), 'scale': 1.0},
                      {'params': poses, 'scale': geometry.pose_lr / geometry.lr, 'poses': True}]
        elif stage == 1:
            # density, colour and poses keep training at the learning rates stage 1 ended with
            semantic_lr = self.config.semantic.lr
            groups = [{'params': list(self.field.semantic_parameters()), 'scale': 1.0},
                      {'params': list(self.field.geometry_parameters()),
                       'scale': geometry.lr * geometry.lr_final_factor / semantic_lr},
                      {'params': poses, 'scale': geometry.pose_lr * geometry.lr_final_factor / semantic_lr,
                       'poses': True}]
        else:
            groups = [{'params': list(self.field.instance_parameters()), 'scale': 1.0}]
        groups = [g for g in groups if g['params']]
        for p in [*self.field.parameters(), *poses]:
            p.requires_grad_(False)
        for group in groups:
            for p in group['params']:
                p.requires_grad_(True)
        lr = self.stage_config(stage).lr
        return torch.optim.Adam(groups, lr=lr, betas=(0.9, 0.99), eps=1e-15)

    def set_lr(self) -> float:
        cfg = self.stage_config(self.stage)
        fraction = self.step / max(cfg.iterations, 1)
        lr = cfg.lr * cfg.lr_final_factor ** fraction
        assert self.optimizer is not None
        # Poses wait for a first geometry: Adam moves every parameter by about its learning rate per step, so
        # corrections trained from the first step random-walk while the field is still noise.
        hold = self.stage == 0 and fraction < self.config.geometry.pose_start_fraction
        for group in self.optimizer.param_groups:
            group['lr'] = 0.0 if hold and group.get('poses') else lr * group['scale']
        return lr

    def current_poses(self) -> torch.Tensor:
        """The camera-to-world poses [V, 4, 4] the rays use: the recorded ones, corrected when refined."""
        return self.poses if self.pose_refinement is None else self.pose_refinement(self.poses)

    def train_step(self, sampler: UniformPixelSampler | GroupInstanceSampler) -> dict[str, float]:
        """One optimisation step of the current stage; returns its logged values."""
        assert self.optimizer is not None
        lr = self.set_lr()
        scalars: dict[str, torch.Tensor] = {}  # read back once, after the step is queued (one GPU sync)
        if self.stage < 2:
            assert isinstance(sampler, UniformPixelSampler)
            cfg = self.stage_config(self.stage)
            pixels = sampler.sample(cfg.batch_rays, self.generator)
        else:
            assert isinstance(sampler, GroupInstanceSampler)
            pixels = sampler.sample(self.generator)
        jitter = torch.rand(len(pixels.view), generator=self.generator)
        view, row, col = (t.to(self.device) for t in (pixels.view, pixels.row, pixels.col))
        rays = rays_for_pixels(self.current_poses(), self.intrinsics, view, row, col)
        if self.stage < 2:
            semantic = self.stage == 1
            out = render_rays(self.field, self.grid, rays, self.settings, jitter=jitter.to(self.device),
                              semantic=semantic, geometry_fn=self.geometry_fn)
            assert out.rgb is not None
            # colour is fitted on the uniformly drawn rays only (the fruit-biased part would skew the geometry)
            n_uniform = sampler.num_uniform(len(view))
            photo = photometric_loss(out.rgb[:n_uniform], self.images[view[:n_uniform], row[:n_uniform],
                                                                      col[:n_uniform]])
            loss = photo
            scalars['photo'] = photo.detach()
            if self.config.geometry.distortion_weight > 0 and out.distortion is not None:
                loss = loss + self.config.geometry.distortion_weight * out.distortion
                scalars['distortion'] = out.distortion.detach()
            if semantic:
                assert out.fruit_prob is not None
                sem = semantic_loss(out.fruit_prob, self.semantics[view, row, col])
                loss = loss + self.config.semantic.semantic_weight * sem
                scalars['semantic_loss'] = sem.detach()
        else:
            out = render_rays(self.field, self.grid, rays, self.settings, jitter=jitter.to(self.device),
                              colour=False, instance=True, geometry_fn=self.geometry_fn)
            assert out.embedding is not None and pixels.fruit is not None
            contr = prototype_infonce(out.embedding, pixels.fruit.to(self.device), self.config.instance.temperature,
                                      num_fruits=int(pixels.fruit.max()) + 1)
            loss = self.config.instance.contrastive_weight * contr
            scalars['contrastive_loss'] = contr.detach()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.step += 1
        self.global_step += 1
        if self.stage < 2 and self.step % self.config.render.occupancy_update_every == 0:
            self.grid.update(lambda xyz: self.geometry_fn(xyz).density, self.settings.step, self.generator)
        scalars['loss'] = loss.detach()
        if self.pose_refinement is not None and self.stage < 2:
            correction = self.pose_refinement.correction.detach()
            scalars['pose_rot_deg'] = torch.rad2deg(correction[:, :3].norm(dim=-1).max())
            scalars['pose_trans_m'] = correction[:, 3:].norm(dim=-1).max()
        values = dict(zip(scalars, torch.stack([v.float() for v in scalars.values()]).tolist()))
        record: dict[str, float] = {'lr': lr}
        if 'photo' in values:
            record['psnr'] = psnr_from_mse(values.pop('photo'))
        record.update(values)
        record['samples_per_ray'] = out.num_samples / max(len(view), 1)
        self.last_loss = record['loss']
        return record


def _resolved_config(run: RunDir, config: TrainConfig | None, resume: bool) -> tuple[TrainConfig, dict | None]:
    state = None
    if resume and run.latest_checkpoint.is_file():
        state = load_checkpoint(run.latest_checkpoint)
        stored = config_from_mapping(TrainConfig, state['config'])
        if config is not None and config != stored:
            log.warning('resume: using the config stored in %s, not the one passed in', run.latest_checkpoint)
        return stored, state
    if not resume and run.latest_checkpoint.is_file():
        raise TrainingError(f'{run.root} already holds a training run ({run.latest_checkpoint}); '
                            'pass resume=True (--resume) to continue it, or choose another run directory')
    return (config if config is not None else TrainConfig.preset('default')), None


def train(dataset_dir: str | Path, run_dir: str | Path, config: TrainConfig | None = None, *, device: str = 'auto',
          resume: bool = False, progress: ProgressCallback | None = None,
          stop_event: threading.Event | None = None, show_progress: bool = False) -> TrainSummary:
    """Train the three cascaded stages on a transforms.json dataset.

    Args:
        dataset_dir: dataset directory (transforms.json, images, instance masks).
        run_dir: output run directory (config.yaml, checkpoints/, metrics.jsonl).
        config: training config (default: the ``default`` preset); ignored on resume (the stored one wins).
        device: ``auto``, ``cpu`` or ``cuda[:N]``.
        resume: continue from ``run_dir/checkpoints/latest.pt`` (starts fresh when there is none).
        progress: called with ``ProgressEvent(phase='train:<stage>', ...)`` at every logging step.
        stop_event: when set, the run checkpoints and returns early (``TrainSummary.stopped``).
        show_progress: tqdm bars per stage (CLI).

    Raises:
        DatasetError: bad dataset. CheckpointError: unreadable checkpoint. TrainingError: run dir in use.
    """
    dev = resolve_device(device)
    run = RunDir(run_dir)
    config, state = _resolved_config(run, config, resume)
    threads = torch.get_num_threads()
    if dev.type == 'cpu' and config.cpu_threads > 0:
        torch.set_num_threads(config.cpu_threads)
    try:
        return _train(dataset_dir, run, config, state, dev, progress, stop_event, show_progress)
    finally:
        torch.set_num_threads(threads)


def _train(dataset_dir: str | Path, run: RunDir, config: TrainConfig, state: dict[str, Any] | None,
           dev: torch.device, progress: ProgressCallback | None, stop_event: threading.Event | None,
           show_progress: bool) -> TrainSummary:
    dataset = load_dataset(dataset_dir, eval_every=config.data.eval_every)
    if state is not None and Path(state['dataset_dir']).resolve() != Path(dataset_dir).resolve():
        log.warning('resume: dataset %s differs from the one the run started with (%s)', dataset_dir,
                    state['dataset_dir'])
    aabb = np.asarray(state['aabb']) if state is not None else build_scene_box(dataset, config)
    run.create()
    save_config(config, run.config_path)
    session = _Session(dataset, config, dev, aabb, run)
    if state is not None:
        session.restore(state)
        run.truncate_metrics(session.global_step)
    train_views = dataset.train_indices
    eval_views = [int(v) for v in dataset.eval_indices[:config.eval_max_views]]
    samplers: dict[int, UniformPixelSampler | GroupInstanceSampler] = {}
    emit = progress or (lambda event: None)
    stopped = False
    while session.stage < len(STAGES):
        stage, name = session.stage, STAGES[session.stage]
        cfg = session.stage_config(stage)
        if session.optimizer is None:
            session.optimizer = session.make_optimizer(stage)
        if stage not in samplers:
            samplers[stage] = (UniformPixelSampler(train_views, dataset.height, dataset.width) if stage == 0 else
                               UniformPixelSampler(train_views, dataset.height, dataset.width,
                                                   fruit_masks=dataset.semantic_masks,
                                                   fruit_fraction=config.semantic.fruit_fraction) if stage == 1 else
                               GroupInstanceSampler(train_views, dataset.instance_masks, groups=cfg.groups,
                                                    group_size=cfg.group_size, pixels_per_fruit=cfg.pixels_per_fruit,
                                                    min_pixels=config.data.min_fruit_pixels))
        bar = None
        if show_progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.iterations, initial=session.step, desc=f'train:{name}', unit='step',
                       dynamic_ncols=True)
        session.field.train()
        while session.step < cfg.iterations:
            if stop_event is not None and stop_event.is_set():
                stopped = True
                break
            started = time.perf_counter()
            record = session.train_step(samplers[stage])
            session.stage_wall += time.perf_counter() - started
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f'{v:.4g}' for k, v in record.items() if k in ('loss', 'psnr')})
            if session.step % config.log_every == 0 or session.step == cfg.iterations:
                run.append_metrics({'stage': name, 'step': session.step, 'global_step': session.global_step,
                                    'wall_s': round(session.stage_wall, 3),
                                    'occupied_fraction': session.grid.occupied_fraction, **record})
                message = ' '.join(f'{k} {v:.4g}' for k, v in record.items() if k in ('loss', 'psnr'))
                emit(ProgressEvent(Phase.training(name), session.step, cfg.iterations, message))
            if session.step % config.checkpoint_every == 0 and session.step < cfg.iterations:
                session.save()
        if bar is not None:
            bar.close()
        if stopped:
            session.save()
            emit(ProgressEvent(Phase.training(name), session.step, cfg.iterations, 'stopped'))
            break
        session.field.eval()
        metrics = evaluate_views(session.field, session.grid, dataset, eval_views, session.settings,
                                 config.render.chunk_rays)
        summary = StageSummary(name, cfg.iterations, session.stage_wall, session.last_loss, metrics)
        run.append_metrics({'stage': name, 'event': 'stage_end', 'step': session.step,
                            'global_step': session.global_step, 'wall_s': round(session.stage_wall, 3),
                            'eval_psnr': metrics.psnr, 'eval_semantic_iou': metrics.semantic_iou,
                            'eval_instance_acc': metrics.instance_acc, 'eval_views': metrics.num_views})
        emit(ProgressEvent(Phase.training(name), cfg.iterations, cfg.iterations,
                           f'eval psnr {metrics.psnr:.2f} iou {metrics.semantic_iou:.3f} '
                           f'inst {metrics.instance_acc:.3f}'))
        session.summaries.append(summary)
        if name == 'semantic' and session.pose_refinement is not None:  # the poses are final from here on
            with torch.no_grad():
                write_refined_poses(run.refined_poses_path, session.poses, session.current_poses(),
                                    list(dataset.file_paths), session.pose_refinement.trained)
        session.stage += 1
        session.step = 0
        session.stage_wall = 0.0
        session.optimizer = None
        session.save()
    for p in session.field.parameters():
        p.requires_grad_(False)
    return TrainSummary(run.root, str(dev), tuple(session.summaries), stopped, aabb)


def load_trained_scene(run_dir: str | Path, device: str = 'auto') -> TrainedScene:
    """Load the field of a run directory (its latest checkpoint) for export.

    Raises:
        CheckpointError: no run or checkpoint in ``run_dir``, or an unreadable / incompatible one.
    """
    run = RunDir(run_dir)
    if not run.latest_checkpoint.is_file():
        raise CheckpointError(f'{run.latest_checkpoint}: not found; is {run.root} a training run directory?')
    dev = resolve_device(device)
    state = load_checkpoint(run.latest_checkpoint, device=dev)
    if state.get('version') != _CHECKPOINT_VERSION:
        raise CheckpointError(f'{run.latest_checkpoint}: checkpoint version {state.get("version")} is not '
                              f'{_CHECKPOINT_VERSION}')
    try:
        config = config_from_mapping(TrainConfig, state['config'])
    except Exception as err:
        raise CheckpointError(f'{run.latest_checkpoint}: stored config is invalid: {err}') from err
    aabb = np.asarray(state['aabb'], dtype=np.float64)
    field = FruitField(config.field, aabb).to(dev)
    grid = OccupancyGrid(torch.as_tensor(aabb, dtype=torch.float32), resolution=config.render.occupancy_resolution,
                         threshold=config.render.occupancy_threshold, decay=config.render.occupancy_decay).to(dev)
    try:
        field.load_state_dict(state['field'])
        grid.load_state_dict(state['grid'])
    except RuntimeError as err:
        raise CheckpointError(f'{run.latest_checkpoint}: weights do not match the stored config: {err}') from err
    field.eval()
    for p in field.parameters():
        p.requires_grad_(False)
    return TrainedScene(field, aabb, config, Path(state['dataset_dir']), int(state['stage']), grid)
