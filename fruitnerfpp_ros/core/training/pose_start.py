"""Where the geometry stage's poses start: the recorded ones, or the pose alignment's and the pass registration's,
refined or held; and the scene box and scale measured on them.

:func:`start_poses` runs it all: :func:`aligned_poses` (the feature-based alignment, core/data/pose_alignment.py,
of the training views), the scene measurement, the registration of a row drive's return pass onto its first pass
(core/data/pass_registration.py), after which the scene is measured again when it moved the pass, and last
:func:`refinement_after` (the photometric refinement, ``geometry.pose_lr``, off where the config asks for it only
after a correction, ``pose_refine_when: aligned``, and neither the alignment nor the registration moved a pose).
:func:`corrected_poses` applies corrections as :class:`PoseRefinement` does.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.pass_registration import PassRegistration, register_passes
from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignment, align_poses
from fruitnerfpp_ros.core.data.scene_scale import SceneScale
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement
from fruitnerfpp_ros.core.training.scene_box import measure_scene

__all__ = ['PoseStart', 'start_poses', 'aligned_poses', 'refinement_after', 'corrected_poses', 'with_transform',
           'lengths_in_pose_units', 'pose_start_lines', 'POSE_ALIGNMENT_JSON', 'PASS_REGISTRATION_JSON']

log = logging.getLogger(__name__)

#: The pose alignment's figures (core/data/pose_alignment.py), written to the run directory when it runs.
POSE_ALIGNMENT_JSON = 'pose_alignment.json'
#: The pass registration's figures (core/data/pass_registration.py), written when it runs.
PASS_REGISTRATION_JSON = 'pass_registration.json'


def aligned_poses(dataset: SceneDataset, config: TrainConfig) -> PoseAlignment | None:
    """The feature-based pose alignment of the training views (``config.pose_alignment``), or None when off; the
    held-out views are posed on the training views' adjusted tracks afterwards (core/data/pose_resection.py), so
    that the held-out figures measure the fields rather than the odometry's error."""
    if not config.pose_alignment.enabled:
        return None
    views = dataset.train_indices.numpy()
    log.info('pose alignment: features and matches of %d training views', len(views))
    images = (dataset.images.numpy() * 255.0).round().astype(np.uint8)
    valid = None if dataset.valid_masks is None else dataset.valid_masks.numpy()
    held_out = np.ones(dataset.num_views, bool)
    held_out[views] = False
    result = align_poses(images, dataset.intrinsics.double().numpy(), dataset.T_world_camera.double().numpy(),
                         config.pose_alignment, valid, held_out)
    correction = result.correction.copy()
    moved = np.any(correction != 0.0, axis=1)
    moved[views] = True
    correction[moved, 3:] -= correction[views, 3:].mean(axis=0)  # its gauge: the views' mean position is kept
    log.info('pose alignment: %s', result.report)
    return PoseAlignment(correction, result.report)


def refinement_after(alignment: PoseAlignment | None, registration: PassRegistration | None, config: TrainConfig
                     ) -> TrainConfig:
    """``config`` with ``geometry.pose_lr`` 0 where ``pose_refine_when`` is ``aligned`` and neither the alignment
    nor the pass registration corrected the poses (the run's config.yaml then says what ran; a resume reads it).

    A return pass the registration moved is refined like poses the alignment corrected: the registration is one
    rigid move per pass, and a drift that grew along the drive leaves the rest to the refinement (apple_s15_drift
    with ``tiny``: docs/results/pose_refinement.md, sessions 40-41)."""
    g = config.geometry
    corrected = any(outcome is not None and outcome.report.get('applied') for outcome in (alignment, registration))
    if g.pose_lr <= 0 or g.pose_refine_when != 'aligned' or corrected:
        return config
    log.info('pose refinement off: %s%s', 'the pose alignment is off' if alignment is None
             else f"the pose alignment kept the recorded poses ({alignment.report.get('reason', 'no correction')})",
             '' if registration is None else ' and no pass was moved')
    return dataclasses.replace(config, geometry=dataclasses.replace(g, pose_lr=0.0))


def corrected_poses(dataset: SceneDataset, correction: np.ndarray) -> torch.Tensor:
    """The dataset's poses with ``correction`` [V, 6] applied as :class:`PoseRefinement` applies it."""
    trained = torch.zeros(dataset.num_views, dtype=torch.bool)
    trained[dataset.train_indices] = True
    with torch.no_grad():
        return PoseRefinement(trained, correction)(dataset.T_world_camera)


