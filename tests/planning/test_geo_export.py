"""GeoJSON and KML outputs: paths and the map's occupied footprint."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from skyrecon.planning.geo_export import (
    KML_NS,
    footprint_geojson,
    footprint_rings,
    path_geojson,
    write_path_geojson,
    write_path_kml,
)
from skyrecon.planning.mission import enu_to_geodetic

ORIGIN = (47.3769, 8.5417, 408.0)
WAYPOINTS = np.array([[0.0, 0.0, 10.0], [100.0, 50.0, 20.0], [120.0, -30.0, 15.0]])


def test_path_geojson_and_kml(tmp_path):
    write_path_geojson(tmp_path / "path.geojson", WAYPOINTS, ORIGIN)
    doc = json.loads((tmp_path / "path.geojson").read_text())
    geom = doc["features"][0]["geometry"]
    assert geom["type"] == "LineString"
    lla = enu_to_geodetic(WAYPOINTS, ORIGIN)
    got = np.array(geom["coordinates"])
    np.testing.assert_allclose(got[:, :2], lla[:, [1, 0]], rtol=0, atol=1e-8)
    np.testing.assert_allclose(got[:, 2], lla[:, 2], rtol=0, atol=1e-3)
    write_path_kml(tmp_path / "path.kml", WAYPOINTS, ORIGIN)
    root = ET.parse(tmp_path / "path.kml").getroot()
    ns = {"k": KML_NS}
    assert root.find(".//k:LineString/k:altitudeMode", ns).text == "absolute"
    coords = [[float(v) for v in c.split(",")] for c in root.find(".//k:coordinates", ns).text.split()]
    np.testing.assert_allclose(np.array(coords), got, rtol=0, atol=1e-6)


def test_path_needs_two_points():
    with pytest.raises(Exception, match="at least 2"):
        path_geojson(WAYPOINTS[:1], ORIGIN)


def _area(ring):
    return 0.5 * sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(ring, ring[1:]))


def test_rings_of_a_square_with_a_hole_and_a_diagonal_neighbour():
    cells = [(i, j) for i in range(3) for j in range(3) if (i, j) != (1, 1)] + [(3, 3)]
    rings = footprint_rings(np.array(cells))
    areas = sorted(_area(r) for r in rings)
    assert areas == [-1.0, 1.0, 9.0]  # the hole (clockwise), the diagonal cell, the 3x3 block
    assert all(r[0] == r[-1] for r in rings)
    assert max(len(r) for r in rings) == 5  # collinear vertices dropped: a square has 4 corners


class _Map:
    voxel_size = 0.5

    def __init__(self, centres):
        self._c = np.asarray(centres, dtype=np.float64)

    def occupied_centers(self):
        return self._c


def test_footprint_in_metres_and_degrees():
    # ground at z 0.25 everywhere, a 1 x 1.5 m building 3 m tall at x 10..11, y 20..21.5
    ground = [[x + 0.25, y + 0.25, 0.25] for x in np.arange(0, 30, 0.5) for y in np.arange(0, 30, 0.5)]
    building = [[10 + x + 0.25, 20 + y + 0.25, 3.25] for x in (0, 0.5) for y in (0, 0.5, 1.0)]
    occ = _Map(ground + building)
    doc = footprint_geojson(occ)
    feature = doc["features"][0]
    assert "note" in feature["properties"] and feature["geometry"]["type"] == "MultiPolygon"
    (poly,) = feature["geometry"]["coordinates"]
    ring = np.array(poly[0])
    assert ring.min(axis=0).tolist() == [10.0, 20.0] and ring.max(axis=0).tolist() == [11.0, 21.5]
    assert _area([tuple(p) for p in poly[0]]) == pytest.approx(1.5)
    geo = footprint_geojson(occ, ORIGIN)["features"][0]["geometry"]["coordinates"][0][0]
    lla = enu_to_geodetic(np.column_stack([ring, np.zeros(len(ring))]), ORIGIN)
    np.testing.assert_allclose(np.array(geo), lla[:, [1, 0]], atol=1e-8)
