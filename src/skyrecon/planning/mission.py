"""Writing planned paths: ``path.json`` and QGroundControl ``.plan`` missions.

``path.json`` (UTF-8 JSON, written atomically)::

    {"format": "skyrecon.path", "version": 1, "frame": "world", "units": "m",
     "waypoints": [[x, y, z], ...], "num_waypoints": K, "length_m": ...,
     "success": true, ... (PlanResult fields when a result is given) }

QGroundControl ``.plan`` (JSON, file version 1, mission version 2): one ``SimpleItem``
``MAV_CMD_NAV_WAYPOINT`` (16) per waypoint (optionally a takeoff (22) first and a land (21)
last). The world frame is taken as a local East-North-Up frame whose origin sits at the given
geodetic point; waypoints are converted to WGS-84 latitude / longitude exactly (ENU -> ECEF ->
geodetic). Altitudes are relative to the home position (= the origin; MAVLink frame 3,
``GLOBAL_RELATIVE_ALT``) by default, or above mean sea level (frame 0, ``GLOBAL``, origin altitude
+ z) with ``altitude_mode="amsl"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.planning.result import PlanResult
from skyrecon.survey.geo import GeoOrigin, ecef_from_lla, lla_from_ecef, lla_from_enu

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_FRAME_GLOBAL = 0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3


def _waypoints(waypoints) -> np.ndarray:
    w = np.asarray(waypoints.waypoints if isinstance(waypoints, PlanResult) else waypoints, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 3:
        raise InputError(f"waypoints must have shape (K, 3), got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise InputError("waypoints contain NaN or infinite values")
    return w


def _origin(origin_lat_lon_alt) -> tuple[float, float, float]:
    o = np.asarray(origin_lat_lon_alt, dtype=np.float64).reshape(-1)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise InputError(f"the geographic origin must be (lat_deg, lon_deg, alt_m), got {origin_lat_lon_alt}")
    lat, lon, alt = (float(x) for x in o)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise InputError(f"origin latitude / longitude out of range: {lat}, {lon} (degrees)")
    return lat, lon, alt


def geodetic_to_ecef(lat_deg: float, lon_deg: float, h_m: float) -> np.ndarray:
    """(3,) ECEF metres of a WGS-84 point (latitude, longitude in degrees, ellipsoidal height)."""
    return ecef_from_lla(lat_deg, lon_deg, h_m)[0]


def ecef_to_geodetic(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) latitude (deg), longitude (deg), ellipsoidal height (m) of ECEF points (N, 3) metres."""
    return np.stack(lla_from_ecef(xyz), axis=1)


def enu_to_geodetic(enu_m: np.ndarray, origin_lat_lon_alt) -> np.ndarray:
    """Local East-North-Up points to WGS-84 (see :mod:`skyrecon.survey.geo`).

    Args:
        enu_m: (N, 3) east, north, up metres from the origin (the skyrecon world frame).
        origin_lat_lon_alt: (3,) latitude (deg), longitude (deg), altitude (m) of the ENU origin.
    Returns:
        (N, 3) latitude (deg), longitude (deg), altitude (m; same datum as the origin's).
    """
    lat0, lon0, alt0 = _origin(origin_lat_lon_alt)
    return np.stack(lla_from_enu(GeoOrigin(lat0, lon0, alt0), enu_m), axis=1)


def write_path_json(path: str | Path, result: PlanResult | np.ndarray, **extra) -> None:
    """Write ``path.json``: waypoints (K, 3) world metres plus length and, for a PlanResult, its
    success, reason and clearance; ``extra`` keys are added (e.g. ``start``, ``goal``)."""
    w = (
        _waypoints(result)
        if not (isinstance(result, PlanResult) and not result.success)
        else np.zeros((0, 3))
    )
    doc = {"format": "skyrecon.path", "version": 1, "frame": "world", "units": "m"}
    if isinstance(result, PlanResult):
        d = result.to_dict()
        d.pop("waypoints")
        doc.update(d)
    doc["waypoints"] = w.tolist()
    doc["num_waypoints"] = int(len(w))
    doc["length_m"] = float(np.linalg.norm(np.diff(w, axis=0), axis=1).sum()) if len(w) else None
    for k, v in extra.items():
        doc[k] = np.asarray(v).tolist() if isinstance(v, np.ndarray) else v
    write_text_atomic(path, json.dumps(doc, indent=2) + "\n")


def qgc_plan(
    waypoints,
    origin_lat_lon_alt,
    altitude_mode: str = "relative",
    takeoff: bool = False,
    land: bool = False,
    cruise_speed_mps: float = 10.0,
    hover_speed_mps: float = 5.0,
    acceptance_radius_m: float = 1.0,
) -> dict:
    """The QGroundControl plan document (a dict) for waypoints (K, 3) in the local ENU world frame."""
    w = _waypoints(waypoints)
    if len(w) == 0:
        raise InputError("no waypoints to write; the plan failed or is empty")
    if altitude_mode not in ("relative", "amsl"):
        raise InputError(f"altitude_mode must be 'relative' or 'amsl', got {altitude_mode!r}")
    lat0, lon0, alt0 = _origin(origin_lat_lon_alt)
    geo = enu_to_geodetic(w, (lat0, lon0, alt0))
    rel = altitude_mode == "relative"
    frame = MAV_FRAME_GLOBAL_RELATIVE_ALT if rel else MAV_FRAME_GLOBAL
    alts = w[:, 2] if rel else alt0 + w[:, 2]
    items: list[dict] = []

    def item(cmd: int, params: list, alt: float) -> dict:
        return {
            "AMSLAltAboveTerrain": None,
            "Altitude": float(alt),
            "AltitudeMode": 1 if rel else 2,
            "autoContinue": True,
            "command": cmd,
            "doJumpId": len(items) + 1,
            "frame": frame,
            "params": params,
            "type": "SimpleItem",
        }

    for i, ((lat, lon, _h), alt) in enumerate(zip(geo, alts)):
        if i == 0 and takeoff:
            items.append(item(MAV_CMD_NAV_TAKEOFF, [0, 0, 0, None, float(lat), float(lon), float(alt)], alt))
        elif i == len(w) - 1 and land:
            items.append(item(MAV_CMD_NAV_LAND, [0, 0, 0, None, float(lat), float(lon), float(alt)], alt))
        else:
            items.append(
                item(
                    MAV_CMD_NAV_WAYPOINT,
                    [0, float(acceptance_radius_m), 0, None, float(lat), float(lon), float(alt)],
                    alt,
                )
            )
    return {
        "fileType": "Plan",
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": float(cruise_speed_mps),
            "firmwareType": 12,
            "globalPlanAltitudeMode": 1 if rel else 2,
            "hoverSpeed": float(hover_speed_mps),
            "items": items,
            "plannedHomePosition": [lat0, lon0, alt0],
            "vehicleType": 2,
            "version": 2,
        },
        "rallyPoints": {"points": [], "version": 2},
        "version": 1,
    }


def write_qgc_plan(path: str | Path, waypoints, origin_lat_lon_alt, **options) -> None:
    """Write a QGroundControl ``.plan`` mission (atomically).

    Args:
        path: output file.
        waypoints: (K, 3) world (local ENU) metres, or a successful PlanResult.
        origin_lat_lon_alt: (3,) latitude (deg), longitude (deg), altitude AMSL (m) of the
            world origin; also the planned home position.
        options: see :func:`qgc_plan` (altitude_mode, takeoff, land, speeds).
    """
    write_text_atomic(path, json.dumps(qgc_plan(waypoints, origin_lat_lon_alt, **options), indent=2) + "\n")
