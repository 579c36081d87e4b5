"""The mission's world: a generated city, a start and a delivery point, and the truth about them.

A :class:`Scenario` holds the city (exact geometry, known only to the simulator), the start and
the goal (world frame, metres), the box the drone's map covers, and the *shortest feasible
path*: planned by the same planner at the same clearance and altitude band, but on a map built
from the true geometry (:meth:`City.occupancy_grid`), so it is the yardstick for the flown
length.

Start and goal come from the seed (:func:`pick_endpoints`: over streets at the cruise altitude,
far apart, with buildings on the straight line between them) or from the user; either way
:func:`make_scenario` checks them against the truth and raises :class:`ImpossibleMission` (an
:class:`~skyrecon.errors.InputError`) when no drone could fly the mission: an endpoint inside
or too close to a building, outside the altitude band or the map, or no way through.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mapping import MapConfig, OccupancyMap
from skyrecon.mission.config import MissionConfig
from skyrecon.planning import Planner, PlanResult
from skyrecon.sim import City, generate_city
from skyrecon.sim.movers import MovingScene, make_movers


class ImpossibleMission(InputError):
    """The mission cannot be flown (bad endpoints, no way through); the message says why.

    Attributes:
        code: a short machine-readable reason (``goal_in_obstacle``, ``no_path``, ...).
    """

    def __init__(self, message: str, code: str = "impossible"):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class MapBox:
    """A voxel-aligned world box: ``origin`` (3,) lower corner, metres; ``shape`` (3,) voxels."""

    origin: np.ndarray
    shape: tuple[int, int, int]
    voxel_size_m: float

    @property
    def upper(self) -> np.ndarray:
        """(3,) upper corner, metres."""
        return self.origin + np.asarray(self.shape) * self.voxel_size_m

    def contains(self, p: np.ndarray, inset_m: float = 0.0) -> bool:
        """Whether the (3,) point lies inside the box shrunk by ``inset_m``."""
        p = np.asarray(p, dtype=np.float64)
        return bool(np.all(p >= self.origin + inset_m) and np.all(p <= self.upper - inset_m))


def map_box(city: City, cfg: MissionConfig, z_lo: float, z_hi: float) -> MapBox:
    """The box over the city (plus ``map_padding_m``) from ``z_lo`` to ``z_hi`` metres, aligned to
    the map's blocks (8 voxels) so that pre-allocating it allocates whole blocks."""
    v = cfg.voxel_size_m
    edge = 8 * v
    x0, y0, x1, y1 = city.extent
    pad = cfg.map_padding_m
    lo = np.floor(np.array([x0 - pad, y0 - pad, z_lo]) / edge) * edge
    hi = np.ceil(np.array([x1 + pad, y1 + pad, z_hi]) / edge) * edge
    nx, ny, nz = (int(s) for s in np.round((hi - lo) / v))
    return MapBox(lo, (nx, ny, nz), v)


def drone_map_box(city: City, cfg: MissionConfig) -> MapBox:
    """The box the drone's own map is pre-allocated over (ground to 6 m above the band)."""
    return map_box(city, cfg, -cfg.voxel_size_m, cfg.max_altitude_m + 6.0)


def truth_planner(city: City, cfg: MissionConfig) -> Planner:
    """A planner on the true geometry: same voxels, clearance, margin and altitude band as the drone's."""
    box = map_box(city, cfg, max(-cfg.voxel_size_m, cfg.min_altitude_m - 6.0), cfg.max_altitude_m + 6.0)
    occ = city.occupancy_grid(box.origin, box.voxel_size_m, box.shape, include_ground=True)
    m = OccupancyMap.from_occupancy_grid(occ, box.origin, MapConfig(voxel_size_m=cfg.voxel_size_m))
    m.pop_changed_blocks()
    return Planner(m, cfg.clearance_m, min_z=cfg.min_altitude_m, max_z=cfg.max_altitude_m)


@dataclass(eq=False)
class Scenario:
    """One delivery: the city, where from, where to, and the truth about it.

    Attributes:
        seed: the city's seed (and of the endpoint choice).
        city: the generated city (exact geometry; the drone never reads it).
        start, goal: (3,) world positions, metres.
        box: the box of the drone's map.
        shortest: the shortest feasible path in the true city (PlanResult, world frame).
        picked: "seed" when start and goal were picked from the seed, "user" when given.
        prior_city: the city as it was when the prior map was made (None: as today).
        changes: :class:`~skyrecon.mission.changes.CityChange` list, yesterday -> today.
        movers: the moving obstacles (:class:`~skyrecon.sim.movers.MovingScene`) or None.
    """

    seed: int
    city: City
    start: np.ndarray
    goal: np.ndarray
    box: MapBox
    shortest: PlanResult
    picked: str = "seed"
    notes: list[str] = field(default_factory=list)
    prior_city: City | None = None
    changes: list = field(default_factory=list)
    movers: MovingScene | None = None

    @property
    def straight_line_m(self) -> float:
        return float(np.linalg.norm(self.goal - self.start))

    @property
    def start_yaw(self) -> float:
        """Initial heading (radians from +x towards +y): towards the goal."""
        d = self.goal - self.start
        return float(math.atan2(d[1], d[0]))

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "start": self.start.tolist(),
            "goal": self.goal.tolist(),
            "picked": self.picked,
            "straight_line_m": self.straight_line_m,
            "city_extent": self.city.extent.tolist(),
            "num_buildings": self.city.num_buildings,
            "map_box_origin": self.box.origin.tolist(),
            "map_box_shape": list(self.box.shape),
            "shortest_feasible_m": self.shortest.length_m if self.shortest.success else None,
            "changes": [c.to_dict() for c in self.changes],
            "movers": None if self.movers is None else self.movers.to_dict()["movers"],
        }


