"""Plans that may retrace the path the vehicle flew while mapping.

A map built by a vehicle knows the space it flew through as free
(:meth:`~skyrecon.mapping.OccupancyMap.mark_flown_free`), but that corridor is only as wide as the
vehicle: the planner, which keeps its clearance from unexplored space too, cannot always use it.
:func:`plan_with_flown_path` plans as usual (snapping a start or goal in unexplored space to the
nearest usable point) and, when that fails and both ends lie near the flown track, retraces the
track between them: the vehicle has flown it, so it is free at the vehicle's size, though not
necessarily at the planner's clearance. The result says which route it took (``adjusted["route"]``).

Frames and units: world frame (z up), metres.
"""

from __future__ import annotations

import numpy as np

from skyrecon.mapping.inputs import check_point3
from skyrecon.mapping.occupancy import OccupancyMap
from skyrecon.planning import _geom
from skyrecon.planning.planner import plan_path
from skyrecon.planning.result import PlanResult


def nearest_on_track(track: np.ndarray, p: np.ndarray) -> tuple[int, float, np.ndarray, float]:
    """The point of the polyline ``track`` (N, 3) nearest ``p`` (3,): (segment index k, fraction
    along segment k, the point (3,), its distance in metres). A one-point track has segment 0."""
    if len(track) == 1:
        return 0, 0.0, track[0].copy(), float(np.linalg.norm(p - track[0]))
    a, b = track[:-1], track[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0.0, 1.0)
    q = a + t[:, None] * ab
    d = np.linalg.norm(q - p, axis=1)
    k = int(np.argmin(d))
    return k, float(t[k]), q[k], float(d[k])


def route_along_track(
    track: np.ndarray, start: np.ndarray, goal: np.ndarray, max_join_m: float
) -> np.ndarray | None:
    """Waypoints (K, 3) from ``start`` to the track, along it, and off it to ``goal``; None when
    either end is farther than ``max_join_m`` from the track."""
    track = np.asarray(track, dtype=np.float64).reshape(-1, 3)
    if len(track) == 0:
        return None
    ks, ts, qs, ds = nearest_on_track(track, start)
    kg, tg, qg, dg = nearest_on_track(track, goal)
    if ds > max_join_m or dg > max_join_m:
        return None
    if (ks, ts) <= (kg, tg):
        inner = track[ks + 1 : kg + 1]
    else:
        inner = track[kg + 1 : ks + 1][::-1]
    pts = np.vstack([start[None], qs[None], inner, qg[None], goal[None]])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    return pts[keep]


def plan_with_flown_path(
    occ_map: OccupancyMap,
    start: np.ndarray,
    goal: np.ndarray,
    clearance_m: float,
    track: np.ndarray | None,
    snap_radius_m: float = 0.0,
    **options,
) -> PlanResult:
    """A path from ``start`` to ``goal`` (3,) world metres: the planner's
    (:func:`~skyrecon.planning.plan_path`, endpoints snapped within ``snap_radius_m``), or, when it
    finds none and both ends lie within ``snap_radius_m`` of the flown ``track`` (N, 3), the track
    retraced (``adjusted["route"] == "flown_path"``, ``min_distance_m`` NaN: the clearance along
    it is the one it was flown at). ``options`` go to the planner."""
    s = check_point3(start, "start")
    g = check_point3(goal, "goal")
    result = plan_path(occ_map, s, g, clearance_m, snap_radius_m=snap_radius_m, **options)
    if result.success or track is None or len(track) == 0:
        return result
    route = route_along_track(track, s, g, snap_radius_m)
    if route is None:
        return result
    return PlanResult(
        True,
        route,
        float(_geom.polyline_length(route)),
        clearance_m=clearance_m,
        margin_m=result.margin_m,
        timings=result.timings,
        adjusted={"route": "flown_path", "planner": {"reason": result.reason, "message": result.message}},
    )
