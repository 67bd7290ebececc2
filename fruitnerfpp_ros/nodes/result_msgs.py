"""ROS messages of the count's results: the fruit cloud (``PointCloud2``), centres (``PoseArray``), markers
(``MarkerArray``) and the report JSON (``std_msgs/String``); and reading a ``PointCloud2`` back.

Pure functions, no ROS graph; conventions as in :mod:`fruitnerfpp_ros.nodes.conversions`.
"""

from __future__ import annotations

import json
from typing import Any, Sequence

import numpy as np

from fruitnerfpp_ros.core.clustering.count_result import CountResult, Fruit
from fruitnerfpp_ros.core.export.point_cloud import FruitPointCloud
from fruitnerfpp_ros.errors import ConversionError
from fruitnerfpp_ros.nodes.conversions import bytes_of, header_msg, pose_msg_from_transform

__all__ = ['REPORT_SCHEMA', 'REPORT_VERSION', 'CLOUD_DTYPE', 'cloud_msg_from_points', 'points_from_cloud_msg',
           'pose_array_from_centers', 'markers_from_fruits', 'report_from_count', 'report_json']

#: Identifies the JSON published on ``~/fruit_report`` and written to ``fruit_report.json``.
REPORT_SCHEMA = 'fruitnerfpp_ros/fruit_report'
#: Bumped whenever a key of the report changes meaning or disappears (adding keys keeps the version).
REPORT_VERSION = 1

#: Point layout of ``~/fruit_cloud``: x, y, z float32; rgb packed 0x00RRGGBB (uint32 read as FLOAT32, as RViz and
#: PCL expect); instance_id uint32 (cluster id, 0 = noise); semantic float32 fruit probability.
CLOUD_DTYPE = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', '<u4'), ('instance_id', '<u4'),
                        ('semantic', '<f4')])


def cloud_msg_from_points(cloud: FruitPointCloud, labels: np.ndarray | None, frame_id: str, stamp_ns: int) -> Any:
    """``sensor_msgs/PointCloud2`` of a fruit cloud with per-point cluster ids (fields: see ``CLOUD_DTYPE``)."""
    from sensor_msgs.msg import PointCloud2, PointField
    n = len(cloud)
    points = np.zeros(n, dtype=CLOUD_DTYPE)
    xyz = np.asarray(cloud.xyz, dtype=np.float32).reshape(n, 3)
    points['x'], points['y'], points['z'] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb = np.asarray(cloud.rgb, dtype=np.uint32).reshape(n, 3)
    points['rgb'] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    points['instance_id'] = 0 if labels is None else np.asarray(labels).astype(np.uint32)
    points['semantic'] = np.asarray(cloud.semantic, dtype=np.float32)
    types = {'x': PointField.FLOAT32, 'y': PointField.FLOAT32, 'z': PointField.FLOAT32, 'rgb': PointField.FLOAT32,
             'instance_id': PointField.UINT32, 'semantic': PointField.FLOAT32}
    fields = [PointField(name=name, offset=CLOUD_DTYPE.fields[name][1], datatype=types[name], count=1)
              for name in CLOUD_DTYPE.names]
    return PointCloud2(header=header_msg(frame_id, stamp_ns), height=1, width=n, fields=fields, is_bigendian=False,
                       point_step=CLOUD_DTYPE.itemsize, row_step=CLOUD_DTYPE.itemsize * n, is_dense=True,
                       data=points.tobytes())


_POINT_FIELD_DTYPES = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}


def points_from_cloud_msg(msg: Any) -> np.ndarray:
    """Structured numpy array (one record per point, one field per PointField) of a ``PointCloud2``.

    Raises:
        ConversionError: a field datatype outside the PointField constants, or too little data.
    """
    endian = '>' if msg.is_bigendian else '<'
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if int(f.datatype) not in _POINT_FIELD_DTYPES:
            raise ConversionError(f'PointCloud2 field {f.name!r}: unknown datatype {f.datatype}')
        names.append(str(f.name))
        formats.append(endian + _POINT_FIELD_DTYPES[int(f.datatype)])
        offsets.append(int(f.offset))
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': int(msg.point_step)})
    n = int(msg.width) * int(msg.height)
    raw = bytes_of(msg.data)
    if raw.size < n * int(msg.point_step):
        raise ConversionError(f'PointCloud2: {raw.size} bytes for {n} points of {msg.point_step} bytes')
    return np.frombuffer(raw[:n * int(msg.point_step)].tobytes(), dtype=dtype)


