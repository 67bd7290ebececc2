"""Where the geometry stage's poses start: the recorded ones, or the pose alignment's, refined or held.

:func:`aligned_poses` runs the feature-based alignment (core/data/pose_alignment.py) on the training views;
:func:`refinement_after` turns the photometric refinement (``geometry.pose_lr``) off where the config asks for it
only after a correction (``pose_refine_when: aligned``) and the alignment kept the recorded poses;
:func:`corrected_poses` applies the corrections as :class:`PoseRefinement` does (for the scene measurement).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import torch

from fruitnerfpp_ros.core.data.dataset import SceneDataset
from fruitnerfpp_ros.core.data.pose_alignment import PoseAlignment, align_poses
from fruitnerfpp_ros.core.training.config import TrainConfig
from fruitnerfpp_ros.core.training.pose_refinement import PoseRefinement

__all__ = ['aligned_poses', 'refinement_after', 'corrected_poses']

log = logging.getLogger(__name__)


def aligned_poses(dataset: SceneDataset, config: TrainConfig) -> PoseAlignment | None:
    """The feature-based pose alignment of the training views (``config.pose_alignment``), or None when off."""
    if not config.pose_alignment.enabled:
        return None
    views = dataset.train_indices.numpy()
    log.info('pose alignment: features and matches of %d training views', len(views))
    images = (dataset.images[views].numpy() * 255.0).round().astype(np.uint8)
    valid = None if dataset.valid_masks is None else dataset.valid_masks[views].numpy()
    result = align_poses(images, dataset.intrinsics[views].double().numpy(),
                         dataset.T_world_camera[views].double().numpy(), config.pose_alignment, valid)
    correction = np.zeros((dataset.num_views, 6))
    correction[views] = result.correction
    log.info('pose alignment: %s', result.report)
    return PoseAlignment(correction, result.report)


def refinement_after(alignment: PoseAlignment | None, config: TrainConfig) -> TrainConfig:
    """``config`` with ``geometry.pose_lr`` 0 where ``pose_refine_when`` is ``aligned`` and the alignment did not
    correct the poses (the run's config.yaml then says what ran; a resume reads it)."""
    g = config.geometry
    if g.pose_lr <= 0 or g.pose_refine_when != 'aligned' or (alignment is not None and alignment.report.get('applied')):
        return config
    log.info('pose refinement off: %s', 'the pose alignment is off' if alignment is None
             else f"the pose alignment kept the recorded poses ({alignment.report.get('reason', 'no correction')})")
    return dataclasses.replace(config, geometry=dataclasses.replace(g, pose_lr=0.0))


def corrected_poses(dataset: SceneDataset, correction: np.ndarray) -> torch.Tensor:
    """The dataset's poses with ``correction`` [V, 6] applied as :class:`PoseRefinement` applies it."""
    trained = torch.zeros(dataset.num_views, dtype=torch.bool)
    trained[dataset.train_indices] = True
    with torch.no_grad():
        return PoseRefinement(trained, correction)(dataset.T_world_camera)
