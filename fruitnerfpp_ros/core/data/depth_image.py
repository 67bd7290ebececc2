"""Depth images on disk: 16-bit PNG in millimetres (``depth_unit_scale_factor`` 0.001), 0 = no return.

This is what RealSense, ZED and OAK-D drivers publish as ``16UC1`` and what nerfstudio reads from
``depth_file_path``; 1 mm steps up to 65.5 m are finer than any stereo camera's error at the ranges it works at.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.png_io import write_uint16_png

__all__ = ['DEPTH_PNG_UNIT_M', 'depth_units_from_metres', 'write_depth_png']

#: Metres per unit of the depth PNGs this package writes (millimetres).
DEPTH_PNG_UNIT_M = 1e-3


def depth_units_from_metres(depth_m: np.ndarray, unit_m: float = DEPTH_PNG_UNIT_M) -> np.ndarray:
    """[H, W] uint16 depth in ``unit_m`` steps (rounded) of [H, W] metres; no return (0, NaN, inf, negative) and
    depths beyond the 16-bit range become 0."""
    depth = np.asarray(depth_m, dtype=np.float64)
    units = np.round(np.where(np.isfinite(depth) & (depth > 0), depth, 0.0) / unit_m)
    return np.where(units <= np.iinfo(np.uint16).max, units, 0).astype(np.uint16)


def write_depth_png(path: str | Path, depth_m: np.ndarray) -> None:
    """Write [H, W] depth in metres as a 16-bit millimetre PNG (0 = no return).

    Raises:
        DatasetError: the file cannot be written.
    """
    write_uint16_png(path, depth_units_from_metres(depth_m))
