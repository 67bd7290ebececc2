"""The trainable FruitNeRF++ model: the field, its occupancy grid, optional pose corrections and the training data
on one device, with one method per loss.

Stages (stages.py) decide which rays to render and which losses to add; the model renders and computes them. The
gradient rules of the method live here and in the field: the photometric, distortion and depth losses reach
density, colour and the pose corrections; the semantic and contrastive losses reach only their own heads (detached
render weights, detached geometry features and detached sample positions).

Depth (RGB-D datasets, ``config.depth``): the training views' depth images are range-limited, cross-checked
between views (``core/data/depth_check.py``: the depth of views that disagree with their neighbours is dropped)
and kept on the device; :meth:`FruitNeRFModel.depth_target` turns the depth of a batch's pixels into ray distances
with windows from the sensor's uncertainty. A dataset without depth builds no depth state at all.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings
from typing import Callable

import numpy as np
import torch
from torch import nn

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.depth_check import DepthViewCheck, check_depth_views
from fruitnerfpp_ros.core.data.rays import PixelBatch, RayBundle, rays_for_pixels
from fruitnerfpp_ros.core.fields.fruit_field import FieldConfig, FruitField, GeometryOutput
from fruitnerfpp_ros.core.rendering.depth_loss import DepthTarget, line_of_sight_loss
from fruitnerfpp_ros.core.rendering.occupancy import OccupancyGrid
from fruitnerfpp_ros.core.rendering.renderer import RenderOutput, RenderSettings, render_rays
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.losses import photometric_loss, prototype_infonce, semantic_loss
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement

__all__ = ['FruitNeRFModel', 'render_settings', 'field_config_for', 'occupancy_grid', 'training_depths']

log = logging.getLogger(__name__)

GeometryFn = Callable[[torch.Tensor], GeometryOutput]


def render_settings(config: TrainConfig, fruit_diameter_m: float) -> RenderSettings:
    """How the rays of a run on fruit of ``fruit_diameter_m`` are marched."""
    return RenderSettings(step=config.render.step_m(fruit_diameter_m), near=config.render.near,
                          mixed_precision=config.render.mixed_precision,
                          weight_threshold=config.instance.weight_threshold,
                          stop_transmittance=config.render.stop_transmittance)


def field_config_for(config: TrainConfig, step: float) -> FieldConfig:
    """The field config with the automatic density bias resolved for the marching ``step`` (m).

    Untrained space starts just below the occupancy threshold (as instant-NGP does at its scale): the first
    occupancy update then keeps only cells whose density training raised, never cells no ray constrains.
    """
    if config.field.density_bias is not None:
        return config.field
    return dataclasses.replace(config.field,
                               density_bias=math.log(0.5 * config.render.occupancy_threshold / step))


def occupancy_grid(config: TrainConfig, aabb: np.ndarray, fruit_diameter_m: float) -> OccupancyGrid:
    """An empty occupancy grid over ``aabb`` with cells of ``config.render.occupancy_cell`` fruit diameters."""
    render = config.render
    extent = float(np.max(np.asarray(aabb)[1] - np.asarray(aabb)[0]))
    return OccupancyGrid(torch.as_tensor(aabb, dtype=torch.float32),
                         resolution=render.occupancy_cells(extent, fruit_diameter_m),
                         threshold=render.occupancy_threshold, decay=render.occupancy_decay)


def training_depths(config: TrainConfig, dataset: SceneDataset) -> tuple[torch.Tensor | None, DepthViewCheck | None]:
    """The depth the training views contribute ([V, H, W] metres, 0 = none; held-out views and out-of-range
    depths removed, the depth of views that disagree with their neighbours removed) and the view check (None when
    not run); (None, None) without depth or with ``depth.weight`` 0."""
    cfg = config.depth
    if dataset.depths is None or cfg.weight <= 0:
        return None, None
    depths = dataset.depths.clone()
    depths[(depths < cfg.min_depth_m) | (depths > cfg.max_depth_m)] = 0.0
    depths[dataset.eval_indices] = 0.0
    check = None
    if cfg.check_views:
        check = check_depth_views(depths, dataset.T_world_camera, dataset.intrinsics, cfg.sigma_m,
                                  min_agreement=cfg.min_agreement, neighbours=cfg.check_neighbours)
        depths[torch.as_tensor(check.rejected_views, dtype=torch.int64)] = 0.0
        (log.warning if check.rejected_views else log.info)('%s', check.summary())
    if not bool((depths > 0).any()):
        log.warning('depth: no usable depth in the training views; training without depth')
        return None, check
    return depths, check


class _GuardedCompile:
    """A torch.compile'd callable that falls back to eager mode, once and for good, when compiling fails."""

    def __init__(self, fn: GeometryFn) -> None:
        self._eager = fn
        self._compiled: GeometryFn | None = torch.compile(fn, dynamic=True)

    def __call__(self, xyz: torch.Tensor) -> GeometryOutput:
        if self._compiled is not None:
            try:
                return self._compiled(xyz)
            except Exception as err:  # compiler back-ends raise many types
                warnings.warn(f'torch.compile failed ({type(err).__name__}: {err}); running eagerly')
                self._compiled = None
        return self._eager(xyz)


