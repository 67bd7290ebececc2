"""The training views a count is checked against (``mask_check.py``): instance masks, intrinsics, poses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fruitnerfpp_ros.core.tracking.camera import PinholeView

__all__ = ['MaskViews', 'pinhole_view']


@dataclass(frozen=True)
class MaskViews:
    """The training views a count is checked against.

    Attributes:
        instance_masks: [V, H, W] integer instance ids (0 = no fruit), as the dataset holds them.
        intrinsics: [V, 4] fx, fy, cx, cy (pixels, undistorted images).
        T_world_camera: [V, 4, 4] camera-to-world poses, OpenGL camera axes (x right, y up, looking along -z): the
            poses the field was trained with (refined ones when pose refinement ran).
        views: indices of the views to use (the training views).
        mask_source: where the masks came from (the dataset's ``mask_source``), None when unknown.
    """

    instance_masks: np.ndarray
    intrinsics: np.ndarray
    T_world_camera: np.ndarray
    views: np.ndarray
    mask_source: str | None = None


def pinhole_view(views: MaskViews, view: int) -> PinholeView:
    """View ``view`` of ``views`` as the tracking package's pinhole camera (the masks are undistorted)."""
    fx, fy, cx, cy = (float(v) for v in views.intrinsics[view])
    height, width = views.instance_masks.shape[1:3]
    return PinholeView(np.asarray(views.T_world_camera[view], np.float64), fx, fy, cx, cy, width, height)
