"""What a row count hands to farm software: ``trees.csv``, ``trees.geojson``, ``fruits.geojson`` and the report JSON.

GeoJSON follows RFC 7946: a FeatureCollection of Point features whose coordinates are ``[longitude, latitude]``
(WGS84 degrees, 8 decimals: about 1 mm) or ``[longitude, latitude, height]`` (ellipsoidal height, m); no ``crs``
member. The report is schema ``fruitnerfpp_ros/fruit_report`` version 2 (docs/ros_interface.md): the version 1 keys
plus ``kind: row``, per fruit its ``tree_id``, ``segment`` and WGS84 position, ``trees``, ``segments``, ``row`` and
``georef``; a fruit's ``id`` numbers the fruit along the whole row, and ``extent`` is gone.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.orchard.merge import RowFruits
from fruitnerfpp_ros.core.orchard.trees import TreeCount

__all__ = ['REPORT_SCHEMA', 'ROW_REPORT_VERSION', 'planting_map_geojson', 'trees_geojson', 'fruits_geojson',
           'trees_csv', 'row_report', 'write_json']

REPORT_SCHEMA = 'fruitnerfpp_ros/fruit_report'
ROW_REPORT_VERSION = 2
_DEG = 8


def _point(geodetic: np.ndarray, with_height: bool) -> dict[str, Any]:
    lat, lon, alt = (float(v) for v in geodetic)
    coordinates = [round(lon, _DEG), round(lat, _DEG)] + ([round(alt, 3)] if with_height else [])
    return {'type': 'Point', 'coordinates': coordinates}


def _collection(features: list[dict[str, Any]]) -> dict[str, Any]:
    return {'type': 'FeatureCollection', 'features': features}


def planting_map_geojson(ids: Sequence[int], geodetic: np.ndarray) -> dict[str, Any]:
    """A planting map: one Point ``[lon, lat]`` per trunk with ``properties.tree_id``."""
    return _collection([{'type': 'Feature', 'id': int(i), 'geometry': _point(g, False),
                         'properties': {'tree_id': int(i)}} for i, g in zip(ids, np.asarray(geodetic))])


def trees_geojson(trees: Sequence[TreeCount], geodetic: np.ndarray, row_id: str) -> dict[str, Any]:
    """``trees.geojson``: one Point ``[lon, lat]`` per tree; properties tree_id, fruit_count, diameter_mean_m,
    diameter_std_m (spread), row, position_along_row_m, complete."""
    return _collection([{
        'type': 'Feature', 'id': int(t.id), 'geometry': _point(g, False),
        'properties': {'tree_id': int(t.id), 'fruit_count': int(t.count),
                       'diameter_mean_m': round(t.diameter_mean_m, 4), 'diameter_std_m': round(t.diameter_std_m, 4),
                       'row': row_id, 'position_along_row_m': round(t.along_m, 3), 'complete': bool(t.complete)}}
        for t, g in zip(trees, np.asarray(geodetic))])


def fruits_geojson(fruits: RowFruits, tree_ids: np.ndarray, geodetic: np.ndarray, row_id: str) -> dict[str, Any]:
    """``fruits.geojson``: one Point ``[lon, lat, height]`` per fruit; properties fruit_id, tree_id, diameter_m,
    row, segment."""
    return _collection([{
        'type': 'Feature', 'id': k + 1, 'geometry': _point(geodetic[k], True),
        'properties': {'fruit_id': k + 1, 'tree_id': int(tree_ids[k]),
                       'diameter_m': round(float(fruits.diameters[k]), 4), 'row': row_id,
                       'segment': int(fruits.segments[k])}} for k in range(len(fruits))])


def trees_csv(trees: Sequence[TreeCount], geodetic: np.ndarray | None, row_id: str) -> str:
    """``trees.csv``: tree_id, row, position_along_row_m, x_m, y_m (world), latitude, longitude (empty without
    georeferencing), fruit_count, diameter_mean_m, diameter_std_m, complete."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['tree_id', 'row', 'position_along_row_m', 'x_m', 'y_m', 'latitude', 'longitude', 'fruit_count',
                     'diameter_mean_m', 'diameter_std_m', 'complete'])
    for k, t in enumerate(trees):
        geo = ['', ''] if geodetic is None else [f'{geodetic[k][0]:.{_DEG}f}', f'{geodetic[k][1]:.{_DEG}f}']
        writer.writerow([t.id, row_id, f'{t.along_m:.3f}', f'{t.position[0]:.3f}', f'{t.position[1]:.3f}', *geo,
                         t.count, f'{t.diameter_mean_m:.4f}', f'{t.diameter_std_m:.4f}', int(t.complete)])
    return out.getvalue()


def row_report(*, run_id: str, frame_id: str, stamp_ns: int, fruits: RowFruits, tree_ids: np.ndarray,
               trees: Sequence[TreeCount], fruit_geodetic: np.ndarray | None, tree_geodetic: np.ndarray | None,
               row: dict[str, Any], segments: list[dict[str, Any]], georef: dict[str, Any] | None,
               extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The row report (schema version 2; see the module docstring and docs/ros_interface.md)."""
    def geo(values: np.ndarray | None, k: int) -> dict[str, Any]:
        if values is None:
            return {}
        return {'latitude': round(float(values[k][0]), _DEG), 'longitude': round(float(values[k][1]), _DEG),
                'altitude': round(float(values[k][2]), 3)}

    fruit_records = [{'id': k + 1, 'center': [round(float(v), 4) for v in fruits.centers[k]],
                      'diameter': round(float(fruits.diameters[k]), 4), 'n_points': int(fruits.n_points[k]),
                      'tree_id': int(tree_ids[k]), 'segment': int(fruits.segments[k]), **geo(fruit_geodetic, k)}
                     for k in range(len(fruits))]
    tree_records = [{'id': int(t.id), 'position': [round(float(v), 4) for v in t.position],
                     'along_row_m': round(t.along_m, 3), 'count': int(t.count),
                     'diameter_mean': round(t.diameter_mean_m, 4), 'diameter_std': round(t.diameter_std_m, 4),
                     'complete': bool(t.complete), **geo(tree_geodetic, k)} for k, t in enumerate(trees)]
    report = {'schema': REPORT_SCHEMA, 'version': ROW_REPORT_VERSION, 'kind': 'row', 'run_id': run_id,
              'stamp': {'sec': int(stamp_ns // 1_000_000_000), 'nanosec': int(stamp_ns % 1_000_000_000)},
              'stamp_ns': int(stamp_ns), 'frame_id': frame_id, 'total': len(fruits), 'fruits': fruit_records,
              'trees': tree_records, 'row': row, 'segments': segments, 'georef': georef}
    report.update(extra or {})
    return report


def write_json(path: str | Path, data: Any) -> Path:
    """Write JSON atomically (indented)."""
    return atomic_write_text(Path(path), json.dumps(data, indent=1) + '\n')
