"""The ground level learnt over a flight and the guesses that lie on it (plain ground)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping import OccupancyMap
from skyrecon.mapping.ground_level import GroundLevel, GroundSettings, lowest_level
from skyrecon.mapping.stereo_sequence import StereoMapSettings

CAM = Intrinsics(80.0, 80.0, 40.0, 30.0, 80, 60)
FB = 80.0 * 0.3  # f B of a 0.3 m rig with this camera, pixel metres


def _pose(x: float, height: float = 10.0) -> Rigid3:
    """world_from_cam of a camera at (x, 0, height) looking 45 degrees down along +y (z up)."""
    eye = np.array([x, 0.0, height])
    return Rigid3.look_at(eye, eye + np.array([0.0, 1.0, -1.0])).inverse()


def _ground_depth(pose: Rigid3, ground_z: float) -> np.ndarray:
    """(60, 80) exact depth of the plane z = ground_z seen from ``pose`` (NaN above the horizon)."""
    dirs = CAM.ray_directions().astype(np.float64)
    down = dirs @ (pose.R.T @ np.array([0.0, 0.0, -1.0]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(down > 1e-6, (pose.t[2] - ground_z) / down, np.nan).astype(np.float32)


def test_lowest_level_is_the_lowest_strong_peak_not_the_strongest():
    z = np.arange(-2.0, 12.0, 0.1) + 0.05
    w = np.zeros_like(z)
    w[np.abs(z - 0.05) < 0.2] = 100  # the ground
    w[np.abs(z - 6.05) < 0.2] = 400  # a big roof
    w[np.abs(z + 1.55) < 0.05] = 10  # a little noise below the ground
    assert lowest_level(z, w, 0.1, 0.15, 0.2) == pytest.approx(0.05, abs=0.06)
    assert lowest_level(z, np.zeros_like(z), 0.1, 0.15, 0.2) is None


def test_the_level_is_learnt_from_trusted_depth_and_ignores_roofs():
    ground = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    assert ground.z_m is None
    for x in (0.0, 1.0, 2.0):
        pose = _pose(x)
        depth = _ground_depth(pose, 0.3)
        roof = _ground_depth(pose, 6.0)
        depth[:, 50:] = roof[:, 50:]  # a roof covers a third of every view: more pixels than ground
        ground.add(depth, CAM, pose)
    assert ground.z_m == pytest.approx(0.3, abs=0.1)


def test_fitted_planes_and_measured_pixels_meet_halfway():
    """Plane-filled ground too far (a level 0.3 m low) outnumbers measured ground a little too
    near (0.1 m high): the level lies between them, not on the fills; without the split (or
    with ``measured_share`` 0) it is the fills'."""
    split = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    whole = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    off = GroundLevel(GroundSettings(min_points=100, measured_share=0.0), max_range_m=20.0)
    fitted = np.zeros((60, 80), bool)
    fitted[:, 12:] = True  # most of the view took a plane
    for x in (0.0, 1.0, 2.0):
        pose = _pose(x)
        depth = np.where(fitted, _ground_depth(pose, -0.3), _ground_depth(pose, 0.1))
        split.add(depth, CAM, pose, fitted)
        whole.add(depth, CAM, pose)
        off.add(depth, CAM, pose, fitted)
    assert whole.z_m == pytest.approx(-0.3, abs=0.06)
    assert off.z_m == pytest.approx(whole.z_m, abs=1e-9)
    assert split.z_m == pytest.approx(-0.1, abs=0.06)
    nothing = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)  # every pixel a fit
    for x in (0.0, 1.0, 2.0):
        nothing.add(_ground_depth(_pose(x), -0.3), CAM, _pose(x), np.ones((60, 80), bool))
    assert nothing.z_m == pytest.approx(-0.3, abs=0.06)


def test_a_level_pickled_before_it_kept_the_measured_pixels_resumes_on_every_pixel():
    """A checkpoint's level from before ``levels`` and the measured pixels' counts were kept
    (``skyrecon map --resume``) goes on with the level of every pixel."""
    import pickle

    level = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    level.add(_ground_depth(_pose(0.0), -0.3), CAM, _pose(0.0))
    state = level.__dict__.copy()
    for key in ("levels", "_measured", "_split"):
        del state[key]
    old = GroundLevel.__new__(GroundLevel)
    old.__setstate__(state)
    resumed = pickle.loads(pickle.dumps(old))
    fitted = np.zeros((60, 80), bool)
    fitted[:, 12:] = True
    pose = _pose(1.0)
    resumed.add(np.where(fitted, _ground_depth(pose, -0.3), _ground_depth(pose, 0.1)), CAM, pose, fitted)
    assert resumed.levels == [resumed.z_m] and resumed.z_m == pytest.approx(-0.3, abs=0.06)


