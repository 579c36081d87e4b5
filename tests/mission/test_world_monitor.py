"""The simulator's judge of changes since the prior map: when an added obstacle is in the map,
and how soon a removed one's voxels are freed after the cameras saw through them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from skyrecon.mapping import MapConfig
from skyrecon.mission.prior import PRIOR_OCCUPIED_LOG_ODDS
from skyrecon.mission.world_monitor import MAPPED_VOXELS, MIN_VISIBLE_PX, WorldMonitor

BOX = np.array([10.0, -2.0, 0.0, 14.0, 2.0, 20.0])  # a scaffold the prior map lacks


class _Map:
    """Stands in for the drone's map: unknown until ``mapped_from`` s, then the box is occupied."""

    def __init__(self, mapped_from: float):
        self.mapped_from = mapped_from
        self.t = 0.0

    def log_odds_at(self, points: np.ndarray) -> np.ndarray:
        return np.full(len(points), 2.0 if self.t >= self.mapped_from else np.nan, np.float32)


def test_an_added_obstacle_reports_its_delay_and_the_time_it_was_in_view():
    """In view at 1.0 s for one cycle, out of view until 3.0 s, mapped at 3.2 s: the delay is
    2.2 s, and 0.3 s in view (four frames seen, 1.0, 3.0, 3.1 and 3.2 s, as if without the gap)."""
    city = SimpleNamespace(boxes=BOX[None].copy())
    change = SimpleNamespace(kind="added", name="scaffold tower", box=BOX)
    mon = WorldMonitor(SimpleNamespace(movers=None, city=city, changes=[change]), 0.5, 17.0)
    occ = _Map(mapped_from=3.2)
    seen = np.zeros((48, 64), np.int32)
    seen[:10, :10] = 1  # object id 1: the added box (100 px >= MIN_VISIBLE_PX)
    assert seen.astype(bool).sum() >= MIN_VISIBLE_PX and len(mon.changes[0].voxels) >= MAPPED_VOXELS
    blank = np.zeros_like(seen)
    cam = np.array([0.0, 0.0, 15.0])  # 10 m from the box
    for k in range(40):
        t = 0.1 * k
        occ.t = t
        in_view = abs(t - 1.0) < 1e-9 or t >= 3.0 - 1e-9
        mon.observe(t, cam, seen if in_view else blank, None, [], occ, None)
    row = mon.summary(occ, 4.0, None)["changes_seen"][0]
    assert row["in_range_s"] == 1.0 and row["mapped_s"] == 3.2
    assert row["delay_s"] == 2.2
    assert row["in_view_s"] == 0.3


class _Timeline:
    """Stands in for the drone's map: each voxel's log-odds follows its own list of (time s,
    log-odds) steps, starting at the prior's belief."""

    def __init__(self, voxels: np.ndarray, steps: dict[int, list[tuple[float, float]]], v: float):
        self.config = MapConfig(voxel_size_m=v)
        self.keys = [tuple(k) for k in voxels]
        self.steps = steps
        self.v = v
        self.t = 0.0

    def log_odds_at(self, points: np.ndarray) -> np.ndarray:
        out = np.full(len(points), PRIOR_OCCUPIED_LOG_ODDS, np.float32)
        for i, p in enumerate(points):
            k = self.keys.index(tuple(np.floor(p / self.v).astype(np.int64)))
            for t, lo in self.steps.get(k, []):
                if self.t >= t - 1e-9:
                    out[i] = lo
        return out


def _removed_stack_monitor(view=None) -> tuple[WorldMonitor, _Timeline]:
    """A monitor of a removed box of four voxels whose log-odds follow the steps below, flown
    for 4 s at 10 Hz (the steps: see the next test's docstring); ``view(t)``, if given, is the
    render the monitor gets at t."""
    box = np.array([0.0, 0.0, 0.0, 2.0, 0.5, 0.5])  # four voxels along x
    city = SimpleNamespace(boxes=np.zeros((0, 6)))
    change = SimpleNamespace(kind="removed", name="container stack", box=box)
    mon = WorldMonitor(SimpleNamespace(movers=None, city=city, changes=[change]), 0.5, 17.0)
    vox = mon.changes[0].voxels
    assert len(vox) == 4
    l_hit, l_miss = (float(x) for x in MapConfig().log_odds[:2])
    order = [int(np.flatnonzero(vox[:, 0] == i)[0]) for i in range(4)]
    steps = {
        order[0]: [(1.0, l_miss)],
        order[1]: [(1.0, PRIOR_OCCUPIED_LOG_ODDS + l_miss), (1.5, PRIOR_OCCUPIED_LOG_ODDS + 3 * l_miss)],
        order[2]: [
            (1.0, l_hit),
            (1.2, l_hit + l_miss),
            (1.4, 2 * l_hit + l_miss),
            (2.0, 2 * l_hit + 2 * l_miss),
            (2.6, 2 * l_hit + 5 * l_miss),
        ],
        order[3]: [(1.0, l_hit), (2.0, 2 * l_hit)],
    }
    occ = _Timeline(vox, steps, 0.5)
    blank = np.zeros((48, 64), np.int32)
    for k in range(40):
        occ.t = 0.1 * k
        mon.observe(occ.t, np.zeros(3), blank, None, [], occ, None, None if view is None else view(occ.t))
    return mon, occ


