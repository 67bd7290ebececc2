"""Pinhole views of a transforms.json dataset: projection, centroid rays and least-squares triangulation.

Conventions of transforms.json (docs/ARCHITECTURE.md): ``T_world_camera`` is camera-to-world with OpenGL camera
axes (x right, y up, z backwards, the camera looks along -z); pixel coordinates put the image's top-left corner
at (0, 0), so the centre of pixel column j, row i is (j + 0.5, i + 0.5). Distorted cameras (nerfstudio's OPENCV
keys k1, k2, p1, p2, k3: OpenCV's plumb_bob model) are projected through the distortion and their pixels
undistorted into rays; the Jacobian (for gating only) ignores the distortion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['PinholeView', 'Triangulation', 'triangulate']


@dataclass(frozen=True)
class PinholeView:
    """One camera view.

    Attributes:
        T_world_camera: [4, 4] camera-to-world pose, OpenGL camera axes, metres.
        fl_x: focal length along x, pixels.
        fl_y: focal length along y, pixels.
        cx: principal point x, pixels (top-left image corner at 0).
        cy: principal point y, pixels.
        width: image width, pixels.
        height: image height, pixels.
        distortion: [5] OpenCV plumb_bob coefficients (k1, k2, p1, p2, k3), or None for a pinhole camera.
    """

    T_world_camera: np.ndarray
    fl_x: float
    fl_y: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: np.ndarray | None = None

    @classmethod
    def from_intrinsics(cls, T_world_camera: np.ndarray, cam: CameraIntrinsics) -> 'PinholeView':
        """A view from a transforms.json pose and its intrinsics.

        Raises:
            DatasetError: a fisheye coefficient (k4), which the tracker does not model.
        """
        coefficients = None
        if any(float(v) != 0.0 for v in cam.distortion.values()):
            if float(cam.distortion.get('k4', 0.0)) != 0.0:
                raise DatasetError(f'fisheye distortion (k4 = {cam.distortion["k4"]}) is not supported by the tracker; '
                                   'undistort the masks first')
            coefficients = np.array([float(cam.distortion.get(k, 0.0)) for k in ('k1', 'k2', 'p1', 'p2', 'k3')])
        return cls(np.asarray(T_world_camera, np.float64), float(cam.fl_x), float(cam.fl_y), float(cam.cx),
                   float(cam.cy), int(cam.w), int(cam.h), coefficients)

    @property
    def focal_px(self) -> float:
        """Mean focal length (pixels): converts a size in pixels at depth z to metres (size * z / focal)."""
        return 0.5 * (self.fl_x + self.fl_y)

    @property
    def origin(self) -> np.ndarray:
        """[3] camera centre in the world frame (m)."""
        return self.T_world_camera[:3, 3]

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions and depths of world points.

        Args:
            points_world: [N, 3] points (m).

        Returns:
            ([N, 2] pixel positions (u, v), [N] depths along the optical axis in metres, <= 0 behind the camera;
            pixel positions of points behind the camera are NaN).
        """
        points = np.asarray(points_world, np.float64).reshape(-1, 3)
        R, t = self.T_world_camera[:3, :3], self.T_world_camera[:3, 3]
        p_cam = (points - t) @ R  # R^T (p - t), row-wise
        depth = -p_cam[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            inv = np.where(depth > 0, 1.0 / depth, np.nan)
        x, y = p_cam[:, 0] * inv, -p_cam[:, 1] * inv  # normalised, OpenCV axes (y down)
        if self.distortion is not None:
            k1, k2, p1, p2, k3 = self.distortion
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            x, y = (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                    y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
        return np.stack([self.cx + self.fl_x * x, self.cy + self.fl_y * y], axis=1), depth

    def jacobian(self, point_world: np.ndarray) -> np.ndarray:
        """[2, 3] derivative of the pixel position (u, v) with respect to a world point in front of the camera
        (pixels per metre)."""
        R, t = self.T_world_camera[:3, :3], self.T_world_camera[:3, 3]
        x, y, z = (np.asarray(point_world, np.float64).reshape(3) - t) @ R
        depth = -z
        J_cam = np.array([[self.fl_x / depth, 0.0, self.fl_x * x / depth ** 2],
                          [0.0, -self.fl_y / depth, -self.fl_y * y / depth ** 2]])
        return J_cam @ R.T

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixel positions.

        Args:
            uv: [N, 2] pixel positions (top-left image corner at 0, 0).

        Returns:
            ([N, 3] unit directions in the world frame, [N] range per unit depth: a point at depth z along the
            optical axis lies ``z * range_per_depth`` metres from the camera centre along its ray).
        """
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        if self.distortion is not None and len(uv):
            K = np.array([[self.fl_x, 0.0, self.cx], [0.0, self.fl_y, self.cy], [0.0, 0.0, 1.0]])
            xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, self.distortion).reshape(-1, 2)
        else:
            xy = np.stack([(uv[:, 0] - self.cx) / self.fl_x, (uv[:, 1] - self.cy) / self.fl_y], axis=1)
        d_cam = np.stack([xy[:, 0], -xy[:, 1], -np.ones(len(uv))], axis=1)
        norm = np.linalg.norm(d_cam, axis=1)
        return (d_cam / norm[:, None]) @ self.T_world_camera[:3, :3].T, norm


class Triangulation(NamedTuple):
    """A triangulated point.

    Attributes:
        point: [3] the point (m).
        information: [3, 3] the normal matrix ``sum A_i`` (1/m^2); its inverse is the point's covariance when the
            weights are inverse variances.
    """

    point: np.ndarray
    information: np.ndarray


def triangulate(origins: np.ndarray, directions: np.ndarray, prior_ranges: np.ndarray,
                perp_weights: np.ndarray, prior_weights: np.ndarray) -> Triangulation:
    """Weighted least-squares point nearest a bundle of rays, with a prior range along each ray.

    Minimises ``sum_i w_perp_i |(I - d_i d_i^T)(p - o_i)|^2 + w_prior_i (d_i . (p - q_i))^2`` with the prior
    points ``q_i = o_i + r_i d_i``; the closed form is ``p = (sum A_i)^-1 sum A_i q_i``,
    ``A_i = w_perp_i (I - d_i d_i^T) + w_prior_i d_i d_i^T``. One ray with its prior gives ``q_0``; two or more
    rays from different places pin the point down by their crossing, the priors only steadying near-parallel
    bundles.

    Args:
        origins: [M, 3] ray origins (m).
        directions: [M, 3] unit ray directions.
        prior_ranges: [M] prior distance (m) along each ray.
        perp_weights: [M] weights (1/m^2) of the perpendicular residuals.
        prior_weights: [M] weights (1/m^2) of the along-ray residuals to the prior points (0: no prior).

    Returns:
        the point and its normal matrix (the mean prior point when the system is singular).
    """
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    q = np.asarray(origins, np.float64).reshape(-1, 3) + np.asarray(prior_ranges, np.float64)[:, None] * d
    along = d[:, :, None] * d[:, None, :]
    A = (np.asarray(perp_weights, np.float64)[:, None, None] * (np.eye(3) - along)
         + np.asarray(prior_weights, np.float64)[:, None, None] * along)
    A_sum = A.sum(axis=0)
    b = np.einsum('mij,mj->i', A, q)
    try:
        point = np.linalg.solve(A_sum, b)
    except np.linalg.LinAlgError:
        point = q.mean(axis=0)
    return Triangulation(point if np.all(np.isfinite(point)) else q.mean(axis=0), A_sum)
