"""The synthetic camera's lens: OpenCV's plumb_bob model (k1, k2, p1, p2, k3), as nerfstudio's ``OPENCV``.

A pixel's ray: the centre of pixel (col, row) sits at (col + 0.5, row + 0.5) in transforms.json coordinates
(top-left image corner at 0, 0), i.e. at (col, row) in OpenCV coordinates with ``cx_cv = cx - 0.5``. Its
distorted normalised coordinates are ``((col + 0.5 - cx) / fl_x, (row + 0.5 - cy) / fl_y)``; undoing the
distortion gives the undistorted normalised coordinates (x, y), and the ray in optical axes is (x, y, 1).
"""

from __future__ import annotations

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.errors import SynthError

__all__ = ['DISTORTION_KEYS', 'distortion_coefficients', 'is_distorted', 'distort_normalized',
           'undistorted_pixel_grid', 'project_points']

#: Coefficient names in OpenCV's / CameraInfo's order (``D = [k1, k2, p1, p2, k3]``).
DISTORTION_KEYS = ('k1', 'k2', 'p1', 'p2', 'k3')
#: Largest reprojection error (pixels) accepted when inverting the lens model over the image.
_INVERSE_TOLERANCE_PX = 1e-3


def distortion_coefficients(K: CameraIntrinsics) -> np.ndarray:
    """[5] float64 ``[k1, k2, p1, p2, k3]`` of ``K`` (missing keys are 0)."""
    return np.array([float(K.distortion.get(k, 0.0)) for k in DISTORTION_KEYS])


def is_distorted(K: CameraIntrinsics) -> bool:
    """Whether ``K`` has a non-zero distortion coefficient."""
    return bool(np.any(distortion_coefficients(K) != 0.0))


def distort_normalized(xy: np.ndarray, D: np.ndarray) -> np.ndarray:
    """OpenCV's forward plumb_bob model: undistorted normalised coordinates [N, 2] -> distorted ones [N, 2]."""
    k1, k2, p1, p2, k3 = D
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def _jacobian(xy: np.ndarray, D: np.ndarray) -> np.ndarray:
    """[N, 2, 2] derivative of :func:`distort_normalized` at the undistorted coordinates ``xy`` [N, 2]."""
    k1, k2, p1, p2, k3 = D
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    J = np.empty((len(xy), 2, 2))
    J[:, 0, 0] = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    J[:, 0, 1] = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 0] = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 1] = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    return J


def _undistort_normalized(distorted: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Invert :func:`distort_normalized`: OpenCV's iterative estimate, refined by a few Newton steps."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    src = distorted[:, None, :]
    if hasattr(cv2, 'undistortPointsIter'):  # OpenCV 4.x
        xy = cv2.undistortPointsIter(src, np.eye(3), D, None, None, criteria)
    else:  # OpenCV 5: undistortPoints takes the criteria
        xy = cv2.undistortPoints(src, np.eye(3), D, R=None, P=None, criteria=criteria)
    xy = xy[:, 0, :].astype(np.float64)
    for _ in range(3):
        residual = distort_normalized(xy, D) - distorted
        xy = xy - np.linalg.solve(_jacobian(xy, D), residual[..., None])[..., 0]
    return xy


def undistorted_pixel_grid(K: CameraIntrinsics) -> np.ndarray:
    """[H * W, 2] float64 undistorted normalised coordinates (x, y) of every pixel centre, row-major.

    Raises:
        SynthError: the distortion cannot be inverted over the image (the model folds over inside it).
    """
    v, u = np.meshgrid(np.arange(K.h, dtype=np.float64), np.arange(K.w, dtype=np.float64), indexing='ij')
    distorted = np.stack([(u.reshape(-1) + 0.5 - K.cx) / K.fl_x, (v.reshape(-1) + 0.5 - K.cy) / K.fl_y], axis=1)
    D = distortion_coefficients(K)
    if not np.any(D != 0.0):
        return distorted
    with np.errstate(all='ignore'):
        undistorted = _undistort_normalized(distorted, D)
        error_px = np.abs(distort_normalized(undistorted, D) - distorted) * np.array([K.fl_x, K.fl_y])
        fold = np.linalg.det(_jacobian(undistorted, D))  # > 0: the lens maps this neighbourhood one to one
    ok = np.isfinite(error_px).all(axis=1) & np.isfinite(fold)
    if not (ok.all() and error_px.max() < _INVERSE_TOLERANCE_PX and fold.min() > 0.05):
        worst = float(error_px[ok].max()) if ok.any() else float('inf')
        raise SynthError(f'distortion {D.tolist()} cannot be inverted over the {K.w}x{K.h} image (reprojection '
                         f'error {worst:.3g} px, smallest Jacobian {float(np.min(fold[ok], initial=0.0)):.3g}): the '
                         'lens model folds over inside the image; use smaller coefficients')
    return undistorted


def project_points(points_optical: np.ndarray, K: CameraIntrinsics) -> np.ndarray:
    """[N, 2] pixel coordinates (transforms.json convention: top-left image corner at 0, 0) of points [N, 3] in
    the optical frame (z forward, metres), through the lens distortion of ``K``."""
    xy = points_optical[:, :2] / points_optical[:, 2:3]
    xy = distort_normalized(xy, distortion_coefficients(K))
    return np.stack([K.fl_x * xy[:, 0] + K.cx, K.fl_y * xy[:, 1] + K.cy], axis=1)
