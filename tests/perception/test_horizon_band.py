"""The horizon band: the unmeasured strip between open sky and far ground is air, and nothing
that stands within the map's range is taken for it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.mission.config import MissionConfig
from skyrecon.mission.perception import flight_perception, mission_rig
from skyrecon.mission.vehicle import look_from
from skyrecon.perception import PerceptionSettings, StereoDepth
from skyrecon.perception.stereo_depth import horizon_band
from skyrecon.sim import generate_city, render_stereo
from skyrecon.sim.sensor_noise import add_sensor_noise
from tests.perception.truth import true_reach

H, W = 120, 40
CAMERA = Intrinsics(100.0, 100.0, 20.0, 60.0, W, H)
HORIZON = 40.0  # row
RANGE_PX, FAR_PX = 4.0, 3.0


def _column_scene():
    """An open view: sky down to row 34, the horizon's edge on rows 36-44, unmeasured far
    ground down to row 56, measured far ground (disparity 0.5 px) below."""
    sky = np.zeros((H, W), bool)
    sky[:34] = True
    separators = np.zeros((H, W), bool)
    separators[36:45] = True
    measured = np.zeros((H, W), bool)
    measured[56:] = True
    disparity = np.full((H, W), 0.5, np.float32)
    return sky, separators, measured, disparity


def _band(sky, separators, measured, disparity):
    return horizon_band(sky, separators, measured, disparity, RANGE_PX, FAR_PX, HORIZON, CAMERA, border_px=2)


def test_the_gap_between_open_sky_and_far_ground_is_taken():
    sky, sep, measured, disp = _column_scene()
    band = _band(sky, sep, measured, disp)
    assert band[34:56, 2:-2].all()
    assert not band[:34].any() and not band[56:].any()
    assert not band[:, :2].any() and not band[:, -2:].any()  # the image's sides


def test_what_stands_in_the_gap_keeps_it_unknown():
    sky, sep, measured, disp = _column_scene()
    # a beam across the gap below the horizon: a second edge
    beam = sep.copy()
    beam[50:52, 10:20] = True
    band = _band(sky, beam, measured, disp)
    assert not band[:, 10:20].any() and band[34:56, 22:-2].all()
    # the first measured pixels are near (a wall under a roof line at the flight altitude)
    near = disp.copy()
    near[56:70, 10:20] = 6.0
    assert not _band(sky, sep, measured, near)[:, 10:20].any()
    # ... or just within the range, measured a little off (far, but not by the error's margin)
    edge = disp.copy()
    edge[56:70, 10:20] = 3.5
    assert not _band(sky, sep, measured, edge)[:, 10:20].any()
    # the matcher's own values in the gap put something within the range
    guess = disp.copy()
    guess[45:50, 10:20] = 5.0
    assert not _band(sky, sep, measured, guess)[:, 10:20].any()
    # a speck of noise that passed the texture test, over an unmeasured plain wall
    speck = np.zeros((H, W), bool)
    speck[58:61, 14:16] = True
    assert not _band(sky, sep, speck, disp).any()
    # far ground only far under the horizon (more than 15 degrees: row 67)
    low = np.zeros((H, W), bool)
    low[75:] = True
    assert not _band(sky, sep, low, disp).any()
    # open sky that ends far above the horizon (a roof line across it)
    high = np.zeros((H, W), bool)
    high[:25] = True
    assert not _band(high, sep, measured, disp).any()


def test_the_setting_is_checked():
    with pytest.raises(InputError, match="horizon far range"):
        PerceptionSettings.flight(horizon_far_m=0.0)


def test_a_noisy_camera_sees_the_air_at_its_own_altitude():
    """Noisy delivery seed 0's stall (session 48): a level view past a building into the open.
    With the band, the rows at the horizon hold open air where the view is open, and no band
    pixel lies on anything within the map's range (checked against the true geometry)."""
    cfg = MissionConfig(camera_noise=1.5)
    rig = mission_rig(cfg)
    city = generate_city(0, 200.0)
    pitch = math.radians(8.0)
    cam_from_world = look_from(np.array([5.33, 87.94, 14.78]), math.radians(160.0), pitch)
    frame = render_stereo(city, rig, cam_from_world.with_frames("left", "world"))
    rng = np.random.default_rng(3)
    left, right = add_sensor_noise(frame.left, 1.5, rng), add_sensor_noise(frame.right, 1.5, rng)
    horizon = rig.left.cy - rig.left.fy * math.tan(pitch)
    settings = flight_perception(cfg)
    assert settings.horizon_far_m == cfg.max_range_m
    with_band = StereoDepth(rig, settings).compute(left, right, horizon_row_px=horizon).depth_m
    without = (
        StereoDepth(rig, PerceptionSettings.flight()).compute(left, right, horizon_row_px=horizon).depth_m
    )
    rows = slice(int(horizon / 2) - 4, int(horizon / 2) + 4)  # the depth is at half resolution
    assert np.isinf(with_band[rows]).mean() > np.isinf(without[rows]).mean() + 0.3
    added = np.isinf(with_band) & ~np.isinf(without)
    reach, _, _ = true_reach(city, rig, cam_from_world, *np.nonzero(added))
    assert len(reach) > 1000 and reach.min() > cfg.max_range_m
