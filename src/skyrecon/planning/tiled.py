"""Planning across a district-scale tiled map (:class:`~skyrecon.mapping.tiles.TiledMap`).

A query whose box (start and goal, padded) is small is planned directly on the tiles it covers,
at full resolution. A longer one is planned in two steps, so that neither memory nor time grows
with the district:

1. **route**: on a coarse copy of the map over the query's box (``coarse_factor`` times larger
   voxels; a coarse voxel is occupied when any of its voxels is, so obstacles never thin out),
   with the same clearance;
2. **segments**: the route is cut every ``segment_m`` metres and each piece is planned again at
   full resolution on the tiles around it, from the end of the previous piece.

Every segment keeps the clearance at full resolution, so the joined path does too; it is slightly
longer than a path planned on the whole fine map at once (each piece bends only within its box).
"""

from __future__ import annotations

import time

import numpy as np

from skyrecon.mapping.inputs import check_point3
from skyrecon.mapping.tiles import TiledMap
from skyrecon.planning import _geom
from skyrecon.planning.planner import Planner
from skyrecon.planning.result import PlanResult


def plan_on_tiles(
    tiled: TiledMap,
    start: np.ndarray,
    goal: np.ndarray,
    clearance_m: float = 2.0,
    *,
    snap_radius_m: float = 0.0,
    coarse_factor: int = 4,
    segment_m: float = 100.0,
    pad_m: float = 30.0,
    max_direct_cells: int = 40_000_000,
    **options,
) -> PlanResult:
    """A collision-free path from ``start`` to ``goal`` (3,) world metres on a tiled map.

    Args:
        tiled: the map.
        clearance_m: distance to keep from obstacles, metres.
        snap_radius_m: start or goal in unknown space or too near an obstacle: plan from / to the
            nearest usable point within this radius (see :meth:`Planner.plan`).
        coarse_factor: how many voxels (per axis) make one voxel of the route map (divides the
            block size).
        segment_m: length of the route pieces planned at full resolution, metres.
        pad_m: margin around start and goal (and around each piece), metres.
        max_direct_cells: a query box of at most this many voxels is planned directly.
        options: passed to the planner (``allow_unknown``, ``min_z``, ``max_z``, ...).
    Returns:
        PlanResult; ``adjusted["route"] == "tiled"`` with the number of pieces when planned in two
        steps, ``timings`` with the seconds of each step and ``tiles_read``.
    """
    t0 = time.perf_counter()
    s = check_point3(start, "start")
    g = check_point3(goal, "goal")
    (map_lo, map_hi) = tiled.bounds()
    # heights the path may use, with room for the clearance: the rest of the column is not loaded
    reach = clearance_m + 2.0 * tiled.voxel_size * coarse_factor
    lo_z = max(map_lo[2], float(options.get("min_z", -np.inf)) - reach)
    hi_z = min(map_hi[2], float(options.get("max_z", np.inf)) + reach)
    read0 = tiled.tiles_read
    # the box around start and goal grows (twice the pad each time) while the way around an
    # obstacle lies outside it, up to the whole map
    result: PlanResult | None = None
    for pad in _pads(pad_m, s, g, map_lo, map_hi):
        lo, hi = _box(s, g, pad, lo_z, hi_z)
        if _cells(lo, hi, tiled.voxel_size) > max_direct_cells:
            break
        result = _plan(tiled.region(lo, hi), s, g, clearance_m, snap_radius_m, options)
        if result.success or result.reason not in _BOX_TOO_SMALL:
            break
    if result is not None and (
        result.success or result.reason not in _BOX_TOO_SMALL or pad >= _need(s, g, map_lo, map_hi)
    ):
        result.timings["tiles_read"] = tiled.tiles_read - read0
        result.timings["total_with_tiles"] = time.perf_counter() - t0
        return result

    t_route = time.perf_counter()
    coarse_voxel = tiled.voxel_size * coarse_factor
    coarse_snap = max(snap_radius_m, 2.0 * coarse_voxel)
    for pad in _pads(max(pad_m, 4 * coarse_voxel), s, g, map_lo, map_hi):
        lo, hi = _box(s, g, pad, lo_z, hi_z)
        coarse = tiled.coarse(coarse_factor, lo, hi)
        route = _plan(coarse, s, g, clearance_m, coarse_snap, options)
        if route.success or route.reason not in _BOX_TOO_SMALL:
            break
    t_route = time.perf_counter() - t_route
    if not route.success:
        return PlanResult.failure(
            route.reason,
            f"no route across the map at {coarse.voxel_size:g} m ({route.message})",
            clearance_m=clearance_m,
            timings={"route": t_route, "tiles_read": tiled.tiles_read - read0},
        )
    cuts = _cut_points(np.asarray(route.waypoints, np.float64), segment_m)
    cuts[0], cuts[-1] = s, g
    waypoints = [s[None]]
    expansions = route.expansions
    min_distance = np.inf
    adjusted: dict = {"route": "tiled", "coarse_voxel_m": coarse.voxel_size, "pieces": len(cuts) - 1}
    t_pieces = time.perf_counter()
    for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:], strict=True)):
        a = waypoints[-1][-1]  # continue from where the previous piece really ended
        # the cut points lie in the route's free space, which may hold a few unexplored voxels at
        # full resolution: every piece may move its ends a little (the user's ends are checked below)
        for pad in list(_pads(pad_m, a, b, map_lo, map_hi))[:3]:
            plo, phi = _box(a, b, pad, lo_z, hi_z)
            piece = _plan(tiled.region(plo, phi), a, b, clearance_m, coarse_snap, options)
            if piece.success or piece.reason not in _BOX_TOO_SMALL:
                break
        if not piece.success:
            return PlanResult.failure(
                piece.reason,
                f"piece {k + 1} of {len(cuts) - 1} of the route ({np.round(a, 1).tolist()} -> "
                f"{np.round(b, 1).tolist()}) could not be planned at full resolution ({piece.message})",
                clearance_m=clearance_m,
                timings={"route": t_route, "tiles_read": tiled.tiles_read - read0},
            )
        wp = np.asarray(piece.waypoints, np.float64)
        waypoints.append(wp[1:] if np.allclose(wp[0], a) else wp)
        expansions += piece.expansions
        if np.isfinite(piece.min_distance_m):
            min_distance = min(min_distance, piece.min_distance_m)
        for end, move in piece.adjusted.items():
            if (end == "start" and k == 0) or (end == "goal" and k == len(cuts) - 2):
                if move.get("distance_m", 0.0) > snap_radius_m:
                    return PlanResult.failure(
                        move.get("reason", f"{end}_unknown"),
                        f"the {end} would have to move {move.get('distance_m', 0.0):.1f} m "
                        f"(snap radius {snap_radius_m:g} m)",
                        clearance_m=clearance_m,
                    )
                adjusted[end] = move
    path = np.concatenate(waypoints)
    return PlanResult(
        True,
        path,
        float(_geom.polyline_length(path)),
        clearance_m=clearance_m,
        margin_m=route.margin_m,
        min_distance_m=float(min_distance),
        expansions=int(expansions),
        timings={
            "route": t_route,
            "pieces": time.perf_counter() - t_pieces,
            "total": time.perf_counter() - t0,
            "tiles_read": tiled.tiles_read - read0,
        },
        adjusted=adjusted,
    )


