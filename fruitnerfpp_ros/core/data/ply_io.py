"""PLY vertex I/O shared by the sparse point clouds (data, synthetic) and the fruit clouds (export).

Vertices travel as numpy structured arrays, one field per PLY property. Reading understands ``ascii``,
``binary_little_endian`` and ``binary_big_endian`` files whose first element is ``vertex`` (later elements, e.g.
faces, are ignored). Errors are :class:`PlyError` (a ``ValueError``); callers translate them into their own
error class at their boundary, naming the file's role.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Iterable

import numpy as np
from numpy.lib import recfunctions

from fruitnerfpp_ros.core.atomic_io import atomic_write_bytes

__all__ = ['PlyError', 'PLY_FORMATS', 'read_ply_vertices', 'read_ply_vertices_and_comments', 'write_ply_vertices']

PLY_FORMATS = ('binary_little_endian', 'binary_big_endian', 'ascii')

#: PLY property type -> numpy type code (byte order added per file).
_PLY_TYPES = {'char': 'i1', 'uchar': 'u1', 'int8': 'i1', 'uint8': 'u1', 'short': 'i2', 'ushort': 'u2',
              'int16': 'i2', 'uint16': 'u2', 'int': 'i4', 'uint': 'u4', 'int32': 'i4', 'uint32': 'u4',
              'float': 'f4', 'float32': 'f4', 'double': 'f8', 'float64': 'f8'}
#: numpy type code -> PLY property type, for writing.
_TYPE_NAMES = {'i1': 'char', 'u1': 'uchar', 'i2': 'short', 'u2': 'ushort', 'i4': 'int', 'u4': 'uint',
               'f4': 'float', 'f8': 'double'}


class PlyError(ValueError):
    """A file is not a PLY this module can read (message starts with the path)."""


def write_ply_vertices(path: str | Path, vertices: np.ndarray, *, comments: Iterable[str] = ()) -> Path:
    """Write structured ``vertices`` as a binary little-endian PLY (atomic: temp file, then rename)."""
    path = Path(path)
    dtype = vertices.dtype.newbyteorder('<')
    header = ['ply', 'format binary_little_endian 1.0', *(f'comment {c}' for c in comments),
              f'element vertex {len(vertices)}']
    header += [f'property {_TYPE_NAMES[dtype.fields[name][0].str[1:]]} {name}' for name in dtype.names]
    header.append('end_header')
    return atomic_write_bytes(path, ('\n'.join(header) + '\n').encode('ascii')
                              + vertices.astype(dtype, copy=False).tobytes())


def read_ply_vertices(path: str | Path, *, formats: tuple[str, ...] = PLY_FORMATS) -> np.ndarray:
    """The vertex element of a PLY file as a structured array (see :func:`read_ply_vertices_and_comments`)."""
    return read_ply_vertices_and_comments(path, formats=formats)[0]


def read_ply_vertices_and_comments(path: str | Path, *, formats: tuple[str, ...] = PLY_FORMATS,
                                   ) -> tuple[np.ndarray, list[str]]:
    """The vertex element of a PLY file as a structured array (one field per property), and the header's
    ``comment`` lines (without the keyword, in order).

    Args:
        path: the PLY file.
        formats: accepted PLY formats.

    Raises:
        OSError: the file cannot be read (FileNotFoundError when missing).
        PlyError: not a PLY, a format outside ``formats``, no leading vertex element, list or unknown vertex
            properties, or truncated / malformed vertex data.
    """
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b'end_header')
    if not raw.startswith(b'ply') or end < 0:
        raise PlyError(f'{path}: not a PLY file (no "ply" magic / end_header)')
    body = raw[raw.find(b'\n', end) + 1:]
    fmt, count, props, seen_element, comments = None, None, [], False, []
    for line in raw[:end].decode('ascii', errors='replace').splitlines():
        words = line.split()
        if words[:1] == ['comment']:
            comments.append(line[len('comment'):].strip())
        elif words[:1] == ['format']:
            fmt = words[1]
        elif words[:1] == ['element']:
            if not seen_element and words[1] != 'vertex':
                raise PlyError(f'{path}: the first PLY element must be "vertex", got {words[1]!r}')
            seen_element = True
            if words[1] != 'vertex':
                break
            count = int(words[2])
        elif words[:1] == ['property'] and count is not None:
            if words[1] == 'list' or words[1] not in _PLY_TYPES:
                raise PlyError(f'{path}: unsupported vertex property {" ".join(words[1:])!r}')
            props.append((words[2], _PLY_TYPES[words[1]]))
    if fmt not in formats:
        raise PlyError(f'{path}: PLY format {fmt!r} not supported (only {" or ".join(formats)} PLY is supported)')
    if count is None:
        raise PlyError(f'{path}: no vertex element')
    order = '>' if fmt == 'binary_big_endian' else '<'
    dtype = np.dtype([(name, order + code) for name, code in props])
    if fmt == 'ascii':
        if count == 0:
            return np.zeros(0, dtype), comments
        try:
            table = np.loadtxt(io.BytesIO(body), dtype=np.float64, max_rows=count, ndmin=2)
        except ValueError as err:
            raise PlyError(f'{path}: malformed ASCII vertex data: {err}') from err
        if table.shape != (count, len(props)):
            raise PlyError(f'{path}: truncated ({len(table)} of {count} vertices)')
        return recfunctions.unstructured_to_structured(table, dtype), comments
    if len(body) < count * dtype.itemsize:
        raise PlyError(f'{path}: truncated ({len(body)} bytes for {count} vertices of {dtype.itemsize})')
    return np.frombuffer(body, dtype, count=count), comments
