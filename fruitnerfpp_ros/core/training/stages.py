"""The three stages of cascaded training, one object each: its sampler, parameter groups, losses and schedule.

1. :class:`GeometryStage`: density + colour (+ pose corrections) on uniform rays (+ the line-of-sight depth loss
   on those with a measured depth, RGB-D datasets only).
2. :class:`SemanticStage`: + the semantic head; a share of fruit pixels is added to every batch for the BCE loss,
   the photometric and distortion losses stay on the uniform rays; density, colour and poses continue at the
   constant learning rate stage 1 ended with.
3. :class:`InstanceStage`: the instance head alone, on the group sampler's pixels, with prototype InfoNCE.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import ClassVar, NamedTuple, Protocol

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.rays import pixels_crossing_box
from fruitnerfpp_ros.core.data.samplers import GroupInstanceSampler, UniformPixelSampler, index_view_fruits, \
    mask_interior
from fruitnerfpp_ros.core.progress import Phase
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.losses import fruit_transparency, opacity_entropy
from fruitnerfpp_ros.core.training.model import FruitNeRFModel

__all__ = ['ParamGroup', 'StepLosses', 'TrainingStage', 'GeometryStage', 'SemanticStage', 'InstanceStage',
           'build_stages', 'stages_the_masks_allow', 'STAGE_NAMES']

STAGE_NAMES = ('geometry', 'semantic', 'instance')

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ParamGroup:
    """Parameters trained together with one learning-rate schedule.

    The rate decays exponentially from ``lr_start`` to ``lr_end`` over the stage; it is 0 before
    ``start_fraction`` of the stage (the pose corrections wait for a first geometry: Adam moves every parameter by
    about its learning rate per step, so corrections trained from the first step random-walk while the field is
    still noise).
    """

    name: str
    params: tuple[nn.Parameter, ...]
    lr_start: float
    lr_end: float
    start_fraction: float = 0.0

    def lr_at(self, fraction: float) -> float:
        """Learning rate at ``fraction`` in [0, 1] of the stage."""
        if fraction < self.start_fraction or self.lr_start == 0.0:
            return 0.0
        return self.lr_start * (self.lr_end / self.lr_start) ** fraction


class StepLosses(NamedTuple):
    """The loss of one step and what is logged of it.

    Attributes:
        total: the scalar to minimise.
        logged: detached scalars by name (``photo``, ``distortion``, ``depth_loss``, ``depth_rays`` (share of the
            batch with a depth), ``semantic_loss``, ``contrastive_loss``).
        samples_per_ray: samples the field evaluated per ray.
    """

    total: torch.Tensor
    logged: dict[str, torch.Tensor]
    samples_per_ray: float


class TrainingStage(Protocol):
    """What the training loop needs of a stage."""

    name: str
    iterations: int
    updates_occupancy: bool

    @property
    def phase(self) -> Phase:
        """The progress phase of the stage."""

    def param_groups(self, model: FruitNeRFModel) -> list[ParamGroup]:
        """The parameters this stage trains (every other parameter is frozen)."""

    def losses(self, model: FruitNeRFModel, generator: torch.Generator) -> StepLosses:
        """Draw one batch from ``generator``, render it and compute the stage's losses."""


