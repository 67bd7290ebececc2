"""GNSS fixes: the record, ``gnss.json`` beside a dataset, ``sensor_msgs/NavSatFix`` in a bag, and the antenna's
world position at a fix's stamp (from the keyframes' camera poses).

``gnss.json``::

    {"fixes": [{"stamp_ns", "latitude", "longitude", "altitude", "covariance": [9] | null, "status"}],
     "antenna_in_camera_m": [x, y, z] | null}

``antenna_in_camera_m``: where the antenna sits in the camera's optical frame (REP-103: z forward, x right,
y down), metres; the world position of a fix is the camera pose at its stamp applied to it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable, NamedTuple, Sequence

import numpy as np

from fruitnerfpp_ros.core.atomic_io import atomic_write_text
from fruitnerfpp_ros.core.geometry import T_OPENGL_OPTICAL
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['GnssFix', 'GNSS_JSON', 'NAVSAT_TYPE', 'write_gnss_json', 'read_gnss_json', 'fixes_from_bag',
           'antenna_positions', 'STATUS_NO_FIX']

GNSS_JSON = 'gnss.json'
NAVSAT_TYPE = 'sensor_msgs/msg/NavSatFix'
#: ``NavSatStatus.status`` of a receiver without a fix (such fixes are never used).
STATUS_NO_FIX = -1


class GnssFix(NamedTuple):
    """One GNSS fix.

    Attributes:
        stamp_ns: header stamp, nanoseconds.
        latitude_deg / longitude_deg: WGS84 degrees.
        altitude_m: height above the WGS84 ellipsoid, metres.
        covariance: 9 values of the ENU position covariance (m^2, row-major), or None when unknown.
        status: ``NavSatStatus.status`` (-1 no fix, 0 fix, 1 SBAS, 2 GBAS / RTK).
    """

    stamp_ns: int
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    covariance: tuple[float, ...] | None = None
    status: int = 0

    def horizontal_sigma_m(self, default: float = 1.0) -> float:
        """Horizontal standard deviation (m) from the covariance (mean of east and north), else ``default``."""
        if self.covariance is None or len(self.covariance) != 9:
            return default
        var = 0.5 * (self.covariance[0] + self.covariance[4])
        return float(np.sqrt(var)) if np.isfinite(var) and var > 0 else default


def write_gnss_json(path: str | Path, fixes: Sequence[GnssFix], antenna_in_camera_m: Sequence[float] | None) -> Path:
    """Write ``gnss.json`` (deterministic: fixed key order and rounding)."""
    records = [{'stamp_ns': int(f.stamp_ns), 'latitude': round(float(f.latitude_deg), 10),
                'longitude': round(float(f.longitude_deg), 10), 'altitude': round(float(f.altitude_m), 4),
                'covariance': None if f.covariance is None else [round(float(v), 8) for v in f.covariance],
                'status': int(f.status)} for f in fixes]
    antenna = None if antenna_in_camera_m is None else [round(float(v), 6) for v in antenna_in_camera_m]
    return atomic_write_text(Path(path), json.dumps({'fixes': records, 'antenna_in_camera_m': antenna}, indent=1,
                                                    sort_keys=True) + '\n')


def read_gnss_json(path: str | Path) -> tuple[list[GnssFix], np.ndarray | None]:
    """(fixes, antenna position in the camera optical frame [3] or None) of a ``gnss.json``.

    Raises:
        OrchardError: missing or malformed file.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        fixes = [GnssFix(int(r['stamp_ns']), float(r['latitude']), float(r['longitude']), float(r['altitude']),
                         None if r.get('covariance') is None else tuple(float(v) for v in r['covariance']),
                         int(r.get('status', 0))) for r in data['fixes']]
        antenna = data.get('antenna_in_camera_m')
    except FileNotFoundError as err:
        raise OrchardError(f'{path}: no such GNSS file') from err
    except (ValueError, KeyError, TypeError) as err:
        raise OrchardError(f'{path}: not a gnss.json ({type(err).__name__}: {err})') from err
    return fixes, None if antenna is None else np.asarray(antenna, np.float64).reshape(3)


def fixes_from_bag(bag_path: str | Path, topic: str) -> list[GnssFix]:
    """Every ``sensor_msgs/NavSatFix`` of ``topic`` in a rosbag2 (a damaged bag is read as far as it goes).

    Raises:
        OrchardError: the bag has no such topic, or it is not NavSatFix.
        BagError: the bag cannot be read at all.
    """
    from rosbags.typesys import Stores, get_typestore

    from fruitnerfpp_ros.core.bags import open_bag

    source = open_bag(bag_path)
    try:
        types = {t.topic: t.msgtype for t in source.topics}
        if topic not in types:
            raise OrchardError(f'{bag_path}: no GNSS topic {topic}; topics in the bag: {", ".join(sorted(types))}')
        if types[topic] != NAVSAT_TYPE:
            raise OrchardError(f'{bag_path}: {topic} is {types[topic]}, expected {NAVSAT_TYPE}')
        typestore = get_typestore(Stores.ROS2_JAZZY)
        fixes = []
        for message in source.messages({topic}):
            msg = typestore.deserialize_cdr(message.data, message.msgtype)
            stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            known = int(msg.position_covariance_type) > 0
            fixes.append(GnssFix(stamp, float(msg.latitude), float(msg.longitude), float(msg.altitude),
                                 tuple(float(v) for v in msg.position_covariance) if known else None,
                                 int(msg.status.status)))
    finally:
        source.close()
    return fixes


def antenna_positions(stamps_ns: Iterable[int], T_world_camera: np.ndarray, fix_stamps_ns: Iterable[int],
                      antenna_in_camera_m: np.ndarray | None = None, *, max_gap_s: float = 1.0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """World position of the GNSS antenna at each fix stamp, interpolated between the keyframes around it.

    Args:
        stamps_ns: [F] keyframe stamps.
        T_world_camera: [F, 4, 4] camera-to-world poses (OpenGL axes, transforms.json).
        fix_stamps_ns: [N] fix stamps.
        antenna_in_camera_m: [3] antenna in the camera optical frame (None: at the camera).
        max_gap_s: a fix between keyframes further apart than this (a turn, a pause in collection) is not used.

    Returns:
        ([N, 3] positions in metres, [N] bool: the fix lies between two keyframes close enough in time).
    """
    stamps = np.asarray(list(stamps_ns), np.int64)
    fix = np.asarray(list(fix_stamps_ns), np.int64)
    if len(stamps) < 2 or len(fix) == 0:
        return np.zeros((len(fix), 3)), np.zeros(len(fix), bool)
    order = np.argsort(stamps, kind='stable')
    stamps, T = stamps[order], np.asarray(T_world_camera, np.float64)[order] @ T_OPENGL_OPTICAL
    offset = np.zeros(3) if antenna_in_camera_m is None else np.asarray(antenna_in_camera_m, np.float64)
    points = T[:, :3, 3] + np.einsum('fij,j->fi', T[:, :3, :3], offset)
    hi = np.clip(np.searchsorted(stamps, fix, side='right'), 1, len(stamps) - 1)
    lo = hi - 1
    gap = (stamps[hi] - stamps[lo]).astype(np.float64)
    w = np.clip((fix - stamps[lo]) / np.maximum(gap, 1.0), 0.0, 1.0)
    positions = (1.0 - w)[:, None] * points[lo] + w[:, None] * points[hi]
    valid = (fix >= stamps[0]) & (fix <= stamps[-1]) & (gap <= max_gap_s * 1e9)
    return positions, valid
