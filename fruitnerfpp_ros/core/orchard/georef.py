"""The relation between the robot's world frame and WGS84, given (a datum) or estimated from GNSS fixes.

The world frame (``map`` / ``odom``: z up, metres) and a local East-North-Up plane (:mod:`.geodesy`) differ by a
yaw about the vertical and a translation, as robot_localization's navsat_transform models them:
``enu = R(yaw) @ world_xy + t_xy``, ``up = world_z + t_z``. Given a datum (the geodetic position of the world
origin and the heading of the world x axis) the relation is exact; otherwise it is the weighted least-squares fit
(2D Kabsch / Umeyama without scale, weights 1 / sigma^2 from each fix's covariance) of the antenna's world
positions at the fixes' stamps onto the fixes, with outliers beyond ``outlier_sigma`` robust standard
deviations dropped once. Its residual (RMS, horizontal and vertical) says how well the drive and the fixes agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from fruitnerfpp_ros.core.orchard.geodesy import Datum, enu_from_geodetic, geodetic_from_enu
from fruitnerfpp_ros.core.orchard.config import GeoConfig
from fruitnerfpp_ros.core.orchard.gnss import STATUS_NO_FIX, GnssFix, antenna_positions
from fruitnerfpp_ros.errors import OrchardError

__all__ = ['WorldGeoref', 'georef_from_datum', 'estimate_georef', 'fit_georef_to_drive', 'parse_datum']


@dataclass(frozen=True)
class WorldGeoref:
    """World frame <-> WGS84.

    Attributes:
        enu_datum: geodetic origin of the local ENU plane.
        yaw_rad: heading of the world x axis, counter-clockwise from east, radians.
        t_enu: [3] world origin in the ENU plane, metres.
        source: ``datum`` (given) or ``gnss`` (estimated from fixes).
        n_fixes: fixes the estimate used (0 for a given datum).
        n_rejected: fixes dropped as outliers.
        residual_rms_m: RMS horizontal distance between the fitted antenna positions and the fixes, metres.
        residual_vertical_rms_m: the same, vertical.
        span_m: largest horizontal distance between two fixes used (a short span gives an uncertain yaw).
    """

    enu_datum: Datum
    yaw_rad: float
    t_enu: np.ndarray
    source: str
    n_fixes: int = 0
    n_rejected: int = 0
    residual_rms_m: float | None = None
    residual_vertical_rms_m: float | None = None
    span_m: float | None = None

    def _R(self) -> np.ndarray:
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def enu_of(self, world: np.ndarray) -> np.ndarray:
        """[N, 3] ENU (m) of world points [N, 3]."""
        return np.asarray(world, np.float64).reshape(-1, 3) @ self._R().T + self.t_enu

    def world_of_enu(self, enu: np.ndarray) -> np.ndarray:
        """[N, 3] world points of ENU points [N, 3]."""
        return (np.asarray(enu, np.float64).reshape(-1, 3) - self.t_enu) @ self._R()

    def geodetic_of(self, world: np.ndarray) -> np.ndarray:
        """[N, 3] (latitude deg, longitude deg, ellipsoidal height m) of world points [N, 3]."""
        return geodetic_from_enu(self.enu_of(world), self.enu_datum)

    def world_of(self, geodetic: np.ndarray) -> np.ndarray:
        """[N, 3] world points of geodetic positions [N, 3] (lat deg, lon deg, height m)."""
        return self.world_of_enu(enu_from_geodetic(geodetic, self.enu_datum))

    @property
    def world_origin(self) -> Datum:
        """Geodetic position of the world origin (navsat_transform's ``datum``)."""
        lat, lon, alt = self.geodetic_of(np.zeros((1, 3)))[0]
        return Datum(float(lat), float(lon), float(alt))

    def to_json(self) -> dict[str, Any]:
        origin = self.world_origin
        return {'source': self.source, 'datum': {'latitude': round(origin.latitude_deg, 9),
                                                 'longitude': round(origin.longitude_deg, 9),
                                                 'altitude': round(origin.altitude_m, 4)},
                'yaw_deg': round(float(np.degrees(self.yaw_rad)), 5), 'n_fixes': self.n_fixes,
                'n_rejected': self.n_rejected,
                'residual_rms_m': None if self.residual_rms_m is None else round(self.residual_rms_m, 4),
                'residual_vertical_rms_m': None if self.residual_vertical_rms_m is None
                else round(self.residual_vertical_rms_m, 4),
                'span_m': None if self.span_m is None else round(self.span_m, 3)}


def parse_datum(text: str | Sequence[float]) -> tuple[Datum, float]:
    """('lat lon alt [yaw_deg]' or a sequence of 3-4 numbers) -> (datum of the world origin, yaw in degrees).

    Raises:
        OrchardError: not 3 or 4 numbers, or out of range.
    """
    try:
        values = [float(v) for v in (text.replace(',', ' ').split() if isinstance(text, str) else text)]
    except (TypeError, ValueError) as err:
        raise OrchardError(f"datum: expected 'latitude longitude altitude [yaw_deg]', got {text!r}") from err
    if len(values) not in (3, 4):
        raise OrchardError(f"datum: expected 'latitude longitude altitude [yaw_deg]' (3 or 4 numbers), got {text!r}")
    return Datum(*values[:3]).checked(), values[3] if len(values) == 4 else 0.0


def georef_from_datum(datum: Datum, yaw_deg: float = 0.0) -> WorldGeoref:
    """The relation of a world frame whose origin is at ``datum`` and whose x axis heads ``yaw_deg`` (counter-
    clockwise from east)."""
    return WorldGeoref(datum.checked(), float(np.radians(yaw_deg)), np.zeros(3), 'datum')


def _fit(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted 2D rotation + 3D translation taking world points p [N, 3] onto ENU points q [N, 3]."""
    w = w / w.sum()
    pc, qc = w @ p, w @ q
    H = ((p - pc)[:, :2] * w[:, None]).T @ (q - qc)[:, :2]
    yaw = float(np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return yaw, qc - R @ pc


def estimate_georef(world: np.ndarray, fixes: Sequence[GnssFix], *, outlier_sigma: float = 3.0,
                    min_span_m: float = 2.0) -> WorldGeoref:
    """Fit the world -> ENU relation to fixes and the antenna's world positions at their stamps.

    Args:
        world: [N, 3] antenna world positions at the fixes' stamps (:func:`~.gnss.antenna_positions`).
        fixes: the N fixes (those without a fix status are left out).
        outlier_sigma: after a first fit, fixes further than this many robust standard deviations (1.4826 x the
            median residual) from the fit are dropped and the fit repeated.
        min_span_m: the fixes used must spread at least this far horizontally (else the yaw is unknown).

    Raises:
        OrchardError: fewer than 3 usable fixes or too short a span.
    """
    world = np.asarray(world, np.float64).reshape(-1, 3)
    finite = [bool(np.isfinite([f.latitude_deg, f.longitude_deg, f.altitude_m]).all()) for f in fixes]
    usable = np.array([f.status != STATUS_NO_FIX and ok for f, ok in zip(fixes, finite)], bool)
    if len(fixes) != len(world):
        raise OrchardError(f'{len(world)} antenna positions for {len(fixes)} fixes')
    world, fixes = world[usable], [f for f, u in zip(fixes, usable) if u]
    if len(fixes) < 3:
        raise OrchardError(f'only {len(fixes)} usable GNSS fix(es) during the keyframes; need at least 3 (or give '
                           'a datum)')
    geo = np.array([[f.latitude_deg, f.longitude_deg, f.altitude_m] for f in fixes])
    datum = Datum(*np.median(geo, axis=0))
    q = enu_from_geodetic(geo, datum)
    sigma = np.array([f.horizontal_sigma_m() for f in fixes])
    w = 1.0 / np.maximum(sigma, 1e-3) ** 2
    span = float(np.ptp(q[:, :2], axis=0).max()) if len(q) else 0.0
    if span < min_span_m:
        raise OrchardError(f'the GNSS fixes span only {span:.2f} m (< {min_span_m:g} m): the heading of the world '
                           'frame cannot be estimated; drive further or give a datum')
    keep = np.ones(len(q), bool)
    for attempt in range(3):  # fit, drop outliers, fit again (at most twice)
        yaw, t = _fit(world[keep], q[keep], w[keep])
        c, s = np.cos(yaw), np.sin(yaw)
        fitted = world @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + t
        horizontal = np.linalg.norm(fitted[:, :2] - q[:, :2], axis=1)
        robust = 1.4826 * float(np.median(horizontal[keep])) + 1e-6
        new_keep = horizontal <= max(outlier_sigma * robust, 3.0 * float(np.median(sigma)))
        if attempt == 2 or new_keep.sum() < 3 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    residual = float(np.sqrt(np.mean(horizontal[keep] ** 2)))
    vertical = float(np.sqrt(np.mean((fitted[keep, 2] - q[keep, 2]) ** 2)))
    return WorldGeoref(datum, yaw, t, 'gnss', int(keep.sum()), int((~keep).sum()), residual, vertical, span)


def fit_georef_to_drive(stamps_ns: Sequence[int], T_world_camera: np.ndarray, fixes: Sequence[GnssFix],
                        geo: GeoConfig, antenna: np.ndarray | None = None) -> WorldGeoref:
    """:func:`estimate_georef` of the fixes against the antenna positions of a drive's camera poses [N, 4, 4] at
    ``stamps_ns``; the antenna offset is ``geo.antenna_in_camera_m``, else ``antenna``, else the camera centre.

    Raises:
        OrchardError: too few fixes matched to the drive, or a fit that fails (see :func:`estimate_georef`).
    """
    offset = np.asarray(geo.antenna_in_camera_m) if geo.antenna_in_camera_m is not None else antenna
    world, valid = antenna_positions(stamps_ns, T_world_camera, [f.stamp_ns for f in fixes], offset,
                                     max_gap_s=geo.max_gap_s)
    return estimate_georef(world[valid], [f for f, v in zip(fixes, valid) if v], outlier_sigma=geo.outlier_sigma)