def _plan(
    occ, a: np.ndarray, b: np.ndarray, clearance_m: float, snap_radius_m: float, options: dict
) -> PlanResult:
    """One query on a map made for it. A :class:`Planner` of its own (not ``plan_path``'s cache, which
    keeps every map it has seen alive): its grids go when the query ends."""
    if occ.grid.count == 0:
        return PlanResult.failure("start_unknown", "no mapped block around the query")
    return Planner(occ, clearance_m, **options).plan(a, b, snap_radius_m)


_BOX_TOO_SMALL = ("start_enclosed", "goal_enclosed", "no_path")


def _box(a: np.ndarray, b: np.ndarray, pad: float, lo_z: float, hi_z: float) -> tuple[np.ndarray, np.ndarray]:
    """World box (lo, hi) around two points, padded by ``pad`` in x and y, all stored heights in z."""
    return np.r_[np.minimum(a, b)[:2] - pad, lo_z - 1.0], np.r_[np.maximum(a, b)[:2] + pad, hi_z + 1.0]


def _cells(lo: np.ndarray, hi: np.ndarray, voxel: float) -> float:
    return float(np.prod(np.maximum(hi - lo, 0.0) / voxel))


def _need(a: np.ndarray, b: np.ndarray, map_lo: np.ndarray, map_hi: np.ndarray) -> float:
    """The pad that makes the box around a and b hold the map's whole x-y extent, metres."""
    return float(np.max(np.r_[np.minimum(a, b)[:2] - map_lo[:2], map_hi[:2] - np.maximum(a, b)[:2], 0.0]))


def _pads(pad: float, a: np.ndarray, b: np.ndarray, map_lo: np.ndarray, map_hi: np.ndarray):
    """Pads doubling from ``pad`` until the box around a and b holds the whole map's x-y extent."""
    need = _need(a, b, map_lo, map_hi)
    p = max(pad, 1e-3)
    while True:
        yield p
        if p >= need:
            return
        p *= 2.0


def _cut_points(route: np.ndarray, segment_m: float) -> np.ndarray:
    """Points along a polyline (K, 3) every ``segment_m`` metres (its ends included), (M, 3)."""
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    total = float(s[-1])
    n = max(1, int(np.ceil(total / max(segment_m, 1e-6))))
    at = np.linspace(0.0, total, n + 1)
    return np.stack([np.interp(at, s, route[:, k]) for k in range(3)], axis=1)
