"""Open sky: plain segments that reach the top of the image and lie wholly above the horizon,
unless what stands near frames them from below (the glass panes of a near tower)."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Intrinsics
from skyrecon.errors import InputError
from skyrecon.perception.stereo_depth import open_sky

H, W = 60, 80
CAMERA = Intrinsics(100.0, 100.0, 40.0, 30.0, W, H)
HORIZON = 50.0  # row: everything above row ~48 lies above the horizon


def _tower_of_panes() -> tuple[np.ndarray, np.ndarray]:
    """A tower's glass panes over the whole view: frames (separators, measured near) every 12
    rows and 16 columns; the panes themselves plain."""
    separators = np.zeros((H, W), bool)
    separators[11::12, :] = True
    separators[:, 15::16] = True
    near = separators.copy()
    return separators, near


def test_panes_framed_by_a_near_tower_are_not_sky():
    separators, near = _tower_of_panes()
    # without the depth under them, the top row of panes passes for sky
    assert open_sky(separators, HORIZON, CAMERA)[2:8, 2:12].all()
    assert not open_sky(separators, HORIZON, CAMERA, near=near).any()


def test_the_frames_under_a_pane_may_be_unmeasured_for_a_few_rows():
    separators, near = _tower_of_panes()
    near[11:14, :] = False  # the horizontal bar under the top panes (a horizontal edge: no match)
    near[14:18, :] = True  # ... the frame's near depth starts 3 rows under it
    assert not open_sky(separators, HORIZON, CAMERA, near=near)[:11].any()


def test_sky_above_a_skyline_of_far_roofs_and_one_near_tower_is_sky():
    separators = np.zeros((H, W), bool)
    separators[40, :] = True  # the skyline
    near = np.zeros((H, W), bool)
    near[41:, 60:] = True  # a near tower under a quarter of it; the rest far (measured or not)
    sky = open_sky(separators, HORIZON, CAMERA, near=near)
    assert sky[:38, 2:-2].all()
    # under a near skyline along most of its length, it is taken for a framed surface
    near[41:, 10:] = True
    assert not open_sky(separators, HORIZON, CAMERA, near=near).any()


def test_near_must_match_the_separators():
    separators, near = _tower_of_panes()
    with pytest.raises(InputError):
        open_sky(separators, HORIZON, CAMERA, near=near[:, :-1])


def test_sky_reaching_down_to_the_horizon_beside_a_near_roof_is_sky():
    separators = np.zeros((H, W), bool)
    separators[40, :50] = True  # a near roof line under the left of the sky ...
    separators[40:, 50] = True  # ... the wall's side ...
    separators[46, 50:] = True  # ... and the horizon's edge beyond it, 4 degrees above the horizon
    near = np.zeros((H, W), bool)
    near[41:, :51] = True
    sky = open_sky(separators, HORIZON, CAMERA, near=near)
    assert sky[:38, 2:-2].all() and sky[:44, 53:-2].all()


def test_a_plain_band_over_another_plain_band_on_a_near_facade_is_not_sky():
    """A red sign band across the top of a near tower (reaching the top of the image), a plain
    grey band under it and the tower's measured windows under that (a random noisy view of
    city 45: 6755 pixels of open air through the tower): the first measured pixel under the
    band's rim, 20 rows down through the plain band, is near."""
    separators = np.zeros((H, W), bool)
    separators[12, :] = True  # the edge between the red band and the grey band
    separators[32:, :] = True  # the windows, textured ...
    measured = np.zeros((H, W), bool)
    measured[33:, :] = True  # ... and measured, near
    near = measured.copy()
    assert open_sky(separators, HORIZON, CAMERA, near=near)[:10, 2:-2].all()  # 8 rows: not seen
    assert not open_sky(separators, HORIZON, CAMERA, near=near, measured=measured).any()
    # far under the grey band (a skyline beyond the range): sky
    assert open_sky(separators, HORIZON, CAMERA, near=np.zeros_like(near), measured=measured)[:10, 2:-2].all()


def test_the_first_measured_pixel_under_a_pixel_within_reach():
    from skyrecon.perception.stereo_depth import _first_measured_below_is_near

    measured = np.zeros((10, 3), bool)
    near = np.zeros((10, 3), bool)
    measured[6, 0] = near[6, 0] = True  # column 0: near at row 6
    measured[4, 1] = True  # column 1: far at row 4, near at row 8 under it
    measured[8, 1] = near[8, 1] = True
    out = _first_measured_below_is_near(measured, near, reach_px=3)
    assert out[:, 0].tolist() == [False, False, False, True, True, True, False, False, False, False]
    assert not out[:5, 1].any()  # the far pixel comes first (or the near one is 4 rows down)
    assert out[5:8, 1].all() and not out[8:, 1].any()  # under the far one, the near one is first
    assert not out[:, 2].any()  # nothing measured
