"""A tiny stand-in orchard for tests: coloured spheres (leaves, fruits) over a ground plane, ray-cast in numpy.

Independent of core/synthetic, so the data/field/training tests do not depend on the synthetic generator.
Instance ids are random per view (per-image labels), as real segmenters give them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fruitnerfpp_ros.core.data.transforms_format import (CameraIntrinsics, FrameEntry, TransformsFile,
                                                         write_transforms)

SKY = np.array([0.75, 0.85, 0.95])


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, up, back, eye
    return T


def make_sphere_scene(out_dir: Path, *, views: int = 24, size: int = 64, fruits: int = 12, seed: int = 0,
                      write_ply: bool = False, distance: float = 3.2) -> Path:
    """Write a transforms.json dataset of a sphere 'tree' into ``out_dir``; returns ``out_dir``.

    ``distance``: of the cameras from the tree centre (m). Fruit centres are stored in ``fruit_centres.npy``
    (metres), every sphere in ``spheres.npz`` (centres, radii, is_fruit), so tests can build the exact field.
    """
    rng = np.random.default_rng(seed)
    out_dir = Path(out_dir)
    for sub in ('images', 'instances'):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    centre = np.array([0.0, 0.0, 1.2])
    leaves_c = centre + rng.normal(size=(14, 3)) * 0.25
    leaves_r = rng.uniform(0.2, 0.3, 14)
    leaves_col = np.array([0.2, 0.5, 0.15]) + rng.uniform(-0.08, 0.08, (14, 3))
    fruit_c: list[np.ndarray] = []
    while len(fruit_c) < fruits:
        d = rng.normal(size=3)
        d[2] = abs(d[2]) * 0.6
        p = centre + 0.62 * d / np.linalg.norm(d)
        if all(np.linalg.norm(p - q) > 0.2 for q in fruit_c):
            fruit_c.append(p)
    fc = np.array(fruit_c)
    fr = rng.uniform(0.07, 0.09, fruits)
    fcol = np.array([0.8, 0.1, 0.08]) + rng.uniform(-0.1, 0.1, (fruits, 3))
    centres = np.vstack([fc, leaves_c])
    radii = np.concatenate([fr, leaves_r])
    colours = np.clip(np.vstack([fcol, leaves_col]), 0, 1)
    np.save(out_dir / 'fruit_centres.npy', fc)
    np.savez(out_dir / 'spheres.npz', centres=centres, radii=radii, is_fruit=np.arange(len(centres)) < fruits)
    focal = 0.5 * size / np.tan(np.radians(25.0))
    intr = CameraIntrinsics(focal, focal, size / 2, size / 2, size, size)
    light = np.array([0.4, 0.3, 0.85])
    light /= np.linalg.norm(light)
    frames = []
    for i in range(views):
        az = 2 * np.pi * i / views * 2.0 + rng.uniform(0, 0.2)
        el = np.radians(15 + 45 * (i % 3) / 2)
        eye = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T = _look_at(eye, centre)
        v, u = np.meshgrid(np.arange(size), np.arange(size), indexing='ij')
        d_cam = np.stack([(u + 0.5 - size / 2) / focal, -(v + 0.5 - size / 2) / focal, -np.ones_like(u, float)], -1)
        d = d_cam.reshape(-1, 3) @ T[:3, :3].T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        oc = eye[None] - centres                                   # [S, 3]
        b = d @ oc.T                                               # [N, S]
        c = (oc ** 2).sum(-1) - radii ** 2
        disc = b ** 2 - c[None]
        t_s = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
        t_s = np.where(t_s > 0, t_s, np.inf)
        t_g = np.where(d[:, 2] < -1e-6, -eye[2] / np.where(d[:, 2] < -1e-6, d[:, 2], -1), np.inf)
        hit = np.argmin(t_s, axis=1)
        t_hit = t_s[np.arange(len(d)), hit]
        rgb = np.tile(SKY, (len(d), 1))
        ground = (t_g < t_hit) & np.isfinite(t_g)
        gp = eye + t_g[ground, None] * d[ground]
        checker = ((np.floor(gp[:, 0] * 2) + np.floor(gp[:, 1] * 2)) % 2)[:, None]
        rgb[ground] = np.array([0.45, 0.35, 0.2]) * (0.8 + 0.2 * checker)
        sphere = np.isfinite(t_hit) & ~ground
        p = eye + t_hit[sphere, None] * d[sphere]
        n = (p - centres[hit[sphere]]) / radii[hit[sphere], None]
        shade = 0.35 + 0.65 * np.clip(n @ light, 0, 1)
        rgb[sphere] = colours[hit[sphere]] * shade[:, None]
        ids = np.zeros(len(d), np.int32)
        labels = rng.permutation(np.arange(1, 1000))[:fruits]      # random per-view labels
        is_fruit = sphere.copy()
        is_fruit[sphere] = hit[sphere] < fruits
        ids[is_fruit] = labels[hit[is_fruit]]
        image = (np.clip(rgb, 0, 1).reshape(size, size, 3) * 255 + 0.5).astype(np.uint8)
        cv2.imwrite(str(out_dir / f'images/{i:04d}.png'), image[..., ::-1])
        cv2.imwrite(str(out_dir / f'instances/{i:04d}.png'), ids.reshape(size, size).astype(np.uint16))
        frames.append(FrameEntry(f'images/{i:04d}.png', T, f'instances/{i:04d}.png'))
    ply = None
    if write_ply:
        dirs = rng.normal(size=(len(centres), 20, 3))
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        pts = (centres[:, None] + radii[:, None, None] * dirs).reshape(-1, 3)
        lines = ['ply', 'format ascii 1.0', f'element vertex {len(pts)}', 'property float x', 'property float y',
                 'property float z', 'end_header'] + [f'{x} {y} {z}' for x, y, z in pts]
        (out_dir / 'sparse_pc.ply').write_text('\n'.join(lines) + '\n')
        ply = 'sparse_pc.ply'
    write_transforms(out_dir, TransformsFile(intr, frames, ply))
    return out_dir