def _segment_blocked(city: City, a: np.ndarray, b: np.ndarray, clearance: float, step: float = 0.5) -> bool:
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / step)) + 1)
    pts = a + (b - a) * np.linspace(0.0, 1.0, n)[:, None]
    return bool(np.any(city.distance(pts, include_ground=True) < clearance))


def _street_candidates(city: City, cfg: MissionConfig, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) points over street centre lines at the cruise altitude, inside the city."""
    xs, ys = city.street_centers
    x0, y0, x1, y1 = city.extent
    inset = 6.0
    out = []
    for _ in range(n):
        if rng.random() < 0.5 and len(ys):
            out.append(
                [rng.uniform(x0 + inset, x1 - inset), ys[int(rng.integers(len(ys)))], cfg.cruise_altitude_m]
            )
        elif len(xs):
            out.append(
                [xs[int(rng.integers(len(xs)))], rng.uniform(y0 + inset, y1 - inset), cfg.cruise_altitude_m]
            )
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def pick_endpoints(
    city: City, cfg: MissionConfig, seed: int, planner: Planner, attempts: int = 60
) -> tuple[np.ndarray, np.ndarray, PlanResult]:
    """Start and goal for a seed: over streets at the cruise altitude, at least
    ``endpoint_clearance_m`` from every obstacle, ``min..max_goal_distance_m`` apart, the straight
    line between them blocked by buildings, and a feasible path in the true city.

    Returns:
        start (3,), goal (3,) world metres, and the shortest feasible path (PlanResult).
    Raises:
        ImpossibleMission: no such pair in this city.
    """
    rng = np.random.default_rng([int(seed), 7919])
    cand = _street_candidates(city, cfg, rng, 400)
    cand = cand[city.distance(cand, include_ground=True) >= cfg.endpoint_clearance_m]
    tried = 0
    for i in rng.permutation(len(cand)):
        a = cand[i]
        d = np.linalg.norm(cand - a, axis=1)
        ok = np.flatnonzero((d >= cfg.min_goal_distance_m) & (d <= cfg.max_goal_distance_m))
        if len(ok) == 0:
            continue
        b = cand[ok[int(rng.integers(len(ok)))]]
        if not _segment_blocked(city, a, b, cfg.clearance_m):
            continue
        tried += 1
        r = planner.plan(a, b)
        if r.success:
            return a.copy(), b.copy(), r
        if tried >= attempts:
            break
    raise ImpossibleMission(
        f"seed {seed}: found no start and goal {cfg.min_goal_distance_m:g}-{cfg.max_goal_distance_m:g} m apart "
        f"over the streets with a feasible path between them; try another seed or give --start and --goal",
        "no_endpoints",
    )


def _check_endpoint(city: City, cfg: MissionConfig, box: MapBox, p: np.ndarray, what: str) -> None:
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ImpossibleMission(
            f"the {what} must be three finite numbers X Y Z (metres), got {p.tolist()}", f"{what}_invalid"
        )
    x0, y0, x1, y1 = city.extent
    if not (x0 <= p[0] <= x1 and y0 <= p[1] <= y1):
        raise ImpossibleMission(
            f"the {what} {_fmt(p)} lies outside the city (x {x0:.0f}..{x1:.0f}, y {y0:.0f}..{y1:.0f} m)",
            f"{what}_outside",
        )
    if not (cfg.min_altitude_m <= p[2] <= cfg.max_altitude_m):
        raise ImpossibleMission(
            f"the {what} {_fmt(p)} is outside the flight band: z must lie in "
            f"{cfg.min_altitude_m:g}..{cfg.max_altitude_m:g} m",
            f"{what}_altitude",
        )
    d = float(city.distance(p[None], include_ground=True)[0])
    if d <= 0:
        raise ImpossibleMission(f"the {what} {_fmt(p)} lies inside a building", f"{what}_in_obstacle")
    need = cfg.clearance_m + cfg.planning_margin_m
    if d < need:
        raise ImpossibleMission(
            f"the {what} {_fmt(p)} is {d:.2f} m from a building; the drone keeps {cfg.clearance_m:g} m "
            f"(+ {cfg.planning_margin_m:.2f} m for its voxels), so it needs {need:.2f} m",
            f"{what}_too_close",
        )


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.1f}" for v in np.asarray(p, dtype=float)) + ")"


def make_scenario(
    seed: int,
    cfg: MissionConfig,
    start: np.ndarray | None = None,
    goal: np.ndarray | None = None,
    city: City | None = None,
) -> Scenario:
    """Generate the city of ``seed`` and fix the mission's endpoints.

    Args:
        seed: the city's seed (also picks start and goal when they are not given).
        cfg: mission settings (city size, altitude band, clearance, distances).
        start, goal: optional (3,) world points, metres; give both or neither.
        city: use this city instead of generating one (tests).
    Returns:
        The Scenario with the shortest feasible path in the true city.
    Raises:
        ImpossibleMission: an endpoint inside / too close to a building, outside the city or the
            altitude band, or no path at the clearance.
    """
    if (start is None) != (goal is None):
        raise ImpossibleMission(
            "give both --start and --goal, or neither (then the seed picks them)", "endpoints"
        )
    city = city if city is not None else generate_city(int(seed), cfg.city_size_m, plain=cfg.plain)
    box = drone_map_box(city, cfg)
    planner = truth_planner(city, cfg)
    if start is None:
        s, g, shortest = pick_endpoints(city, cfg, seed, planner)
        picked = "seed"
    else:
        s = np.asarray(start, dtype=np.float64).reshape(-1)
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        _check_endpoint(city, cfg, box, s, "start")
        _check_endpoint(city, cfg, box, g, "goal")
        if np.linalg.norm(g - s) < cfg.arrival_tolerance_m:
            raise ImpossibleMission(
                f"start and goal are less than {cfg.arrival_tolerance_m:g} m apart", "too_short"
            )
        shortest = planner.plan(s, g)
        if not shortest.success:
            raise ImpossibleMission(
                f"no way through from {_fmt(s)} to {_fmt(g)} in the true city: {shortest.message}",
                shortest.reason or "no_path",
            )
        picked = "user"
    scenario = Scenario(int(seed), city, s, g, box, shortest, picked)
    if cfg.city_changes:
        _apply_changes(scenario, cfg)
    if cfg.movers_file:
        scenario.movers = load_movers(cfg.movers_file, scenario.city, scenario.start, cfg)
    elif cfg.movers:
        scenario.movers = make_movers(
            scenario.city,
            scenario.seed,
            scenario.start,
            scenario.goal,
            scenario.shortest.waypoints,
            band=(cfg.min_altitude_m, cfg.max_altitude_m),
            cruise_speed_mps=cfg.cruise_speed_mps,
            plain=cfg.plain,
            n_drones=4,
            pace=(0.7, 1.0) if cfg.prior_map else (0.35, 0.6),
        )
    return scenario


def load_movers(path: str | Path, city: City, start: np.ndarray, cfg: MissionConfig) -> MovingScene:
    """The movers described in a JSON file (a list of :meth:`~skyrecon.sim.movers.Mover.to_dict`
    descriptions, or ``{"movers": [...]}``), checked against the city and the drone's start.

    Raises:
        ImpossibleMission: an unreadable file, a bad description, a mover inside a building or
            on the drone's start (the message names the file and the mover).
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError:
        raise ImpossibleMission(f"{p}: no such movers file", "movers_file") from None
    except (OSError, json.JSONDecodeError) as e:
        raise ImpossibleMission(f"{p}: not a JSON movers file ({e})", "movers_file") from None
    desc = {"movers": doc} if isinstance(doc, list) else doc
    try:
        scene = MovingScene.from_dict(desc, city)
        scene.validate(start, cfg.clearance_m)
    except InputError as e:
        raise ImpossibleMission(f"{p}: {e.reason}", "movers_file") from None
    return scene


