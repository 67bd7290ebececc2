"""Deterministic writers of the synthetic dataset's own files: gt_fruits.json and sparse_pc.ply.

JSON with sorted keys and rounded floats, so the same scene gives byte-identical files (the PNGs come from
``core/data/png_io.py``, equally deterministic).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fruitnerfpp_ros.core.data.ply_io import write_ply_vertices
from fruitnerfpp_ros.core.synthetic.scene import GtFruit

__all__ = ['write_gt_fruits', 'write_sparse_ply', 'GT_NAME', 'SPARSE_PLY_NAME']

GT_NAME = 'gt_fruits.json'
SPARSE_PLY_NAME = 'sparse_pc.ply'


def _round(values: Any, digits: int = 6) -> list[float]:
    return [round(float(v), digits) for v in np.asarray(values).reshape(-1)]


def write_gt_fruits(path: Path, fruits: Sequence[GtFruit], visible: np.ndarray,
                    extra: dict[str, Any] | None = None) -> None:
    """Write ``gt_fruits.json``: ``{"fruits": [{"id", "type", "center", "radii", "diameter", "rotation",
    "views_visible", "n_views_visible"(, "tree_id")}...], ...extra}``; metres, world frame (z up, ground z = 0);
    ``tree_id`` only for fruits of a row of trees (``GtFruit.tree_id`` set).

    Args:
        path: the file to write.
        fruits: ground truth ordered by id.
        visible: [V, N] bool, view v shows at least one pixel of fruit n (all views: the generator knows no
            training split). ``views_visible`` lists the view indices, ``n_views_visible`` counts them.
        extra: other top-level keys.
    """
    records = []
    for fruit, seen_by in zip(fruits, np.asarray(visible, dtype=bool).T):
        views = np.flatnonzero(seen_by)
        records.append({
            'id': int(fruit.id),
            'type': fruit.type,
            'center': _round(fruit.center),
            'radii': _round(fruit.radii),
            'diameter': round(float(2.0 * max(fruit.radii[0], fruit.radii[1])), 6),
            'rotation': [_round(row) for row in fruit.rotation],
            'views_visible': [int(v) for v in views],
            'n_views_visible': len(views),
        })
        if fruit.tree_id is not None:
            records[-1]['tree_id'] = int(fruit.tree_id)
    data: dict[str, Any] = dict(extra or {})
    data['fruits'] = records
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + '\n')


def write_sparse_ply(path: Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Write a binary little-endian PLY of points [N, 3] (metres, float32) with colours [N, 3] uint8."""
    vertex = np.zeros(len(points), dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'),
                                          ('red', 'u1'), ('green', 'u1'), ('blue', 'u1')])
    vertex['x'], vertex['y'], vertex['z'] = points[:, 0], points[:, 1], points[:, 2]
    vertex['red'], vertex['green'], vertex['blue'] = colors[:, 0], colors[:, 1], colors[:, 2]
    write_ply_vertices(path, vertex)
