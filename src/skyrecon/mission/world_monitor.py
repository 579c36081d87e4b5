"""The simulator's judge of a city that moves: how well the drone saw movers and changes.

Runs beside the loop (never inside its timing, and the drone never reads it), comparing what
the drone believed with the simulator's truth:

* **movers** (other drones and vehicles; the crane is judged as a structure): in every frame
  where a mover shows at least :data:`MIN_VISIBLE_PX` pixels and lies within
  :data:`DETECTION_RANGE_M` of the camera, whether a confirmed track sits within
  :data:`MATCH_RADIUS_M` of its true centre, and that track's position error. The true and the
  tracked paths are kept for the report.
* **phantom tracks**: in every frame, the tracks the planner keeps clear of (confirmed, not
  static, moving once) and how many of them lie farther than :data:`PHANTOM_TRACK_M` from
  every mover (crane included) at the true time (``mover_tracks``): keep-outs around nothing.
* **phantom trails**: at the end, the voxels each mover swept until 2 s before the end (minus
  the static city), and how many of those the drone observed that its map holds as occupied.
* **vacated voxels**: every voxel the map holds as occupied inside a mover's box; once the mover
  has left it, the time until the map frees it.
* **changes since the prior** (:mod:`skyrecon.mission.changes`, the crane's tower): for an
  added obstacle, the time from when it first shows within the trusted range to when the map
  holds :data:`MAPPED_VOXELS` occupied voxels inside it (``delay_s``), and how much of that time
  it was in view, showing :data:`MIN_VISIBLE_PX` pixels within the range (``in_view_s``: a
  drone that turns away after a first glimpse cannot map it until it looks again); for a
  removed one, per voxel the time from its first measurement (its log-odds leaves the prior's:
  a miss, the cameras saw through it; a hit stops the clock until the next miss) to free
  (median, p95, max, how many voxels took over 2 s, and for up to 10 of those their centre,
  distance to today's city and delay: the top of a stack seen through once at the top edge of a
  camera pitched down, then out of view until the drone is past it, is freed only when seen
  again). A voxel freed late that a mover came within one voxel of is left out
  (``mover_swept_voxels``): the space a mover passed through is judged by the mover figures
  (phantom trails, vacated voxels). The same clock counting only the cycles the voxel was in
  view (inside the left image, within the trusted range, not behind today's city) is given
  beside it (``free_in_view_s_*``): what the cameras could have freed.

Positions are compared in the drone's estimated world (``est_from_true`` maps the truth
there), so a drifting pose does not count against perception.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyrecon.core import Rigid3
from skyrecon.mapping import OccupancyMap
from skyrecon.mission.prior import PRIOR_OCCUPIED_LOG_ODDS

#: A mover counts as visible from this many pixels of the left image.
MIN_VISIBLE_PX = 30
#: Movers are judged within this distance of the camera, metres.
DETECTION_RANGE_M = 20.0
#: A track within this distance of a mover's true centre detects it, metres.
MATCH_RADIUS_M = 1.5
#: A planner track whose centre lies farther than this from every mover is a phantom, metres.
PHANTOM_TRACK_M = 3.0
#: An added obstacle is "in the map" with this many occupied voxels inside it.
MAPPED_VOXELS = 20


def detection_error(track_positions, center: np.ndarray) -> float | None:
    """Distance (m) from a mover's true ``center`` (3,) to the nearest of the live tracks'
    positions ((3,) each), when within :data:`MATCH_RADIUS_M` (the mover is detected); else None."""
    if not len(track_positions):
        return None
    err = float(np.min(np.linalg.norm(np.asarray(track_positions) - center, axis=1)))
    return err if err <= MATCH_RADIUS_M else None


def phantom_tracks(scene, positions: np.ndarray, time_s: float) -> int:
    """How many of the planner's track positions (K, 3), in the movers' (true) world, lie
    farther than :data:`PHANTOM_TRACK_M` from every mover of ``scene``
    (:class:`~skyrecon.sim.movers.MovingScene`) at ``time_s`` seconds: the phantom tracks."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if not len(pos):
        return 0
    return int(np.count_nonzero(scene.mover_distance(pos, float(time_s)) > PHANTOM_TRACK_M))


