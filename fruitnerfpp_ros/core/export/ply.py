"""Binary little-endian PLY for fruit point clouds (readable by Open3D, CloudCompare, MeshLab).

Vertex properties, in order: ``x y z`` (float, m), ``red green blue`` (uchar), ``semantic`` (float fruit
probability), ``emb_0 .. emb_{D-1}`` (float embedding) and, when labels are given, ``cluster`` (int, 0 = noise).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ExportError

__all__ = ['write_ply', 'read_ply']

_PLY_TYPES = {'float': '<f4', 'float32': '<f4', 'double': '<f8', 'float64': '<f8', 'uchar': 'u1', 'uint8': 'u1',
              'char': 'i1', 'int8': 'i1', 'ushort': '<u2', 'uint16': '<u2', 'short': '<i2', 'int16': '<i2',
              'uint': '<u4', 'uint32': '<u4', 'int': '<i4', 'int32': '<i4'}


def _vertex_dtype(dim: int, with_labels: bool) -> np.dtype:
    fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('red', 'u1'), ('green', 'u1'), ('blue', 'u1'),
              ('semantic', '<f4')] + [(f'emb_{i}', '<f4') for i in range(dim)]
    if with_labels:
        fields.append(('cluster', '<i4'))
    return np.dtype(fields)


def write_ply(path: str | Path, cloud: FruitPointCloud, labels: np.ndarray | None = None) -> Path:
    """Write ``cloud`` (and optional [N] cluster ``labels``) as binary little-endian PLY; atomic."""
    path = Path(path)
    if labels is not None and len(labels) != len(cloud):
        raise ExportError(f'{path}: {len(labels)} labels for {len(cloud)} points')
    dtype = _vertex_dtype(cloud.embedding_dim, labels is not None)
    vertices = np.empty(len(cloud), dtype)
    for axis, name in enumerate('xyz'):
        vertices[name] = cloud.xyz[:, axis]
    for channel, name in enumerate(('red', 'green', 'blue')):
        vertices[name] = cloud.rgb[:, channel]
    vertices['semantic'] = cloud.semantic
    for i in range(cloud.embedding_dim):
        vertices[f'emb_{i}'] = cloud.embedding[:, i]
    if labels is not None:
        vertices['cluster'] = labels
    type_names = {'<f4': 'float', 'u1': 'uchar', '<i4': 'int'}
    header = ['ply', 'format binary_little_endian 1.0', 'comment fruitnerfpp_ros fruit point cloud',
              f'comment embedding_dim {cloud.embedding_dim}', f'element vertex {len(cloud)}']
    header += [f'property {type_names[dtype.fields[name][0].str.replace("|", "")]} {name}' for name in dtype.names]
    header.append('end_header')
    tmp = path.with_name(path.name + '.tmp')
    with open(tmp, 'wb') as f:
        f.write(('\n'.join(header) + '\n').encode('ascii'))
        f.write(vertices.tobytes())
    tmp.replace(path)
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
        raw = path.read_bytes()
    except FileNotFoundError as err:
        raise ExportError(f'{path}: point cloud file not found') from err
    end = raw.find(b'end_header\n')
    if not raw.startswith(b'ply') or end < 0:
        raise ExportError(f'{path}: not a PLY file (no "ply" magic / end_header)')
    lines = raw[:end].decode('ascii', errors='replace').splitlines()
    if 'format binary_little_endian 1.0' not in lines:
        raise ExportError(f'{path}: only binary_little_endian PLY is supported')
    n_vertices, fields, in_vertex = None, [], False
    for line in lines:
        parts = line.split()
        if parts[:1] == ['element']:
            in_vertex = parts[1] == 'vertex'
            if in_vertex:
                n_vertices = int(parts[2])
            elif n_vertices is not None:
                break  # only the vertex element (first) is read
        elif parts[:1] == ['property'] and in_vertex:
            if parts[1] == 'list' or parts[1] not in _PLY_TYPES:
                raise ExportError(f'{path}: unsupported vertex property {" ".join(parts[1:])!r}')
            fields.append((parts[2], _PLY_TYPES[parts[1]]))
    if n_vertices is None:
        raise ExportError(f'{path}: no vertex element')
    dtype = np.dtype(fields)
    names = set(dtype.names or ())
    if not {'x', 'y', 'z'} <= names:
        raise ExportError(f'{path}: vertex element lacks x/y/z properties')
    body = raw[end + len(b'end_header\n'):]
    if len(body) < n_vertices * dtype.itemsize:
        raise ExportError(f'{path}: truncated ({len(body)} bytes for {n_vertices} vertices of {dtype.itemsize})')
    v = np.frombuffer(body, dtype, count=n_vertices)
    xyz = np.stack([v['x'], v['y'], v['z']], 1).astype(np.float32)
    rgb = (np.stack([v['red'], v['green'], v['blue']], 1).astype(np.uint8) if {'red', 'green', 'blue'} <= names
           else np.zeros((n_vertices, 3), np.uint8))
    semantic = v['semantic'].astype(np.float32) if 'semantic' in names else np.ones(n_vertices, np.float32)
    emb_names = sorted((n for n in names if n.startswith('emb_')), key=lambda n: int(n[4:]))
    embedding = (np.stack([v[n] for n in emb_names], 1).astype(np.float32) if emb_names
                 else np.zeros((n_vertices, 0), np.float32))
    labels = v['cluster'].astype(np.int32) if 'cluster' in names else None
    return FruitPointCloud(xyz, rgb, semantic, embedding), labels
