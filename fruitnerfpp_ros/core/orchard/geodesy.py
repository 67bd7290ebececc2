"""WGS84 geodesy: geodetic (latitude, longitude, ellipsoidal height) <-> ECEF <-> a local East-North-Up plane.

All functions are vectorised over points ([N] or [N, 3] arrays), degrees and metres. The local tangent plane
(ENU) is the one robot_localization's navsat_transform and GeographicLib's ``LocalCartesian`` use: origin at a
datum on the ellipsoid, x east, y north, z up along the ellipsoid normal. Over a few hundred metres a point is
converted back and forth to well under a millimetre.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fruitnerfpp_ros.errors import OrchardError

__all__ = ['Datum', 'WGS84_A', 'WGS84_F', 'ecef_from_geodetic', 'geodetic_from_ecef', 'enu_from_geodetic',
           'geodetic_from_enu']

#: WGS84 semi-major axis (m) and flattening.
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
_E2 = WGS84_F * (2.0 - WGS84_F)            # first eccentricity squared
_B = WGS84_A * (1.0 - WGS84_F)             # semi-minor axis
_EP2 = (WGS84_A ** 2 - _B ** 2) / _B ** 2  # second eccentricity squared


class Datum(NamedTuple):
    """A geodetic position on WGS84.

    Attributes:
        latitude_deg: latitude, degrees north (-90..90).
        longitude_deg: longitude, degrees east (-180..180).
        altitude_m: height above the WGS84 ellipsoid, metres (what ``sensor_msgs/NavSatFix.altitude`` holds).
    """

    latitude_deg: float
    longitude_deg: float
    altitude_m: float

    def checked(self) -> 'Datum':
        """This datum, or :class:`OrchardError` when a value is out of range or not finite."""
        lat, lon, alt = (float(v) for v in self)
        if not (np.isfinite([lat, lon, alt]).all() and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0
                and -12000.0 < alt < 100000.0):
            raise OrchardError(f'datum must be latitude -90..90, longitude -180..180 (degrees) and a height in '
                               f'metres, got {tuple(self)}')
        return Datum(lat, lon, alt)


def ecef_from_geodetic(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray) -> np.ndarray:
    """[N, 3] Earth-centred Earth-fixed coordinates (m) of geodetic positions."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    alt = np.asarray(alt_m, np.float64)
    n = WGS84_A / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
    return np.stack([(n + alt) * np.cos(lat) * np.cos(lon), (n + alt) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - _E2) + alt) * np.sin(lat)], axis=-1)


def geodetic_from_ecef(xyz: np.ndarray) -> np.ndarray:
    """[N, 3] (latitude deg, longitude deg, height m) of ECEF points [N, 3] (Bowring's method, two iterations:
    sub-millimetre anywhere near the Earth's surface)."""
    xyz = np.asarray(xyz, np.float64)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z * WGS84_A, p * _B)
    for _ in range(2):
        lat = np.arctan2(z + _EP2 * _B * np.sin(beta) ** 3, p - _E2 * WGS84_A * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
    n = WGS84_A / np.sqrt(1.0 - _E2 * np.sin(lat) ** 2)
    alt = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.maximum(np.cos(lat), 1e-12) - n,
                   np.abs(z) / np.maximum(np.abs(np.sin(lat)), 1e-12) - n * (1.0 - _E2))
    return np.stack([np.degrees(lat), np.degrees(lon), alt], axis=-1)


def _enu_rotation(datum: Datum) -> np.ndarray:
    """[3, 3] rotation whose rows are the east, north and up unit vectors at ``datum`` in ECEF."""
    lat, lon = np.radians(datum.latitude_deg), np.radians(datum.longitude_deg)
    return np.array([[-np.sin(lon), np.cos(lon), 0.0],
                     [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                     [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])


def enu_from_geodetic(geodetic: np.ndarray, datum: Datum) -> np.ndarray:
    """[N, 3] east, north, up (m) of geodetic positions [N, 3] (lat deg, lon deg, height m) around ``datum``."""
    g = np.asarray(geodetic, np.float64).reshape(-1, 3)
    origin = ecef_from_geodetic(*datum)
    return (ecef_from_geodetic(g[:, 0], g[:, 1], g[:, 2]) - origin) @ _enu_rotation(datum).T


def geodetic_from_enu(enu: np.ndarray, datum: Datum) -> np.ndarray:
    """[N, 3] (lat deg, lon deg, height m) of local east, north, up points [N, 3] (m) around ``datum``."""
    e = np.asarray(enu, np.float64).reshape(-1, 3)
    return geodetic_from_ecef(ecef_from_geodetic(*datum) + e @ _enu_rotation(datum))