def _recall(sightings: list[tuple[float, bool]], within_m: float) -> float | None:
    """Share of the mover-frames within ``within_m`` metres in which the mover was detected."""
    near = [h for d, h in sightings if d <= within_m]
    return round(sum(near) / len(near), 4) if near else None


def _r(x: float, nd: int = 2) -> float | None:
    """``round(x, nd)``, None for NaN (JSON)."""
    return None if x != x else round(float(x), nd)


def _voxels_of_boxes(boxes: np.ndarray, v: float) -> np.ndarray:
    """(M, 3) int64 voxels whose centres lie inside any of the boxes (K, 6)."""
    out = []
    for b in np.asarray(boxes, dtype=np.float64).reshape(-1, 6):
        lo = np.ceil(b[:3] / v - 0.5).astype(np.int64)
        hi = np.floor(b[3:] / v - 0.5).astype(np.int64)
        if np.any(hi < lo):
            continue
        g = np.stack(np.meshgrid(*[np.arange(lo[i], hi[i] + 1) for i in range(3)], indexing="ij"), -1)
        out.append(g.reshape(-1, 3))
    return np.unique(np.concatenate(out), axis=0) if out else np.zeros((0, 3), np.int64)


@dataclass
class _Change:
    kind: str
    name: str
    boxes: np.ndarray
    voxels: np.ndarray  # (M, 3) int64 voxels inside the boxes (they do not move)
    object_ids: set[int] = field(default_factory=set)
    t_in_range: float | None = None
    t_mapped: float | None = None
    in_view_s: float = 0.0  # time in view between t_in_range and t_mapped
    # removed obstacles, per voxel (M,): the time its clock started and the time it was freed
    # (NaN: not yet), and its log-odds at the last cycle
    touched_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    freed_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    last_log_odds: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    # per voxel (M,): seconds in view while its clock ran (reset with the clock, kept once
    # freed); whether the monitor was given views to tell
    seen_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    viewed: bool = False


