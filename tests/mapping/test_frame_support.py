"""Multi-frame support of guessed depth: hits only where several frames' guesses agree, never
free space, never in a voxel the map knows as free; and ``OccupancyMap.add_hits``."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.mapping.frame_support import FrameSupport
from skyrecon.mapping.occupancy import FREE, OCCUPIED, UNKNOWN

CAM = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)


def _pose(x: float) -> Rigid3:
    """world_from_cam of a camera at (x, 0, 2) looking along +y (world z up)."""
    return Rigid3.look_at(np.array([x, 0.0, 2.0]), np.array([x, 10.0, 2.0])).inverse()


def _wall_depth(x: float, y_wall: float = 6.0) -> np.ndarray:
    """(60, 80) depth of a wall at world y = y_wall seen from _pose(x): z-depth = y_wall."""
    return np.full((60, 80), y_wall, np.float32)


def test_add_hits_marks_occupied_without_carving():
    m = OccupancyMap(voxel_size_m=0.5)
    vox = np.array([[0, 0, 0], [0, 0, 0], [3, 1, 2]])
    assert m.add_hits(vox) == 2
    assert m.counts()["occupied"] == 2 and m.counts()["free"] == 0
    centres = (np.array([[0, 0, 0], [3, 1, 2], [1, 1, 1]]) + 0.5) * 0.5
    np.testing.assert_array_equal(m.state_at(centres), [OCCUPIED, OCCUPIED, UNKNOWN])
    # clamped like any hit
    for _ in range(50):
        m.add_hits(vox[:1])
    assert m.log_odds_at(centres[:1])[0] == pytest.approx(m.config.log_odds[3])


def test_guesses_count_only_when_enough_frames_agree():
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    support = FrameSupport(m, min_frames=3, max_range_m=20.0, next_to_occupied=False)
    assert support.add(_wall_depth(0.0), CAM, _pose(0.0)) == 0
    assert support.add(_wall_depth(0.3), CAM, _pose(0.3)) == 0
    assert m.counts()["occupied"] == 0
    hits = support.add(_wall_depth(0.6), CAM, _pose(0.6))
    assert hits > 20 and m.counts()["free"] == 0
    occ = m.occupied_centers()
    assert np.all(np.abs(occ[:, 1] - 6.25) < 1e-6)  # the voxel layer holding the wall (y in [6, 6.5))
    # guesses that disagree (a wall at another depth in every frame) never reach 3 frames
    other = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    s2 = FrameSupport(other, min_frames=3, max_range_m=20.0, next_to_occupied=False)
    for y in (5.0, 7.0, 9.0, 11.0):
        s2.add(_wall_depth(0.0, y), CAM, _pose(0.0))
    assert other.counts()["occupied"] == 0


def test_guesses_do_not_override_known_free_space_or_exceed_the_range():
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    # trusted depth of a farther wall: the rays carve free space through y = 6
    for _ in range(3):
        m.integrate_depth(_wall_depth(0.0, 10.0), CAM, _pose(0.0))
    before = m.state_at(np.array([[0.25, 6.25, 2.25]]))[0]
    assert before == FREE
    support = FrameSupport(m, min_frames=2, max_range_m=20.0)
    for x in (0.0, 0.3, 0.6):
        support.add(_wall_depth(x), CAM, _pose(x))
    assert m.state_at(np.array([[0.25, 6.25, 2.25]]))[0] == FREE
    near = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    short = FrameSupport(near, min_frames=2, max_range_m=5.0, next_to_occupied=False)
    for x in (0.0, 0.3, 0.6):
        short.add(_wall_depth(x), CAM, _pose(x))
    assert near.counts()["occupied"] == 0
    with pytest.raises(InputError):
        FrameSupport(m, min_frames=1, max_range_m=5.0)


def test_guesses_extend_a_surface_but_start_none_in_the_air():
    lone = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    support = FrameSupport(lone, min_frames=2, max_range_m=20.0)
    for x in (0.0, 0.3, 0.6):
        support.add(_wall_depth(x), CAM, _pose(x))
    assert lone.counts()["occupied"] == 0  # no trusted surface next to them
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    trusted = _wall_depth(0.0)
    trusted[:, 40:] = np.nan  # trusted depth of the left half of the wall only
    m.integrate_depth(trusted, CAM, _pose(0.0))
    before = m.counts()["occupied"]
    support = FrameSupport(m, min_frames=2, max_range_m=20.0)
    for x in (0.0, 0.3, 0.6):
        support.add(_wall_depth(x), CAM, _pose(x))
    assert m.counts()["occupied"] > before  # the guesses grew the wall from its measured half
