"""Hand-made posed scenes for the tracker tests: spheres rendered into instance masks, written as a dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.png_io import write_rgb_png, write_uint16_png
from fruitnerfpp_ros.core.data.transforms_format import CameraIntrinsics, FrameEntry, TransformsFile, write_transforms
from fruitnerfpp_ros.core.tracking.camera import PinholeView

SIZE = 96
INTRINSICS = CameraIntrinsics(100.0, 100.0, SIZE / 2, SIZE / 2, SIZE, SIZE)
RADIUS_M = 0.0375  # the tracker's default prior diameter is 7.5 cm


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world pose (OpenGL axes, z up in the world) of a camera at ``eye`` looking at ``target``."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, np.cross(right, forward), -forward, eye
    return T


def row_pose(x: float, side: float) -> np.ndarray:
    """A camera 1 m from the row (the x axis) on side ``side`` (-1: y < 0), at height 0, facing the row."""
    return look_at(np.array([x, side * 1.0, 0.0]), np.array([x, 0.0, 0.0]))


def render(T_world_camera: np.ndarray, centers: np.ndarray, *, radius: float = RADIUS_M,
           ids: np.ndarray | None = None) -> np.ndarray:
    """[H, W] instance ids of spheres seen by the camera (nearest sphere wins; 0 = background).

    ``ids``: the label of each sphere in this image (default 1..K): per-image labels need not agree between views.
    """
    view = PinholeView.from_intrinsics(T_world_camera, INTRINSICS)
    v, u = np.mgrid[0:SIZE, 0:SIZE]
    directions, _ = view.rays(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1))
    labels = np.zeros(SIZE * SIZE, np.int32)
    best = np.full(SIZE * SIZE, np.inf)
    ids = np.arange(1, len(centers) + 1) if ids is None else np.asarray(ids)
    for center, label in zip(np.asarray(centers, float).reshape(-1, 3), ids):
        offset = center - view.origin
        along = directions @ offset
        miss2 = offset @ offset - along ** 2
        hit = (miss2 <= radius ** 2) & (along > 0)
        distance = along - np.sqrt(np.maximum(radius ** 2 - miss2, 0.0))
        closer = hit & (distance < best)
        labels[closer], best[closer] = label, distance[closer]
    return labels.reshape(SIZE, SIZE)


def write_scene(out: Path, poses: list[np.ndarray], masks: list[np.ndarray], *, stamps: bool = True) -> Path:
    """A transforms.json dataset of the given poses and instance masks (grey images), 0.1 s apart."""
    frames = []
    for i, (pose, mask) in enumerate(zip(poses, masks)):
        write_rgb_png(out / 'images' / f'{i:04d}.png', np.full((SIZE, SIZE, 3), 128, np.uint8))
        write_uint16_png(out / 'instances' / f'{i:04d}.png', mask)
        frames.append(FrameEntry(f'images/{i:04d}.png', pose, f'instances/{i:04d}.png',
                                 stamp_ns=1_000_000_000 + 100_000_000 * i if stamps else None))
    write_transforms(out, TransformsFile(INTRINSICS, frames))
    return out