class WorldMonitor:
    """Collects the dynamic-world figures of one mission (see the module docstring).

    Args:
        scenario: the mission's scenario (city, changes, movers).
        voxel_size_m: the drone's map voxel size.
        trusted_range_m: the stereo range the drone trusts, metres.
    """

    def __init__(self, scenario, voxel_size_m: float, trusted_range_m: float):
        self.scene = scenario.movers
        self.v = float(voxel_size_m)
        self.range_m = float(trusted_range_m)
        self.static = scenario.city
        movers = [] if self.scene is None else list(self.scene.movers)
        self.judged = [i for i, m in enumerate(movers) if m.kind in ("drone", "vehicle")]
        self.names = [m.name for m in movers]
        self.kinds = [m.kind for m in movers]
        self.true_paths: dict[int, list] = {i: [] for i in range(len(movers))}
        self.track_paths: dict[int, list] = {}
        self.visible_frames = {i: 0 for i in self.judged}
        self.detected_frames = {i: 0 for i in self.judged}
        self.errors: list[float] = []
        self.sightings: list[tuple[float, bool]] = []  # (distance m, detected) per visible mover-frame
        # per visible mover-frame: (time s, mover index, distance m, true centre (3,) in the
        # estimate's world frame), for replaying the tracker (benchmarks/dynamic/replay_tracker.py)
        self.sighting_log: list[tuple[float, int, float, np.ndarray]] = []
        self.times: list[float] = []
        self.track_frames = 0  # planner tracks (confirmed, not static, moving once) per frame
        self.phantom_track_frames = 0  # of those, farther than PHANTOM_TRACK_M from every mover
        self.vacate_pending: dict[tuple, float] = {}
        self.vacate_delays: list[float] = []
        self.closest: list[dict] = []
        self.changes: list[_Change] = []
        for c in getattr(scenario, "changes", []):
            box = np.asarray(c.box, dtype=np.float64)[None]
            self.changes.append(_Change(c.kind, c.name, box, _voxels_of_boxes(box, self.v)))
        if self.scene is not None:
            for m in self.scene.new_obstacles:
                tower = m.boxes_at(0.0)[:1]  # the crane's tower; its boom moves
                self.changes.append(
                    _Change("added", f"{m.name} tower", tower, _voxels_of_boxes(tower, self.v))
                )
        for ch in self.changes:
            if ch.kind == "added":
                ch.object_ids = self._object_ids(ch.boxes)

    def _object_ids(self, boxes: np.ndarray) -> set[int]:
        """Object ids (``1 + box index`` in the rendered scene) of static boxes equal to ``boxes``."""
        ids: set[int] = set()
        for b in boxes:
            hit = np.flatnonzero(np.all(np.abs(self.static.boxes - b) < 1e-6, axis=1))
            ids.update(int(k) + 1 for k in hit)
        return ids

    def observe(
        self,
        time_s: float,
        cam_position: np.ndarray,
        object_id: np.ndarray,
        snapshot,
        tracks: list,
        occ_map: OccupancyMap,
        est_from_true: Rigid3 | None,
        view=None,
    ) -> None:
        """One cycle: the true camera position (3,), the left image's object ids (H, W) of the
        rendered ``snapshot``, the tracker's tracks (estimated world) and the drone's map;
        ``view``, the left image's render (:class:`skyrecon.sim.RenderResult`: true pose,
        intrinsics and depth), tells which voxels of a removed obstacle were in view."""
        t = float(time_s)
        self.times.append(t)
        to_est = (lambda p: p) if est_from_true is None else (lambda p: est_from_true.apply(p))  # noqa: E731
        live = [tr for tr in tracks if tr.confirmed and not tr.static]
        for tr in live:
            self.track_paths.setdefault(int(tr.track_id), []).append([t, *np.round(tr.position, 3).tolist()])
        if self.scene is not None and self.scene.movers:
            self._phantoms(t, tracks, est_from_true)
        if self.scene is not None:
            mover_px = self.scene.mover_of_object_id(snapshot, object_id)
            counts = np.bincount(mover_px[mover_px >= 0].ravel(), minlength=len(self.names))
            states = self.scene.mover_states(t)
            for i, st in enumerate(states):
                self.true_paths[i].append([t, *np.round(st["center"], 3).tolist()])
            for i in self.judged:
                m = self.scene.movers[i]
                d = float(m.distance(np.asarray(cam_position, dtype=np.float64)[None], t)[0])
                if counts[i] < MIN_VISIBLE_PX or d > DETECTION_RANGE_M:
                    continue
                self.visible_frames[i] += 1
                c = to_est(np.asarray(states[i]["center"], dtype=np.float64)[None])[0]
                self.sighting_log.append((t, i, d, c))
                err = detection_error([tr.position for tr in live], c)
                if err is not None:
                    self.detected_frames[i] += 1
                    self.errors.append(err)
                self.sightings.append((d, err is not None))
            self._vacated(t, occ_map, to_est)
        self._changes(t, cam_position, object_id, occ_map, to_est, view)

    def _phantoms(self, t: float, tracks: list, est_from_true: Rigid3 | None) -> None:
        """Count the tracks the planner keeps clear of (confirmed, not static, moving once) and
        those of them farther than :data:`PHANTOM_TRACK_M` from every mover at the true time."""
        planner = [tr for tr in tracks if tr.avoided]
        if not planner:
            return
        pos = np.array([tr.position for tr in planner], dtype=np.float64)
        if est_from_true is not None:
            pos = est_from_true.inverse().apply(pos)
        self.track_frames += len(pos)
        self.phantom_track_frames += phantom_tracks(self.scene, pos, t)

    def _vacated(self, t: float, occ_map: OccupancyMap, to_est) -> None:
        """Voxels the map holds occupied inside a mover now; once the mover leaves, time to free."""
        boxes = (
            np.concatenate([self.scene.movers[i].boxes_at(t) for i in self.judged]) if self.judged else None
        )
        inside = set()
        if boxes is not None and len(boxes):
            vox = _voxels_of_boxes(boxes, self.v)
            if len(vox):
                centres = to_est((vox + 0.5) * self.v)
                occ = occ_map.state_at(centres) == 1
                inside = {tuple(x) for x in vox}
                for x in vox[occ]:
                    self.vacate_pending.setdefault(tuple(x), -1.0)  # occupied while the mover is there
        keys = list(self.vacate_pending)
        if not keys:
            return
        st = occ_map.state_at(to_est((np.array(keys, dtype=np.float64) + 0.5) * self.v))
        for key, s in zip(keys, st):
            if key in inside:
                self.vacate_pending[key] = -1.0
                continue
            t_left = self.vacate_pending[key]
            if t_left < 0:
                self.vacate_pending[key] = t_left = t
            if s != 1:
                self.vacate_delays.append(t - t_left)
                del self.vacate_pending[key]

    def _in_view(self, voxels: np.ndarray, view) -> np.ndarray:
        """(M,) bool: which voxels' centres (true world) the rendered ``view`` shows: inside
        the image, within the trusted range and not behind today's city (its depth there at
        most a voxel nearer). All False without a view."""
        if view is None or len(voxels) == 0:
            return np.zeros(len(voxels), bool)
        pc = view.cam_from_world.apply((voxels + 0.5) * self.v)
        uv = view.intrinsics.project(pc)
        H, W = view.depth_m.shape
        with np.errstate(invalid="ignore"):
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        inside &= np.linalg.norm(pc, axis=1) <= self.range_m
        out = np.zeros(len(voxels), bool)
        k = np.flatnonzero(inside)
        d = view.depth_m[uv[k, 1].astype(np.int64), uv[k, 0].astype(np.int64)]
        out[k] = ~(d < pc[k, 2] - self.v)  # sky (NaN) hides nothing
        return out

    def _changes(self, t, cam_position, object_id, occ_map: OccupancyMap, to_est, view=None) -> None:
        dt = t - self.times[-2] if len(self.times) > 1 else 0.0
        for ch in self.changes:
            vox = ch.voxels
            if len(vox) == 0:
                continue
            lo = occ_map.log_odds_at(to_est((vox + 0.5) * self.v))
            if ch.kind == "added":
                if ch.t_mapped is None and ch.object_ids:
                    px = int(np.isin(object_id, list(ch.object_ids)).sum())
                    b = ch.boxes[0]
                    d = float(np.linalg.norm(np.clip(cam_position, b[:3], b[3:]) - cam_position))
                    in_view = px >= MIN_VISIBLE_PX and d <= self.range_m
                    if ch.t_in_range is None and in_view:
                        ch.t_in_range = t
                    elif ch.t_in_range is not None and in_view:
                        ch.in_view_s += dt  # in view over the last cycle
                if ch.t_mapped is None and ch.t_in_range is not None:
                    with np.errstate(invalid="ignore"):
                        if int(np.count_nonzero(lo >= 0.0)) >= MAPPED_VOXELS:
                            ch.t_mapped = t
            else:
                self._removed(ch, t, lo, occ_map, dt, None if view is None else self._in_view(vox, view))

    def _removed(
        self,
        ch: _Change,
        t: float,
        lo: np.ndarray,
        occ_map: OccupancyMap,
        dt: float = 0.0,
        in_view: np.ndarray | None = None,
    ) -> None:
        """A removed obstacle's voxels (log-odds ``lo`` (M,) now): a voxel's clock starts at its
        first miss (the cameras saw through it) and stops when it is free; a hit before it is
        free (a mover passing, a stray match) stops the clock until the next miss. With
        ``in_view`` (M,) bool (this cycle), the clock's time in view is kept too: the last
        cycle's ``dt`` seconds count when the voxel is in view now."""
        if len(ch.last_log_odds) != len(lo):  # the first cycle: every voxel at the prior's belief
            ch.last_log_odds = np.full(len(lo), PRIOR_OCCUPIED_LOG_ODDS, np.float32)
            ch.touched_s = np.full(len(lo), np.nan)
            ch.freed_s = np.full(len(lo), np.nan)
            ch.seen_s = np.zeros(len(lo))
        last = ch.last_log_odds
        l_hit = np.float32(occ_map.config.log_odds[0])
        with np.errstate(invalid="ignore"):
            # a hit raises the log-odds, or restarts a voxel still at the prior's belief
            hit = (lo > last + 1e-6) | ((last == np.float32(PRIOR_OCCUPIED_LOG_ODDS)) & (lo == l_hit))
            miss = ~hit & (lo < last - 1e-6)
            free = lo < 0.0
        ch.last_log_odds = lo.astype(np.float32)
        open_ = np.isnan(ch.freed_s)
        running = open_ & ~np.isnan(ch.touched_s)
        if in_view is not None:  # in view over the last cycle, as for an added obstacle
            ch.seen_s[running & in_view] += dt
            ch.viewed = True
        ch.touched_s[hit & open_] = np.nan
        ch.seen_s[hit & open_] = 0.0
        measured = open_ & ~hit & (miss | free)
        ch.touched_s[measured & np.isnan(ch.touched_s)] = t
        ch.freed_s[measured & free] = t

    def _mover_swept(self, voxels: np.ndarray, end_time_s: float) -> np.ndarray:
        """(K,) bool: which of the voxels (K, 3) (integer indices) a mover came within one voxel
        of (sampled every 0.05 s until ``end_time_s``): the space a mover passed through is
        judged as vacated space (phantom trails, vacated voxels), not as the removed obstacle's."""
        if len(voxels) == 0 or self.scene is None or not self.scene.movers or end_time_s <= 0:
            return np.zeros(len(voxels), bool)
        centres = (np.asarray(voxels, np.float64) + 0.5) * self.v
        ts = np.arange(0.0, end_time_s, 0.05)
        pts = np.repeat(centres, len(ts), axis=0)
        d = self.scene.mover_distance(pts, np.tile(ts, len(voxels))).reshape(len(voxels), len(ts))
        return np.any(d <= self.v, axis=1)

    def summary(self, occ_map: OccupancyMap, end_time_s: float, est_from_true: Rigid3 | None) -> dict:
        """The figures for ``mission.json`` (see the module docstring)."""
        to_est = (lambda p: p) if est_from_true is None else (lambda p: est_from_true.apply(p))  # noqa: E731
        vis = sum(self.visible_frames.values())
        det = sum(self.detected_frames.values())
        out: dict = {
            "moving_obstacles": len(self.names),
            "mover_kinds": {k: self.kinds.count(k) for k in sorted(set(self.kinds))},
            "mover_visible_frames": vis,
            "mover_detection_recall": round(det / vis, 4) if vis else None,
            "mover_position_error_m": {
                "median": round(float(np.median(self.errors)), 3) if self.errors else None,
                "p95": round(float(np.percentile(self.errors, 95)), 3) if self.errors else None,
                "max": round(float(np.max(self.errors)), 3) if self.errors else None,
            },
            "mover_recall_within_10m": _recall(self.sightings, 10.0),
            "mover_tracks": {
                "track_frames": self.track_frames,
                "phantom_frames": self.phantom_track_frames,
                "phantom_share": round(self.phantom_track_frames / self.track_frames, 4)
                if self.track_frames
                else None,
            },
            "mover_sightings": [[round(d, 2), bool(h)] for d, h in self.sightings],
            "mover_recall_by_mover": {
                self.names[i]: round(self.detected_frames[i] / self.visible_frames[i], 3)
                for i in self.judged
                if self.visible_frames[i]
            },
        }
        swept_total = swept_known = phantom = 0
        if self.scene is not None and self.judged:
            t_end = end_time_s - 2.0
            for i in self.judged:
                m = self.scene.movers[i]
                if t_end <= 0:
                    continue
                ts = np.arange(0.0, t_end, 0.1)
                vox = (
                    _voxels_of_boxes(m.boxes_many(ts).reshape(-1, 6), self.v) if len(ts) else np.zeros((0, 3))
                )
                if len(vox) == 0:
                    continue
                centres = (vox + 0.5) * self.v
                vox = vox[self.static.distance(centres, include_ground=True) > self.v]
                if len(vox) == 0:
                    continue
                st = occ_map.state_at(to_est((vox + 0.5) * self.v))
                swept_total += len(vox)
                swept_known += int(np.count_nonzero(st >= 0))
                phantom += int(np.count_nonzero(st == 1))
        out["phantom_trail"] = {
            "swept_voxels": swept_total,
            "observed_swept_voxels": swept_known,
            "occupied_voxels": phantom,
            "fraction_of_observed": round(phantom / swept_known, 5) if swept_known else None,
            "fraction_of_swept": round(phantom / swept_total, 5) if swept_total else None,
        }
        d = np.asarray(self.vacate_delays)
        out["vacated_free_s"] = {
            "voxels": int(len(d)),
            "still_occupied": int(len(self.vacate_pending)),
            "median": round(float(np.median(d)), 3) if len(d) else None,
            "max": round(float(d.max()), 3) if len(d) else None,
        }
        changes = []
        for ch in self.changes:
            row = {"kind": ch.kind, "name": ch.name, "box": np.round(ch.boxes[0], 2).tolist()}
            if ch.kind == "added":
                row["in_range_s"] = ch.t_in_range
                row["mapped_s"] = ch.t_mapped
                row["delay_s"] = (
                    round(ch.t_mapped - ch.t_in_range, 3)
                    if ch.t_mapped is not None and ch.t_in_range is not None
                    else None
                )
                row["in_view_s"] = round(ch.in_view_s, 3) if ch.t_mapped is not None else None
            else:
                freed = np.flatnonzero(~np.isnan(ch.freed_s))
                freed = freed[np.argsort(ch.freed_s[freed], kind="stable")]  # in the order freed
                delay = ch.freed_s[freed] - ch.touched_s[freed]
                swept = self._mover_swept(ch.voxels[freed[delay > 0]], end_time_s)
                judged = ~np.isin(freed, freed[delay > 0][swept])
                delays = delay[judged]
                row["touched_voxels"] = int(np.count_nonzero(~np.isnan(ch.touched_s)))
                row["freed_voxels"] = len(freed)
                row["mover_swept_voxels"] = int(np.count_nonzero(swept))
                row["free_delay_s_median"] = round(float(np.median(delays)), 3) if len(delays) else None
                row["free_delay_s_p95"] = round(float(np.percentile(delays, 95)), 3) if len(delays) else None
                row["free_delay_s_max"] = round(float(np.max(delays)), 3) if len(delays) else None
                late = judged & (delay > 2.0 + 1e-6)
                row["freed_after_2s_voxels"] = int(np.count_nonzero(late))
                seen = ch.seen_s[freed] if ch.viewed else np.full(len(freed), np.nan)
                if judged.any() and ch.viewed:
                    # the same clock counting only the time the voxel was in view
                    row["free_in_view_s_p95"] = round(float(np.percentile(seen[judged], 95)), 3)
                    row["free_in_view_s_max"] = round(float(np.max(seen[judged])), 3)
                    row["freed_after_2s_in_view_voxels"] = int(np.count_nonzero(seen[judged] > 2.0 + 1e-6))
                if late.any():  # where they lie (up to 10): centre, metres from today's city, delay,
                    # seconds of it in view
                    centres = (ch.voxels[freed[late][:10]] + 0.5) * self.v
                    dist = self.static.distance(centres, include_ground=True)
                    row["freed_after_2s_detail"] = [
                        [*np.round(c, 2).tolist(), round(float(d), 2), round(float(x), 2), _r(y)]
                        for c, d, x, y in zip(centres, dist, delay[late][:10], seen[late][:10])
                    ]
            changes.append(row)
        out["changes_seen"] = changes
        return out