def with_transform(dataset: SceneDataset, correction: np.ndarray, views: np.ndarray, transform: np.ndarray
                   ) -> np.ndarray:
    """Corrections [V, 6] that put ``views`` where ``transform`` [4, 4] moves their poses corrected by
    ``correction`` [V, 6], the other views where ``correction`` puts them: the registration's gauge is the first
    pass, which stays where it was (halving the move between the passes would shift the whole reconstruction by
    half the drift: 2-5 cm on apple_s15_drift, docs/results/pose_refinement.md, session 39)."""
    poses = corrected_poses(dataset, correction).double().numpy()
    recorded = dataset.T_world_camera.double().numpy()
    poses[views] = transform[None] @ poses[views]
    out = np.zeros((dataset.num_views, 6))
    out[:, :3] = Rotation.from_matrix(np.swapaxes(recorded[:, :3, :3], 1, 2) @ poses[:, :3, :3]).as_rotvec()
    out[:, 3:] = poses[:, :3, 3] - recorded[:, :3, 3]
    return out


@dataclass(frozen=True)
class PoseStart:
    """The poses a run starts from and the scene measured on them.

    Attributes:
        config: the run's config (``geometry.pose_lr`` 0 where :func:`refinement_after` turned the refinement off).
        correction: [V, 6] starting pose corrections, or None (the recorded poses).
        aabb: [2, 3] scene box.
        scale: the scene's measured scale.
        alignment: the pose alignment's outcome (None when off).
        registration: the pass registration's outcome (None when off).
    """

    config: TrainConfig
    correction: np.ndarray | None
    aabb: np.ndarray
    scale: SceneScale
    alignment: PoseAlignment | None
    registration: PassRegistration | None


def lengths_in_pose_units(config: TrainConfig, units_per_metre: float) -> TrainConfig:
    """``config`` with what it gives in metres, and the run uses after the scene measurement, in the poses' units
    (``SceneScale.units_per_metre``): the marching's ``render.near``, the pass registration's ``max_shift_m``, the
    distortion loss's weight (the loss is a length: per metre) and the far field's density (per metre). The scene
    box's ``data.box_margin_m`` is converted where the box is built."""
    if units_per_metre == 1.0:
        return config
    u = units_per_metre
    geometry = dataclasses.replace(config.geometry, distortion_weight=config.geometry.distortion_weight / u)
    shift = tuple(float(v) * u for v in config.pass_registration.max_shift_m)
    field = dataclasses.replace(config.field, far_field=dataclasses.replace(config.field.far_field, units_per_metre=u))
    return dataclasses.replace(
        config, render=dataclasses.replace(config.render, near=config.render.near * u), geometry=geometry,
        field=field, pass_registration=dataclasses.replace(config.pass_registration, max_shift_m=shift))


def start_poses(dataset: SceneDataset, config: TrainConfig, device: torch.device) -> PoseStart:
    """Align the poses, measure the scene, register the passes (measuring again when they moved); see above."""
    alignment = aligned_poses(dataset, config)
    correction = None if alignment is None else alignment.correction
    posed = dataset if correction is None else dataclasses.replace(
        dataset, T_world_camera=corrected_poses(dataset, correction))
    aabb, scale = measure_scene(posed, config, device)
    config = lengths_in_pose_units(config, scale.units_per_metre)
    registration = None
    if config.pass_registration.enabled:
        registration = register_passes(posed, aabb, scale.fruit_diameter_m, config.pass_registration, config.scale,
                                       device=device)
        log.info('pass registration: %s', registration.report)
        if registration.applied:
            correction = with_transform(dataset, np.zeros((dataset.num_views, 6)) if correction is None
                                        else correction, registration.moved_views, registration.transform)
            posed = dataclasses.replace(dataset, T_world_camera=corrected_poses(dataset, correction))
            aabb, scale = measure_scene(posed, config, device)
    config = refinement_after(alignment, registration, config)
    return PoseStart(config, correction, aabb, scale, alignment, registration)


def pose_start_lines(run_dir: str | Path) -> list[str]:
    """What a run's pose start did, in words, from its ``pose_alignment.json`` and ``pass_registration.json`` (a
    line each that the run has)."""
    def read(name: str) -> dict | None:
        try:
            return json.loads((Path(run_dir) / name).read_text())
        except (OSError, ValueError):
            return None

    lines = []
    aligned = read(POSE_ALIGNMENT_JSON)
    if aligned is not None:
        held = aligned.get('held_out') or {}
        lines.append(f"poses aligned to the images: tracks' reprojection {aligned.get('reprojection_px_before')} -> "
                     f"{aligned.get('reprojection_px_after')} px" + (
                         f"; held-out views posed on them: {held['posed']} of {held['views']}" if held else '')
                     if aligned.get('applied') else
                     f"poses kept by the alignment: {aligned.get('reason', 'no correction')}")
    passes = read(PASS_REGISTRATION_JSON)
    if passes is not None:
        if passes.get('applied'):
            along, across, up = (100.0 * float(v) for v in passes['offset_m'])
            lines.append(f"return pass moved onto the first: {along:+.1f} cm along the row, {across:+.1f} cm across, "
                         f"{up:+.1f} cm up, {float(passes['yaw_deg']):+.1f} deg (its fruit meet the first pass's "
                         f"{float(passes['gain']):.2f}x more)")
        else:
            lines.append(f"return pass kept: {passes.get('reason', 'no offset')}")
    return lines