def pose_array_from_centers(centers: np.ndarray, frame_id: str, stamp_ns: int) -> Any:
    """``geometry_msgs/PoseArray`` with one identity-oriented pose per fruit centre ([N, 3], metres)."""
    from geometry_msgs.msg import Point, Pose, PoseArray, Quaternion
    poses = [Pose(position=Point(x=float(c[0]), y=float(c[1]), z=float(c[2])), orientation=Quaternion(w=1.0))
             for c in np.asarray(centers, dtype=float).reshape(-1, 3)]
    return PoseArray(header=header_msg(frame_id, stamp_ns), poses=poses)


def markers_from_fruits(fruits: Sequence[Fruit], frame_id: str, stamp_ns: int) -> Any:
    """``visualization_msgs/MarkerArray``: DELETEALL, then per fruit a sphere (ns ``fruits``, id = fruit id)
    sized by its diameter and a text label (ns ``fruit_labels``) above it."""
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker, MarkerArray
    header = header_msg(frame_id, stamp_ns)
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    for fruit in fruits:
        pose = pose_msg_from_transform(np.eye(4))
        pose.position.x, pose.position.y, pose.position.z = (float(v) for v in fruit.center)
        diameter = float(max(fruit.diameter_m, 1e-3))
        sphere = Marker(header=header, ns='fruits', id=int(fruit.id), type=Marker.SPHERE, action=Marker.ADD,
                        pose=pose, color=ColorRGBA(r=1.0, g=0.3, b=0.1, a=0.8))
        sphere.scale.x = sphere.scale.y = sphere.scale.z = diameter
        label_pose = pose_msg_from_transform(np.eye(4))
        label_pose.position.x, label_pose.position.y = pose.position.x, pose.position.y
        label_pose.position.z = pose.position.z + diameter
        label = Marker(header=header, ns='fruit_labels', id=int(fruit.id), type=Marker.TEXT_VIEW_FACING,
                       action=Marker.ADD, pose=label_pose, text=str(int(fruit.id)),
                       color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0))
        label.scale.z = max(diameter * 0.6, 0.02)
        markers += [sphere, label]
    return MarkerArray(markers=markers)


def report_from_count(count: CountResult, frame_id: str, stamp_ns: int, run_id: str,
                      extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The fruit report (schema ``fruitnerfpp_ros/fruit_report``, version 1).

    Keys: ``schema``, ``version``, ``run_id``, ``stamp`` {``sec``, ``nanosec``}, ``stamp_ns``, ``frame_id``
    (world frame of every coordinate), ``total`` (number of fruits), ``fruits`` (list of {``id`` (as in the
    cloud's instance_id and the markers), ``center`` [x, y, z] m, ``diameter`` m, ``extent`` [3] m,
    ``n_points``}), plus ``extra`` (e.g. ``keyframes``, ``stats``).
    """
    report = {'schema': REPORT_SCHEMA, 'version': REPORT_VERSION, 'run_id': run_id,
              'stamp': {'sec': int(stamp_ns // 1_000_000_000), 'nanosec': int(stamp_ns % 1_000_000_000)},
              'stamp_ns': int(stamp_ns), 'frame_id': frame_id, 'total': int(count.count),
              'fruits': [f.to_json() for f in count.fruits]}
    report.update(extra or {})
    return report


def report_json(count: CountResult, frame_id: str, stamp_ns: int, run_id: str,
                extra: dict[str, Any] | None = None) -> str:
    """:func:`report_from_count` as a JSON string (what ``~/fruit_report`` carries)."""
    return json.dumps(report_from_count(count, frame_id, stamp_ns, run_id, extra), default=_json_default)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
