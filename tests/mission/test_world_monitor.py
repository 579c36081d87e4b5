"""The simulator's judge of changes since the prior map: when an added obstacle is in the map."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

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
