"""Far hits confirmed by the frame before: a far surface seen twice goes into the map, a
one-frame speck of far depth does not; near, open-air and missing pixels are never touched."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.mapping.far_hits import FarHitFilter
from skyrecon.mapping.occupancy import FREE, OCCUPIED, UNKNOWN

CAM = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)
FB = 80.0 * 3.0  # f B of a 3 m rig with this camera, pixels metres


def _pose(y: float) -> Rigid3:
    """world_from_cam of a camera at (0, y, 15) looking along +y (world z up)."""
    return Rigid3.look_at(np.array([0.0, y, 15.0]), np.array([0.0, y + 10.0, 15.0])).inverse()


def _wall(y_cam: float, y_wall: float = 14.0) -> np.ndarray:
    """(60, 80) depth of a wall at world y = y_wall seen from _pose(y_cam)."""
    return np.full((60, 80), y_wall - y_cam, np.float32)


def _filter(**kw) -> FarHitFilter:
    return FarHitFilter(min_range_m=10.0, focal_baseline_px_m=FB, min_tol_m=0.5, **kw)


def test_a_far_wall_seen_twice_is_kept_from_the_second_frame():
    f = _filter()
    first = f.unconfirmed(_wall(0.0, 18.0), CAM, _pose(0.0), 0.0)
    assert first.all()  # nothing before it confirms the wall (18 m away)
    second = f.unconfirmed(_wall(0.6, 18.0), CAM, _pose(0.6), 0.1)
    # the camera came 0.6 m nearer: every pixel whose point the first frame saw is confirmed
    # (those reprojecting outside the first image are the outer ring)
    assert not second[5:-5, 5:-5].any()
    assert f.last_far == 60 * 80 and f.last_dropped == np.count_nonzero(second)


def test_a_one_frame_speck_in_front_of_a_far_wall_is_left_out():
    f = _filter()
    f.unconfirmed(_wall(0.0, 30.0), CAM, _pose(0.0), 0.0)
    depth = _wall(0.6, 30.0)
    depth[20:24, 30:34] = 14.0  # noise: 16 pixels matched at a wrong disparity, 15 m in front
    out = f.unconfirmed(depth, CAM, _pose(0.6), 0.1)
    assert out[20:24, 30:34].all()
    assert not out[40:50, 10:20].any()  # the wall itself is confirmed


def test_a_far_surface_whose_disparity_moved_by_more_than_the_tolerance_is_left_out():
    f = _filter(disparity_tol_px=1.0)
    tol = 12.0 * 12.0 * 1.0 / FB  # 0.6 m at 12 m
    f.unconfirmed(_wall(0.0, 12.0), CAM, _pose(0.0), 0.0)
    near_enough = f.unconfirmed(_wall(0.0, 12.0 + 0.8 * tol), CAM, _pose(0.0), 0.1)
    assert not near_enough.any()
    f.reset()
    f.unconfirmed(_wall(0.0, 12.0), CAM, _pose(0.0), 0.0)
    assert f.unconfirmed(_wall(0.0, 12.0 + 1.5 * tol), CAM, _pose(0.0), 0.1).all()


def test_near_open_air_and_missing_pixels_are_never_left_out():
    f = _filter()
    depth = np.full((60, 80), 6.0, np.float32)  # near: no confirmation needed
    depth[:10] = np.inf  # open air
    depth[10:20] = np.nan
    assert not f.unconfirmed(depth, CAM, _pose(0.0), 0.0).any()
    assert f.last_far == 0


def test_depth_beyond_the_hit_range_is_not_checked():
    """Farther than the map's hit range depth marks no obstacle anyway: nothing to confirm."""
    f = FarHitFilter(min_range_m=10.0, focal_baseline_px_m=FB, max_range_m=17.0)
    depth = _wall(0.0, 25.0)  # 25 m ahead, every pixel beyond 17 m
    assert not f.unconfirmed(depth, CAM, _pose(0.0), 0.0).any()
    assert f.last_far == 0


def test_an_old_frame_confirms_nothing():
    f = _filter(max_age_s=0.35)
    f.unconfirmed(_wall(0.0, 18.0), CAM, _pose(0.0), 0.0)
    assert f.unconfirmed(_wall(0.0, 18.0), CAM, _pose(0.0), 0.5).all()
    assert not f.unconfirmed(_wall(0.0, 18.0), CAM, _pose(0.0), 0.6)[5:-5, 5:-5].any()


def _fly_past_a_speck(f: FarHitFilter | None) -> tuple[int, int]:
    """Two frames of a wall 16 m ahead, the second with a speck of noise 12 m ahead, into a
    map as the delivery loop does it (unconfirmed pixels carve only). Returns the map's states
    at a point of the wall and at the speck."""
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=17.0)
    speck_world = _pose(0.6).apply(np.array([[0.0, 0.0, 12.0]]))
    for k, y in enumerate((0.0, 0.6)):
        depth = _wall(y, 16.0)
        if k == 1:
            depth[28:32, 38:42] = 12.0
        carve = None if f is None else f.unconfirmed(depth, CAM, _pose(y), 0.1 * k)
        m.integrate_depth(depth, CAM, _pose(y), carve_only=carve)
    wall_point = _pose(0.6).apply(np.array([[2.0, 1.0, 15.4]]))
    return int(m.state_at(wall_point)[0]), int(m.state_at(speck_world)[0])


def test_the_map_gets_the_wall_but_not_the_speck():
    assert _fly_past_a_speck(None) == (OCCUPIED, OCCUPIED)
    wall, speck = _fly_past_a_speck(_filter())
    assert wall == OCCUPIED and speck != OCCUPIED  # carved free by the wall's rays around it


def test_carve_only_pixels_carve_in_front_of_their_point_and_mark_nothing():
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=17.0)
    depth = _wall(0.0, 12.0)
    m.integrate_depth(depth, CAM, _pose(0.0), carve_only=np.ones(depth.shape, bool))
    pose = _pose(0.0)
    ahead = pose.apply(np.array([[0.0, 0.0, 6.0], [0.0, 0.0, 11.0]]))
    assert (m.state_at(ahead) == FREE).all()
    assert m.counts()["occupied"] == 0
    assert m.state_at(pose.apply(np.array([[0.0, 0.0, 12.1]])))[0] == UNKNOWN  # the point's voxel
    with pytest.raises(InputError, match="carve_only"):
        m.integrate_depth(depth, CAM, pose, carve_only=np.ones((3, 3), bool))


def test_bad_settings_and_shapes_are_refused():
    with pytest.raises(InputError):
        FarHitFilter(0.0, FB)
    with pytest.raises(InputError):
        FarHitFilter(10.0, -1.0)
    with pytest.raises(InputError, match="does not match"):
        _filter().unconfirmed(np.zeros((10, 10), np.float32), CAM, _pose(0.0), 0.0)