def _apply_changes(scenario: Scenario, cfg: MissionConfig) -> None:
    """Make today's city differ from yesterday's (:func:`~skyrecon.mission.changes.city_changes`)
    and re-plan the shortest path in today's city; a change that would make the mission
    impossible is left out (and said in ``notes``)."""
    from skyrecon.mission.changes import city_changes

    base = scenario.city
    today, yesterday, changes = city_changes(
        base, scenario.seed, scenario.shortest.waypoints, scenario.start, scenario.goal, cfg
    )
    shortest = truth_planner(today, cfg).plan(scenario.start, scenario.goal)
    if not shortest.success:
        scenario.notes.append("the new obstacle would close the way; left out")
        changes = [c for c in changes if c.kind != "added"]
        today = base
    else:
        scenario.shortest = shortest
    scenario.city, scenario.prior_city, scenario.changes = today, yesterday, changes


def impossible_scenario_stub(seed: int, cfg: MissionConfig, start, goal) -> dict:
    """What is known about a mission refused before flight (for its report)."""

    def as_list(p):
        return None if p is None else [float(v) for v in np.asarray(p, dtype=float).reshape(-1)]

    return {
        "seed": int(seed),
        "start": as_list(start),
        "goal": as_list(goal),
        "picked": "user" if start is not None else "seed",
    }
