"""Scene bounds (an axis-aligned box in metres) derived from the data, never hard-coded.

Two sources, combined when both exist (see :func:`scene_aabb`):

- the cameras: the region that many cameras see (frustum overlap of the views, carved on a coarse grid);
- the sparse point cloud named by ``ply_file_path`` (robust percentiles of its points).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from fruitnerfpp_ros.core.data.ply_io import PlyError, read_ply_vertices
from fruitnerfpp_ros.errors import DatasetError

__all__ = ['scene_aabb', 'aabb_from_cameras', 'aabb_from_points', 'read_ply_points']


def read_ply_points(path: str | Path) -> np.ndarray:
    """Finite vertex positions [N, 3] float64 of a PLY file (ascii or binary, vertex x/y/z properties).

    Raises:
        DatasetError: the file is missing or not a PLY with vertex x, y, z.
    """
    try:
        vertices = read_ply_vertices(path)
    except OSError as err:
        raise DatasetError(f'{path}: cannot read point cloud: {err}') from err
    except PlyError as err:
        raise DatasetError(str(err)) from err
    if not {'x', 'y', 'z'} <= set(vertices.dtype.names or ()):
        raise DatasetError(f'{path}: expected a first PLY element "vertex" with x, y, z properties')
    points = np.stack([vertices['x'], vertices['y'], vertices['z']], axis=1).astype(np.float64)
    return points[np.all(np.isfinite(points), axis=1)]


def aabb_from_points(points: np.ndarray, *, percentile: float = 0.5, padding: float = 0.1) -> np.ndarray:
    """Box [2, 3] around the ``percentile``..``100-percentile`` range of points, padded by a fraction of its size."""
    lo = np.percentile(points, percentile, axis=0)
    hi = np.percentile(points, 100.0 - percentile, axis=0)
    pad = padding * (hi - lo).max()
    return np.stack([lo - pad, hi + pad])


def aabb_from_cameras(T_world_camera: np.ndarray, intrinsics: np.ndarray, width: int, height: int, *,
                      min_view_fraction: float = 0.5, grid: int = 48, padding: float = 0.05) -> np.ndarray:
    """Box [2, 3] of the region seen by at least ``min_view_fraction`` of the cameras.

    Candidate points fill a grid over the cameras' box, grown by the cameras' distance to their common focus
    (the least-squares point nearest every optical axis); a point counts as seen by a camera when it is in front
    of it and projects inside its image.

    Args:
        T_world_camera: [V, 4, 4] camera-to-world, OpenGL axes.
        intrinsics: [V, 4] fl_x, fl_y, cx, cy in pixels.
        width: image width in pixels.
        height: image height in pixels.
    """
    T = np.asarray(T_world_camera, dtype=np.float64)
    K = np.asarray(intrinsics, dtype=np.float64)
    centres = T[:, :3, 3]
    axes = -T[:, :3, 2]
    # Least-squares point nearest every optical axis: sum_i (I - a a^T) (p - c_i) = 0.
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    A = proj.sum(0)
    b = np.einsum('vij,vj->i', proj, centres)
    focus = np.linalg.lstsq(A, b, rcond=None)[0] if np.linalg.matrix_rank(A) == 3 else centres.mean(0) + axes.mean(0)
    reach = np.linalg.norm(centres - focus, axis=1).max()
    lo = np.minimum(centres.min(0), focus - reach)
    hi = np.maximum(centres.max(0), focus + reach)
    ticks = [np.linspace(lo[i], hi[i], grid) for i in range(3)]
    points = np.stack(np.meshgrid(*ticks, indexing='ij'), -1).reshape(-1, 3)
    # views that see each candidate point, one view at a time (a [V, N] array is ~2 GB for 300 keyframes)
    seen_by = np.zeros(len(points), np.int32)
    for R, c, (fx, fy, cx, cy) in zip(T[:, :3, :3], centres, K):
        cam = (points - c) @ R  # world -> camera: R^T (p - c)
        depth = -cam[:, 2]
        safe = np.where(depth > 1e-6, depth, 1.0)
        u = fx * cam[:, 0] / safe + cx
        v = -fy * cam[:, 1] / safe + cy
        seen_by += (depth > 1e-6) & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    fraction = seen_by / len(T)
    keep = fraction >= min_view_fraction
    if not keep.any():
        keep = fraction >= fraction.max()
    kept = points[keep]
    step = (hi - lo) / (grid - 1)
    box = np.stack([kept.min(0) - step, kept.max(0) + step])
    pad = padding * (box[1] - box[0]).max()
    return np.stack([box[0] - pad, box[1] + pad])


def scene_aabb(T_world_camera: torch.Tensor | np.ndarray, intrinsics: torch.Tensor | np.ndarray, width: int,
               height: int, *, ply_path: Path | None = None, min_view_fraction: float = 0.3,
               padding: float = 0.05, points_growth: float = 2.0) -> np.ndarray:
    """Scene box [2, 3] (metres, world frame) from the cameras and, when given, the sparse point cloud.

    Cameras: the region seen by at least ``min_view_fraction`` of them (suits inward-looking captures:
    hemisphere, orbit). Point cloud: its robust 0.5-99.5 percentile extent. With both, the box is their union
    limited to the point box grown ``points_growth`` times about its centre: it holds the geometry the cameras see
    around the sparse points (the ground around a tree: left outside, it turns into fog inside the box) without
    reaching far into space nothing was reconstructed in.
    """
    T = T_world_camera.numpy() if isinstance(T_world_camera, torch.Tensor) else np.asarray(T_world_camera)
    K = intrinsics.numpy() if isinstance(intrinsics, torch.Tensor) else np.asarray(intrinsics)
    box = aabb_from_cameras(T, K, width, height, min_view_fraction=min_view_fraction, padding=padding)
    if ply_path is not None:
        points = read_ply_points(ply_path)
        if len(points) >= 4:
            cloud = aabb_from_points(points, padding=padding)
            centre, half = cloud.mean(0), 0.5 * points_growth * (cloud[1] - cloud[0])
            union = np.stack([np.minimum(box[0], cloud[0]), np.maximum(box[1], cloud[1])])
            box = np.stack([np.maximum(union[0], centre - half), np.minimum(union[1], centre + half)])
    return box.astype(np.float64)
