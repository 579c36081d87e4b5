"""The drone's own map and path: occupancy map, distance field, planner and replanner.

Exploration policy (the drone starts knowing nothing; its map is pre-allocated over the city as
unknown space, so that the goal lies inside it from the start):

* **Optimistic planning.** The planner treats unknown space as free
  (``Planner(allow_unknown=True)`` on a distance field with ``unknown_is_occupied=False``), so
  the first path is the straight line to the goal and every replan heads through unexplored
  space by the shortest way the map still allows.
* **Observed before entered.** The drone only flies through space it has *seen* free: every
  cycle :meth:`Navigator.verified_distance` walks the path ahead and finds the first point
  whose voxel is not known free, or whose tube (``verify_radius_m`` to the left, right and
  below) still holds unknown voxels. The speed is capped so that the drone can brake
  ``verify_buffer_m`` before that point, and the camera turns to look at it (see
  :mod:`skyrecon.mission.guidance`): the stretch ahead is observed as the drone comes closer,
  and at a corner it slows down, turns, looks, and goes on. Sky matches at infinite depth and
  carves free space up to the map's range, so open air above roofs gets observed too.
* **Replanning.** Every cycle the new depth is integrated; the blocks whose *occupied* voxels
  changed (``map.pop_changed_blocks(occupied_only=True)``) are passed to the distance field
  (with unknown space counted as free, a block that only turned from unknown to free cannot
  change the field, so it is skipped, which keeps the update small); the :class:`~skyrecon.planning.Replanner` re-checks the remaining path where
  the field changed, and the drone plans again from where it is when the path is blocked by
  more than ``replan_tolerance_m`` inside the clearance (hysteresis: a path planned at the
  clearance hugs it, and every new observation would otherwise nibble at it and trigger a
  replan). If the drone is too close to a freshly mapped obstacle for the planner to start
  there, the plan starts from the nearest point at the full clearance that it can reach without
  getting closer to anything (:meth:`Navigator.escape_point`), and the path leads there first.

Frames and units: world frame (z up), metres.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.mapping import FREE, OCCUPIED, UNKNOWN, DistanceField, MapConfig, OccupancyMap
from skyrecon.mapping.config import STEREO_PLAUSIBLE_DEPTH_M
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.guidance import out_of_reach_mask
from skyrecon.mission.prior import OBSERVED_FREE_LOG_ODDS, PriorMap
from skyrecon.mission.scenario import MapBox
from skyrecon.mission.unseen import UnseenSpots, unknown, unknown_pocket
from skyrecon.mission.vehicle import sample_path
from skyrecon.perception import GroundPlane
from skyrecon.planning import Planner, PlanResult, Replanner, path_conflict, remaining_path
from skyrecon.planning.keep_out import warm_kernels as warm_keep_out

#: Why a plan cannot start where the drone is (too close to an obstacle): an escape point is sought.
_START_PROBLEMS = ("start_too_close", "start_in_obstacle", "start_enclosed")


@dataclass
class CheckOutcome:
    """The path check of one cycle.

    Attributes:
        clear: the remaining path keeps the clearance in the updated map.
        checked: it had to be re-checked (the distance field changed on it).
        blocked_segment: first blocked segment of the remaining path, or -1.
        tolerated: blocked, but within ``replan_tolerance_m`` of the clearance (kept).
        evading: the path only steps out of a mover's predicted sweep and goes no further
            (see :meth:`Navigator.replan`): not clear, so that a path to the goal is sought
            every cycle.
    """

    clear: bool
    checked: bool
    blocked_segment: int
    tolerated: bool = False
    evading: bool = False


class Navigator:
    """The drone's map and planner for one mission.

    Args:
        cfg: mission settings.
        box: the world box the map is pre-allocated over (unknown everywhere at first), so that
            the goal lies inside the map from the start and the planner's dense grid keeps its size.
        goal: (3,) world metres.
        max_range_m: the map's range (measurements farther carve free space up to it only),
            metres; None: ``cfg.max_range_m``.
    """

    def __init__(
        self,
        cfg: MissionConfig,
        box: MapBox,
        goal: np.ndarray,
        max_range_m: float | None = None,
        prior: PriorMap | None = None,
    ):
        self.cfg = cfg
        self.goal = np.asarray(goal, dtype=np.float64)
        rng = cfg.max_range_m if max_range_m is None else max_range_m
        # the loop's depth is its own stereo's, in metres: a view over far fields is not an error
        mc = MapConfig(
            voxel_size_m=cfg.voxel_size_m, max_range_m=rng, max_plausible_depth_m=STEREO_PLAUSIBLE_DEPTH_M
        )
        if prior is not None:
            self.map = prior.seed_map(mc)
            # a voxel is seen free only after this flight's own cameras saw it (see mission.prior)
            self.observed_free_below = OBSERVED_FREE_LOG_ODDS
        else:
            nothing = np.zeros(box.shape, bool)
            self.map = OccupancyMap.from_occupancy_grid(nothing, box.origin, mc, known=nothing)
            self.map.pop_changed_blocks()
            self.map.pop_changed_blocks(occupied_only=True)
            self.observed_free_below = 0.0
        self.prior = prior
        v = cfg.voxel_size_m
        need = cfg.clearance_m + cfg.planning_margin_m + 2 * v + 0.05  # what the Planner needs, no more
        self.df = DistanceField(self.map, max_distance_m=need, unknown_is_occupied=False)
        self.planner = Planner(
            self.df, cfg.clearance_m, allow_unknown=True, min_z=cfg.min_altitude_m, max_z=cfg.max_altitude_m
        )
        self.replanner = Replanner(self.planner, self.goal)
        self.escape_to: np.ndarray | None = None  # the escape point of the path followed, if any
        self.evading = False  # the path followed ends at its escape point (no way on from there yet)
        # space the cameras could not observe, kept clear of (mission.unseen)
        self.unseen = UnseenSpots(v, cfg.drone_radius_m + cfg.safety_margin_m)

    def warm_up(self, intrinsics: Intrinsics) -> None:
        """Load the map's kernels before the first cycle: integrate one synthetic depth image
        (a wall 8 m ahead, a band beyond the range, a band of invalid pixels) with the camera's
        ``intrinsics`` into a throwaway map of the same configuration, mark a flown segment free
        and build its distance field; load the keep-out kernel and build the planner's dense grid
        (24 ms on a 512 x 512 x 40 map, once). Numba loads each cached kernel on its first call
        (about 8 ms apiece); left to the first cycle, that stalled it by 50 ms. This map is not
        touched."""
        scratch = OccupancyMap(self.map.config)
        h, w = intrinsics.height, intrinsics.width
        depth = np.full((h, w), 8.0, np.float32)
        depth[: h // 4] = np.inf
        depth[h // 4 : h // 3] = np.nan
        cam = Rigid3.identity("world", "cam")
        scratch.integrate_depth(depth, intrinsics, cam)
        scratch.mark_flown_free(np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]), self.cfg.drone_radius_m)
        DistanceField(scratch, max_distance_m=self.df.max_distance, unknown_is_occupied=False)  # computes it
        warm_keep_out()  # the first replan around a mover must not load it either
        # the dense planning grid (the whole map box; patched from now on, not rebuilt in a cycle)
        self.planner.grid_for(self.goal, self.goal)

    # ----- sensing -----------------------------------------------------------------------
    def integrate(
        self,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        cam_from_world: Rigid3,
        flown_from: np.ndarray | None = None,
        carve_only: np.ndarray | None = None,
    ) -> None:
        """Integrate one depth image (h, w) float32 metres (NaN invalid, inf beyond range); with
        ``flown_from`` (3,) world metres, the segment flown from there to the camera is marked free
        (the drone's body swept it, ``drone_radius_m``); ``carve_only`` (h, w) bool: pixels that
        carve free space in front of them but mark no obstacle (unconfirmed far depth)."""
        world_from_cam = cam_from_world.inverse().with_frames("world", "cam")
        self.map.integrate_depth(depth_m, intrinsics, world_from_cam, carve_only=carve_only)
        if flown_from is not None:
            self.map.mark_flown_free(np.stack([flown_from, world_from_cam.t]), self.cfg.drone_radius_m)
        self.unseen.forget_known(self.map, self.observed_free_below)

    def ground_plane(self, cam_from_world: Rigid3) -> GroundPlane | None:
        """The ground (world z ``cfg.ground_z_m``) as a camera at ``cam_from_world`` sees it,
        for the stereo stage's ground prior; None when the camera is not above it or the
        ground's height is not given."""
        if self.cfg.ground_z_m is None:
            return None
        return GroundPlane.from_pose(cam_from_world.inverse(), self.cfg.ground_z_m)

    def update_distance(self) -> np.ndarray:
        """Bring the distance field and the planner's grid up to date.

        Returns:
            (K, 3) int32 distance-field blocks that were rewritten.
        """
        return self.planner.update(self.map.pop_changed_blocks(occupied_only=True))

    # ----- the path ----------------------------------------------------------------------
    @property
    def waypoints(self) -> np.ndarray:
        """(K, 3) the current path, world metres."""
        return self.replanner.waypoints

    def check(self, position: np.ndarray, rewritten: np.ndarray) -> CheckOutcome:
        """Whether the rest of the path from ``position`` (3,) is still clear (re-checked only
        where the distance field changed, see ``Replanner.check``). A path the Replanner finds
        blocked is kept when it stays within ``replan_tolerance_m`` of the clearance (see
        :meth:`clear_at`)."""
        if len(self.replanner.waypoints) == 0:
            return CheckOutcome(False, True, 0)
        if self.evading:
            return CheckOutcome(False, True, 0, evading=True)
        clear, k, checked = self.replanner.check(position, rewritten)
        if not clear:
            rest = remaining_path(self.replanner.waypoints, position)
            if self.clear_at(rest, self.planner.threshold - self.cfg.replan_tolerance_m):
                return CheckOutcome(True, checked, k, tolerated=True)
        return CheckOutcome(clear, checked, k)

    def clear_at(self, path: np.ndarray, threshold_m: float) -> bool:
        """Whether the interpolated distance field stays at least ``threshold_m`` along ``path``
        (K, 3) world metres (sampled every quarter voxel, on the planner's grid).

        The first stretch may start closer than that (after an escape, see :meth:`replan`): its
        first 3.5 m pass as long as the distance does not decrease along them (the path leads out).
        """
        if len(path) < 2:
            return True
        grid = self.planner.grid_for(path.min(axis=0), path.max(axis=0))
        pts, s = sample_path(path, 0.25 * self.cfg.voxel_size_m, np.inf)
        d = grid.distance(pts)
        ok = d >= threshold_m
        k = 0
        while k < len(d) and not ok[k] and s[k] <= 3.5 and (k == 0 or d[k] >= d[k - 1] - 0.02):
            k += 1
        return bool(np.all(ok[k:]))

    def escape_point(self, position: np.ndarray, radius_m: float = 3.0) -> np.ndarray | None:
        """The nearest point (within ``radius_m``) at the full clearance that the drone can reach
        in a straight line without getting closer to any mapped obstacle; None if there is none.

        Used when the drone finds itself closer than the clearance to something it has just
        mapped: the planner cannot start there, so it plans from this point instead.
        """
        return self.planner.nearest_clear_point(position, radius_m, toward=self.goal)

    def replan(self, position: np.ndarray, keep_out: np.ndarray | None = None) -> tuple[PlanResult, str]:
        """Plan from ``position`` (3,) to the goal; on success the new path is followed.

        When the drone is too close to a mapped obstacle for the planner to start there
        (``start_too_close``, ``start_in_obstacle``, ``start_enclosed``), the plan starts at the
        :meth:`escape_point` instead and the path leads there first. With
        ``MissionConfig.evade_movers`` (on by default, see there), the escape point of the
        path followed is kept while it stays usable (:meth:`Planner.is_clear_point`), so that
        escapes do not flip from one side to the other between cycles as a mover's prediction
        shifts; and with ``keep_out``, when no path goes on from the escape point (a mover's
        sweep closes the way to the goal), the path is the step out of the sweep alone
        (:attr:`evading`): hovering in a mover's way is not safe (mission 115: a crane boom
        swept at 0.6 m/s into a drone that hovered for 10 s, its escapes found but never
        followed because no path to the goal started there); when no point within reach clears
        the sweep, the step goes to the reachable point farthest from it
        (:meth:`Planner.point_away_from`). The unseen spots (:attr:`unseen`, see
        :meth:`avoid_unseen`) are kept clear of as well when a path goes round them, and left
        out when none does.

        Args:
            keep_out: (K, 7) capsules of the tracked movers' predicted sweep
                (:mod:`skyrecon.planning.keep_out`), kept clear like obstacles for this plan.
        Returns:
            The PlanResult (its waypoints start at ``position``) and how it was planned:
            "plan" or "escape".
        """
        p = np.asarray(position, dtype=np.float64)
        movers = _any(keep_out)
        if len(self.unseen):
            # unseen spots are kept clear of like obstacles; when no path goes round them, the
            # plan is what it would be without them
            r, how = self._replan_avoiding(p, self._keep_out(keep_out), movers)
            if r.success:
                return r, how
        if keep_out is None or not movers:
            return self._replan(p, 3.0, evade=False)
        return self._replan_avoiding(p, keep_out, True)

    def _keep_out(self, movers: np.ndarray | None) -> np.ndarray:
        """(K, 7) the movers' capsules (or None) and the unseen spots' together."""
        spots = self.unseen.capsules(self.planner.threshold)
        return np.vstack([movers, spots]) if movers is not None and _any(movers) else spots

    def _replan_avoiding(self, p: np.ndarray, keep_out: np.ndarray, movers: bool) -> tuple[PlanResult, str]:
        """:meth:`replan` keeping clear of the capsules ``keep_out`` (K, 7); ``movers``: some of
        them are movers' predicted sweeps (an escape step out of them is taken even with no
        way on, see :meth:`replan`)."""
        evade = movers and self.cfg.evade_movers
        # MissionConfig.keep_out_heuristic_weight > 1 finds a way around a mover's predicted
        # sweep with a small fraction of the expansions (see its notes: 1 by default)
        with (
            self.planner.avoiding(keep_out, p, self.goal),
            self.planner.weighted(self.cfg.keep_out_heuristic_weight),
        ):
            r, how = self._replan(p, 6.0, evade=evade)
        if evade and not r.success and r.reason in _START_PROBLEMS:
            # no point within reach clears the sweep (a crane boom's keep-out can be 7 m across):
            # farther from it is still safer than hovering in it
            away = self.planner.point_away_from(p, 6.0, keep_out)
            if away is not None:
                return self._escape_along(p, away, None, r), "escape"
        return r, how

    def avoid_unseen(
        self, position: np.ndarray, keep_out: np.ndarray | None = None
    ) -> tuple[PlanResult, str] | None:
        """Make the unobserved space that holds the drone at ``position`` (3,) unseen spots
        (:mod:`skyrecon.mission.unseen`) and plan round them (with the movers' ``keep_out``
        capsules, as :meth:`replan`).

        Returns:
            The new plan and how it was planned, as :meth:`replan`; None when nothing ahead is
            unobserved, or when no path goes round it: then the spots are taken back and the
            path is left as it was.
        """
        p = np.asarray(position, dtype=np.float64)
        cfg = self.cfg
        probes = self.unverified_probes(self.rest(p), cfg.verify_horizon_m, cfg.verify_skip_m)
        pocket = unknown_pocket(self.map, probes, self.observed_free_below)
        if self.unseen.add(pocket) == 0:
            return None
        movers = _any(keep_out)
        before = (self.replanner.waypoints, self.escape_to, self.evading)
        r, how = self._replan_avoiding(p, self._keep_out(keep_out), movers)
        if not r.success or self.evading:  # a step out of a mover's way alone is not a way round
            self.unseen.undo()
            self.replanner.waypoints, self.escape_to, self.evading = before
            return None
        return r, how

    def _replan(self, p: np.ndarray, escape_radius_m: float, evade: bool) -> tuple[PlanResult, str]:
        r = self.replanner.replan(p)
        if r.success or r.reason not in _START_PROBLEMS:
            if r.success:
                self.escape_to = None
                self.evading = False
            return r, "plan"
        kept = self.escape_to if self.cfg.evade_movers else None
        esc: np.ndarray | None
        if (
            kept is not None
            and np.linalg.norm(kept - p) <= escape_radius_m
            and self.planner.is_clear_point(p, kept)
        ):
            esc = kept.copy()
        else:
            esc = self.escape_point(p, escape_radius_m)
        if esc is None:
            return r, "plan"
        on = self.planner.plan(esc, self.goal)
        if not on.success and not evade:
            return r, "plan"
        # with evade and no way on from there: step out of the sweep all the same
        return self._escape_along(p, esc, on if on.success else None, r), "escape"

    def _escape_along(
        self, p: np.ndarray, esc: np.ndarray, on: PlanResult | None, failed: PlanResult
    ) -> PlanResult:
        """Follow the straight step from ``p`` to the escape point ``esc`` (3,), then the plan
        ``on`` from there to the goal; with ``on`` None, the step alone (:attr:`evading`).
        ``failed`` is the plan that could not start at ``p`` (its clearance is reported)."""
        if on is None:
            out = PlanResult(
                True, np.vstack([p, esc]), 0.0, clearance_m=failed.clearance_m, margin_m=failed.margin_m
            )
        else:
            out = on
            out.waypoints = np.vstack([p[None], on.waypoints])
        out.length_m = float(np.linalg.norm(np.diff(out.waypoints, axis=0), axis=1).sum())
        self.replanner.waypoints = out.waypoints
        self.escape_to, self.evading = esc.copy(), on is None
        return out

    def escaping(self, position: np.ndarray) -> bool:
        """Whether the drone at ``position`` (3,) is on the first leg of an escape path (to the
        :meth:`escape_point`, in a straight line that gets closer to nothing mapped nor to a
        mover's predicted sweep) and not yet there."""
        if self.escape_to is None:
            return False
        w = self.replanner.waypoints
        if len(w) < 2 or np.linalg.norm(w[1] - self.escape_to) > 1e-6:
            self.escape_to = None  # another path is followed now
            self.evading = False
            return False
        if np.linalg.norm(np.asarray(position, dtype=np.float64) - self.escape_to) < 0.3:
            self.escape_to = None
            return False
        return True

    def mover_conflict(self, rest: np.ndarray, keep_out: np.ndarray | None, reach_m: float) -> float:
        """Where the path ahead meets a mover's predicted sweep.

        Args:
            rest: (K, 3) the path ahead, starting at the drone, world metres.
            keep_out: (K, 7) capsules (:mod:`skyrecon.planning.keep_out`) or None.
            reach_m: only the first ``reach_m`` of the path count (where the drone can be
                within the prediction horizon).
        Returns:
            Arc length of the first sample closer to a capsule than the planner's threshold
            less ``replan_tolerance_m`` (hysteresis, as for static obstacles), metres; inf if none.
        """
        if keep_out is None or len(keep_out) == 0 or len(rest) < 2:
            return float("inf")
        near, _ = sample_path(rest, 0.5 * self.cfg.voxel_size_m, reach_m)
        if len(near) < 2:
            return float("inf")
        thr = self.planner.threshold - self.cfg.replan_tolerance_m
        return path_conflict(near, keep_out, thr, 0.5 * self.cfg.voxel_size_m)

    def rest(self, position: np.ndarray) -> np.ndarray:
        """(K, 3) the part of the path still ahead, starting at ``position``."""
        return remaining_path(self.replanner.waypoints, position)

    def verified_distance(self, rest: np.ndarray, horizon_m: float, skip_m: float) -> float:
        """How far along the path ahead (``rest`` (K, 3), starting at the drone) space is observed.

        A sample (every half voxel) is verified when its voxel is known free and the voxels
        ``verify_radius_m`` to its left, right and below (perpendicular to the path) are known
        (free or occupied: occupied ones are the distance field's business). Nothing in the
        city overhangs the flight band, so the tube is not probed above. Samples within
        ``skip_m`` of the drone are taken as verified (the drone is there, and they lie below the
        camera's field of view).

        Returns:
            Arc length of the first unverified sample, metres, or ``horizon_m`` when all are.
        """
        tube = self._tube(rest, horizon_m, skip_m)
        if tube is None:
            return horizon_m
        s, _, _, ok = tube
        bad = np.flatnonzero(~ok)
        return float(s[bad[0]]) if len(bad) else horizon_m

    def unverified_probes(self, rest: np.ndarray, horizon_m: float, skip_m: float) -> np.ndarray:
        """The probes of the first unverified sample of :meth:`verified_distance` (the sample
        itself and its tube points) whose voxels are not observed: (M, 3) world metres, (0, 3)
        when the whole horizon is verified."""
        tube = self._tube(rest, horizon_m, skip_m)
        if tube is None or tube[3].all():
            return np.zeros((0, 3))
        _, probes, unseen, ok = tube
        k = int(np.argmin(ok))
        return probes[unseen[:, k], k]

    def _tube(
        self, rest: np.ndarray, horizon_m: float, skip_m: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The samples of :meth:`verified_distance` beyond ``skip_m``: their arc lengths (N,),
        probes (4, N, 3) (the sample; left, right, below it), whether each probe's voxel is
        unobserved (4, N) (:func:`~skyrecon.mission.unseen.unknown`) and whether each sample is
        verified (N,); None when there are none."""
        if len(rest) < 2:
            return None
        v = self.cfg.voxel_size_m
        pts, s = sample_path(rest, 0.5 * v, horizon_m)
        if len(pts) < 2:
            return None
        sel = s >= skip_m
        if not np.any(sel):
            return None
        tang = np.gradient(pts, axis=0)
        pts, s, tang = pts[sel], s[sel], tang[sel]
        tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
        side = np.cross(tang, [0.0, 0.0, 1.0])
        ns = np.linalg.norm(side, axis=1, keepdims=True)
        side = np.where(ns > 1e-6, side / np.maximum(ns, 1e-9), [1.0, 0.0, 0.0])
        down = -np.cross(side, tang)
        r = self.cfg.verify_radius_m
        probes = np.stack([pts, pts + r * side, pts - r * side, pts + r * down])
        lo = self.map.log_odds_at(probes.reshape(-1, 3)).reshape(4, -1)
        unseen = unknown(lo, self.observed_free_below)
        with np.errstate(invalid="ignore"):
            seen_free = lo[0] < self.observed_free_below
        known = ~unseen[1:]
        if self.cfg.reach_aware_verify and not known.all():
            # near tube probes the camera cannot reach from here count as known, as the path
            # samples within skip_m do (see MissionConfig.reach_aware_verify)
            tube = probes[1:]
            near = np.linalg.norm(tube - rest[0], axis=2) <= skip_m + r
            check = near & ~known
            if check.any():
                known[check] = out_of_reach_mask(rest[0], tube[check], self.cfg)
        return s, probes, unseen, seen_free & np.all(known, axis=0)

    def free_along(self, position: np.ndarray, velocity: np.ndarray, horizon_m: float) -> float:
        """How far along the straight line from ``position`` (3,) in the direction of ``velocity``
        (3,) world m/s the space is known free (observed, as :meth:`verified_distance` checks a
        path) and keeps ``drone_radius_m + safety_margin_m`` from every mapped obstacle: where the
        drone's momentum carries it if it brakes now.

        Returns:
            Metres (at most ``horizon_m``); ``inf`` when the drone is about still (below 0.5 m/s).
        """
        v = np.asarray(velocity, dtype=np.float64)
        speed = float(np.linalg.norm(v))
        if speed < 0.5:
            return float("inf")
        p = np.asarray(position, dtype=np.float64)
        ray = np.stack([p, p + v / speed * horizon_m])
        seen = self.verified_distance(ray, horizon_m, self.cfg.verify_skip_m)
        pts, s = sample_path(ray, 0.5 * self.cfg.voxel_size_m, seen)
        grid = self.planner.grid_for(pts.min(axis=0), pts.max(axis=0))
        near = np.flatnonzero(grid.distance(pts) < self.cfg.drone_radius_m + self.cfg.safety_margin_m)
        near = near[s[near] >= self.cfg.verify_skip_m]
        return float(min(seen, s[near[0]])) if len(near) else seen

    def counts(self) -> dict:
        """Occupied / free / unknown voxel counts of the map (allocated blocks)."""
        return self.map.counts()


def timed(fn, *args, **kwargs):
    """``(fn(*args, **kwargs), milliseconds)``."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, 1e3 * (time.perf_counter() - t0)


__all__ = ["Navigator", "CheckOutcome", "timed", "OCCUPIED", "FREE", "UNKNOWN"]


def _any(capsules: np.ndarray | None) -> bool:
    """Whether ``capsules`` (K, 7) or None holds any capsule."""
    return capsules is not None and len(capsules) > 0
