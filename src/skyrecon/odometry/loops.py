"""Loop closure for the stereo odometry: place recognition, checks, pose-graph correction.

The engine (:class:`skyrecon.odometry.engine.StereoOdometry`) hands every keyframe to
:meth:`LoopCloser.add_keyframe` and asks :meth:`LoopCloser.search` whether the current keyframe
closes a loop. A loop goes through, in order:

1. place recognition (:class:`skyrecon.odometry.places.PlaceDatabase`): an old keyframe near the
   current estimate that looks alike (thumbnail, then ORB matches);
2. the geometric check (:func:`skyrecon.odometry.places.verify_loop`): PnP both ways, enough
   inliers, spread, the two directions agreeing;
3. the drift gate: the correction the loop implies (where the current keyframe should be, against
   where the odometry has it) must be no larger than the drift could be (``gate_m + gate_fraction *
   path``, ``path`` the metres flown since the old keyframe);
4. confirmation: ``confirmations`` keyframes in a row found loops implying the same correction;
5. the pose graph (:func:`skyrecon.odometry.pose_graph.optimize_pose_graph`): odometry edges
   between consecutive keyframes plus the loop edges (Cauchy loss), solved first nearly without
   the robust loss (a large first correction is real, the gates checked it) and then with it; a new
   loop whose residual stays large after the optimisation disagrees with the rest and is rolled
   back.

A loop that fails a step is dropped and counted with its reason (:meth:`LoopCloser.report`); the
trajectory is only ever changed by a loop that passed them all. Loops whose correction is tiny
(a revisit after an earlier loop already corrected the drift) are added to the graph without
solving it again (bounded work per keyframe); the last solve happens in :meth:`LoopCloser.finish`.

Poses are ``world_from_left`` of keyframes, 4x4, metres.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from skyrecon.core.rigid import rotation_angle
from skyrecon.odometry.places import LoopMatch, Place, PlaceDatabase, verify_loop
from skyrecon.odometry.pose_graph import PoseEdge, edge_errors, optimize_pose_graph

__all__ = ["LoopCloser", "LoopOutcome"]

# pose-graph sigmas: odometry edges (per metre between keyframes, plus a floor) and loop edges
ODOM_SIGMA_T_M, ODOM_SIGMA_T_PER_M = 0.01, 0.005
ODOM_SIGMA_R_DEG, ODOM_SIGMA_R_DEG_PER_M = 0.02, 0.01
REINIT_SIGMA_FACTOR = 20.0  # an edge across a re-initialisation (chained by the motion prior)
LOOP_SIGMA_T_M, LOOP_SIGMA_R_DEG = 0.05, 0.2
# a new loop's residual after the optimisation above these is rolled back
MAX_LOOP_RESIDUAL_M, MAX_LOOP_RESIDUAL_DEG = 0.25, 0.75
# a loop implying a smaller correction than this joins the graph without a solve (until
# MAX_DEFERRED of them wait, or the next solve); above BIG_CORRECTION_M the solve starts nearly
# without the robust loss
QUIET_CORRECTION_M, QUIET_CORRECTION_DEG = 0.25, 0.25
MAX_DEFERRED = 30
BIG_CORRECTION_M = 0.5
LOG_LIMIT = 200


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


@dataclass
class LoopOutcome:
    """What a search did.

    Attributes:
        poses: (N, 4, 4) corrected ``world_from_left`` of every keyframe when the graph was solved
            and the result accepted, else None (the keyframes stay as they are).
        message: one line for the frame (empty when nothing was found).
    """

    poses: np.ndarray | None
    message: str


@dataclass
class _Candidate:
    edge: PoseEdge
    keyframe: int
    frame: int
    match_frame: int
    correction: np.ndarray  # (4, 4) world_from_world: maps the current estimate onto the loop's
    correction_m: float
    correction_deg: float
    match: LoopMatch
    accepted: bool = False


class LoopCloser:
    """Loop detection and correction over keyframes (see the module docstring).

    Args:
        focal_px, principal_px: the left camera's (fx, fy), (cx, cy), pixels.
        image_size: (width, height), pixels.
        min_inliers: PnP inliers a loop needs (both ways), and descriptor matches to try one.
        min_path_m: candidates are at least this many metres of flight back.
        gate_m, gate_fraction: the search radius and the largest correction, ``gate_m +
            gate_fraction * path`` metres; rotations up to ``2 deg + 1 deg per 100 m``.
        confirmations: consecutive keyframes whose loops must agree before one is applied.
        threshold_px: PnP inlier threshold, pixels.
        seed: seeds the RANSAC.
    """

    def __init__(
        self,
        focal_px: tuple[float, float],
        principal_px: tuple[float, float],
        image_size: tuple[int, int],
        min_inliers: int = 40,
        min_path_m: float = 40.0,
        gate_m: float = 3.0,
        gate_fraction: float = 0.03,
        confirmations: int = 2,
        threshold_px: float = 2.0,
        seed: int = 0,
    ) -> None:
        self.focal_px, self.principal_px, self.image_size = focal_px, principal_px, image_size
        self.min_inliers = min_inliers
        self.gate_m, self.gate_fraction = gate_m, gate_fraction
        self.confirmations = confirmations
        self.threshold_px = threshold_px
        self.seed = seed
        self.db = PlaceDatabase(image_size, min_path_m=min_path_m, gate_m=gate_m, gate_fraction=gate_fraction)
        self._reinit: dict[int, bool] = {}  # keyframe -> it started a new track
        self._odom: dict[int, np.ndarray] = {}  # k -> (4, 4) kf_{k-1}_from_kf_k, fixed once used
        self._loops: list[PoseEdge] = []
        self._recent: list[_Candidate] = []  # verified loops of the last keyframes
        self._unsolved: list[_Candidate] = []  # accepted loops in the graph, not solved yet
        self._log: list[dict] = []
        self._rejected: Counter = Counter()
        self._searches = 0
        self._checked = 0
        self._accepted = 0
        self._solves = 0
        self._solve_ms: list[float] = []
        self._max_correction = (0.0, 0.0)

    # ----- keyframes -------------------------------------------------------------------------
    def add_keyframe(
        self,
        keyframe: int,
        frame: int,
        grey: np.ndarray,
        uv: np.ndarray,
        points_cam: np.ndarray,
        poses: list[np.ndarray],
        reinit: bool,
    ) -> None:
        """Describe keyframe ``keyframe`` (its grey image, corners ``uv`` (N, 2) pixels and their
        stereo points ``points_cam`` (N, 3) in its left camera, NaN without depth); ``poses``: the
        current ``world_from_left`` of every keyframe so far, this one last."""
        prev = self.db.places[-1] if self.db.places else None
        path = 0.0
        if prev is not None and keyframe > 0:
            path = prev.path_m + float(np.linalg.norm(poses[keyframe][:3, 3] - poses[keyframe - 1][:3, 3]))
        self.add_place(self.db.describe(keyframe, frame, grey, uv, points_cam, path), reinit)

    def add_place(self, place: Place, reinit: bool = False) -> None:
        """Add a described keyframe (keyframes in order, from 0); ``reinit``: it started a new track."""
        self._reinit[place.keyframe] = reinit
        self.db.add(place)

    # ----- search ------------------------------------------------------------------------------
    def _reject(self, cand_frame: int, frame: int, reason: str, **extra: float) -> None:
        self._rejected[reason.split(":")[0]] += 1
        if len(self._log) < LOG_LIMIT:
            self._log.append(
                {"frame": frame, "match_frame": cand_frame, "status": "rejected", "reason": reason, **extra}
            )

    def _verified(self, query: Place, poses: list[np.ndarray]) -> _Candidate | None:
        """The best candidate of ``query`` that passes the geometric check and the drift gate."""
        cands = self.db.candidates(query, poses, self.min_inliers)
        T_cur = poses[query.keyframe]
        for cand, pairs in cands[:2]:
            self._checked += 1
            m = verify_loop(
                query,
                cand,
                pairs,
                self.focal_px,
                self.principal_px,
                self.image_size,
                threshold_px=self.threshold_px,
                min_inliers=self.min_inliers,
                seed=self.seed + query.frame,
            )
            if isinstance(m, str):
                self._reject(cand.frame, query.frame, m)
                continue
            implied = poses[cand.keyframe] @ m.candidate_from_current
            corr_m = float(np.linalg.norm(implied[:3, 3] - T_cur[:3, 3]))
            corr_deg = math.degrees(rotation_angle(T_cur[:3, :3].T @ implied[:3, :3]))
            path = query.path_m - cand.path_m
            gate_m = self.gate_m + self.gate_fraction * path
            gate_deg = 2.0 + path / 100.0
            if corr_m > gate_m or corr_deg > gate_deg:
                self._reject(
                    cand.frame,
                    query.frame,
                    f"correction beyond the drift gate: {corr_m:.2f} m, {corr_deg:.2f} deg after "
                    f"{path:.0f} m (gate {gate_m:.2f} m, {gate_deg:.2f} deg)",
                )
                continue
            edge = PoseEdge(
                cand.keyframe,
                query.keyframe,
                m.candidate_from_current,
                LOOP_SIGMA_T_M,
                math.radians(LOOP_SIGMA_R_DEG),
                robust=True,
            )
            return _Candidate(
                edge, query.keyframe, query.frame, cand.frame, implied @ _inv(T_cur), corr_m, corr_deg, m
            )
        return None

    def search(self, poses: list[np.ndarray]) -> LoopOutcome:
        """Look for a loop at the last keyframe added; ``poses``: current ``world_from_left`` of every
        keyframe. Returns the corrected poses when a loop was applied."""
        query = self.db.places[-1]
        self._searches += 1
        found = self._verified(query, poses)
        # forget loops of keyframes too far back to confirm anything
        for c in self._recent:
            if c.keyframe < query.keyframe - self.confirmations and not c.accepted:
                self._reject(
                    c.match_frame,
                    c.frame,
                    f"unconfirmed: no loop of the next {self.confirmations - 1} keyframe(s) implied the same correction",
                )
        self._recent = [c for c in self._recent if c.keyframe >= query.keyframe - self.confirmations]
        if found is None:
            return LoopOutcome(None, "")
        agree = [c for c in self._recent if self._consistent(c, found, poses)]
        self._recent.append(found)
        if len(agree) + 1 < self.confirmations:
            return LoopOutcome(None, f"loop candidate with frame {found.match_frame} (awaiting confirmation)")
        new = [c for c in [*agree, found] if not c.accepted]
        for c in new:
            c.accepted = True
        quiet = all(
            c.correction_m < QUIET_CORRECTION_M and c.correction_deg < QUIET_CORRECTION_DEG for c in new
        )
        self._loops.extend(c.edge for c in new)
        if quiet and len(self._unsolved) + len(new) < MAX_DEFERRED:
            self._unsolved.extend(new)
            return LoopOutcome(
                None,
                f"loop with frame {found.match_frame} (correction {found.correction_m:.2f} m: solved later)",
            )
        result = self._solve(poses, new)
        if result is None:
            return LoopOutcome(None, f"loop with frame {found.match_frame} rejected after the pose graph")
        corr = float(np.linalg.norm(result[query.keyframe][:3, 3] - poses[query.keyframe][:3, 3]))
        return LoopOutcome(result, f"loop closed with frame {found.match_frame}: correction {corr:.2f} m")

    def _consistent(self, a: _Candidate, b: _Candidate, poses: list[np.ndarray]) -> bool:
        """Two loops imply the same correction of the current keyframe (within 0.3 m, 1 degree)."""
        T = poses[b.keyframe]
        pa, pb = a.correction @ T, b.correction @ T
        dm = float(np.linalg.norm(pa[:3, 3] - pb[:3, 3]))
        dd = math.degrees(rotation_angle(pa[:3, :3].T @ pb[:3, :3]))
        return dm < 0.3 + 0.1 * max(a.correction_m, b.correction_m) and dd < 1.0

    def _log_accepted(self, new: list[_Candidate], moved_m: float) -> None:
        self._accepted += len(new)
        for c in new:
            if len(self._log) < LOG_LIMIT:
                self._log.append(
                    {
                        "frame": c.frame,
                        "match_frame": c.match_frame,
                        "status": "accepted",
                        "inliers": c.match.inliers,
                        "matches": c.match.matches,
                        "implied_correction_m": round(c.correction_m, 3),
                        "implied_correction_deg": round(c.correction_deg, 3),
                        "newest_keyframe_moved_m": round(moved_m, 3),
                    }
                )

    # ----- pose graph --------------------------------------------------------------------------
    def _graph(self, poses: list[np.ndarray], loops: list[PoseEdge]) -> tuple[int, list[PoseEdge]]:
        """The first node of the graph (the oldest loop's old keyframe, held fixed) and its edges
        (indices from that node)."""
        n0 = min(e.i for e in loops)
        last = len(poses) - 1
        edges = []
        for k in range(n0 + 1, last + 1):
            Z = self._odom.get(k)
            if Z is None:
                Z = self._odom[k] = _inv(poses[k - 1]) @ poses[k]
            d = float(np.linalg.norm(Z[:3, 3]))
            f = REINIT_SIGMA_FACTOR if self._reinit.get(k, False) else 1.0
            edges.append(
                PoseEdge(
                    k - 1 - n0,
                    k - n0,
                    Z,
                    f * (ODOM_SIGMA_T_M + ODOM_SIGMA_T_PER_M * d),
                    f * math.radians(ODOM_SIGMA_R_DEG + ODOM_SIGMA_R_DEG_PER_M * d),
                )
            )
        for e in loops:
            edges.append(PoseEdge(e.i - n0, e.j - n0, e.i_from_j, e.sigma_t_m, e.sigma_r_rad, e.robust))
        return n0, edges

    def _solve(self, poses: list[np.ndarray], new: list[_Candidate]) -> np.ndarray | None:
        """Solve the graph with every loop edge. The loops not solved before (``new`` and the waiting
        ones) whose residual stays large after the solve are dropped and the graph solved again
        without them; None (every one of them dropped) when the solve fails or no loop is left."""
        t0 = time.perf_counter()
        fresh = [*self._unsolved, *new]
        self._unsolved = []
        result: np.ndarray | None = None
        why = ""
        for _attempt in range(2):
            if not self._loops:
                break
            n0, edges = self._graph(poses, self._loops)
            P = np.stack(poses[n0:])
            try:
                if any(c.correction_m > BIG_CORRECTION_M for c in fresh):
                    P = optimize_pose_graph(P, edges, fixed=0, loss_scale=1e3).poses
                res = optimize_pose_graph(P, edges, fixed=0, loss_scale=3.0)
            except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
                why = f"pose-graph optimisation failed: {exc}"
                break
            if not np.all(np.isfinite(res.poses)):
                why = "pose-graph optimisation failed: non-finite poses"
                break
            checked = [PoseEdge(c.edge.i - n0, c.edge.j - n0, c.edge.i_from_j, 1.0, 1.0) for c in fresh]
            err_m, err_deg = edge_errors(res.poses, checked)
            bad = (err_m > MAX_LOOP_RESIDUAL_M) | (err_deg > MAX_LOOP_RESIDUAL_DEG)
            if not np.any(bad):
                result = np.stack(poses).copy()
                result[n0:] = res.poses
                break
            for c, b, em, ed in zip(fresh, bad, err_m, err_deg):
                if b:
                    self._drop(
                        [c],
                        f"inconsistent after the pose graph: residual {em:.2f} m, {ed:.2f} deg "
                        f"(> {MAX_LOOP_RESIDUAL_M} m, {MAX_LOOP_RESIDUAL_DEG} deg)",
                    )
            fresh = [c for c, b in zip(fresh, bad) if not b]
        self._solves += 1
        self._solve_ms.append((time.perf_counter() - t0) * 1e3)
        if result is None:
            self._drop(fresh, why or "inconsistent after the pose graph")
            return None
        moved = np.linalg.norm(result[:, :3, 3] - np.stack(poses)[:, :3, 3], axis=1)
        turned = [math.degrees(rotation_angle(a[:3, :3].T @ b[:3, :3])) for a, b in zip(poses, result)]
        self._max_correction = (
            max(self._max_correction[0], float(moved.max())),
            max(self._max_correction[1], float(max(turned))),
        )
        self._log_accepted(fresh, float(moved[-1]))
        return result

    def _drop(self, loops: list[_Candidate], why: str) -> None:
        """Take ``loops`` out of the graph and report them rejected with ``why``."""
        drop = {id(c.edge) for c in loops}
        self._loops = [e for e in self._loops if id(e) not in drop]
        self._recent = [c for c in self._recent if id(c.edge) not in drop]
        for c in loops:
            self._reject(c.match_frame, c.frame, why)

    def finish(self, poses: list[np.ndarray]) -> np.ndarray | None:
        """Solve the graph once more if loops joined it since the last solve; the corrected poses or None."""
        if not self._unsolved or not self._loops:
            return None
        return self._solve(poses, [])

    # ----- report ------------------------------------------------------------------------------
    def report(self) -> dict:
        """The loop-closure diagnostics of ``odometry.json``."""
        ms = np.array(self._solve_ms)
        return {
            "enabled": True,
            "keyframes": len(self.db.places),
            "searches": self._searches,
            "candidates_checked": self._checked,
            "accepted": self._accepted,
            "rejected": int(sum(self._rejected.values())),
            "rejected_reasons": dict(self._rejected.most_common()),
            "loop_edges": len(self._loops),
            "pose_graph_solves": self._solves,
            "pose_graph_ms_max": round(float(ms.max()), 1) if len(ms) else None,
            "max_correction_m": round(self._max_correction[0], 3),
            "max_correction_deg": round(self._max_correction[1], 3),
            "log": list(self._log),
            "log_truncated": len(self._log) >= LOG_LIMIT,
        }
