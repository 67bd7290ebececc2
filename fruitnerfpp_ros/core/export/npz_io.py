"""Compact ``.npz`` storage of a fruit point cloud (and optional cluster labels)."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_path
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ExportError

__all__ = ['write_npz', 'read_npz', 'read_cloud']

_KEYS = ('xyz', 'rgb', 'semantic', 'embedding')


def write_npz(path: str | Path, cloud: FruitPointCloud, labels: np.ndarray | None = None) -> Path:
    """Write ``cloud`` (+ optional [N] int32 ``labels``) compressed; atomic. Arrays: xyz, rgb, semantic, embedding
    (+ labels, + spacing_m, fruit_diameter_m and view_dir when known)."""
    path = Path(path)
    arrays = {'xyz': cloud.xyz, 'rgb': cloud.rgb, 'semantic': cloud.semantic, 'embedding': cloud.embedding,
              'format_version': np.int32(1)}
    if labels is not None:
        arrays['labels'] = np.asarray(labels, np.int32)
    if cloud.spacing_m is not None:
        arrays['spacing_m'] = np.float64(cloud.spacing_m)
    if cloud.fruit_diameter_m is not None:
        arrays['fruit_diameter_m'] = np.float64(cloud.fruit_diameter_m)
    if cloud.view_dir is not None:
        arrays['view_dir'] = np.asarray(cloud.view_dir, np.float32)
    with atomic_path(path, suffix='.tmp.npz') as tmp:
        np.savez_compressed(tmp, **arrays)
    return path


def read_npz(path: str | Path) -> tuple[FruitPointCloud, np.ndarray | None]:
    """Read a cloud written by :func:`write_npz`; returns (cloud, labels or None).

    Raises:
        ExportError: missing file, missing arrays or inconsistent shapes.
    """
    path = Path(path)
    try:
        with np.load(path) as data:
            missing = [k for k in _KEYS if k not in data]
            if missing:
                raise ExportError(f'{path}: missing array(s) {", ".join(missing)}')
            spacing = float(data['spacing_m']) if 'spacing_m' in data else None
            diameter = float(data['fruit_diameter_m']) if 'fruit_diameter_m' in data else None
            arrays = [np.asarray(data[k]) for k in _KEYS]
            view_dir = np.asarray(data['view_dir']) if 'view_dir' in data else None
            labels = np.asarray(data['labels']) if 'labels' in data else None
    except FileNotFoundError as err:
        raise ExportError(f'{path}: point cloud file not found') from err
    except (zipfile.BadZipFile, ValueError, OSError) as err:
        raise ExportError(f'{path}: not a readable point cloud .npz: {err}') from err
    try:
        return FruitPointCloud(*arrays, spacing_m=spacing, fruit_diameter_m=diameter, view_dir=view_dir), labels
    except ExportError as err:
        raise ExportError(f'{path}: {err}') from err


def read_cloud(path: str | Path) -> tuple[FruitPointCloud, np.ndarray | None]:
    """Read a ``.ply`` or ``.npz`` fruit point cloud by extension."""
    from fruitnerfpp_ros.core.export.ply import read_ply

    path = Path(path)
    if path.suffix.lower() == '.ply':
        return read_ply(path)
    if path.suffix.lower() == '.npz':
        return read_npz(path)
    raise ExportError(f'{path}: unknown point cloud format (expected .ply or .npz)')
