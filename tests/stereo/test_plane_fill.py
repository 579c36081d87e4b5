"""Plane-supported filling: an unmeasured segment takes the plane its measured border lies on, all
around it; an occluded strip, the sky above a roof line, a region between two planes or one
bounded by a single edge stays unfilled."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.stereo import plane_supported_fill

H, W = 120, 160


def _plane(a: float, b: float, c: float) -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return (a * u + b * v + c).astype(np.float32)


def _hole(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """(H, W) measured mask: everything but the rectangle [r0, r1) x [c0, c1)."""
    m = np.ones((H, W), bool)
    m[r0:r1, c0:c1] = False
    return m


def test_a_slanted_plain_wall_bounded_all_around_takes_its_plane():
    rng = np.random.default_rng(0)
    truth = _plane(0.03, -0.02, 12.0)  # a wall seen at an angle: disparity affine in (u, v)
    measured = _hole(20, 100, 30, 130)
    disp = truth + rng.normal(0.0, 0.05, truth.shape).astype(np.float32)  # measurement noise
    # the matcher's own fill would be background-favouring along rows: here, garbage
    disp[~measured] = 3.0
    out, accepted = plane_supported_fill(disp, measured)
    inner = np.zeros((H, W), bool)
    inner[22:98, 32:128] = True  # all but the pixel next to the measured border (the seal)
    assert accepted[inner].all() and not (accepted & measured).any()
    assert np.abs(out[accepted] - truth[accepted]).max() < 0.05
    np.testing.assert_array_equal(out[measured], disp[measured])
    assert np.isnan(out[~measured & ~accepted]).all()


def test_an_occluded_strip_between_background_and_foreground_is_refused():
    # its border is background on the left and foreground on the right: the only plane through
    # both rises by about 1 px of disparity per pixel, a surface the right camera could not see
    disp = np.full((H, W), 10.0, np.float32)  # background
    disp[20:100, 70:110] = 20.0  # a foreground object
    measured = _hole(20, 100, 58, 70)  # the strip left of it that the right camera cannot see
    out, accepted = plane_supported_fill(disp, measured)
    assert not accepted.any() and np.isnan(out[~measured]).all()
    # the same strip with the object at the background's depth is a plain patch of one plane
    flat = np.full((H, W), 10.0, np.float32)
    assert plane_supported_fill(flat, measured)[1][22:98, 60:68].all()


def test_the_sky_above_a_roof_line_is_refused():
    disp = _plane(0.0, 0.01, 8.0)
    measured = np.ones((H, W), bool)
    measured[:40] = False  # the sky: unmeasured, open to the top of the image
    _, accepted = plane_supported_fill(disp, measured)
    assert not accepted.any()
    # a road cut by the bottom of the image is bounded by the frame there and is filled
    road = np.ones((H, W), bool)
    road[70:, 40:120] = False
    _, accepted = plane_supported_fill(disp, road)
    assert accepted[75:, 45:115].all()


def test_a_region_between_two_planes_is_refused():
    left = _plane(0.08, 0.0, 4.0)
    right = _plane(-0.08, 0.0, 4.0 + 0.16 * 80)  # meets the left wall at u = 80: a concave corner
    disp = np.where(np.arange(W)[None, :] < 80, left, right).astype(np.float32)
    measured = _hole(20, 100, 30, 130)
    _, accepted = plane_supported_fill(disp, measured)
    assert not accepted.any()


def test_a_region_bounded_by_a_single_edge_or_cut_by_a_boundary():
    disp = _plane(0.02, 0.01, 9.0)
    # a measured vertical line alone does not fix a plane: its slope across is unknown
    measured = np.zeros((H, W), bool)
    measured[:, 78:81] = True
    assert not plane_supported_fill(disp, measured)[1].any()
    # an unmeasured image edge (boundary) splits a hole: the right part, bounded by the edge
    # and not by measured pixels on its left, is refused; the left part is filled
    m = _hole(20, 100, 30, 130)
    edge = np.zeros((H, W), bool)
    edge[:, 90:93] = True
    m[:, 90:93] = False  # an edge the matcher could not measure (e.g. horizontal texture)
    m[20:100, 93:130] = True  # and the region right of it measured
    m[20:100, 93:130] = False
    m[:20, 90:93] = m[100:, 90:93] = True
    _, accepted = plane_supported_fill(disp, m, boundary=edge)
    assert accepted[25:95, 35:85].all() and not accepted[:, 89:94].any()


def test_bad_input():
    d = np.zeros((10, 10), np.float32)
    with pytest.raises(InputError):
        plane_supported_fill(d, np.ones((10, 11), bool))
    with pytest.raises(InputError):
        plane_supported_fill(d, np.ones((10, 10), bool), boundary=np.ones((9, 10), bool))
    out, accepted = plane_supported_fill(d, np.ones((10, 10), bool))
    assert not accepted.any() and (out == 0).all()


def test_a_plane_that_does_not_map_onto_the_right_image_is_refused():
    # a plain square (disparity 12) in front of a textured wall (disparity 4); the matcher
    # measured only the texture, and the pixels at the square's border took the wall's
    # disparity (the only texture in their window): the border says "wall plane", wrongly
    rng = np.random.default_rng(1)
    wall = rng.uniform(40, 220, (H, W + 40)).astype(np.float32)
    r0, r1, c0, c1, d_sq, d_wall = 30, 90, 60, 120, 12, 4
    left = wall[:, 20 : 20 + W].copy()
    right = wall[:, 20 + d_wall : 20 + d_wall + W].copy()  # x_right = x_left - d
    left[r0:r1, c0:c1] = 128.0
    right[r0:r1, c0 - d_sq : c1 - d_sq] = 128.0
    disp = np.full((H, W), float(d_wall), np.float32)
    measured = _hole(r0, r1, c0, c1)
    _, wrong = plane_supported_fill(disp, measured)
    assert wrong[r0 + 3 : r1 - 3, c0 + 3 : c1 - 3].all()  # geometry alone cannot tell
    _, accepted = plane_supported_fill(disp, measured, left=left, right=right)
    assert not accepted.any()
    # the right plane (the square's border measured at its own disparity) passes the check
    disp[~measured] = np.nan
    disp[r0 - 3 : r1 + 3, c0 - 3 : c1 + 3][measured[r0 - 3 : r1 + 3, c0 - 3 : c1 + 3]] = float(d_sq)
    _, right_plane = plane_supported_fill(disp, measured, left=left, right=right)
    assert right_plane[r0 + 3 : r1 - 3, c0 + 3 : c1 - 3].all()


def test_a_plain_road_between_two_poles_is_not_a_sheet_hung_between_them():
    # a gantry (two poles and a beam at disparity 8) over a plain road the matcher sees at
    # about 5 (its paths come in from the road around the poles): the poles "bound" the road on
    # a plane of their own, open to the bottom of the image; only the guesses tell them apart
    rng = np.random.default_rng(1)
    disp = np.full((H, W), 5.0, np.float32) + rng.normal(0.0, 0.4, (H, W)).astype(np.float32)
    measured = np.zeros((H, W), bool)
    for c0 in (30, 126):  # the poles
        measured[40:, c0 : c0 + 4] = True
    measured[40:44, 30:130] = True  # the beam
    disp[measured] = 8.0
    out, accepted = plane_supported_fill(disp, measured)
    assert accepted[60:110, 40:120].all()  # without the check: the sheet
    out, accepted = plane_supported_fill(disp, measured, max_guess_gap_px=1.5)
    assert not accepted.any() and np.isnan(out[~measured]).all()
    # a plain wall whose guesses are smoothed in from its border (within a pixel) keeps its plane
    truth = _plane(0.03, -0.02, 12.0)
    wall = _hole(20, 100, 30, 130)
    guessed = truth + rng.uniform(-1.0, 1.0, truth.shape).astype(np.float32)
    out, accepted = plane_supported_fill(np.where(wall, truth, guessed), wall, max_guess_gap_px=1.5)
    assert accepted[22:98, 32:128].all()
    assert np.abs(out[accepted] - truth[accepted]).max() < 0.05
    # invalid guesses (NaN) are no evidence either way
    out, accepted = plane_supported_fill(np.where(wall, truth, np.nan), wall, max_guess_gap_px=1.5)
    assert accepted[22:98, 32:128].all()


# ----- a prior plane (the ground) for segments their own border does not fix -------------------


def _field() -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float, float]]:
    """A plain field below a horizon at row 20, running out of the image right, bottom and up to
    the horizon (an edge at rows 18-19 parts it from the sky); its only measured border is a
    street edge along its lower left (a diagonal band of measured ground). Returns (disparity,
    measured, the horizon's edge, ground plane)."""
    ground = (0.0, 0.05, -1.0)  # d = 0.05 v - 1: zero at row 20, the horizon
    disp = _plane(*ground)
    v, u = np.mgrid[0:H, 0:W]
    measured = (u - 0.8 * (v - 20) > -6) & (u - 0.8 * (v - 20) < 0) & (v >= 20)  # the street edge
    disp[~measured] = 7.0  # the matcher's values on the plain field and the sky: anything
    return disp, measured, (v >= 18) & (v < 20), ground


def test_a_field_bounded_on_one_side_takes_the_prior_ground_plane():
    disp, measured, horizon, ground = _field()
    _, accepted = plane_supported_fill(disp, measured, boundary=horizon)
    assert not accepted.any()  # its own border (one edge) does not fix a plane
    out, accepted = plane_supported_fill(disp, measured, boundary=horizon, prior_plane=ground)
    assert accepted[40:110, 100:150].all() and not accepted[:18].any()
    np.testing.assert_allclose(out[accepted], _plane(*ground)[accepted], rtol=1e-5, atol=1e-5)


def test_the_prior_is_refused_when_the_border_disagrees_or_lies_only_above():
    disp, measured, horizon, ground = _field()
    # the border is a wall 1.5 px nearer than the ground: not the ground
    nearer = np.where(measured, disp + 1.5, disp).astype(np.float32)
    assert not plane_supported_fill(nearer, measured, boundary=horizon, prior_plane=ground)[1].any()
    # a plain wall filling the lower image whose only measured border is the far ground above
    # its (horizontal, unmatched) roof line: all support above the segment, refused
    v = np.mgrid[0:H, 0:W][0]
    wall_measured = (v >= 20) & (v < 26)  # a band of measured far ground over the roof line
    wall = np.where(wall_measured, _plane(*ground), 9.0).astype(np.float32)
    _, accepted = plane_supported_fill(wall, wall_measured, boundary=horizon, prior_plane=ground)
    assert not accepted[26:].any()
    # and with no measured border at all, nothing
    none = np.zeros((H, W), bool)
    assert not plane_supported_fill(wall, none, boundary=horizon, prior_plane=ground)[1].any()


def _street() -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float, float]]:
    """A plain street running from the vanishing point (80, 20) out of the bottom of the image,
    seen from above: its left kerb a measured diagonal band down to the image's left border
    (row 86), its right kerb an unmatched edge (a boundary) down to the right border; below the
    kerbs' ends the street spans the image, so its segment is narrow at the top and wide at the
    bottom, its centroid low in its box and its only support (the left kerb) higher up.
    Returns (disparity, measured, boundaries: the horizon and the right kerb, ground plane)."""
    ground = (0.0, 0.05, -1.0)  # d = 0.05 v - 1: zero at row 20, the horizon
    disp = _plane(*ground)
    v, u = np.mgrid[0:H, 0:W]
    left = u + 1.2 * (v - 20) - 80.0  # 0 on the left kerb's line
    right = u - 1.2 * (v - 20) - 80.0  # 0 on the right kerb's line
    measured = (left > -4) & (left < 0) & (v >= 22)
    boundary = ((v >= 18) & (v < 20)) | ((right > 0) & (right < 3) & (v >= 22))
    disp[~measured] = 7.0  # the matcher's values on the plain street and the sky: anything
    return disp, measured, boundary, ground


