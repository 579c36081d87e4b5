"""Paths and map footprints for GIS and flight tools: GeoJSON and KML.

* :func:`path_geojson` / :func:`write_path_geojson`: a path as a GeoJSON ``LineString`` of
  ``[lon, lat, alt]`` (degrees, degrees, metres on the origin's datum) in a ``FeatureCollection``.
* :func:`write_path_kml`: the same path as a KML ``LineString`` with ``altitudeMode`` absolute.
* :func:`footprint_geojson` / :func:`write_footprint_geojson`: the map's occupied footprint, the
  union of the (x, y) columns holding an occupied voxel at or above a height, as a ``MultiPolygon``
  (outer rings counter-clockwise, holes clockwise, RFC 7946) in ``[lon, lat]`` when a geographic
  origin is given, else in local world metres ``[x east, y north]`` with a note.

World coordinates are the skyrecon world frame (local East-North-Up metres); conversion to WGS-84 is
:func:`skyrecon.planning.mission.enu_to_geodetic`.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.planning.mission import enu_to_geodetic

__all__ = [
    "path_geojson",
    "write_path_geojson",
    "write_path_kml",
    "footprint_rings",
    "footprint_geojson",
    "write_footprint_geojson",
]

KML_NS = "http://www.opengis.net/kml/2.2"


def _lon_lat_alt(waypoints: Any, origin: Any) -> np.ndarray:
    """(K, 3) ``[lon, lat, alt]`` of world (ENU) waypoints (K, 3) metres."""
    wp = np.asarray(getattr(waypoints, "waypoints", waypoints), dtype=np.float64).reshape(-1, 3)
    if len(wp) < 2:
        raise InputError(f"a path needs at least 2 waypoints, got {len(wp)}")
    lla = enu_to_geodetic(wp, origin)
    return lla[:, [1, 0, 2]]


def path_geojson(waypoints: Any, origin: Any, name: str = "skyrecon path") -> dict[str, Any]:
    """A GeoJSON FeatureCollection with one LineString ``[lon, lat, alt]`` of ``waypoints`` (K, 3)
    world metres, ``origin`` = (lat deg, lon deg, alt m) of the world origin."""
    coords = [
        [round(float(v), 9) if k < 2 else round(float(v), 3) for k, v in enumerate(p)]
        for p in _lon_lat_alt(waypoints, origin)
    ]
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"name": name, "altitude": "metres, the datum of the origin's altitude"},
                "geometry": {"type": "LineString", "coordinates": coords},
            }
        ],
    }


def write_path_geojson(path: str | Path, waypoints: Any, origin: Any) -> None:
    """Write :func:`path_geojson` atomically."""
    write_text_atomic(path, json.dumps(path_geojson(waypoints, origin), indent=1) + "\n")


def write_path_kml(path: str | Path, waypoints: Any, origin: Any, name: str = "skyrecon path") -> None:
    """Write the path as KML 2.2 (a Placemark with a LineString, ``altitudeMode`` absolute), atomically."""
    lla = _lon_lat_alt(waypoints, origin)
    ET.register_namespace("", KML_NS)
    kml = ET.Element(f"{{{KML_NS}}}kml")
    doc = ET.SubElement(kml, f"{{{KML_NS}}}Document")
    ET.SubElement(doc, f"{{{KML_NS}}}name").text = name
    mark = ET.SubElement(doc, f"{{{KML_NS}}}Placemark")
    ET.SubElement(mark, f"{{{KML_NS}}}name").text = name
    line = ET.SubElement(mark, f"{{{KML_NS}}}LineString")
    ET.SubElement(line, f"{{{KML_NS}}}altitudeMode").text = "absolute"
    ET.SubElement(line, f"{{{KML_NS}}}coordinates").text = " ".join(
        f"{lon:.9f},{lat:.9f},{alt:.3f}" for lon, lat, alt in lla
    )
    text = ET.tostring(kml, encoding="unicode", xml_declaration=False)
    write_text_atomic(path, '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n")


# ----- footprint -------------------------------------------------------------------------------
def footprint_rings(columns: np.ndarray) -> list[list[tuple[int, int]]]:
    """Closed rings (first vertex repeated) around the union of unit grid cells ``columns`` (N, 2)
    integer (i, j): cell (i, j) is the square [i, i+1] x [j, j+1]. Outer rings run counter-clockwise,
    holes clockwise; rings that touch at a corner are kept apart (left turns are taken first)."""
    cells = {(int(i), int(j)) for i, j in np.asarray(columns).reshape(-1, 2)}
    edges: set[tuple[tuple[int, int], tuple[int, int]]] = set()
    for i, j in cells:
        corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
        for a, b in zip(corners, corners[1:] + corners[:1]):
            if (b, a) in edges:
                edges.remove((b, a))
            else:
                edges.add((a, b))
    outgoing: dict[tuple[int, int], list[tuple[int, int]]] = defaultdict(list)
    for a, b in edges:
        outgoing[a].append(b)
    rings = []
    while edges:
        start = min(edges)
        ring, (a, b) = [start[0]], start
        while True:
            edges.discard((a, b))
            outgoing[a].remove(b)
            ring.append(b)
            if b == ring[0]:
                break
            d = (b[0] - a[0], b[1] - a[1])
            left = (-d[1], d[0])
            options = outgoing[b]
            rank = {left: 0, d: 1, (d[1], -d[0]): 2}
            nxt = min(options, key=lambda c: rank.get((c[0] - b[0], c[1] - b[1]), 3))
            a, b = b, nxt
        rings.append(_drop_collinear(ring))
    return rings


def _drop_collinear(ring: list[tuple[int, int]]) -> list[tuple[int, int]]:
    pts = ring[:-1]
    keep = []
    for k, p in enumerate(pts):
        a, c = pts[k - 1], pts[(k + 1) % len(pts)]
        if (p[0] - a[0]) * (c[1] - p[1]) - (p[1] - a[1]) * (c[0] - p[0]) != 0:
            keep.append(p)
    return keep + keep[:1]


def _area2(ring: list[tuple[float, float]]) -> float:
    return float(sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(ring, ring[1:])))


def _inside(p: tuple[float, float], ring: list[tuple[float, float]]) -> bool:
    x, y, inside = p[0], p[1], False
    for (x0, y0), (x1, y1) in zip(ring, ring[1:]):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


def footprint_geojson(
    occ: Any, origin: Any | None = None, min_height_m: float | None = None
) -> dict[str, Any]:
    """The occupied footprint of a map as GeoJSON (see the module docstring).

    Args:
        occ: an occupancy map (``occupied_centers()`` (N, 3) world metres, ``voxel_size``).
        origin: (lat deg, lon deg, alt m) of the world origin, or None for local metres.
        min_height_m: only voxels whose centre is at or above this world z count (default: 2 m above
            the lowest occupied voxel, so that the ground is left out).
    """
    centres = np.asarray(occ.occupied_centers(), dtype=np.float64).reshape(-1, 3)
    v = float(occ.voxel_size)
    if min_height_m is None:
        min_height_m = float(centres[:, 2].min()) + 2.0 if len(centres) else 0.0
    top = centres[centres[:, 2] >= min_height_m]
    polygons: list[list[list[list[float]]]] = []
    if len(top):
        corner0 = top[:, :2].min(axis=0) - v / 2
        cells = np.round((top[:, :2] - v / 2 - corner0) / v).astype(np.int64)
        rings = [[(corner0[0] + v * i, corner0[1] + v * j) for i, j in r] for r in footprint_rings(cells)]
        outers = [r for r in rings if _area2(r) > 0]
        holes = [r for r in rings if _area2(r) < 0]
        groups: list[list[list[tuple[float, float]]]] = [[r] for r in outers]
        for h in holes:
            probe = ((h[0][0] + h[1][0]) / 2, (h[0][1] + h[1][1]) / 2)
            owners = [g for g in groups if _inside(probe, g[0])]
            if owners:
                min(owners, key=lambda g: abs(_area2(g[0]))).append(h)
        for g in groups:
            poly = []
            for ring in g:
                xy = np.array(ring)
                if origin is not None:
                    lla = enu_to_geodetic(np.column_stack([xy, np.zeros(len(xy))]), origin)
                    coords = [[round(float(lon), 9), round(float(lat), 9)] for lat, lon, _ in lla]
                else:
                    coords = [[round(float(x), 3), round(float(y), 3)] for x, y in xy]
                poly.append(coords)
            polygons.append(poly)
    props: dict[str, Any] = {
        "name": "occupied footprint",
        "voxel_size_m": v,
        "min_height_m": round(float(min_height_m), 3),
        "columns": int(len({tuple(c) for c in np.floor(top[:, :2] / v).astype(int).tolist()}))
        if len(top)
        else 0,
    }
    if origin is None:
        props["note"] = (
            "local world metres [x east, y north], not longitude/latitude: no geographic origin given"
        )
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": props,
                "geometry": {"type": "MultiPolygon", "coordinates": polygons},
            }
        ],
    }


def write_footprint_geojson(
    path: str | Path, occ: Any, origin: Any | None = None, min_height_m: float | None = None
) -> dict[str, Any]:
    """Write :func:`footprint_geojson` atomically; returns the document."""
    doc = footprint_geojson(occ, origin, min_height_m)
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")
    return doc
