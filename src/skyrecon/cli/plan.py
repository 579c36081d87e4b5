"""``skyrecon plan``: a collision-free 3D path through a map, keeping a clearance from obstacles.

Reads a map written by ``skyrecon map`` and writes ``path.json`` (``{"waypoints": [[x, y, z], ...]}``
in the world frame, metres, with length and clearance), ``preview.png`` (top view with the path)
and, with ``--origin LAT LON ALT`` (the world origin's geographic position), a QGroundControl
mission ``mission.plan``, the path as ``path.geojson`` and ``path.kml`` and the map's occupied
footprint as ``footprint.geojson`` (lon/lat). Unknown space is not flyable unless ``--allow-unknown``. A start or goal
in unexplored space or within the clearance of an obstacle (where the vehicle was, say) is joined
to the nearest usable point within ``--snap-radius``; when the map was built by ``skyrecon map`` from
a flight and no path keeps the clearance, the path retraces the flown track (``flown_path.json``).
``path.json`` says what was done under ``adjusted``. With ``--prior-map`` an older map of the same
place (an earlier flight) fills what this map has not observed.
When no path exists it says why (start or goal inside or too near an obstacle, enclosed, outside
the map).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from skyrecon.cli.common import add_command, info, output_dir
from skyrecon.errors import EstimationError, InputError
from skyrecon.mapping import load_map, read_flown_path, write_map_preview
from skyrecon.mapping.tiles import TiledMap, is_tiled_map
from skyrecon.planning import plan_with_flown_path, write_path_json, write_qgc_plan
from skyrecon.planning.geo_export import write_footprint_geojson, write_path_geojson, write_path_kml
from skyrecon.planning.tiled import plan_on_tiles

EXAMPLES = """  skyrecon plan flight_map/ --start 0 0 15 --goal 120 80 20 --out route/
  skyrecon plan flight_map/ --start 0 0 15 --goal 120 80 20 --clearance 3 --max-z 40 --out route/
  skyrecon plan today_map/ --prior-map yesterday_map/ --start 0 0 15 --goal 120 80 20 --out route/
  skyrecon plan flight_map/ --start 0 0 15 --goal 120 80 20 --origin 47.3769 8.5417 408 --out route/
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = add_command(
        subparsers,
        "plan",
        help="collision-free 3D path through a map",
        description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        examples=EXAMPLES,
    )
    p.add_argument("map_dir", help="map directory written by 'skyrecon map'")
    p.add_argument(
        "--start", type=float, nargs=3, required=True, metavar=("X", "Y", "Z"), help="world metres"
    )
    p.add_argument("--goal", type=float, nargs=3, required=True, metavar=("X", "Y", "Z"), help="world metres")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument(
        "--clearance", type=float, default=2.0, help="distance to keep from obstacles, metres (default 2)"
    )
    p.add_argument(
        "--snap-radius",
        type=float,
        default=3.0,
        help="a start or goal in unexplored space or nearer an obstacle than the clearance is moved to the "
        "nearest usable point within this radius, and path.json says so (metres, default 3; 0: never)",
    )
    p.add_argument(
        "--prior-map",
        metavar="MAP_DIR",
        help="an older map of the same place and frame (an earlier flight): it fills the voxels MAP_DIR "
        "has not observed; what MAP_DIR observed wins where they disagree",
    )
    p.add_argument("--allow-unknown", action="store_true", help="let the path cross unexplored space")
    p.add_argument("--min-z", type=float, default=-np.inf, help="lowest altitude allowed, world z metres")
    p.add_argument("--max-z", type=float, default=np.inf, help="highest altitude allowed, world z metres")
    p.add_argument(
        "--origin",
        type=float,
        nargs=3,
        metavar=("LAT", "LON", "ALT"),
        help="geographic position of the world origin (degrees, degrees, metres AMSL) for mission.plan "
        "(default: MAP_DIR/geo_origin.json when the map has one, e.g. from 'skyrecon survey')",
    )
    return p


def _map_geo_origin(map_dir: str) -> list[float] | None:
    """(lat, lon, alt) of a map's world origin from ``MAP_DIR/geo_origin.json`` (``skyrecon survey``), or None."""
    path = Path(map_dir) / "geo_origin.json"
    if not path.is_file():
        return None
    try:
        d = json.loads(path.read_text())
        return [float(d["lat"]), float(d["lon"]), float(d["alt"])]
    except (ValueError, KeyError, TypeError):
        raise InputError("unreadable geographic origin; rewrite it or pass --origin", path) from None