def test_a_street_running_out_of_the_image_takes_the_prior_supported_beside_it():
    disp, measured, boundary, ground = _street()
    out, accepted = plane_supported_fill(disp, measured, boundary=boundary, prior_plane=ground)
    # the street, between its kerbs and across the bottom rows (every kerb pixel lies above its
    # centroid row, more than a tenth of them below the middle row of its box)
    assert accepted[100:, 5:155].all() and accepted[40:60, 75:85].all()
    np.testing.assert_allclose(out[accepted], _plane(*ground)[accepted], rtol=1e-5, atol=1e-5)


def test_the_prior_need_not_agree_with_the_matchers_values_when_asked_not_to():
    disp, measured, boundary, ground = _street()
    args = dict(boundary=boundary, prior_plane=ground, max_guess_gap_px=1.5)
    # the matcher's values inside are 7 px, far off the ground's: refused with the check ...
    assert not plane_supported_fill(disp, measured, **args)[1][100:].any()
    # ... taken without it (skyrecon map takes such segments for hits on the ground only)
    out, accepted = plane_supported_fill(disp, measured, prior_guess_check=False, **args)
    assert accepted[100:, 5:155].all()
    np.testing.assert_allclose(out[accepted], _plane(*ground)[accepted], rtol=1e-5, atol=1e-5)
    # a fitted plane is still held to them: a plain wall bounded all round, its values far off
    wall = np.zeros((H, W), bool)
    wall[20:100, 30:130] = True
    wall[22:98, 32:128] = False
    truth = _plane(0.02, 0.01, 10.0)
    values = np.where(wall, truth, truth - 5.0).astype(np.float32)
    _, accepted = plane_supported_fill(values, wall, max_guess_gap_px=1.5, prior_guess_check=False)
    assert not accepted.any()


