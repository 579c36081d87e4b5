"""Local ENU, WGS84 and UTM conversions of :mod:`skyrecon.survey.geo`."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.survey.geo import (
    GeoOrigin,
    ecef_from_lla,
    enu_from_lla,
    lla_from_ecef,
    lla_from_enu,
    lla_from_projected,
    projected_from_enu,
    utm_epsg,
)

ZURICH = GeoOrigin(47.3769, 8.5417, 450.0)


def test_ecef_of_known_points():
    # the equator at the prime meridian lies one semi-major axis from the centre
    np.testing.assert_allclose(ecef_from_lla(0.0, 0.0, 0.0)[0], [6378137.0, 0.0, 0.0], atol=1e-6)
    # the north pole: the semi-minor axis
    np.testing.assert_allclose(ecef_from_lla(90.0, 0.0, 0.0)[0, 2], 6356752.314245, atol=1e-5)


def test_lla_round_trip_to_micrometres():
    rng = np.random.default_rng(0)
    lat = rng.uniform(-80, 80, 200)
    lon = rng.uniform(-180, 180, 200)
    alt = rng.uniform(-100, 9000, 200)
    la, lo, al = lla_from_ecef(ecef_from_lla(lat, lon, alt))
    np.testing.assert_allclose(la, lat, atol=1e-10)
    np.testing.assert_allclose(lo, lon, atol=1e-10)
    np.testing.assert_allclose(al, alt, atol=1e-6)


def test_enu_axes_point_east_north_up():
    o = ZURICH
    east = enu_from_lla(o, o.lat_deg, o.lon_deg + 0.001, o.alt_m)[0]
    north = enu_from_lla(o, o.lat_deg + 0.001, o.lon_deg, o.alt_m)[0]
    up = enu_from_lla(o, o.lat_deg, o.lon_deg, o.alt_m + 10.0)[0]
    assert east[0] > 70 and abs(east[1]) < 0.01  # 0.001 deg of longitude at 47 deg is about 75 m
    assert north[1] > 110 and abs(north[0]) < 1e-6  # 0.001 deg of latitude is about 111 m
    np.testing.assert_allclose(up, [0, 0, 10.0], atol=1e-6)


def test_enu_round_trip_keeps_millimetres_kilometres_away():
    rng = np.random.default_rng(1)
    enu = rng.uniform(-3000, 3000, (500, 3))
    lat, lon, alt = lla_from_enu(ZURICH, enu)
    np.testing.assert_allclose(enu_from_lla(ZURICH, lat, lon, alt), enu, atol=1e-6)


def test_utm_zone_codes():
    assert utm_epsg(47.37, 8.54) == 32632  # Zurich
    assert utm_epsg(-33.87, 151.21) == 32756  # Sydney
    assert utm_epsg(60.0, 5.0) == 32632  # Norway's exception (would be 31)
    assert utm_epsg(40.7, -74.0) == 32618  # New York


def test_projected_matches_pyproj_and_round_trips():
    pytest.importorskip("pyproj")
    enu = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 5.0], [0.0, 100.0, 0.0]])
    proj, code = projected_from_enu(ZURICH, enu)
    assert code == 32632
    # Zurich's Hauptbahnhof area lies near E 465 km, N 5247 km in UTM 32N
    assert 460_000 < proj[0, 0] < 470_000 and 5_240_000 < proj[0, 1] < 5_255_000
    # 100 m east in ENU is about 100 m in UTM (scale factor and grid convergence are small)
    assert abs(np.linalg.norm(proj[1, :2] - proj[0, :2]) - 100.0) < 0.1
    lat, lon = lla_from_projected(proj[:, 0], proj[:, 1], code)
    lat0, lon0, _ = lla_from_enu(ZURICH, enu)
    np.testing.assert_allclose(lat, lat0, atol=1e-9)
    np.testing.assert_allclose(lon, lon0, atol=1e-9)


def test_bad_origin_and_code_are_input_errors():
    with pytest.raises(InputError):
        GeoOrigin(123.0, 8.0)
    with pytest.raises(InputError):
        GeoOrigin.from_json({"lat": "x"})
    assert GeoOrigin.from_json(ZURICH.to_json()) == ZURICH
    pytest.importorskip("pyproj")
    with pytest.raises(InputError):
        projected_from_enu(ZURICH, np.zeros((1, 3)), epsg=999999)