def test_a_removed_obstacle_s_clock_runs_from_the_first_miss_and_a_hit_stops_it():
    """Voxel 0: seen through at 1.0 s, free at once (0 s). Voxel 1: a miss at 1.0 s, free at
    1.5 s (0.5 s). Voxel 2: hit at 1.0 s (a fresh hit, as today's first measurement of a stale
    voxel), a miss at 1.2 s starts its clock, a second hit at 1.4 s stops it, the next miss at
    2.0 s starts it again, free at 2.6 s: 0.6 s. Voxel 3 is only ever hit: never touched."""
    mon, occ = _removed_stack_monitor()
    row = mon.summary(occ, 4.0, None)["changes_seen"][0]
    assert row["touched_voxels"] == 3 and row["freed_voxels"] == 3
    assert row["free_delay_s_median"] == 0.5
    assert row["free_delay_s_max"] == 0.6
    assert row["freed_after_2s_voxels"] == 0 and row["mover_swept_voxels"] == 0


def test_late_voxels_a_mover_passed_through_are_left_out_of_the_removed_obstacle():
    """A mover crossing voxel 2 at 1.3 s (the hits) makes it vacated space: left out, counted."""
    mon, occ = _removed_stack_monitor()
    centre = (mon.changes[0].voxels[mon.changes[0].voxels[:, 0] == 2][0] + 0.5) * 0.5

    def mover_distance(points, times):
        near = np.abs(np.asarray(times) - 1.3) < 0.1
        return np.where(near & (np.linalg.norm(points - centre, axis=1) < 0.1), -0.1, np.inf)

    mon.scene = SimpleNamespace(movers=["a drone"], mover_distance=mover_distance)
    row = mon.summary(occ, 4.0, None)["changes_seen"][0]
    assert row["mover_swept_voxels"] == 1
    assert row["free_delay_s_max"] == 0.5


def test_a_removed_obstacle_s_clock_in_view_counts_only_the_cycles_it_was_seen():
    """The same four voxels, seen by a camera looking at them only until 1.2 s and again from
    2.4 s (a wall hides them from 1.3 to 2.3 s; the rendered depth there is nearer): voxel 2's
    clock runs 1.0-1.4 s (reset by a hit) and 2.0-2.6 s, in view at 1.1, 1.2, 2.4, 2.5 and 2.6 s
    of them: 0.3 s of its 0.6 s. Voxel 1 (1.0-1.5 s): 0.2 s. Voxel 0 (freed at once): 0 s."""
    from skyrecon.core import Intrinsics, Rigid3

    # a camera 10 m in front of the voxels (at y = -10 looking along +y), all in its image
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # camera x = world x, y = -z, z = y
    pose = dict(
        cam_from_world=Rigid3(R, -R @ np.array([1.0, -10.0, 0.25])),
        intrinsics=Intrinsics.from_fov(64, 48, 90.0),
    )
    open_view = SimpleNamespace(depth_m=np.full((48, 64), np.nan), **pose)
    wall = SimpleNamespace(depth_m=np.full((48, 64), 5.0), **pose)
    mon, occ = _removed_stack_monitor(lambda t: wall if 1.3 - 1e-9 <= t <= 2.3 + 1e-9 else open_view)
    ch = mon.changes[0]
    order = [int(np.flatnonzero(ch.voxels[:, 0] == i)[0]) for i in range(4)]
    assert ch.seen_s[order[0]] == 0.0
    assert abs(ch.seen_s[order[1]] - 0.2) < 1e-9
    assert abs(ch.seen_s[order[2]] - 0.3) < 1e-9
    row = mon.summary(occ, 4.0, None)["changes_seen"][0]
    assert row["free_delay_s_max"] == 0.6 and row["free_in_view_s_max"] == 0.3
    assert row["freed_after_2s_in_view_voxels"] == 0


def test_phantom_tracks_are_planner_tracks_far_from_every_mover():
    """Of the tracks the planner keeps clear of, those over PHANTOM_TRACK_M from every mover at
    the true time are phantoms; tentative and static tracks are not counted; an estimated world
    that is shifted from the truth is mapped back first."""
    from skyrecon.core import Rigid3
    from skyrecon.mission.world_monitor import PHANTOM_TRACK_M
    from skyrecon.perception.movers import MoverTrack

    mover_at = np.array([10.0, 0.0, 5.0])  # a mover of 0.5 m radius, standing still
    scene = SimpleNamespace(
        movers=[object()], mover_distance=lambda p, t: np.linalg.norm(p - mover_at, axis=1) - 0.5
    )
    mon = WorldMonitor(
        SimpleNamespace(movers=None, city=SimpleNamespace(boxes=np.zeros((0, 6))), changes=[]), 0.5, 17.0
    )
    mon.scene = scene

    def track(pos, confirmed=True, moving=True, static=False):
        z = np.zeros(3)
        return MoverTrack(
            1,
            np.array(pos, float),
            z,
            np.eye(6),
            z,
            confirmed=confirmed,
            moving=moving,
            was_moving=moving,
            static=static,
        )

    far = 0.5 + PHANTOM_TRACK_M + 1.0
    tracks = [
        track([10.4, 0.0, 5.0]),  # on the mover
        track([10.0 + far, 0.0, 5.0]),  # a phantom
        track([30.0, 0.0, 5.0], confirmed=False),  # tentative: not the planner's
        track([30.0, 0.0, 5.0], static=True, moving=False),  # a new static obstacle
    ]
    mon._phantoms(1.0, tracks, None)
    assert (mon.track_frames, mon.phantom_track_frames) == (2, 1)
    # the estimate's world is the truth shifted by 2 m along y: its track positions are too
    shift = Rigid3(np.eye(3), np.array([0.0, 2.0, 0.0]))
    mon._phantoms(1.1, [track([10.4, 2.0, 5.0])], shift)
    assert (mon.track_frames, mon.phantom_track_frames) == (3, 1)
