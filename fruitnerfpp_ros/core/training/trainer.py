"""Cascaded FruitNeRF++ training: geometry -> + semantics -> instance field only, as a loop over stage objects.

All randomness comes from two CPU ``torch.Generator``s seeded with ``config.seed``: one draws the initial weights,
the other every batch, jitter and occupancy sample; the second is saved in every checkpoint with the optimiser,
occupancy grid and counters, so ``resume=True`` ends bit-exactly where an uninterrupted run ends on the CPU (on
CUDA within a small tolerance: the hash-grid backward uses atomic adds). Nothing here touches process-wide state
(global seeds, thread counts): that is the caller's.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fruitnerfpp_ros.core.config_io import config_from_mapping, config_to_mapping, save_config
from fruitnerfpp_ros.core.data.dataset import SceneDataset, load_dataset
from fruitnerfpp_ros.core.device import resolve_device
from fruitnerfpp_ros.core.progress import ProgressCallback, ProgressEvent
from fruitnerfpp_ros.core.training.checkpoint import load_checkpoint, save_checkpoint
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.metrics import EvalMetrics, evaluate_views, psnr_from_mse, spread_views
from fruitnerfpp_ros.core.training.model import FruitNeRFModel
from fruitnerfpp_ros.core.training.pose_refinement import write_refined_poses
from fruitnerfpp_ros.core.training.pose_start import PASS_REGISTRATION_JSON, POSE_ALIGNMENT_JSON, start_poses
from fruitnerfpp_ros.core.training.run_dir import RunDir
from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.data.scene_scale import SceneScale
from fruitnerfpp_ros.core.training.stages import STAGE_NAMES, ParamGroup, TrainingStage, build_stages, \
    stages_the_masks_allow
from fruitnerfpp_ros.core.training.trained_scene import CHECKPOINT_VERSION, SCALE_JSON, scale_from_json
from fruitnerfpp_ros.errors import TrainingError

__all__ = ['STAGES', 'StageSummary', 'TrainSummary', 'train', 'make_optimizer']

log = logging.getLogger(__name__)


#: Stage names, in order; progress phases are ``Phase.training(name)``.
STAGES = STAGE_NAMES


@dataclass(frozen=True)
class StageSummary:
    """What one stage did.

    Attributes:
        name: ``geometry``, ``semantic`` or ``instance``.
        steps: steps trained.
        wall_s: wall-clock seconds spent training the stage (summed over resumed runs, evaluation excluded).
        final_loss: loss of the last step.
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
        scale: the scene's fruit diameter and fruit region.
        prepare_s: wall seconds of this call before the first training step: the dataset read, the pose
            alignment, the scene measurement, the model built.
        evaluate_s: wall seconds of this call's held-out evaluations (stage ends).
        checkpoint_s: wall seconds of this call's checkpoint writes.
    """

    run_dir: Path
    device: str
    stages: tuple[StageSummary, ...]
    stopped: bool
    aabb: np.ndarray
    scale: SceneScale
    prepare_s: float = 0.0
    evaluate_s: float = 0.0
    checkpoint_s: float = 0.0

    @property
    def completed(self) -> bool:
        return len(self.stages) == len(STAGES) and not self.stopped


def make_optimizer(groups: list[ParamGroup], config: TrainConfig) -> torch.optim.Adam:
    """Adam over ``groups`` (empty groups left out); learning rates are set per step by the loop.

    The fused update (one kernel over all parameters) where torch has one for the parameters' device: on the CPU
    an update of three 2^15-entry hash tables takes 1.6 ms instead of 10 (one thread), a few percent of a ``cpu``
    preset step (the `cpu` suite: 44.1 -> 42.1 min). Same update rule; only the floating-point rounding differs.
    """
    o = config.optimizer
    params = [{'params': list(g.params), 'lr': 0.0} for g in groups if g.params]
    devices = {p.device.type for group in params for p in group['params']}
    return torch.optim.Adam(params, betas=(o.beta1, o.beta2), eps=o.eps,
                            fused=True if devices and devices <= {'cpu', 'cuda'} else None)


@dataclass
class _Progress:
    """Where a run stands: the checkpointed counters (plus the generator and optimiser state)."""

    stage: int = 0
    step: int = 0
    global_step: int = 0
    stage_wall: float = 0.0
    last_loss: float = float('nan')
    summaries: list[StageSummary] | None = None

    def to_state(self) -> dict[str, Any]:
        return {'stage': self.stage, 'step': self.step, 'global_step': self.global_step,
                'stage_wall': self.stage_wall, 'last_loss': self.last_loss,
                'summaries': [(s.name, s.steps, s.wall_s, s.final_loss, tuple(s.eval)) for s in self.summaries or []]}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> '_Progress':
        summaries = [StageSummary(n, st, w, fl, EvalMetrics(*ev)) for n, st, w, fl, ev in state['summaries']]
        return cls(state['stage'], state['step'], state['global_step'], state['stage_wall'], state['last_loss'],
                   summaries)


@dataclass
class _CallClock:
    """Where one call of :func:`train` spends its time (not checkpointed: a resumed run's call has its own)."""

    started: float = dataclasses.field(default_factory=time.perf_counter)
    evaluate_s: float = 0.0
    checkpoint_s: float = 0.0

    def elapsed_s(self) -> float:
        """Wall seconds since the call started (metrics records: the run's timeline)."""
        return round(time.perf_counter() - self.started, 3)


class _Checkpointer:
    """Writes and restores the whole training state of one run."""

    def __init__(self, run: RunDir, config: TrainConfig, dataset_dir: Path, aabb: np.ndarray, scale: SceneScale,
                 model: FruitNeRFModel, generator: torch.Generator, clock: _CallClock) -> None:
        self.run, self.config, self.dataset_dir, self.aabb, self.scale = run, config, dataset_dir, aabb, scale
        self.model, self.generator, self.clock = model, generator, clock

    def save(self, progress: _Progress, optimizer: torch.optim.Optimizer | None) -> None:
        started = time.perf_counter()
        model = self.model
        save_checkpoint({
            'version': CHECKPOINT_VERSION, 'config': config_to_mapping(self.config),
            **self.run.dataset_record(self.dataset_dir), 'aabb': self.aabb, 'scale': self.scale.to_json(),
            **progress.to_state(),
            'field': model.field.state_dict(), 'grid': model.grid.state_dict(),
            'poses': None if model.pose_refinement is None else model.pose_refinement.state_dict(),
            'optimizer': None if optimizer is None else optimizer.state_dict(),
            'generator': self.generator.get_state(),
        }, self.run.latest_checkpoint)
        self.clock.checkpoint_s += time.perf_counter() - started

    def restore(self, state: dict[str, Any]) -> tuple[_Progress, dict[str, Any] | None]:
        """Load the model and generator; returns the counters and the optimiser state (None at a stage start)."""
        self.model.field.load_state_dict(state['field'])
        self.model.grid.load_state_dict(state['grid'])
        if self.model.pose_refinement is not None and state.get('poses') is not None:
            self.model.pose_refinement.load_state_dict(state['poses'])
        self.generator.set_state(state['generator'])
        return _Progress.from_state(state), state['optimizer']


def _resolved_config(run: RunDir, config: TrainConfig | None, resume: bool) -> tuple[TrainConfig, dict | None]:
    state = None
    if resume and run.latest_checkpoint.is_file():
        state = load_checkpoint(run.latest_checkpoint)
        if state.get('version') != CHECKPOINT_VERSION:
            raise TrainingError(f'{run.latest_checkpoint}: checkpoint version {state.get("version")} is not '
                                f'{CHECKPOINT_VERSION} (written by another release); start a new run directory')
        stored = config_from_mapping(TrainConfig, state['config'])
        if config is not None and config != stored:
            log.warning('resume: using the config stored in %s, not the one passed in', run.latest_checkpoint)
        return stored, state
    if not resume and run.latest_checkpoint.is_file():
        raise TrainingError(f'{run.root} already holds a training run ({run.latest_checkpoint}); '
                            'pass resume=True (--resume) to continue it, or choose another run directory')
    return (config if config is not None else TrainConfig.preset('default')), None


def _set_trainable(model: FruitNeRFModel, groups: list[ParamGroup]) -> None:
    """Freeze every parameter of the model except those of ``groups``."""
    for p in model.parameters():
        p.requires_grad_(False)
    for group in groups:
        for p in group.params:
            p.requires_grad_(True)


def _train_step(stage: TrainingStage, model: FruitNeRFModel, groups: list[ParamGroup],
                optimizer: torch.optim.Optimizer, progress: _Progress, generator: torch.Generator,
                config: TrainConfig) -> dict[str, float]:
    """One optimisation step of ``stage``; returns its logged values (read back once, after the step is queued)."""
    fraction = progress.step / max(stage.iterations, 1)
    lrs = [g.lr_at(fraction) for g in groups if g.params]
    for param_group, lr in zip(optimizer.param_groups, lrs):
        param_group['lr'] = lr
    opening = config.geometry.coarse_to_fine_fraction
    if stage.name == 'geometry' and opening > 0:
        model.field.encoding.open_levels(fraction / opening)
    step = stage.losses(model, generator)
    optimizer.zero_grad(set_to_none=True)
    step.total.backward()
    optimizer.step()
    progress.step += 1
    progress.global_step += 1
    if stage.updates_occupancy and progress.step % config.render.occupancy_update_every == 0:
        model.update_occupancy(generator)
    scalars = {**step.logged, 'loss': step.total.detach()}
    if model.pose_refinement is not None and stage.updates_occupancy:
        correction = model.pose_refinement.correction.detach()
        scalars['pose_rot_deg'] = torch.rad2deg(correction[:, :3].norm(dim=-1).max())
        scalars['pose_trans_m'] = correction[:, 3:].norm(dim=-1).max()
    values = dict(zip(scalars, torch.stack([v.float() for v in scalars.values()]).tolist()))
    record: dict[str, float] = {'lr': lrs[0]}
    if 'photo' in values:
        record['psnr'] = psnr_from_mse(values.pop('photo'))
    record.update(values)
    record['samples_per_ray'] = step.samples_per_ray
    progress.last_loss = record['loss']
    return record


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
        progress: called with ``ProgressEvent(Phase.training(stage), ...)`` at every logging step.
        stop_event: when set, the run checkpoints and returns early (``TrainSummary.stopped``).
        show_progress: tqdm bars per stage (CLI).

    Raises:
        DatasetError: bad dataset. CheckpointError: unreadable checkpoint. TrainingError: run dir in use.
    """
    clock = _CallClock()
    dev = resolve_device(device)
    run = RunDir(run_dir)
    config, state = _resolved_config(run, config, resume)
    dataset = load_dataset(dataset_dir, eval_every=config.data.eval_every)
    started_on = None if state is None else run.find_dataset(state)
    if started_on is not None and started_on.resolve() != Path(dataset_dir).resolve():
        log.warning('resume: dataset %s differs from the one the run started with (%s)', dataset_dir, started_on)
    start = None
    if state is not None:
        aabb, scale = np.asarray(state['aabb']), scale_from_json(state['scale'])
    else:
        start = start_poses(dataset, config, dev)
        config, aabb, scale = start.config, start.aabb, start.scale
        config = stages_the_masks_allow(config, dataset)
    stages = build_stages(config, dataset, aabb)
    run.create()
    save_config(config, run.config_path)
    atomic_write_text(run.root / SCALE_JSON, json.dumps({**scale.to_json(), 'aabb': np.round(aabb, 4).tolist()},
                                                        indent=1))
    if scale.source == 'pose_units':
        log.warning('the fruit measured from the masks and poses is %.4g pose units across, outside '
                    'scale.diameter_range_m for metres: the poses are taken to be in other units (about %.4g to a '
                    'metre, by scale.default_diameter_m); every length follows the fruit size, and the outputs are '
                    'in the poses\' units. Set scale.outside_range: clamp if the poses are in metres',
                    scale.fruit_diameter_m, scale.units_per_metre)
    if scale.source == 'clamped':
        log.warning('the fruit measured from the masks and poses is outside scale.diameter_range_m; using %.3f m: '
                    'are the poses in metres (a COLMAP reconstruction is not)? Every length of the pipeline follows '
                    'the fruit size in metres: scale the poses to metres, or set scale.fruit_diameter_m and '
                    'scale.diameter_range_m in their units', scale.fruit_diameter_m)
    if scale.source == 'default':
        log.warning('could not measure the fruit size from the masks (%d fruit voxels); using %.3f m: set '
                    'scale.fruit_diameter_m if that is far off', scale.n_fruit_voxels, scale.fruit_diameter_m)
    # the geometry stage's pose corrections start at the alignment's and registration's (a resume: its checkpoint's)
    model = FruitNeRFModel(config, dataset, aabb, scale.fruit_diameter_m, dev,
                           None if start is None else start.correction)
    if start is not None:  # what the pose start did (a resume keeps the files of the run's first start)
        for name, step in ((POSE_ALIGNMENT_JSON, start.alignment), (PASS_REGISTRATION_JSON, start.registration)):
            if step is not None:
                atomic_write_text(run.root / name, json.dumps(step.report, indent=1))
    if model.depth_check is not None:  # RGB-D: which views' depth agreed with their neighbours'
        atomic_write_text(run.root / 'depth_check.json', json.dumps(model.depth_check.to_json(), indent=1))
    generator = torch.Generator().manual_seed(config.seed)
    checkpointer = _Checkpointer(run, config, dataset.dataset_dir, aabb, scale, model, generator, clock)
    counters, optimizer_state = _Progress(summaries=[]), None
    if state is not None:
        counters, optimizer_state = checkpointer.restore(state)
    if state is not None or resume:  # a resumed run keeps only what its checkpoint holds (none yet: nothing)
        run.truncate_metrics(counters.global_step)
    stopped = False
    prepare_s = time.perf_counter() - clock.started
    log.info('training prepared in %.1f s (dataset, pose alignment, scene measurement, model)', prepare_s)
    while counters.stage < len(stages) and not stopped:
        stopped = _run_stage(stages[counters.stage], model, dataset, config, run, checkpointer, counters,
                             optimizer_state, progress, stop_event, show_progress)
        optimizer_state = None
    for p in model.parameters():
        p.requires_grad_(False)
    return TrainSummary(run.root, str(dev), tuple(counters.summaries or ()), stopped, aabb, scale, prepare_s,
                        clock.evaluate_s, clock.checkpoint_s)


def _run_stage(stage: TrainingStage, model: FruitNeRFModel, dataset: SceneDataset, config: TrainConfig, run: RunDir,
               checkpointer: _Checkpointer, counters: _Progress, optimizer_state: dict[str, Any] | None,
               progress: ProgressCallback | None, stop_event: threading.Event | None, show_progress: bool) -> bool:
    """Train ``stage`` from ``counters.step`` to its end (or until stopped); returns True when stopped."""
    emit = progress or (lambda event: None)
    groups = stage.param_groups(model)
    _set_trainable(model, groups)
    optimizer = make_optimizer(groups, config)
    if optimizer_state is not None:
        optimizer.load_state_dict(optimizer_state)
    bar = None
    if show_progress:
        from tqdm import tqdm
        bar = tqdm(total=stage.iterations, initial=counters.step, desc=str(stage.phase), unit='step',
                   dynamic_ncols=True)
    model.field.train()
    generator, clock = checkpointer.generator, checkpointer.clock
    try:
        while counters.step < stage.iterations:
            if stop_event is not None and stop_event.is_set():
                checkpointer.save(counters, optimizer)
                emit(ProgressEvent(stage.phase, counters.step, stage.iterations, 'stopped'))
                return True
            started = time.perf_counter()
            record = _train_step(stage, model, groups, optimizer, counters, generator, config)
            counters.stage_wall += time.perf_counter() - started
            shown = {k: v for k, v in record.items() if k in ('loss', 'psnr')}
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f'{v:.4g}' for k, v in shown.items()})
            if counters.step % config.log_every == 0 or counters.step == stage.iterations:
                run.append_metrics({'stage': stage.name, 'step': counters.step, 'global_step': counters.global_step,
                                    'wall_s': round(counters.stage_wall, 3), 'elapsed_s': clock.elapsed_s(),
                                    'occupied_fraction': model.grid.occupied_fraction, **record})
                emit(ProgressEvent(stage.phase, counters.step, stage.iterations,
                                   ' '.join(f'{k} {v:.4g}' for k, v in shown.items())))
            if counters.step % config.checkpoint_every == 0 and counters.step < stage.iterations:
                checkpointer.save(counters, optimizer)
    finally:
        if bar is not None:
            bar.close()
    _finish_stage(stage, model, dataset, config, run, counters, clock, emit)
    checkpointer.save(counters, None)
    return False


def _finish_stage(stage: TrainingStage, model: FruitNeRFModel, dataset: SceneDataset, config: TrainConfig,
                  run: RunDir, counters: _Progress, clock: _CallClock, emit: ProgressCallback) -> None:
    """Held-out evaluation, the stage-end log line and summary; moves the counters to the next stage."""
    model.field.encoding.open_levels(1.0)  # every level from here on (coarse_to_fine_fraction 1 ends just short)
    model.field.eval()
    # a field no step has trained (masks without fruit: nothing to count) has nothing to score
    eval_views = spread_views(dataset.eval_indices, config.eval_max_views) if counters.global_step else []
    # the heads a stage has not trained yet are not rendered (their figures are NaN: null in metrics.jsonl)
    started = time.perf_counter()
    # rendered from the poses the model uses: with a pose start the held-out views' are the alignment's resection
    # and the pass registration's move (before session 48 the recorded ones: the figures measured the odometry)
    posed = dataset if model.pose_refinement is None else dataclasses.replace(
        dataset, T_world_camera=model.current_poses().detach().to('cpu', dataset.T_world_camera.dtype))
    metrics = evaluate_views(model.field, model.grid, posed, eval_views, model.settings, config.render.chunk_rays,
                             semantic=stage.name != 'geometry', instance=stage.name == 'instance',
                             max_pixels=config.eval_max_pixels)
    evaluate_s = time.perf_counter() - started
    clock.evaluate_s += evaluate_s
    run.append_metrics({'stage': stage.name, 'event': 'stage_end', 'step': counters.step,
                        'global_step': counters.global_step, 'wall_s': round(counters.stage_wall, 3),
                        'elapsed_s': clock.elapsed_s(), 'evaluate_s': round(evaluate_s, 3),
                        'eval_psnr': metrics.psnr, 'eval_semantic_iou': metrics.semantic_iou,
                        'eval_instance_acc': metrics.instance_acc, 'eval_instance_chance': metrics.instance_chance,
                        'eval_views': metrics.num_views})
    emit(ProgressEvent(stage.phase, stage.iterations, stage.iterations,
                       f'eval psnr {metrics.psnr:.2f} iou {metrics.semantic_iou:.3f} inst {metrics.instance_acc:.3f}'))
    assert counters.summaries is not None
    counters.summaries.append(StageSummary(stage.name, stage.iterations, counters.stage_wall, counters.last_loss,
                                           metrics))
    if stage.name == 'semantic' and model.pose_refinement is not None:  # the poses are final from here on
        with torch.no_grad():
            write_refined_poses(run.refined_poses_path, model.poses, model.current_poses(),
                                list(dataset.file_paths), model.pose_refinement.trained)
    counters.stage += 1
    counters.step = 0
    counters.stage_wall = 0.0
