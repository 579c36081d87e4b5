"""Failsafes: what the drone does when its depth cannot be trusted (see :mod:`skyrecon.mission.health`).

A state machine over the loop's cycles, as PX4 and ArduPilot specify one per fault:

* ``fly``: normal flight;
* ``hold``: the depth of this cycle is not trustworthy: the drone uses none of it, brakes to a
  hover within its stopping distance (inside space it has already observed free) and waits;
  when trustworthy depth returns it flies on;
* after ``failsafe_after_s`` of untrustworthy depth, or ``no_progress_failsafe_s`` without coming
  1 m closer to the goal (the goal or every way to it stays blocked in the map: the delivery
  cannot go on), the configured action (``failsafe``):
  ``return`` (fly back along its own flown track, which its body swept free, at the degraded
  speed, to the take-off point: outcome ``returned``), ``land`` (descend where it is when the
  column below it down to the ground is observed free: outcome ``landed``; otherwise hold), or
  ``hover`` (hold until the time limit: outcome ``hovering``). Return and land, once begun, are
  finished even if the sensors recover.

Every change of mode is logged with its reason (:attr:`Failsafe.events`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyrecon.mapping import FREE, OCCUPIED, OccupancyMap
from skyrecon.mission.config import MissionConfig


@dataclass
class Failsafe:
    """The failsafe state of one mission.

    Attributes:
        cfg: the mission settings (``failsafe``, ``failsafe_after_s``).
        mode: "fly", "hold", "return", "land".
        events: every decision: ``{"time_s", "decision", "reason"}``.
    """

    cfg: MissionConfig
    mode: str = "fly"
    events: list[dict] = field(default_factory=list)
    _bad_since: float | None = None
    _best_to_goal: tuple[float, float] | None = None  # (closest distance to the goal, since when)
    _last_progress_t: float | None = None
    _track: list[np.ndarray] = field(default_factory=list)

    def _log(self, t: float, decision: str, reason: str) -> None:
        self.events.append({"time_s": round(float(t), 2), "decision": decision, "reason": reason})

    def remember(self, position: np.ndarray) -> None:
        """Record the believed position of a cycle flown normally (the way back)."""
        p = np.asarray(position, dtype=np.float64)
        if not self._track or np.linalg.norm(p - self._track[-1]) >= 0.5:
            self._track.append(p.copy())

    def update(
        self, t: float, trusted: bool, reasons: list[str], position: np.ndarray, occ: OccupancyMap
    ) -> str:
        """The mode of this cycle, given whether its depth is trustworthy."""
        why = ",".join(reasons) or "untrusted"
        if self.mode in ("return", "land"):
            return self.mode
        if trusted:
            if self.mode == "hold":
                self._log(t, "fly", "trustworthy depth again")
            self.mode, self._bad_since = "fly", None
            return self.mode
        if self._bad_since is None:
            self._bad_since = t
        if self.mode == "fly":
            self.mode = "hold"
            self._log(t, "hold", f"no trustworthy depth ({why}): brake to a hover in space seen free")
        if t - self._bad_since >= self.cfg.failsafe_after_s and self.cfg.failsafe != "hover":
            if self.cfg.failsafe == "land":
                if self.column_free(position, occ):
                    self.mode = "land"
                    self._log(
                        t,
                        "land",
                        f"no trustworthy depth for {t - self._bad_since:.1f} s; the column below is seen free",
                    )
                elif self.events[-1]["decision"] != "hold (cannot land)":
                    self._log(t, "hold (cannot land)", "the column below has not been observed free")
            else:
                self.mode = "return"
                self._log(
                    t,
                    "return",
                    f"no trustworthy depth for {t - self._bad_since:.1f} s: back along the flown track",
                )
        return self.mode

    def progress(
        self, t: float, to_goal_m: float, position: np.ndarray, occ: OccupancyMap, paused: bool = False
    ) -> str:
        """After this cycle (``to_goal_m``: the believed distance to the goal, metres): no metre
        gained for ``no_progress_failsafe_s`` begins the configured action (``hover``: the drone
        keeps holding). Time in a failsafe hold does not count (its own timer acts), but does not
        start the count again either: depth that is untrustworthy every other frame (a camera
        turning between a plain wall and the goal, noisy plain seed 19) restarted the count at
        every held frame, and the drone hovered 100 s without progress until its time limit;
        nor does time since the last call while ``paused`` (the drone backing off to see its way,
        :class:`~skyrecon.mission.guidance.BackOff`: a bounded manoeuvre away from the goal;
        counted, two back-offs used up the 30 s and odometry mission seed 4 turned home)."""
        held = self.mode != "fly"
        if (paused or held) and self._best_to_goal is not None and self._last_progress_t is not None:
            best, since = self._best_to_goal
            self._best_to_goal = (best, since + (t - self._last_progress_t))
        self._last_progress_t = t
        if held:
            return self.mode
        if self._best_to_goal is None or to_goal_m < self._best_to_goal[0] - 1.0:
            self._best_to_goal = (to_goal_m, t)
            return self.mode
        stuck = t - self._best_to_goal[1]
        if stuck < self.cfg.no_progress_failsafe_s or self.cfg.failsafe == "hover":
            return self.mode
        if self.cfg.failsafe == "land" and not self.column_free(position, occ):
            return self.mode
        self.mode = self.cfg.failsafe
        self._log(
            t,
            self.mode,
            f"no progress towards the goal for {stuck:.1f} s (its way stays blocked): the delivery cannot go on",
        )
        return self.mode

    def column_free(self, position: np.ndarray, occ: OccupancyMap) -> bool:
        """Whether the column under ``position`` (3,) down to the ground is observed free (the
        drone's radius around its axis), the ground itself observed occupied."""
        p = np.asarray(position, dtype=np.float64)
        v = occ.voxel_size
        r = self.cfg.drone_radius_m + v
        zs = np.arange(p[2] - v, 0.75 * v, -v)
        ring = np.array([[0, 0], [r, 0], [-r, 0], [0, r], [0, -r]])
        pts = np.array([[p[0] + dx, p[1] + dy, z] for z in zs for dx, dy in ring])
        if len(pts) == 0:
            return True
        ground = occ.state_at(np.array([[p[0], p[1], 0.5 * v], [p[0], p[1], -0.5 * v]]))
        return bool(np.all(occ.state_at(pts) == FREE) and np.any(ground == OCCUPIED))

    def way_back(self, position: np.ndarray) -> np.ndarray:
        """(K, 3) the flown track from ``position`` back to the take-off point, world metres."""
        p = np.asarray(position, dtype=np.float64)
        if not self._track:
            return p[None].copy()
        track = np.array(self._track)
        k = int(np.argmin(np.linalg.norm(track - p, axis=1)))  # where on the track the drone is
        return np.vstack([p[None], track[k::-1]])

    def landing_target(self, position: np.ndarray) -> np.ndarray:
        """(3,) the point straight below ``position`` at touch-down height."""
        p = np.asarray(position, dtype=np.float64).copy()
        p[2] = self.cfg.drone_radius_m + 0.25
        return p
