"""How far camera poses are from the true ones, measured where it matters: the fruit centres in the images."""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.geometry import rotation_angle_deg
from fruitnerfpp_ros.core.tracking.camera import PinholeView

__all__ = ['pose_errors']


def pose_errors(T: np.ndarray, truth: np.ndarray, cameras: list[CameraIntrinsics], X: np.ndarray
                ) -> dict[str, float]:
    """Rotation / position error and the reprojection error of points ``X`` [N, 3] under poses ``T`` against
    ``truth`` ([V, 4, 4] camera-to-world, OpenGL axes): medians, and the reprojection's 90th percentile (px)."""
    angle = rotation_angle_deg(truth[:, :3, :3], T[:, :3, :3])
    shift = np.linalg.norm(T[:, :3, 3] - truth[:, :3, 3], axis=-1)
    px = []
    for pose, exact, cam in zip(T, truth, cameras):
        true_uv, depth = PinholeView.from_intrinsics(exact, cam).project(X)
        uv, _ = PinholeView.from_intrinsics(pose, cam).project(X)
        px.append(np.linalg.norm(uv - true_uv, axis=1)[depth > 0.1])
    errors = np.concatenate(px)
    return {'rotation_deg_median': float(np.median(angle)), 'position_m_median': float(np.median(shift)),
            'reprojection_px_median': float(np.nanmedian(errors)),
            'reprojection_px_p90': float(np.nanpercentile(errors, 90))}
