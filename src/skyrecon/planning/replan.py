"""Keeping a path valid while the map changes: check the rest of the path, replan when blocked.

Typical loop::

    planner = Planner(occ_map, clearance_m=2.0)
    rp = Replanner(planner, goal)
    rp.replan(current_position)                       # first path
    while flying:
        occ_map.integrate_depth(depth, K, world_from_cam)
        d = rp.update(current_position, occ_map.pop_changed_blocks())
        if d.replanned: follow(d.waypoints)

:meth:`Replanner.update` brings the distance field up to date for the changed blocks only,
skips the check when none of the rewritten distance blocks lies on the remaining path, else
checks every remaining segment at the clearance, and plans again from the current position
only when a segment is blocked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.mapping.inputs import check_point3
from skyrecon.planning.planner import Planner
from skyrecon.planning.result import PlanResult


@dataclass
class ReplanDecision:
    """What :meth:`Replanner.update` decided.

    Attributes:
        clear: the remaining path was still clear at the clearance (before any replanning).
        replanned: a new path was planned from the current position.
        waypoints: (K, 3) world metres, the path to follow now (from the current position).
        blocked_segment: index of the first blocked segment of the old remaining path, or -1.
        checked: whether the remaining path had to be re-checked (some rewritten distance
            block lay on it).
        result: the PlanResult of the replanning, if any (its ``reason`` says why it failed).
    """

    clear: bool
    replanned: bool
    waypoints: np.ndarray
    blocked_segment: int = -1
    checked: bool = False
    result: PlanResult | None = None


def remaining_path(waypoints: np.ndarray, position: np.ndarray) -> np.ndarray:
    """The part of a polyline (K, 3) still ahead of ``position`` (3,): the position followed by
    the waypoints after the segment nearest to it."""
    w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)
    p = np.asarray(position, dtype=np.float64).reshape(3)
    if len(w) < 2:
        return np.vstack([p[None], w])
    a, b = w[:-1], w[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0, 1)
    d = np.linalg.norm(a + t[:, None] * ab - p, axis=1)
    k = int(np.argmin(d))
    return np.vstack([p[None], w[k + 1 :]])


def _blocks_on_path(path: np.ndarray, block_edge: float) -> np.ndarray:
    """(M, 3) int64 blocks visited by a polyline (sampled every quarter block)."""
    pts = [path[:1]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / (0.25 * block_edge))))
        pts.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.unique(np.floor(np.concatenate(pts) / block_edge).astype(np.int64), axis=0)


class Replanner:
    """Follows the map's changes for one goal and keeps a clear path to it.

    Args:
        planner: the :class:`Planner` (map, clearance, limits) to use.
        goal: (3,) world metres.
        waypoints: an initial path (K, 3), or None (call :meth:`replan`).
    """

    def __init__(self, planner: Planner, goal: np.ndarray, waypoints: np.ndarray | None = None):
        self.planner = planner
        self.goal = check_point3(goal, "goal")
        self.waypoints = (
            np.zeros((0, 3)) if waypoints is None else np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)
        )
        # the distance field must know every change made to the map before we started
        planner.update(planner.map.pop_changed_blocks())

    def replan(self, position: np.ndarray) -> PlanResult:
        """Plan from ``position`` to the goal; on success the new path replaces the current one."""
        r = self.planner.plan(check_point3(position, "current position"), self.goal)
        if r.success:
            self.waypoints = r.waypoints
        return r

    def check(
        self, position: np.ndarray, changed_distance_blocks: np.ndarray | None = None
    ) -> tuple[bool, int, bool]:
        """Whether the remaining path is clear: (clear, first blocked segment or -1, checked).

        With ``changed_distance_blocks`` (K, 3) (from the distance-field update) the path is
        only re-checked when it passes through one of them.
        """
        rest = remaining_path(self.waypoints, position)
        if len(rest) < 2:
            return True, -1, False
        if changed_distance_blocks is not None:
            ch = np.asarray(changed_distance_blocks, dtype=np.int64).reshape(-1, 3)
            if len(ch) == 0:
                return True, -1, False
            on = _blocks_on_path(rest, self.planner.map.config.block_edge_m)
            if not set(map(tuple, on.tolist())) & set(map(tuple, ch.tolist())):
                return True, -1, False
        ok, k = self.planner.path_is_clear(rest)
        return ok, k, True

    def update(self, position: np.ndarray, changed_blocks: np.ndarray | None) -> ReplanDecision:
        """Take the map's latest changes, check the rest of the path, replan only if it is blocked.

        Args:
            position: (3,) current position, world metres.
            changed_blocks: (M, 3) map blocks changed since the last call
                (``map.pop_changed_blocks()``); None re-checks the whole remaining path.
        Returns:
            ReplanDecision.
        """
        p = check_point3(position, "current position")
        if len(self.waypoints) == 0:
            r = self.replan(p)
            return ReplanDecision(False, True, self.waypoints if r.success else np.zeros((0, 3)), -1, True, r)
        rewritten = self.planner.update(
            np.zeros((0, 3), np.int64) if changed_blocks is None else changed_blocks
        )
        ok, k, checked = self.check(p, None if changed_blocks is None else rewritten)
        if ok:
            return ReplanDecision(True, False, remaining_path(self.waypoints, p), -1, checked, None)
        r = self.replan(p)
        if not r.success:
            return ReplanDecision(False, True, np.zeros((0, 3)), k, True, r)
        return ReplanDecision(False, True, self.waypoints, k, True, r)
