"""The shared PLY vertex reader/writer: binary round trip, ASCII and big-endian files, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fruitnerfpp_ros.core.data.ply_io import PlyError, read_ply_vertices, write_ply_vertices


def _vertices(n: int) -> np.ndarray:
    v = np.zeros(n, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('red', 'u1'), ('label', '<i4')])
    rng = np.random.default_rng(0)
    v['x'], v['y'], v['z'] = rng.normal(size=(3, n)).astype(np.float32)
    v['red'], v['label'] = rng.integers(0, 255, n), rng.integers(-5, 5, n)
    return v


def test_binary_round_trip_keeps_every_field(tmp_path: Path) -> None:
    v = _vertices(40)
    path = write_ply_vertices(tmp_path / 'a.ply', v, comments=['made by a test'])
    assert b'comment made by a test\n' in path.read_bytes()
    back = read_ply_vertices(path)
    assert back.dtype.names == v.dtype.names
    for name in v.dtype.names:
        np.testing.assert_array_equal(back[name], v[name])


def test_ascii_and_big_endian_give_the_same_vertices(tmp_path: Path) -> None:
    v = _vertices(5)
    props = 'property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty int label\n'
    rows = '\n'.join(' '.join(repr(value) for value in row) for row in v.tolist())
    (tmp_path / 'a.ply').write_text(f'ply\nformat ascii 1.0\nelement vertex 5\n{props}end_header\n{rows}\n')
    (tmp_path / 'b.ply').write_bytes(f'ply\nformat binary_big_endian 1.0\nelement vertex 5\n{props}end_header\n'
                                     .encode() + v.astype(v.dtype.newbyteorder('>')).tobytes())
    for name in ('a.ply', 'b.ply'):
        back = read_ply_vertices(tmp_path / name)
        for field in v.dtype.names:
            np.testing.assert_allclose(back[field].astype(np.float64), v[field].astype(np.float64), rtol=1e-6)


def test_errors_name_the_file(tmp_path: Path) -> None:
    (tmp_path / 'junk.ply').write_bytes(b'hello')
    with pytest.raises(PlyError, match='junk.ply: not a PLY'):
        read_ply_vertices(tmp_path / 'junk.ply')
    (tmp_path / 'face.ply').write_bytes(b'ply\nformat ascii 1.0\nelement face 1\nend_header\n')
    with pytest.raises(PlyError, match='first PLY element must be "vertex"'):
        read_ply_vertices(tmp_path / 'face.ply')
    path = write_ply_vertices(tmp_path / 'cut.ply', _vertices(10))
    path.write_bytes(path.read_bytes()[:-3])
    with pytest.raises(PlyError, match='cut.ply: truncated'):
        read_ply_vertices(path)
    (tmp_path / 'ascii.ply').write_bytes(b'ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n')
    assert len(read_ply_vertices(tmp_path / 'ascii.ply')) == 0
    with pytest.raises(PlyError, match='only binary_little_endian'):
        read_ply_vertices(tmp_path / 'ascii.ply', formats=('binary_little_endian',))
