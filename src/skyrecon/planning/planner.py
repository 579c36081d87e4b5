"""Collision-free 3-D paths over an occupancy map: grid search, then shortening and smoothing.

1. The map's distance field (:class:`~skyrecon.mapping.distance.DistanceField`; unknown space
   counts as an obstacle unless ``allow_unknown``) is read into a dense grid over the map (or a
   box around start and goal when the map is too large). A voxel centre is *flyable* when its
   distance is at least ``clearance_m + margin_m`` and it lies within ``[min_z, max_z]``.
2. Lazy Theta* (any-angle; or A*), 26-connected, searches between nodes joined to the start
   and goal by clear straight segments, first on a coarser level of cells (fewer expansions),
   then, if that finds nothing, at full resolution. Line of sight is exact on the cells whose
   8 corner voxel centres are all clear (:mod:`skyrecon.planning._los`).
3. The grid path is shortened (greedy string pulling, then vertices pulled towards the chords
   of their neighbours until the length converges) and its corners are cut (Chaikin) where the
   cut stays clear. Every segment is checked against the trilinearly interpolated distance
   field: exactly (line of sight over safe cells), or for the first and last segment, which
   touch the free-standing start and goal, by sampling every quarter voxel.

``margin_m`` (default half a voxel diagonal, ``voxel * sqrt(3) / 2``) accounts for obstacles
filling occupied voxels up to their faces while the distance field measures between voxel
centres: with a correct map, a path that keeps ``clearance + margin`` from occupied voxel
centres keeps ``clearance`` from the obstacles themselves.

Frames and units: world frame (z up), metres.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from skyrecon.errors import InputError
from skyrecon.mapping.distance import DistanceField
from skyrecon.mapping.inputs import check_point3
from skyrecon.mapping.occupancy import OCCUPIED, UNKNOWN, OccupancyMap
from skyrecon.planning import _geom
from skyrecon.planning._search import component, search
from skyrecon.planning.grid import PlanningGrid
from skyrecon.planning.keep_out import keep_out
from skyrecon.planning.result import PlanResult


class Planner:
    """Plans paths on one map at one clearance; reuses the distance field and grid across queries.

    Args:
        source: an :class:`OccupancyMap` (a distance field is built for it) or a
            :class:`DistanceField` (used as is; it must clip above clearance + margin + 2 voxels
            and treat unknown space as ``not allow_unknown`` says).
        clearance_m: distance to keep from obstacles, metres (>= 0).
        margin_m: extra distance for the voxel discretisation (None: ``voxel * sqrt(3) / 2``).
        allow_unknown: let paths cross unexplored space (default: unknown space is an obstacle).
        min_z, max_z: altitude limits of the path, world z metres.
        any_angle: search with Lazy Theta* (any-angle; picks the way around obstacles by
            Euclidean length), else A* on the 26-connected grid.
        levels: search levels tried in turn, coarse first: level f searches the lattice of every
            f-th voxel (far fewer expansions, but passages narrower than about f voxels may be
            missed, so the next level is tried when it finds nothing). Must end with 1. None:
            ``(round(1.5 m / voxel), 1)``, i.e. a 1.5 m lattice first.
        heuristic_weight: heuristic weight (1: no inflation; larger: faster, longer).
        max_expansions: expansion limit per level (0: none).
        smoothing_iterations: corner-cutting rounds (0: none); smooth_radius_m: largest cut, metres.
        max_cells: largest dense grid, voxels; bigger maps are planned in a box around start
            and goal padded by ``pad_m`` (or a quarter of their separation, if larger).
    """

    def __init__(
        self,
        source: OccupancyMap | DistanceField,
        clearance_m: float = 2.0,
        *,
        margin_m: float | None = None,
        allow_unknown: bool = False,
        min_z: float = -np.inf,
        max_z: float = np.inf,
        any_angle: bool = True,
        levels: tuple[int, ...] | None = None,
        heuristic_weight: float = 1.0,
        max_expansions: int = 0,
        smoothing_iterations: int = 2,
        smooth_radius_m: float = 2.0,
        max_cells: int = 64_000_000,
        pad_m: float = 30.0,
    ):
        if not np.isfinite(clearance_m) or clearance_m < 0:
            raise InputError(f"clearance must be a non-negative number of metres, got {clearance_m}")
        if np.isnan(min_z) or np.isnan(max_z) or min_z >= max_z:
            raise InputError(f"altitude limits must satisfy min_z < max_z, got {min_z}, {max_z}")
        if not heuristic_weight >= 1.0:
            raise InputError(f"heuristic_weight must be >= 1, got {heuristic_weight}")
        if levels is not None and (not levels or min(levels) < 1 or levels[-1] != 1):
            raise InputError(f"levels must be positive integers ending with 1, got {levels}")
        if isinstance(source, DistanceField):
            occ = source.map
        elif isinstance(source, OccupancyMap):
            occ = source
        else:
            raise InputError(f"plan on an OccupancyMap or a DistanceField, got {type(source).__name__}")
        if occ.grid.count == 0:
            raise InputError("the map is empty; integrate some depth frames first")
        self.map = occ
        v = occ.voxel_size
        self.clearance = float(clearance_m)
        self.margin = float(0.5 * np.sqrt(3.0) * v if margin_m is None else margin_m)
        if not np.isfinite(self.margin) or self.margin < 0:
            raise InputError(f"margin must be a non-negative number of metres, got {margin_m}")
        self.threshold = self.clearance + self.margin
        self.allow_unknown = bool(allow_unknown)
        self.min_z = float(min_z)
        self.max_z = float(max_z)
        self.any_angle = bool(any_angle)
        if levels is None:
            f = max(1, int(round(1.5 / v)))
            levels = (f, 1) if f > 1 else (1,)
        self.levels = tuple(int(f) for f in levels)
        self.weight = float(heuristic_weight)
        self.max_expansions = int(max_expansions)
        self.smoothing_iterations = int(smoothing_iterations)
        self.smooth_radius = float(smooth_radius_m)
        self.max_cells = int(max_cells)
        self.pad = float(pad_m)
        self.step = 0.25 * v
        need = self.threshold + 2 * v
        if isinstance(source, DistanceField):
            if source.unknown_is_occupied == self.allow_unknown:
                raise InputError(
                    "the distance field treats unknown space as "
                    f"{'occupied' if source.unknown_is_occupied else 'free'} but allow_unknown={allow_unknown}; "
                    "build it with unknown_is_occupied = not allow_unknown"
                )
            if source.max_distance < need:
                raise InputError(
                    f"the distance field is clipped at {source.max_distance} m, below clearance + margin "
                    f"+ 2 voxels = {need:.2f} m; build it with a larger max_distance_m"
                )
            self.df = source
        else:
            self.df = DistanceField(occ, max_distance_m=need, unknown_is_occupied=not self.allow_unknown)
        self._grid: PlanningGrid | None = None

    # ----- grid management -------------------------------------------------------------------
    def update(self, changed_blocks: np.ndarray | None = None) -> np.ndarray:
        """Bring the distance field (and the cached planning grid) up to date after the map changed.

        Args:
            changed_blocks: (M, 3) map blocks that changed; None: ``map.pop_changed_blocks()``.
        Returns:
            (K, 3) int32 distance-field blocks whose values were rewritten.
        """
        if changed_blocks is None:
            changed_blocks = self.map.pop_changed_blocks()
        grid = self._grid
        grid_was_current = grid is not None and grid.version == self.df.version
        rewritten = self.df.update(changed_blocks)
        if (
            grid is not None and grid_was_current
        ):  # patch the dense grid in place (a grown map is caught by grid_for)
            grid.refresh(self.df, rewritten)
        return rewritten

    def _box_for(self, start: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = self.map.voxel_size
        lo, hi = self.map.voxel_bounds()
        if np.isfinite(self.min_z):
            lo[2] = max(lo[2], int(np.floor(self.min_z / v)) - 2)
        if np.isfinite(self.max_z):
            hi[2] = min(hi[2], int(np.ceil(self.max_z / v)) + 2)
        if np.prod((hi - lo).astype(np.float64)) > self.max_cells:
            pad = max(self.pad, 0.25 * float(np.linalg.norm(goal - start)))
            lo = np.maximum(lo, np.floor((np.minimum(start, goal) - pad) / v).astype(np.int64))
            hi = np.minimum(hi, np.ceil((np.maximum(start, goal) + pad) / v).astype(np.int64))
            if np.prod((hi - lo).astype(np.float64)) > self.max_cells:
                raise InputError(
                    f"planning box of {np.prod(hi - lo):.0f} voxels exceeds max_cells={self.max_cells}; "
                    "use a coarser map, tighter altitude limits or a larger max_cells"
                )
        return lo, hi

    def grid_for(self, start: np.ndarray, goal: np.ndarray) -> PlanningGrid:
        """The dense grid for a query (cached while the distance field and box do not change)."""
        lo, hi = self._box_for(start, goal)
        g = self._grid
        if (
            g is not None
            and g.version == self.df.version
            and np.all(g.lo <= lo)
            and np.all(g.lo + np.array(g.shape) >= hi)
        ):
            return g
        self._grid = None  # free the old grid before building the new one
        self._grid = PlanningGrid(self.df, lo, hi - lo, self.threshold, self.min_z, self.max_z, self.step)
        return self._grid

    @contextmanager
    def avoiding(self, capsules: np.ndarray | None, near: np.ndarray, goal: np.ndarray) -> Iterator[int]:
        """Within the ``with`` block, queries between ``near`` and ``goal`` ((3,) world metres)
        also keep the clearance from the keep-out capsules (K, 7) (moving obstacles, see
        :mod:`skyrecon.planning.keep_out`); the map's own grid is restored on exit. Do not
        update the planner inside the block.

        Yields:
            The number of grid voxels the capsules lowered.
        """
        grid = self.grid_for(np.minimum(near, goal), np.maximum(near, goal))
        with keep_out(grid, capsules) as n:
            yield n

    @contextmanager
    def weighted(self, heuristic_weight: float) -> Iterator[None]:
        """Within the ``with`` block, searches inflate their heuristic by ``heuristic_weight``
        (>= 1; paths at most that factor longer than the shortest, found with far fewer
        expansions); the planner's own weight is restored on exit."""
        if not heuristic_weight >= 1.0:
            raise InputError(f"heuristic_weight must be >= 1, got {heuristic_weight}")
        old = self.weight
        self.weight = float(heuristic_weight)
        try:
            yield
        finally:
            self.weight = old

    # ----- queries --------------------------------------------------------------------------
    def _kw(self) -> dict:
        return {"clearance_m": self.clearance, "margin_m": self.margin}

    def _check_inside(self, p: np.ndarray, what: str) -> None:
        lo, hi = self.map.bounds()
        if not (np.all(p >= lo) and np.all(p < hi)):
            raise InputError(
                f"{what} {np.round(p, 3).tolist()} is outside the map "
                f"(x {lo[0]:.1f}..{hi[0]:.1f}, y {lo[1]:.1f}..{hi[1]:.1f}, z {lo[2]:.1f}..{hi[2]:.1f} m); "
                "choose a point inside the mapped area"
            )

    def _endpoint_problem(self, grid: PlanningGrid, p: np.ndarray, what: str) -> PlanResult | None:
        if not (self.min_z <= p[2] <= self.max_z):
            return PlanResult.failure(
                f"{what}_altitude", f"z = {p[2]:.2f} m, limits {self.min_z:g}..{self.max_z:g} m", **self._kw()
            )
        state = int(self.map.state_at(p[None])[0])
        if state == OCCUPIED:
            return PlanResult.failure(f"{what}_in_obstacle", f"at {np.round(p, 2).tolist()}", **self._kw())
        if state == UNKNOWN and not self.allow_unknown:
            return PlanResult.failure(f"{what}_unknown", f"at {np.round(p, 2).tolist()}", **self._kw())
        d = float(grid.distance(p[None])[0])
        if d < self.threshold:
            return PlanResult.failure(
                f"{what}_too_close",
                f"distance field {max(d, 0):.2f} m at {np.round(p, 2).tolist()}, need clearance "
                f"{self.clearance:g} m + margin {self.margin:.2f} m",
                **self._kw(),
            )
        return None

    def _connect(
        self, grid: PlanningGrid, f: int, p: np.ndarray, limit: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Level-f nodes near p reachable from p in a clear straight line: flat indices and costs (fine voxels)."""
        cells_arr = grid.level(f)
        shape = np.array(cells_arr.shape)
        c = grid.node_of(f, p)
        r = np.arange(-2, 3)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        cells = c + offs
        cells = cells[np.all((cells >= 0) & (cells < shape), axis=1)]
        flat = (cells[:, 0] * shape[1] + cells[:, 1]) * shape[2] + cells[:, 2]
        flat = flat[cells_arr.reshape(-1)[flat] == 1]
        pos = grid.node_positions(f, flat)
        dist = np.linalg.norm(pos - p, axis=1)
        out_f, out_c = [], []
        ctx = grid.ctx()
        for i in np.argsort(dist):
            if _geom.clear(*ctx, p, pos[i], True):
                out_f.append(flat[i])
                out_c.append(dist[i] / grid.voxel)
                if len(out_f) >= limit:
                    break
        return np.array(out_f, np.int64), np.array(out_c, np.float64)

    def nearest_clear_point(
        self, position: np.ndarray, radius_m: float, toward: np.ndarray | None = None
    ) -> np.ndarray | None:
        """The nearest point within ``radius_m`` of ``position`` (3,) world metres where a path
        may start (at the full clearance, known free unless ``allow_unknown``, within the altitude
        limits), reachable in a straight line without getting closer to any obstacle; among
        equally near ones, the one nearest ``toward``. None if there is none.

        Used where a path must start or end at a point the planner cannot use: a drone that finds
        itself closer than the clearance to something it has just mapped, or a start or goal in
        space the map has not observed.
        """
        p = check_point3(position, "position")
        other = p if toward is None else check_point3(toward, "toward")
        grid = self.grid_for(np.minimum(p, other), np.maximum(p, other))
        offs = self._ball_offsets(radius_m)
        cand = p + offs
        good = np.flatnonzero(self._usable(grid, cand))
        if len(good) == 0:
            return None
        order = good[
            np.lexsort((np.linalg.norm(cand[good] - other, axis=1), np.linalg.norm(offs[good], axis=1)))
        ]
        d0 = float(grid.distance(p[None])[0])
        for i in order[:64]:
            if self._reachable_without_closing_in(grid, p, cand[i], d0):
                return cand[i]
        return None

    def point_away_from(
        self, position: np.ndarray, radius_m: float, capsules: np.ndarray, min_gain_m: float = 0.5
    ) -> np.ndarray | None:
        """The point within ``radius_m`` of ``position`` (3,) world metres farthest from the
        keep-out ``capsules`` (K, 7) (:mod:`skyrecon.planning.keep_out`) among those at the full
        clearance from the map's obstacles, within the altitude limits, and reachable in a
        straight line that gets closer to neither the map's obstacles nor the capsules; None
        when none is at least ``min_gain_m`` farther from the capsules than ``position``.

        A best-effort escape for when no point within reach clears a mover's predicted sweep
        (a crane boom's keep-out can be 7 m across): farther away is still safer than hovering
        in it. Call it outside :meth:`avoiding` (the map's own distances).
        """
        from skyrecon.planning.keep_out import as_capsules, capsule_distance

        p = check_point3(position, "position")
        caps = as_capsules(capsules)
        if len(caps) == 0:
            return None
        grid = self.grid_for(p - radius_m, p + radius_m)
        cand = p + self._ball_offsets(radius_m)
        cand = cand[self._usable(grid, cand)]
        if len(cand) == 0:
            return None
        c0 = float(capsule_distance(p[None], caps)[0])
        gain = capsule_distance(cand, caps) - c0
        order = np.lexsort((np.linalg.norm(cand - p, axis=1), -gain))
        d0 = float(grid.distance(p[None])[0])
        for i in order[:64]:
            if gain[i] < min_gain_m:
                return None
            q = cand[i]
            if self._reachable_without_closing_in(grid, p, q, d0) and np.all(
                capsule_distance(self._segment(p, q), caps) >= c0 - 0.02
            ):
                return q
        return None

    def is_clear_point(self, position: np.ndarray, point: np.ndarray) -> bool:
        """Whether ``point`` (3,) world metres is one :meth:`nearest_clear_point` could pick from
        ``position`` (3,): at the full clearance, within the altitude limits, and reachable in a
        straight line without getting closer to any obstacle (radius not checked). Lets a caller
        keep a point it chose before while it stays usable (hysteresis)."""
        p = check_point3(position, "position")
        q = check_point3(point, "point")
        grid = self.grid_for(np.minimum(p, q), np.maximum(p, q))
        if not self._usable(grid, q[None])[0]:
            return False
        return self._reachable_without_closing_in(grid, p, q, float(grid.distance(p[None])[0]))

    def _ball_offsets(self, radius_m: float) -> np.ndarray:
        """(N, 3) offsets on the voxel lattice within ``radius_m`` (metres), the zero one left out."""
        r = np.arange(-radius_m, radius_m + 1e-9, self.map.voxel_size)
        offs = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        norm = np.linalg.norm(offs, axis=1)
        return offs[(norm <= radius_m) & (norm > 0)]

    def _usable(self, grid: PlanningGrid, pts: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3) lie at the full clearance and within the altitude limits."""
        return (
            (grid.distance(pts) >= self.threshold + 0.05)
            & (pts[:, 2] >= self.min_z)
            & (pts[:, 2] <= self.max_z)
        )

    def _segment(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(n, 3) points from ``p`` to ``q`` (both included), every quarter voxel."""
        n = max(2, int(np.ceil(np.linalg.norm(q - p) / (0.25 * self.map.voxel_size))) + 1)
        return p + (q - p) * np.linspace(0.0, 1.0, n)[:, None]

    def _reachable_without_closing_in(
        self, grid: PlanningGrid, p: np.ndarray, q: np.ndarray, d0: float
    ) -> bool:
        """The straight segment ``p`` -> ``q`` never comes closer to an obstacle than ``p`` is
        (``d0``, its distance) or than the clearance, whichever is less."""
        return bool(np.all(grid.distance(self._segment(p, q)) >= min(d0, self.threshold) - 0.02))

    def plan(self, start: np.ndarray, goal: np.ndarray, snap_radius_m: float = 0.0) -> PlanResult:
        """Plan from ``start`` to ``goal`` ((3,) world points, metres).

        Args:
            snap_radius_m: when the start or the goal lies in unknown space or closer to an
                obstacle than the clearance (e.g. a point the vehicle flew through, which the
                cameras never saw), plan from / to the nearest usable point within this radius
                (:meth:`nearest_clear_point`) and join it with a straight segment; the result's
                ``adjusted`` says what was moved, from where, to where and why. 0: never.
        Returns:
            PlanResult (success, waypoints (K, 3) world, length, or the reason of failure).
        Raises:
            InputError: NaN or misshaped points, or a point outside the map.
        """
        t0 = time.perf_counter()
        s = check_point3(start, "start")
        g = check_point3(goal, "goal")
        self._check_inside(s, "start")
        self._check_inside(g, "goal")
        grid = self.grid_for(s, g)
        t_grid = time.perf_counter()
        moved: dict[str, dict] = {}
        for p, what, other in ((s, "start", g), (g, "goal", s)):
            bad = self._endpoint_problem(grid, p, what)
            if (
                bad is not None
                and snap_radius_m > 0
                and bad.reason in (f"{what}_unknown", f"{what}_too_close")
            ):
                near = self.nearest_clear_point(p, snap_radius_m, toward=other)
                if near is not None:
                    moved[what] = {
                        "from": p.tolist(),
                        "to": near.tolist(),
                        "distance_m": float(np.linalg.norm(near - p)),
                        "reason": bad.reason,
                    }
                    continue
                bad.message += f"; no usable point within {snap_radius_m:g} m either"
            if bad is not None:
                bad.timings = {"grid": t_grid - t0, "total": time.perf_counter() - t0}
                return bad
        if moved:
            inner = self.plan(
                np.asarray(moved.get("start", {}).get("to", s)),
                np.asarray(moved.get("goal", {}).get("to", g)),
            )
            if inner.success:
                parts = [s[None]] if "start" in moved else []
                parts.append(inner.waypoints)
                if "goal" in moved:
                    parts.append(g[None])
                inner.waypoints = np.vstack(parts)
                inner.length_m = float(_geom.polyline_length(inner.waypoints))
            inner.adjusted = moved
            inner.timings["total"] = time.perf_counter() - t0
            return inner
        expansions = 0
        t_search = time.perf_counter()
        raw: np.ndarray | None
        if _geom.clear(*grid.ctx(), s, g, True):
            raw = np.stack([s, g])
        else:
            raw = None
            failure: PlanResult | None = None
            for f in self.levels:
                raw, failure, n_exp = self._search_level(grid, f, s, g)
                expansions += n_exp
                if raw is not None:
                    break
            if raw is None:
                assert failure is not None  # a level without a path says why
                failure.timings = {"grid": t_grid - t0, "total": time.perf_counter() - t0}
                failure.expansions = expansions
                return failure
        t_search2 = time.perf_counter()
        path = self._refine(grid, raw)
        t_ref = time.perf_counter()
        length = float(_geom.polyline_length(path))
        dmin = float(
            _geom.path_min_distance(grid.dist, grid.origin, grid.inv_v, grid.zmin, grid.zmax, self.step, path)
        )
        return PlanResult(
            True,
            path,
            length,
            "",
            "",
            self.clearance,
            self.margin,
            dmin,
            int(expansions),
            {
                "grid": t_grid - t0,
                "search": t_search2 - t_search,
                "refine": t_ref - t_search2,
                "total": t_ref - t0,
            },
        )

    def _search_level(
        self, grid: PlanningGrid, f: int, s: np.ndarray, g: np.ndarray
    ) -> tuple[np.ndarray | None, PlanResult | None, int]:
        """Search on level f: (raw polyline or None, failure PlanResult or None, expansions)."""
        starts, costs = self._connect(grid, f, s, 8)
        goals, _ = self._connect(grid, f, g, 1)
        if len(starts) == 0:
            return (
                None,
                PlanResult.failure(
                    "start_enclosed", "no free node nearby is reachable in a straight line", **self._kw()
                ),
                0,
            )
        if len(goals) == 0:
            return (
                None,
                PlanResult.failure(
                    "goal_enclosed", "no free node nearby is reachable in a straight line", **self._kw()
                ),
                0,
            )
        cells = grid.level(f)
        gs, parent, stamp, gen = grid.search_state(f)
        # a small enclosed goal region would otherwise make the search flood the whole start region
        limit = 20000
        n_goal, reached, capped = component(cells, goals[0], starts[0], limit, stamp, gen)
        reached = reached or bool(np.any(stamp[starts] == 2 * gen + 1))
        if not reached and not capped:
            vol = n_goal * (f * grid.voxel) ** 3
            return (
                None,
                PlanResult.failure(
                    "goal_enclosed",
                    f"the goal's free region holds {vol:.1f} m^3 of flyable space",
                    **self._kw(),
                ),
                0,
            )
        gs, parent, stamp, gen = grid.search_state(f)
        path, _cost, n_exp, status = search(
            cells,
            f,
            grid.safe,
            starts,
            costs,
            goals[0],
            self.weight,
            self.any_angle,
            self.max_expansions,
            gs,
            parent,
            stamp,
            gen,
        )
        if status == 0:
            return np.concatenate([s[None], grid.node_positions(f, path), g[None]]), None, n_exp
        if status == 2:
            return (
                None,
                PlanResult.failure("search_limit", f"{n_exp} expansions on level {f}", **self._kw()),
                n_exp,
            )
        vol = n_exp * (f * grid.voxel) ** 3
        return (
            None,
            PlanResult.failure(
                "start_enclosed",
                f"the start's free region holds {vol:.1f} m^3 of flyable space",
                **self._kw(),
            ),
            n_exp,
        )

    def _refine(self, grid: PlanningGrid, raw: np.ndarray) -> np.ndarray:
        """Shorten and smooth a clear polyline, keeping every segment clear."""
        ctx = grid.ctx()
        v = grid.voxel
        pts = _turning_points(raw)
        pts = _geom.shortcut(*ctx, pts)
        best = pts
        pts = _geom.densify(pts, 4.0 * v)
        pts = _geom.relax(*ctx, pts, 200, 1e-3)
        pts = _geom.shortcut(*ctx, pts)
        if self.smoothing_iterations > 0:
            pts = _geom.smooth_corners(*ctx, pts, self.smoothing_iterations, self.smooth_radius)
        pts = _geom.drop_collinear(*ctx, pts, 0.02 * v)
        if _geom.first_blocked(*grid.sampled_ctx(), pts) >= 0:  # not expected; keep a checked path
            pts = best
        return pts

    def path_is_clear(self, waypoints: np.ndarray) -> tuple[bool, int]:
        """Whether a polyline (K, 3) keeps clearance + margin everywhere (sampled every quarter
        voxel); and the index of the first blocked segment (-1 if clear)."""
        w = np.ascontiguousarray(np.asarray(waypoints, dtype=np.float64).reshape(-1, 3))
        if len(w) == 0:
            return True, -1
        grid = self.grid_for(w.min(axis=0), w.max(axis=0))
        if len(w) == 1:
            ok = float(grid.distance(w)[0]) >= self.threshold
            return ok, -1 if ok else 0
        k = int(_geom.first_blocked(*grid.sampled_ctx(), w))
        return k < 0, k


def _turning_points(raw: np.ndarray) -> np.ndarray:
    """Keep the endpoints and the vertices where a grid path changes direction."""
    if len(raw) <= 2:
        return raw.copy()
    d = np.diff(raw, axis=0)
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    turn = np.any(np.abs(d[1:] - d[:-1]) > 1e-9, axis=1)
    keep = np.concatenate([[True], turn, [True]])
    return np.ascontiguousarray(raw[keep])


_CACHE_ATTR = "_skyrecon_planner_cache"


def plan_path(
    occ_map: OccupancyMap | DistanceField,
    start: np.ndarray,
    goal: np.ndarray,
    clearance_m: float = 2.0,
    snap_radius_m: float = 0.0,
    **options,
) -> PlanResult:
    """Plan a collision-free path on a map (see :class:`Planner` for the options).

    Repeated calls on the same, unchanged map with the same options reuse the distance field and
    the dense grid.

    Args:
        occ_map: the map (or its distance field).
        start, goal: (3,) world points, metres.
        clearance_m: distance to keep from obstacles, metres.
        snap_radius_m: start or goal in unknown space or too near an obstacle: plan from / to the
            nearest usable point within this radius (see :meth:`Planner.plan`).
    Returns:
        PlanResult: waypoints (K, 3) world metres, length, success, and reason on failure.
    Raises:
        InputError: malformed input or start / goal outside the map.
    """
    base = occ_map.map if isinstance(occ_map, DistanceField) else occ_map
    key = (id(occ_map), float(clearance_m), tuple(sorted(options.items())))
    # the cache lives on the map itself: a planner refers to its map, so a module-level weak mapping
    # from maps to planners would keep every map ever planned on alive; this way both go together
    per_map = base.__dict__.setdefault(_CACHE_ATTR, {}) if isinstance(base, OccupancyMap) else {}
    hit = per_map.get(key)
    if hit is None or hit[0] != base.version:
        planner = Planner(occ_map, clearance_m, **options)
        per_map.clear()
        per_map[key] = (base.version, planner)
    else:
        planner = hit[1]
    return planner.plan(start, goal, snap_radius_m)