class GeometryStage:
    """Stage 1: photometric + distortion loss on uniform rays plus a share of fruit-pixel rays (their colour only,
    behind the box the background); density, colour and pose corrections train."""

    name: ClassVar[str] = 'geometry'
    updates_occupancy = True
    fruit_rays_train_colour: ClassVar[bool] = True
    """The fruit-drawn rays train the photometric loss and the transparency term (stage 1), or only the semantic
    head (stage 2)."""

    def __init__(self, config: TrainConfig, dataset: SceneDataset, drawable: torch.Tensor | None = None,
                 background: torch.Tensor | None = None) -> None:
        """``drawable``: [V, H, W] bool, the pixels rays are drawn from (None: the dataset's valid pixels);
        ``background``: the pixels ``data.outside_box_fraction`` of the uniform rays come from (None: none)."""
        stage = getattr(config, self.name)  # this stage's section: iterations, batch_rays, fruit_fraction
        self.config = config
        self.iterations = stage.iterations
        self.batch_rays = stage.batch_rays
        fruit = dataset.semantic_masks
        if getattr(stage, 'fruit_interior', False):  # the geometry stage's option (the semantic stage has none)
            fruit = mask_interior(dataset.instance_masks, fruit)
        self.opaque_fruit = None  # [V, H, W] the fruit pixels the transparency term covers (stage 1); None = all
        if self.fruit_rays_train_colour and config.geometry.fruit_opacity_interior:
            self.opaque_fruit = mask_interior(dataset.instance_masks, dataset.semantic_masks)
        self.sampler = UniformPixelSampler(dataset.train_indices, dataset.height, dataset.width,
                                           fruit_masks=fruit, fruit_fraction=stage.fruit_fraction,
                                           valid_masks=dataset.valid_masks if drawable is None else drawable,
                                           background_masks=background,
                                           background_fraction=config.data.outside_box_fraction)

    @property
    def phase(self) -> Phase:
        return Phase.training(self.name)

    def _geometry_groups(self, model: FruitNeRFModel, *, decaying: bool) -> list[ParamGroup]:
        g = self.config.geometry
        start, pose_start = (g.lr, g.pose_lr) if decaying else (g.lr_final, g.pose_lr_final)
        groups = [ParamGroup('geometry', tuple(model.field.geometry_parameters()), start, g.lr_final)]
        if model.pose_refinement is not None and g.pose_lr > 0:  # else fixed at the alignment's corrections
            groups.append(ParamGroup('poses', tuple(model.pose_refinement.parameters()), pose_start,
                                     g.pose_lr_final, g.pose_start_fraction if decaying else 0.0))
        return groups

    def param_groups(self, model: FruitNeRFModel) -> list[ParamGroup]:
        return self._geometry_groups(model, decaying=True)

    def losses(self, model: FruitNeRFModel, generator: torch.Generator) -> StepLosses:
        return self._photometric_step(model, generator, semantic=False)

    def _photometric_step(self, model: FruitNeRFModel, generator: torch.Generator, *, semantic: bool) -> StepLosses:
        pixels = self.sampler.sample(self.batch_rays, generator)
        jitter = torch.rand(len(pixels.view), generator=generator)
        n_uniform = self.sampler.num_uniform(len(pixels.view))
        target = model.depth_target(pixels, n_uniform)
        colour_rays = len(pixels.view) if self.fruit_rays_train_colour else n_uniform
        far_rays = n_uniform if self.fruit_rays_train_colour and not self.config.geometry.fruit_rays_far_field \
            else None
        out = model.render(pixels, jitter, colour=True, semantic=semantic, distortion_rays=n_uniform,
                           far_field_rays=far_rays, depth_target=target)
        photo = model.photometric_loss(out, pixels, colour_rays)
        total, logged = photo, {'photo': photo.detach()}
        weight = self.config.geometry.distortion_weight
        if weight > 0 and out.distortion is not None:
            total = total + weight * out.distortion
            logged['distortion'] = out.distortion.detach()
        entropy_weight = self.config.geometry.opacity_entropy_weight
        if entropy_weight > 0:
            entropy = opacity_entropy(out.opacity[:n_uniform])
            total = total + entropy_weight * entropy
            logged['opacity_entropy'] = entropy.detach()
        opacity_weight = self.config.geometry.fruit_opacity_weight
        if opacity_weight > 0 and self.fruit_rays_train_colour and len(pixels.view) > n_uniform:
            keep = None if self.opaque_fruit is None else \
                self.opaque_fruit[pixels.view[n_uniform:], pixels.row[n_uniform:], pixels.col[n_uniform:]]
            transparency = fruit_transparency(out.opacity[n_uniform:], keep)
            total = total + opacity_weight * transparency
            logged['fruit_transparency'] = transparency.detach()
        if target is not None:
            depth = model.depth_loss(out, target)
            total = total + self.config.depth.weight * depth
            logged['depth_loss'] = depth.detach()
            logged['depth_rays'] = (target.weight > 0).float().mean()
        if semantic:
            bce = model.semantic_loss(out, pixels)
            total = total + self.config.semantic.semantic_weight * bce
            logged['semantic_loss'] = bce.detach()
        return StepLosses(total, logged, out.num_samples / max(len(pixels.view), 1))


class SemanticStage(GeometryStage):
    """Stage 2: stage 1's losses on its uniform rays only, plus fruit BCE on every ray (uniform and fruit-biased)."""

    name: ClassVar[str] = 'semantic'
    fruit_rays_train_colour: ClassVar[bool] = False

    def param_groups(self, model: FruitNeRFModel) -> list[ParamGroup]:
        s = self.config.semantic
        return [ParamGroup('semantic', tuple(model.field.semantic_parameters()), s.lr, s.lr_final),
                *self._geometry_groups(model, decaying=False)]

    def losses(self, model: FruitNeRFModel, generator: torch.Generator) -> StepLosses:
        return self._photometric_step(model, generator, semantic=True)


