"""Binary little-endian PLY for fruit point clouds (readable by Open3D, CloudCompare, MeshLab).

Vertex properties, in order: ``x y z`` (float, m), ``red green blue`` (uchar), ``semantic`` (float fruit
probability), ``emb_0 .. emb_{D-1}`` (float embedding), when known ``view_x view_y view_z`` (float, the point's
mean viewing direction, ``FruitPointCloud.view_dir``) and, when labels are given, ``cluster`` (int, 0 = noise).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.data.ply_io import PlyError, read_ply_vertices_and_comments, write_ply_vertices
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ExportError

__all__ = ['write_ply', 'read_ply', 'SPACING_COMMENT', 'FRUIT_DIAMETER_COMMENT']

SPACING_COMMENT = 'spacing_m'
"""Header comment ``spacing_m <metres>``: the export voxel of the cloud (see ``FruitPointCloud.spacing_m``)."""
FRUIT_DIAMETER_COMMENT = 'fruit_diameter_m'
"""Header comment ``fruit_diameter_m <metres>``: the scene's fruit diameter (``FruitPointCloud.fruit_diameter_m``)."""


_VIEW = ('view_x', 'view_y', 'view_z')


def _vertex_dtype(dim: int, with_labels: bool, with_view: bool = False) -> np.dtype:
    fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('red', 'u1'), ('green', 'u1'), ('blue', 'u1'),
              ('semantic', '<f4')] + [(f'emb_{i}', '<f4') for i in range(dim)]
    if with_view:
        fields += [(name, '<f4') for name in _VIEW]
    if with_labels:
        fields.append(('cluster', '<i4'))
    return np.dtype(fields)


def write_ply(path: str | Path, cloud: FruitPointCloud, labels: np.ndarray | None = None) -> Path:
    """Write ``cloud`` (and optional [N] cluster ``labels``) as binary little-endian PLY; atomic."""
    path = Path(path)
    if labels is not None and len(labels) != len(cloud):
        raise ExportError(f'{path}: {len(labels)} labels for {len(cloud)} points')
    dtype = _vertex_dtype(cloud.embedding_dim, labels is not None, cloud.view_dir is not None)
    vertices = np.empty(len(cloud), dtype)
    for axis, name in enumerate('xyz'):
        vertices[name] = cloud.xyz[:, axis]
    for channel, name in enumerate(('red', 'green', 'blue')):
        vertices[name] = cloud.rgb[:, channel]
    vertices['semantic'] = cloud.semantic
    for i in range(cloud.embedding_dim):
        vertices[f'emb_{i}'] = cloud.embedding[:, i]
    if cloud.view_dir is not None:
        for axis, name in enumerate(_VIEW):
            vertices[name] = cloud.view_dir[:, axis]
    if labels is not None:
        vertices['cluster'] = labels
    comments = ['fruitnerfpp_ros fruit point cloud', f'embedding_dim {cloud.embedding_dim}']
    if cloud.spacing_m is not None:
        comments.append(f'{SPACING_COMMENT} {cloud.spacing_m!r}')
    if cloud.fruit_diameter_m is not None:
        comments.append(f'{FRUIT_DIAMETER_COMMENT} {cloud.fruit_diameter_m!r}')
    write_ply_vertices(path, vertices, comments=comments)
    return path


def read_ply(path: str | Path) -> tuple[FruitPointCloud, np.ndarray | None]:
    """Read a fruit point cloud PLY written by :func:`write_ply` (or any binary LE PLY with those properties).

    Returns:
        The cloud and the [N] int32 cluster labels (None when the file has no ``cluster`` property).

    Raises:
        ExportError: missing file, ASCII/big-endian PLY, or missing x/y/z properties.
    """
    path = Path(path)
    try:
        v, comments = read_ply_vertices_and_comments(path, formats=('binary_little_endian',))
    except FileNotFoundError as err:
        raise ExportError(f'{path}: point cloud file not found') from err
    except (OSError, PlyError) as err:
        raise ExportError(str(err)) from err
    names = set(v.dtype.names or ())
    if not {'x', 'y', 'z'} <= names:
        raise ExportError(f'{path}: vertex element lacks x/y/z properties')
    n_vertices = len(v)
    xyz = np.stack([v['x'], v['y'], v['z']], 1).astype(np.float32)
    rgb = (np.stack([v['red'], v['green'], v['blue']], 1).astype(np.uint8) if {'red', 'green', 'blue'} <= names
           else np.zeros((n_vertices, 3), np.uint8))
    semantic = v['semantic'].astype(np.float32) if 'semantic' in names else np.ones(n_vertices, np.float32)
    emb_names = sorted((n for n in names if n.startswith('emb_')), key=lambda n: int(n[4:]))
    embedding = (np.stack([v[n] for n in emb_names], 1).astype(np.float32) if emb_names
                 else np.zeros((n_vertices, 0), np.float32))
    labels = v['cluster'].astype(np.int32) if 'cluster' in names else None
    view_dir = np.stack([v[n] for n in _VIEW], 1).astype(np.float32) if set(_VIEW) <= names else None
    return FruitPointCloud(xyz, rgb, semantic, embedding, _value_from_comments(comments, SPACING_COMMENT),
                           _value_from_comments(comments, FRUIT_DIAMETER_COMMENT), view_dir), labels


def _value_from_comments(comments: list[str], key: str) -> float | None:
    for comment in comments:
        words = comment.split()
        if len(words) == 2 and words[0] == key:
            try:
                return float(words[1])
            except ValueError:
                return None
    return None