def run(args: argparse.Namespace) -> int:
    start, goal = np.asarray(args.start), np.asarray(args.goal)
    for name, p in (("--start", start), ("--goal", goal)):
        if not np.all(np.isfinite(p)):
            raise InputError(f"{name} must be three finite numbers, got {p.tolist()}")
    if is_tiled_map(args.map_dir):
        return _run_tiled(args, start, goal)
    occ = load_map(args.map_dir)
    if args.origin is None:
        args.origin = _map_geo_origin(args.map_dir)
    prior_note = ""
    if args.prior_map:
        prior = load_map(args.prior_map)
        (alo, ahi), (blo, bhi) = occ.bounds(), prior.bounds()
        if np.any(np.minimum(ahi, bhi) <= np.maximum(alo, blo)):
            raise InputError(
                f"the prior map covers {np.round(blo, 1).tolist()}..{np.round(bhi, 1).tolist()} m and the map "
                f"{np.round(alo, 1).tolist()}..{np.round(ahi, 1).tolist()} m: they do not overlap (another place "
                "or another frame?)",
                args.prior_map,
            )
        try:
            filled = occ.fill_unknown_from(prior)
        except InputError as e:
            raise InputError(f"{e.reason}; rebuild the prior with the same --voxel", args.prior_map) from None
        prior_note = f"the prior map filled {filled} unobserved voxels"
    result = plan_with_flown_path(
        occ,
        start,
        goal,
        args.clearance,
        read_flown_path(args.map_dir),
        snap_radius_m=max(0.0, args.snap_radius),
        allow_unknown=args.allow_unknown,
        min_z=args.min_z,
        max_z=args.max_z,
    )
    out = _write_path(args, result, start, goal)
    write_map_preview(occ, out / "preview.png", [result.waypoints])
    if args.origin is not None:
        _write_route_files(out, result.waypoints, args.origin)
        write_footprint_geojson(out / "footprint.geojson", occ, args.origin)
    if not args.quiet:
        straight = float(np.linalg.norm(goal - start))
        info(
            f"path of {len(result.waypoints)} waypoints, {result.length_m:.1f} m ({result.length_m / max(straight, 1e-9):.3f} x straight line), "
            f"clearance {args.clearance} m, planned in {1000 * result.timings.get('total', float('nan')):.0f} ms"
        )
        if prior_note:
            info(f"note: {prior_note}")
        if result.adjusted.get("route") == "flown_path":
            info(
                "note: no path keeps the clearance from unexplored space here; this one retraces the path "
                "flown while mapping (path.json 'adjusted')"
            )
        for what, move in result.adjusted.items():
            if what not in ("start", "goal"):
                continue
            info(
                f"note: the {what} lies in {'unexplored space' if move['reason'].endswith('unknown') else 'the clearance of an obstacle'}; "
                f"the path joins the nearest usable point {move['distance_m']:.1f} m away in a straight line (see path.json 'adjusted')"
            )
        info(
            f"wrote {out}/path.json, preview.png"
            + (", mission.plan, path.geojson, path.kml, footprint.geojson" if args.origin is not None else "")
        )
    return 0


def _run_tiled(args: argparse.Namespace, start: np.ndarray, goal: np.ndarray) -> int:
    """Plan on a tiled (district) map: only the tiles around the query are read (see
    :mod:`skyrecon.planning.tiled`)."""
    if args.prior_map:
        raise InputError(
            "--prior-map is not supported with a tiled map; merge the maps instead (map --merge)"
        )
    tiled = TiledMap.open(args.map_dir)
    result = plan_on_tiles(
        tiled,
        start,
        goal,
        args.clearance,
        snap_radius_m=max(0.0, args.snap_radius),
        allow_unknown=args.allow_unknown,
        min_z=args.min_z,
        max_z=args.max_z,
    )
    out = _write_path(args, result, start, goal)
    if args.origin is not None:
        _write_route_files(out, result.waypoints, args.origin)
    if not args.quiet:
        straight = float(np.linalg.norm(goal - start))
        how = (
            f"a {result.adjusted['coarse_voxel_m']:g} m route refined in {result.adjusted['pieces']} pieces"
            if result.adjusted.get("route") == "tiled"
            else "directly"
        )
        info(
            f"path of {len(result.waypoints)} waypoints, {result.length_m:.1f} m "
            f"({result.length_m / max(straight, 1e-9):.3f} x straight line), clearance {args.clearance} m, "
            f"planned {how} on {result.timings.get('tiles_read', 0)} tiles read "
            f"in {result.timings.get('total', result.timings.get('total_with_tiles', float('nan'))):.1f} s"
        )
        info(
            f"wrote {out}/path.json"
            + (", mission.plan, path.geojson, path.kml" if args.origin is not None else "")
        )
    return 0


def _write_path(args: argparse.Namespace, result, start: np.ndarray, goal: np.ndarray):
    """``path.json`` in ``--out`` (also for a failed query, with its reason); raises when there is no path."""
    out = output_dir(args.out)
    write_path_json(out / "path.json", result, start=start, goal=goal)
    if not result.success:
        raise EstimationError(
            f"no path from {start.tolist()} to {goal.tolist()}: {result.message or result.reason}"
        )
    return out


def _write_route_files(out, waypoints: np.ndarray, origin) -> None:
    """The route for a ground station and GIS: ``mission.plan``, ``path.geojson``, ``path.kml``."""
    write_qgc_plan(out / "mission.plan", waypoints, origin)
    write_path_geojson(out / "path.geojson", waypoints, origin)
    write_path_kml(out / "path.kml", waypoints, origin)
