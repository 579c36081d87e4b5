"""The answer of a path query."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Why a query failed (PlanResult.reason). Start and goal have the same codes with their prefix.
REASONS = {
    "start_in_obstacle": "the start lies inside an occupied voxel",
    "goal_in_obstacle": "the goal lies inside an occupied voxel",
    "start_unknown": "the start lies in unexplored (unknown) space and unknown space is not flyable",
    "goal_unknown": "the goal lies in unexplored (unknown) space and unknown space is not flyable",
    "start_too_close": "the start is closer to an obstacle than the clearance",
    "goal_too_close": "the goal is closer to an obstacle than the clearance",
    "start_altitude": "the start lies outside the altitude limits",
    "goal_altitude": "the goal lies outside the altitude limits",
    "start_enclosed": "the free space around the start is enclosed: the goal cannot be reached",
    "goal_enclosed": "the free space around the goal is enclosed: it cannot be reached from the start",
    "no_path": "start and goal lie in separate free regions at this clearance",
    "search_limit": "the search gave up after its expansion limit",
}


@dataclass
class PlanResult:
    """A planned path, or why there is none.

    Attributes:
        success: a collision-free path was found.
        waypoints: (K, 3) float64 world points, metres, from start to goal ((0, 3) on failure).
        length_m: path length, metres (inf on failure).
        reason: '' on success, else a key of :data:`REASONS`.
        message: human-readable explanation (empty on success).
        clearance_m: the clearance asked for, metres.
        margin_m: the extra margin added to the clearance for the voxel discretisation, metres.
        min_distance_m: smallest distance to an obstacle along the path according to the
            distance field (voxel-centre distances, interpolated), metres.
        expansions: nodes expanded by the grid search.
        timings: seconds per stage.
        adjusted: endpoints the planner moved (``{"start"|"goal": {"from", "to", "distance_m",
            "reason"}}``, see ``Planner.plan(snap_radius_m=...)``); empty when none was.
    """

    success: bool
    waypoints: np.ndarray
    length_m: float
    reason: str = ""
    message: str = ""
    clearance_m: float = 0.0
    margin_m: float = 0.0
    min_distance_m: float = float("nan")
    expansions: int = 0
    timings: dict = field(default_factory=dict)
    adjusted: dict = field(default_factory=dict)

    @classmethod
    def failure(cls, reason: str, message: str = "", **kw) -> PlanResult:
        text = REASONS.get(reason, reason)
        return cls(
            False, np.zeros((0, 3)), float("inf"), reason, f"{text}{': ' + message if message else ''}", **kw
        )

    def to_dict(self) -> dict:
        """JSON-ready summary (waypoints as lists)."""
        return {
            "success": self.success,
            "waypoints": np.asarray(self.waypoints, dtype=float).tolist(),
            "length_m": self.length_m if np.isfinite(self.length_m) else None,
            "reason": self.reason,
            "message": self.message,
            "clearance_m": self.clearance_m,
            "margin_m": self.margin_m,
            "min_distance_m": self.min_distance_m if np.isfinite(self.min_distance_m) else None,
            "expansions": self.expansions,
            "timings_s": self.timings,
            **({"adjusted": self.adjusted} if self.adjusted else {}),
        }
