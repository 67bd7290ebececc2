"""WGS84 geodesy and the world <-> WGS84 relation: round trips, a fit to noisy fixes, outliers, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from fruitnerfpp_ros.core.orchard.geodesy import (Datum, ecef_from_geodetic, enu_from_geodetic, geodetic_from_ecef,
                                                  geodetic_from_enu)
from fruitnerfpp_ros.core.orchard.georef import estimate_georef, georef_from_datum, parse_datum
from fruitnerfpp_ros.core.orchard.gnss import GnssFix, antenna_positions
from fruitnerfpp_ros.errors import OrchardError

DATUM = Datum(49.5732, 11.0275, 290.0)


def test_ecef_of_known_points() -> None:
    assert np.allclose(ecef_from_geodetic(0.0, 0.0, 0.0), [6378137.0, 0.0, 0.0])
    assert np.allclose(ecef_from_geodetic(90.0, 0.0, 0.0), [0.0, 0.0, 6356752.314245], atol=1e-3)
    back = geodetic_from_ecef(ecef_from_geodetic(np.array([49.5, -33.9]), np.array([11.0, 151.2]),
                                                 np.array([300.0, -20.0])))
    assert np.allclose(back, [[49.5, 11.0, 300.0], [-33.9, 151.2, -20.0]], atol=1e-9)


def test_enu_round_trip_and_scale() -> None:
    rng = np.random.default_rng(0)
    enu = rng.uniform(-500, 500, (50, 3))
    assert np.abs(enu_from_geodetic(geodetic_from_enu(enu, DATUM), DATUM) - enu).max() < 1e-4
    north = geodetic_from_enu(np.array([[0.0, 1000.0, 0.0]]), DATUM)[0]
    assert 0.0089 < north[0] - DATUM.latitude_deg < 0.0091   # ~ 1 km per 0.009 degrees of latitude


def _drive(yaw_deg: float, t: np.ndarray, noise: float, seed: int = 0) -> tuple[np.ndarray, list[GnssFix]]:
    rng = np.random.default_rng(seed)
    world = np.c_[np.linspace(-5, 5, 40), np.where(np.arange(40) < 20, -1.2, 1.2), np.full(40, 1.0)]
    truth = georef_from_datum(DATUM, yaw_deg)
    geo = geodetic_from_enu(truth.enu_of(world) + t + rng.normal(scale=noise, size=world.shape), truth.enu_datum)
    cov = (noise ** 2, 0, 0, 0, noise ** 2, 0, 0, 0, noise ** 2)
    return world, [GnssFix(i, *g, cov, 2) for i, g in enumerate(geo)]


def test_fit_recovers_yaw_and_origin_with_its_residual() -> None:
    world, fixes = _drive(30.0, np.zeros(3), 0.02)
    fit = estimate_georef(world, fixes)
    assert fit.source == 'gnss' and fit.n_fixes == 40 and fit.n_rejected == 0
    assert abs(np.degrees(fit.yaw_rad) - 30.0) < 0.5
    assert 0.01 < fit.residual_rms_m < 0.04
    truth = georef_from_datum(DATUM, 30.0)
    probe = np.array([[3.0, 0.5, 1.0], [-4.0, -0.2, 0.0]])
    err = enu_from_geodetic(fit.geodetic_of(probe), DATUM) - truth.enu_of(probe)
    assert np.abs(err[:, :2]).max() < 0.05
    assert np.abs(fit.world_of(fit.geodetic_of(probe)) - probe).max() < 1e-6


def test_outlier_fixes_are_dropped() -> None:
    world, fixes = _drive(-100.0, np.zeros(3), 0.02, seed=1)
    for i in (3, 17, 30):  # multipath jumps of metres
        fixes[i] = fixes[i]._replace(latitude_deg=fixes[i].latitude_deg + 3e-5)
    fit = estimate_georef(world, fixes)
    assert fit.n_rejected == 3 and fit.residual_rms_m < 0.05
    assert abs(np.degrees(fit.yaw_rad) + 100.0) < 0.5


def test_bad_fixes_and_datums_are_errors() -> None:
    world, fixes = _drive(0.0, np.zeros(3), 0.02)
    with pytest.raises(OrchardError, match='usable GNSS'):
        estimate_georef(world[:2], fixes[:2])
    with pytest.raises(OrchardError, match='span only'):
        estimate_georef(np.zeros((5, 3)), [fixes[0]] * 5)
    no_fix = [f._replace(status=-1) for f in fixes]
    with pytest.raises(OrchardError, match='usable'):
        estimate_georef(world, no_fix)
    assert parse_datum('49.5 11.0 300 45')[1] == 45.0
    with pytest.raises(OrchardError, match='3 or 4'):
        parse_datum('49.5 11.0')
    with pytest.raises(OrchardError, match='latitude'):
        parse_datum([95.0, 0.0, 0.0])


def test_antenna_positions_interpolate_and_skip_gaps() -> None:
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, 0, 3] = [0.0, 1.0, 2.0, 10.0]
    stamps = [0, 1_000_000_000, 2_000_000_000, 10_000_000_000]
    pos, valid = antenna_positions(stamps, T, [500_000_000, 1_500_000_000, 5_000_000_000, 11_000_000_000],
                                   np.array([0.0, -0.5, 0.0]), max_gap_s=1.0)
    assert valid.tolist() == [True, True, False, False]
    # OpenGL identity pose: the optical frame's y points down in the world, so -0.5 in optical y is +0.5 m up
    assert np.allclose(pos[:2], [[0.5, 0.5, 0.0], [1.5, 0.5, 0.0]])
