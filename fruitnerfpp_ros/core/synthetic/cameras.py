"""Camera trajectories around the synthetic tree: upper hemisphere (BlenderNeRF style) and an orchard row.

Poses are camera-to-world in OpenGL camera axes (x right, y up, z backwards), as in transforms.json.
"""

from __future__ import annotations

import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics
from fruitnerfpp_ros.core.synthetic.config import SynthConfig
from fruitnerfpp_ros.core.synthetic.scene import Scene

__all__ = ['look_at', 'make_intrinsics', 'hemisphere_poses', 'row_poses', 'make_poses']

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """4x4 camera-to-world pose (OpenGL axes) of a camera at ``eye`` looking at ``target`` (metres)."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight up/down
        right = np.array([1.0, 0.0, 0.0])
    right = right / np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, cam_up, -forward, eye
    return T


def make_intrinsics(config: SynthConfig) -> CameraIntrinsics:
    """Pinhole intrinsics: ``fov_deg`` across the shorter side, square pixels, centred principal point."""
    w, h = config.resolution
    focal = 0.5 * min(w, h) / np.tan(np.radians(config.fov_deg) / 2.0)
    return CameraIntrinsics(float(focal), float(focal), w / 2.0, h / 2.0, w, h)


def hemisphere_poses(scene: Scene, config: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """[V, 4, 4] random views on the upper hemisphere, stratified in azimuth and height, framing the tree."""
    n = config.views
    half_fov = np.radians(config.fov_deg) / 2.0
    distance = scene.bound_radius / np.sin(half_fov)
    sin_lo, sin_hi = np.sin(np.radians(5.0)), np.sin(np.radians(70.0))
    strata = (np.arange(n) + rng.uniform(size=n)) / n
    elevation = np.arcsin(sin_lo + rng.permutation(strata) * (sin_hi - sin_lo))
    azimuth = rng.uniform(0.0, 2.0 * np.pi) + _GOLDEN_ANGLE * np.arange(n)
    dist = distance * rng.uniform(1.0, 1.12, n)
    poses = np.zeros((n, 4, 4))
    for i in range(n):
        direction = np.array([np.cos(elevation[i]) * np.cos(azimuth[i]),
                              np.cos(elevation[i]) * np.sin(azimuth[i]), np.sin(elevation[i])])
        target = scene.bound_center + rng.normal(scale=0.03 * scene.bound_radius, size=3)
        poses[i] = look_at(scene.bound_center + dist[i] * direction, target)
    return poses


def row_poses(scene: Scene, config: SynthConfig, rng: np.random.Generator) -> np.ndarray:
    """[V, 4, 4] views of a robot driving along the row (x axis) on both sides, camera facing the tree.

    The first half of the views drive +x on the side y < 0, the rest drive back (-x) on the side y > 0. The
    camera sits at mid-tree height, far enough for the whole tree height to fit.
    """
    n = config.views
    half_fov = np.radians(config.fov_deg) / 2.0
    height = scene.bound_center[2]
    distance = 1.1 * scene.bound_radius / np.tan(half_fov)
    span = 0.9 * scene.crown_radii[0]
    n_a = (n + 1) // 2
    poses = np.zeros((n, 4, 4))
    for i in range(n):
        side, k, m = (-1.0, i, n_a) if i < n_a else (1.0, i - n_a, n - n_a)
        frac = (k + 0.5) / m
        x = (-span + 2.0 * span * frac) * (-side)  # side -1 drives +x, side +1 drives -x
        eye = np.array([x, side * distance, height]) + rng.normal(scale=[0.01, 0.02, 0.02])
        yaw = rng.normal(scale=0.02)
        target = eye + np.array([np.sin(yaw), -side * np.cos(yaw), rng.normal(scale=0.01)])
        poses[i] = look_at(eye, target)
    return poses


def make_poses(scene: Scene, config: SynthConfig) -> np.ndarray:
    """[V, 4, 4] camera-to-world poses (OpenGL axes) of ``config.trajectory``, deterministic in the seed."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0xCA3]))
    if config.trajectory == 'row':
        return row_poses(scene, config, rng)
    return hemisphere_poses(scene, config, rng)
