"""A tiny scene for the masks step's tests: spheres ray-cast into pinhole cameras on a circle (a z-buffer gives
each pixel the nearest fruit), rendered here independently of the package's projection code."""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.clustering.mask_views import MaskViews

DIAMETER = 0.07
SIZE, FOCAL = 120, 120.0
#: five fruits in a 0.5 m crown; each is 2-3 diameters from the others
FRUITS = np.array([[0.0, 0.0, 0.0], [0.2, 0.05, 0.1], [-0.18, 0.12, -0.05], [0.05, -0.2, 0.15],
                   [-0.1, -0.1, -0.2]])


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world pose, OpenGL axes (x right, y up, looking along -z)."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(forward, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(x, forward), -forward, eye
    return T


def render(poses: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """[V, H, W] instance ids (fruit k is k + 1) of spheres of DIAMETER at ``centers``, nearest hit per pixel."""
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    cam = np.stack([(cols + 0.5 - SIZE / 2) / FOCAL, -(rows + 0.5 - SIZE / 2) / FOCAL, -np.ones((SIZE, SIZE))], -1)
    masks = np.zeros((len(poses), SIZE, SIZE), np.int32)
    for v, T in enumerate(poses):
        d = cam @ T[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        rel = centers - T[:3, 3]                                           # [K, 3]
        along = d @ rel.T                                                  # [H, W, K]
        off2 = (rel * rel).sum(1) - along ** 2
        hit = (off2 <= (DIAMETER / 2) ** 2) & (along > 0)
        depth = np.where(hit, along, np.inf)
        nearest = depth.argmin(-1)
        masks[v] = np.where(np.isfinite(depth.min(-1)), nearest + 1, 0)
    return masks


def circle_views(centers: np.ndarray = FRUITS, n_views: int = 12, radius_m: float = 1.2) -> MaskViews:
    """``n_views`` cameras on a circle of ``radius_m`` around the crown, 0.3 m up, seeing spheres at ``centers``
    (a fruit spans 7 px at 1.2 m, 2-3 px at 3.4 m)."""
    angles = np.linspace(0, 2 * np.pi, n_views, endpoint=False)
    poses = np.stack([look_at(np.array([radius_m * np.cos(a), radius_m * np.sin(a), 0.3]), np.zeros(3))
                      for a in angles])
    intrinsics = np.tile([FOCAL, FOCAL, SIZE / 2, SIZE / 2], (len(poses), 1))
    return MaskViews(render(poses, centers), intrinsics, poses, np.arange(len(poses)))