def test_the_prior_never_fills_a_segment_reaching_above_its_horizon():
    disp, measured, _, ground = _field()
    # no edge at the horizon: the field's segment runs on into the sky above it (the ground
    # left of the street edge, wholly below the horizon, is still taken)
    _, accepted = plane_supported_fill(disp, measured, prior_plane=ground)
    assert not accepted[:, 100:].any() and accepted[100:, 10:40].all()


def test_warm_kernels_loads_every_kernel_the_fill_runs():
    """A flight loads them before its first cycle (StereoDepth.warm_up): none may be left."""
    from skyrecon.stereo import plane_fill

    plane_fill.warm_kernels()
    called_from_python = (
        "_border_pairs",
        "_ransac_planes",
        "_segment_planes",
        "_prior_planes",
        "_photo_check",
        "_count_against_guesses",
        "_paint_planes",
    )
    assert [k for k in called_from_python if not getattr(plane_fill, k).signatures] == []


def _near_wall_before_far_building(specks: bool) -> tuple[np.ndarray, np.ndarray]:
    """A plain wall filling the left of the view (cut by the image's left, top and bottom), a
    far textured building measured right of its diagonal edge, and (``specks``) a few 3 x 3
    specks of noise on the wall that matched at the far building's disparity."""
    far = _plane(0.01, 0.0, 5.0)
    v, u = np.mgrid[0:H, 0:W]
    measured = u > 130 - v // 4  # the far building, right of the wall's edge
    if specks:
        for r, c in [(10, 10), (10, 60), (50, 20), (60, 70), (100, 15), (105, 70), (30, 100)]:
            measured[r : r + 3, c : c + 3] = True
    return far, measured