class InstanceStage:
    """Stage 3: prototype InfoNCE on the group sampler's pixels; only the instance head trains."""

    name: ClassVar[str] = 'instance'
    updates_occupancy = False

    def __init__(self, config: TrainConfig, dataset: SceneDataset) -> None:
        cfg = config.instance
        self.config = config
        self.iterations = cfg.iterations
        self.sampler = None if self.iterations == 0 else \
            GroupInstanceSampler(dataset.train_indices, _instance_masks(config, dataset), groups=cfg.groups,
                                 group_size=cfg.group_size, pixels_per_fruit=cfg.pixels_per_fruit,
                                 min_pixels=config.data.min_fruit_pixels)

    @property
    def phase(self) -> Phase:
        return Phase.training(self.name)

    def param_groups(self, model: FruitNeRFModel) -> list[ParamGroup]:
        i = self.config.instance
        return [ParamGroup('instance', tuple(model.field.instance_parameters()), i.lr, i.lr_final)]

    def losses(self, model: FruitNeRFModel, generator: torch.Generator) -> StepLosses:
        pixels = self.sampler.sample(generator)
        jitter = torch.rand(len(pixels.view), generator=generator)
        out = model.render(pixels, jitter, colour=False, instance=True)
        contrastive = model.contrastive_loss(out, pixels)
        return StepLosses(self.config.instance.contrastive_weight * contrastive,
                          {'contrastive_loss': contrastive.detach()}, out.num_samples / max(len(pixels.view), 1))


def _instance_masks(config: TrainConfig, dataset: SceneDataset) -> torch.Tensor:
    """[V, H, W] the instance masks the group sampler draws from (their interior with ``instance.interior``)."""
    masks = dataset.instance_masks
    if config.instance.interior:
        masks = torch.where(mask_interior(masks, masks > 0), masks, torch.zeros_like(masks))
    return masks


def _can_contrast(config: TrainConfig, dataset: SceneDataset) -> bool:
    """Whether a training view gives the instance stage two fruits of at least ``data.min_fruit_pixels`` pixels
    each in its (interior) instance mask (the search stops at the first such view)."""
    masks = _instance_masks(config, dataset)
    return any(index_view_fruits(int(i), masks[int(i)], config.data.min_fruit_pixels) is not None
               for i in dataset.train_indices)


def stages_the_masks_allow(config: TrainConfig, dataset: SceneDataset) -> TrainConfig:
    """``config`` with the stages the masks cannot train at 0 steps (a warning says why): masks without a fruit pixel
    in any training view leave nothing to count, so no stage trains (the count is 0); masks that never show two
    fruits in one view leave the instance stage nothing to contrast (the count then goes by position)."""
    views = len(dataset.train_indices)
    if not bool(dataset.semantic_masks[dataset.train_indices].any()):
        log.warning('the masks of the %d training views hold no fruit: nothing to count, nothing trained (the count '
                    'is 0). Check the masks (their source, topic or model)', views)
        return dataclasses.replace(config, **{name: dataclasses.replace(getattr(config, name), iterations=0)
                                              for name in STAGE_NAMES})
    if config.instance.iterations > 0 and not _can_contrast(config, dataset):
        log.warning('no training view shows two fruits (%d views; a fruit of at least %d pixels): the instance field '
                    'is not trained (instance.iterations 0 in the run\'s config), and the count tells fruits apart by '
                    'their positions alone (touching fruits count as one)', views, config.data.min_fruit_pixels)
        return dataclasses.replace(config, instance=dataclasses.replace(config.instance, iterations=0))
    return config


def build_stages(config: TrainConfig, dataset: SceneDataset,
                 aabb: np.ndarray | None = None) -> tuple[TrainingStage, ...]:
    """The three stages in order, with their samplers.

    ``aabb`` [2, 3]: the scene box; with ``data.rays_through_box`` the photometric stages draw their rays through
    pixels whose rays cross it (recorded poses; the alignment moves them by centimetres), all but
    ``data.outside_box_fraction`` of the uniform ones, which come from the other pixels (the far field's backdrop).

    Raises:
        DatasetError: no training view to draw rays from, or (``instance.iterations`` > 0) none with two fruits
            (before any step is trained; :func:`stages_the_masks_allow` takes that stage out beforehand).
    """
    drawable = background = None
    if aabb is not None and config.data.rays_through_box:
        crossing = pixels_crossing_box(dataset.T_world_camera, dataset.intrinsics, dataset.height, dataset.width,
                                       torch.as_tensor(aabb, dtype=torch.float32))
        valid = torch.ones_like(crossing) if dataset.valid_masks is None else dataset.valid_masks
        if not bool(crossing[valid].all()):  # else the same draws as without the test
            drawable, background = crossing & valid, ~crossing & valid
    return (GeometryStage(config, dataset, drawable, background),
            SemanticStage(config, dataset, drawable, background), InstanceStage(config, dataset))