def test_only_guesses_that_agree_with_the_ground_plane_are_ground():
    ground = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    pose = _pose(0.0)
    exact = _ground_depth(pose, 0.0)
    ground.add(exact, CAM, pose)
    guess = exact * np.float32(1.02)  # a guess within the tolerance (2 % of disparity)
    guess[:20] = np.float32(5.0)  # a plain box standing 5 m in front: not ground
    out = ground.ground_depth(guess, CAM, pose, FB)
    assert out is not None
    on = np.isfinite(out)
    assert not on[:20].any()
    assert on[30:].all()
    np.testing.assert_allclose(out[on], exact[on], rtol=0.05)  # the plane's depth, not the guess's
    # every third pixel alone (what the frame support reads) is the same
    np.testing.assert_array_equal(ground.ground_depth(guess, CAM, pose, FB, step=3), out[::3, ::3])
    # half a metre under the level: the same pixels, deeper along the same rays
    deeper = ground.ground_depth(guess, CAM, pose, FB, below_m=0.5)
    drop = pose.t[2] - ground.z_m
    np.testing.assert_allclose(deeper[on], out[on] * (drop + 0.5) / drop, rtol=1e-5)
    assert np.array_equal(np.isfinite(deeper), on)
    # above the camera, or before any depth: nothing
    assert GroundLevel().ground_depth(guess, CAM, pose, FB) is None
    high = GroundLevel(GroundSettings(min_points=100))
    high.add(_ground_depth(pose, 0.0), CAM, _pose(0.0, height=30.0))  # a level at 20 m, above 10 m
    assert high.z_m is not None and high.z_m > pose.t[2]
    assert high.ground_depth(guess, CAM, pose, FB) is None


def test_ground_hits_reach_the_map_as_hits_only():
    """Through the mapper's ground support: two frames' ground guesses become occupied ground
    voxels, no free space is carved, and the voxels are those of the ground plane."""
    from skyrecon.mapping.frame_support import FrameSupport

    m = OccupancyMap(voxel_size_m=0.5, max_range_m=20.0)
    support = FrameSupport(m, 2, 20.0, next_to_occupied=False)
    ground = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    for x in (0.0, 0.3):
        pose = _pose(x)
        exact = _ground_depth(pose, -0.2)
        ground.add(exact, CAM, pose)
        on = ground.ground_depth(exact, CAM, pose, FB)
        assert on is not None
        support.add(on, CAM, pose)
    assert m.counts()["free"] == 0 and m.counts()["occupied"] > 20
    z = m.occupied_centers()[:, 2]
    assert np.all(np.abs(z + 0.25) < 1e-6)  # the voxel layer holding the ground at z = -0.2 ([-0.5, 0))


def test_settings():
    assert StereoMapSettings().ground == GroundSettings()  # on by default (see StereoMapSettings)
    assert StereoMapSettings().with_overrides(ground=None).ground is None
    with pytest.raises(InputError):
        GroundSettings(below_voxels=2.0)
    with pytest.raises(InputError):
        GroundSettings(min_down_cos=0.0)
    with pytest.raises(InputError):
        GroundSettings(tolerance_px=-1.0)
    with pytest.raises(InputError):
        GroundSettings(measured_share=1.5)


def test_a_wall_seen_from_above_is_no_level():
    """A wall's foot seen from above spreads over every height: a plateau, not a level."""
    z = np.arange(0.0, 8.0, 0.1) + 0.05
    w = np.where((z > 0.2) & (z < 4.0), 300.0, 0.0)
    assert lowest_level(z, w, 0.1, 0.15, 0.2) is None


def test_the_level_after_each_frame_is_kept():
    ground = GroundLevel(GroundSettings(min_points=100), max_range_m=20.0)
    assert ground.level_after(1) is None
    pose = _pose(0.0)
    ground.add(np.full((60, 80), np.nan, np.float32), CAM, pose)  # nothing trusted: no level yet
    ground.add(_ground_depth(pose, 0.3), CAM, pose)
    assert ground.levels == [None, ground.z_m] and ground.z_m is not None
    assert ground.level_after(1) is None and ground.level_after(2) == ground.z_m
    assert ground.level_after(0) is None and ground.level_after(3) is None
    ground.levels.append(None)  # the peak lost for a frame: no level for the next frames
    assert ground.level_after(3) is None


def test_a_noisy_plain_street_between_its_kerbs_becomes_ground_hits_only():
    """``skyrecon map`` on a noisy plain city (frames 14-33 of plain seed 1 of the stereo map
    benchmark): the plain street segments whose measured border agrees with the ground level
    learnt from the earlier frames (given to the plane fill) add hits in the ground's voxel
    layer through the ground support, and no free space."""
    from dataclasses import replace

    from skyrecon.mapping import StereoMapper
    from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo
    from skyrecon.sim.sensor_noise import add_sensor_noise

    city = generate_city(1, 200.0, plain=True)
    rig = default_rig(640, 480, 90.0, 0.3)
    poses = flight_poses(city, 40, 1)[14:34]
    rng = np.random.default_rng(1)
    frames = []
    for p in poses:
        f = render_stereo(city, rig, p.inverse())
        frames.append(
            replace(f, left=add_sensor_noise(f.left, 1.5, rng), right=add_sensor_noise(f.right, 1.5, rng))
        )
    maps = {}
    for fill in (True, False):
        mapper = StereoMapper(rig, voxel_size_m=0.5, ground_plane_fill=fill, overlap=False)
        for f, p in zip(frames, poses):
            mapper.add_frame(f.left, f.right, p)
        maps[fill] = mapper.map
    on, off = maps[True], maps[False]
    assert on.counts()["free"] <= off.counts()["free"]  # the ground carves nothing
    before = {tuple(v) for v in off.occupied_voxels().tolist()}
    after = {tuple(v) for v in on.occupied_voxels().tolist()}
    added = np.array(sorted(after - before))
    assert before <= after and len(added) > 30
    centres = (added + 0.5) * 0.5
    assert np.all(centres[:, 2] == -0.25)  # the street's voxel layer (z in [-0.5, 0))
    assert np.all(np.abs(city.distance(centres, include_ground=True)) <= 0.25 + 1e-9)