def test_specks_of_noise_do_not_support_a_plane():
    far, measured = _near_wall_before_far_building(specks=True)
    # the specks "span" the wall: it takes the far building's plane (the hazard: a near wall read far)
    assert plane_supported_fill(far, measured)[1][40:80, 30:60].all()
    # blobs under 25 pixels support no plane: one edge alone does not fix one
    _, accepted = plane_supported_fill(far, measured, min_support_area_px=25)
    assert not accepted.any()
    # without the specks, the wall is refused as well
    far, measured = _near_wall_before_far_building(specks=False)
    assert not plane_supported_fill(far, measured)[1].any()


def test_open_borders_can_be_required_to_bound_a_segment():
    # a wall cut by the image's left and bottom edges, measured on its right and along most of
    # its top; an unmeasured image edge above its left third (a boundary)
    disp = _plane(0.02, 0.01, 8.0)
    measured = np.zeros((H, W), bool)
    measured[:, 80:] = True
    measured[:30, 26:80] = True
    boundary = np.zeros((H, W), bool)
    boundary[28:31, :26] = True
    assert plane_supported_fill(disp, measured, boundary=boundary)[1][40:110, 10:70].all()
    # too little supports it left of its centre: refused unless the image border may stand for it
    _, accepted = plane_supported_fill(disp, measured, boundary=boundary, open_borders=False)
    assert not accepted.any()