class FruitNeRFModel(nn.Module):
    """Field + occupancy grid + pose corrections of one training run, and the images they are fitted to.

    Args:
        config: the run's training config.
        dataset: the loaded dataset (images and masks are copied to ``device``).
        aabb: [2, 3] scene box, metres.
        fruit_diameter_m: the scene's fruit diameter (every length of the field and the marching follows from it).
        device: torch device.
        pose_correction: optional [V, 6] starting pose corrections (the pose alignment's; zeros when None). They
            exist with ``geometry.pose_lr`` > 0, ``pose_alignment.enabled`` or ``pass_registration.enabled`` (at
            pose_lr 0 they stay fixed; a resume loads them too).
    """

    def __init__(self, config: TrainConfig, dataset: SceneDataset, aabb: np.ndarray, fruit_diameter_m: float,
                 device: torch.device, pose_correction: np.ndarray | None = None) -> None:
        super().__init__()
        self.config = config
        self.settings = render_settings(config, fruit_diameter_m)
        init = torch.Generator().manual_seed(config.seed)  # weights are reproducible without seeding the process
        self.field = FruitField(field_config_for(config, self.settings.step), aabb, fruit_diameter_m,
                                generator=init).to(device)
        self.grid = occupancy_grid(config, aabb, fruit_diameter_m).to(device)
        trained = torch.zeros(dataset.num_views, dtype=torch.bool)
        trained[dataset.train_indices] = True
        refines = config.geometry.pose_lr > 0 or config.pose_alignment.enabled or config.pass_registration.enabled
        self.pose_refinement = PoseRefinement(trained, pose_correction).to(device) if refines else None
        self.register_buffer('images', dataset.images.to(device), persistent=False)
        self.register_buffer('semantics', dataset.semantic_masks.to(device), persistent=False)
        self.register_buffer('poses', dataset.T_world_camera.to(device), persistent=False)
        self.register_buffer('intrinsics', dataset.intrinsics.to(device), persistent=False)
        # The narrowest surface window: the field cannot put a surface sharper than its finest geometry cell.
        self.depth_window_min_m = max(self.settings.step, config.field.geometry_grid.finest_cell * fruit_diameter_m)
        depths, self.depth_check = training_depths(config, dataset)
        self.depths: torch.Tensor | None
        self.register_buffer('depths', None if depths is None else depths.to(device), persistent=False)
        self.geometry_fn: GeometryFn = self.field.geometry
        if device.type == 'cuda' and config.render.compile and hasattr(torch, 'compile'):
            self.geometry_fn = _GuardedCompile(self.field.geometry)

    @property
    def device(self) -> torch.device:
        return self.images.device

    def current_poses(self) -> torch.Tensor:
        """The camera-to-world poses [V, 4, 4] the rays use: the recorded ones, corrected when refined."""
        return self.poses if self.pose_refinement is None else self.pose_refinement(self.poses)

    def rays(self, pixels: PixelBatch) -> RayBundle:
        """World rays through ``pixels`` (on the model's device)."""
        view, row, col = (t.to(self.device) for t in (pixels.view, pixels.row, pixels.col))
        return rays_for_pixels(self.current_poses(), self.intrinsics, view, row, col)

    def render(self, pixels: PixelBatch, jitter: torch.Tensor, *, colour: bool = True, semantic: bool = False,
               instance: bool = False, distortion_rays: int | None = None, far_field_rays: int | None = None,
               depth_target: DepthTarget | None = None) -> RenderOutput:
        """Render the rays of ``pixels`` with first-sample offsets ``jitter`` [N] in [0, 1)."""
        return render_rays(self.field, self.grid, self.rays(pixels), self.settings, jitter=jitter.to(self.device),
                           colour=colour, semantic=semantic, instance=instance, geometry_fn=self.geometry_fn,
                           distortion_rays=distortion_rays, far_field_rays=far_field_rays,
                           depth_target=depth_target)

    def depth_target(self, pixels: PixelBatch, num_rays: int) -> DepthTarget | None:
        """Measured depths of the first ``num_rays`` rays of ``pixels`` (the uniformly drawn part), or None when
        the run has no depth.

        The optical-axis depth z becomes the distance along the unit ray; the window is ``window_sigmas`` standard
        deviations of the stereo model, never narrower than what the field resolves (one marching step, the finest
        geometry cell), and the ray's weight is that narrowest window / its window (1 for depth as sharp as the
        field, less for uncertain depth); 0 where depth is missing.
        """
        if self.depths is None:
            return None
        view, row, col = (t.to(self.device) for t in (pixels.view, pixels.row, pixels.col))
        z = self.depths[view, row, col]
        z = torch.where(torch.arange(len(z), device=z.device) < num_rays, z, torch.zeros_like(z))
        K = self.intrinsics[view]
        x, y = (col.float() + 0.5 - K[:, 2]) / K[:, 0], (row.float() + 0.5 - K[:, 3]) / K[:, 1]
        stretch = torch.sqrt(1.0 + x * x + y * y)  # distance along the ray per metre of optical depth
        cfg, narrowest = self.config.depth, self.depth_window_min_m
        window = torch.clamp(cfg.window_sigmas * cfg.sigma_m(z) * stretch, min=narrowest)
        weight = torch.where(z > 0, narrowest / window, torch.zeros_like(z))
        return DepthTarget(z * stretch, window, weight)

    def depth_loss(self, out: RenderOutput, target: DepthTarget) -> torch.Tensor:
        """The line-of-sight loss of the rendered rays against their measured depths."""
        assert out.line_of_sight is not None
        return line_of_sight_loss(out.line_of_sight, target, self.config.depth.free_space_weight)

    def _targets(self, table: torch.Tensor, pixels: PixelBatch, count: int | None = None) -> torch.Tensor:
        view, row, col = (t[:count].to(self.device) for t in (pixels.view, pixels.row, pixels.col))
        return table[view, row, col]

    def photometric_loss(self, out: RenderOutput, pixels: PixelBatch, num_rays: int) -> torch.Tensor:
        """Colour MSE over the first ``num_rays`` rays (the uniformly drawn part of a batch)."""
        assert out.rgb is not None
        return photometric_loss(out.rgb[:num_rays], self._targets(self.images, pixels, num_rays))

    def semantic_loss(self, out: RenderOutput, pixels: PixelBatch) -> torch.Tensor:
        """Fruit BCE over every ray of the batch."""
        assert out.fruit_prob is not None
        return semantic_loss(out.fruit_prob, self._targets(self.semantics, pixels))

    def contrastive_loss(self, out: RenderOutput, pixels: PixelBatch) -> torch.Tensor:
        """Prototype InfoNCE of the rendered embeddings against the batch's fruit labels."""
        assert out.embedding is not None and pixels.fruit is not None
        return prototype_infonce(out.embedding, pixels.fruit.to(self.device), self.config.instance.temperature,
                                 num_fruits=int(pixels.fruit.max()) + 1)

    def update_occupancy(self, generator: torch.Generator) -> None:
        """Refresh the occupancy grid from the current density."""
        self.grid.update(lambda xyz: self.geometry_fn(xyz).density, self.settings.step, generator,
                         probe_fraction=self.config.render.occupancy_probe_fraction)
