"""Undo lens distortion (OpenCV's plumb_bob / rational_polynomial and the equidistant fisheye model).

The undistorted image keeps the camera matrix of the distorted one, so its intrinsics are the dataset's own. Parts
of the undistorted image map to points outside the sensor: those pixels hold no data, and :attr:`valid` marks them
so training never samples them (a black border is not a black world).
"""

from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['LensUndistorter', 'DISTORTION_MODELS', 'opencv_coefficients']

DISTORTION_MODELS = ('plumb_bob', 'rational_polynomial', 'equidistant')


def opencv_coefficients(distortion: Mapping[str, float], model: str) -> np.ndarray:
    """OpenCV's coefficient vector for nerfstudio-style keys (k1, k2, k3, k4, p1, p2).

    ``plumb_bob`` / ``rational_polynomial``: [k1, k2, p1, p2, k3]; ``equidistant``: [k1, k2, k3, k4].
    """
    get = lambda key: float(distortion.get(key, 0.0))  # noqa: E731
    if model == 'equidistant':
        return np.array([get('k1'), get('k2'), get('k3'), get('k4')])
    return np.array([get('k1'), get('k2'), get('p1'), get('p2'), get('k3')])


class LensUndistorter:
    """Remap tables of one distorted camera; :meth:`image`, :meth:`labels` and :attr:`valid` of its frames.

    Args:
        K: 3x3 camera matrix, OpenCV convention (the centre of the top-left pixel at 0, 0).
        D: distortion coefficients in OpenCV's order for ``model``.
        model: one of :data:`DISTORTION_MODELS`.
        size: (width, height) in pixels.

    Raises:
        DatasetError: an unknown model or an invalid camera matrix.
    """

    def __init__(self, K: np.ndarray, D: np.ndarray, model: str, size: tuple[int, int]) -> None:
        if model not in DISTORTION_MODELS:
            raise DatasetError(f'distortion model {model!r} is not supported; expected one of '
                               f'{", ".join(DISTORTION_MODELS)}')
        K = np.asarray(K, np.float64).reshape(3, 3)
        if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise DatasetError(f'camera matrix {K.tolist()} is not a valid pinhole camera')
        self.size = (int(size[0]), int(size[1]))
        D = np.asarray(D, np.float64).reshape(-1)
        if model == 'equidistant':
            fisheye = np.zeros(4)
            fisheye[:min(4, D.size)] = D[:4]
            maps = cv2.fisheye.initUndistortRectifyMap(K, fisheye, np.eye(3), K, self.size, cv2.CV_32FC1)
        else:
            maps = cv2.initUndistortRectifyMap(K, D, None, K, self.size, cv2.CV_32FC1)
        self._map_x, self._map_y = maps[0], maps[1]
        w, h = self.size
        # A pixel is valid when its source point and its bilinear neighbours lie on the sensor (no border blend).
        self.valid = ((self._map_x >= 0.0) & (self._map_x <= w - 1.0) & (self._map_y >= 0.0)
                      & (self._map_y <= h - 1.0))

    @classmethod
    def for_intrinsics(cls, intrinsics: CameraIntrinsics, model: str = 'plumb_bob') -> 'LensUndistorter | None':
        """The undistorter of transforms.json intrinsics (top-left-corner principal point), or None when they carry
        no distortion."""
        D = opencv_coefficients(intrinsics.distortion, model)
        if not np.any(D != 0.0):
            return None
        K = np.array([[intrinsics.fl_x, 0.0, intrinsics.cx - 0.5], [0.0, intrinsics.fl_y, intrinsics.cy - 0.5],
                      [0.0, 0.0, 1.0]])
        return cls(K, D, model, (intrinsics.w, intrinsics.h))

    def _check(self, array: np.ndarray, what: str) -> None:
        if array.shape[1::-1] != self.size:
            raise DatasetError(f'{what} is {array.shape[1]}x{array.shape[0]}, the camera {self.size[0]}x'
                               f'{self.size[1]}')

    def image(self, image: np.ndarray) -> np.ndarray:
        """The undistorted image (bilinear); invalid pixels are 0."""
        self._check(image, 'image')
        return cv2.remap(image, self._map_x, self._map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def labels(self, labels: np.ndarray) -> np.ndarray:
        """An undistorted label or instance mask (nearest neighbour: ids never blend); invalid pixels are 0."""
        self._check(labels, 'mask')
        # remap has no 32-bit integer path: ids below 2^24 are exact in float32
        source = labels.astype(np.float32) if labels.dtype.itemsize > 2 else labels
        out = cv2.remap(source, self._map_x, self._map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=0)
        return np.where(self.valid, out, 0).astype(labels.dtype)
