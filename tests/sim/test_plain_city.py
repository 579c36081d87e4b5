"""``generate_city(..., plain=True)``: plain and glass facades, plain grey ground, and images in
which those surfaces are near-uniform (faint shading, no fine texture)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from skyrecon.sim import default_rig, generate_city, render_stereo, street_view_pose
from skyrecon.sim.city import KIND_BUILDING
from skyrecon.sim.generate import PLAIN_FACADE_FRACTION, PLAIN_GLASS_FRACTION
from skyrecon.sim.texture import GROUND_CITY, GROUND_PLAIN, MAT_GLASS, MAT_PLAIN


@pytest.fixture(scope="module")
def plain_city():
    return generate_city(3, plain=True)


def _uniform_share(frame, select) -> float:
    """Share of the selected pixels, away from object and face borders, whose 7x7 grey-level
    standard deviation is below 1 (0-255 scale); colour borders within a face (kerbs) lower it."""
    grey = cv2.cvtColor(frame.left, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mean = cv2.boxFilter(grey, -1, (7, 7))
    std = np.sqrt(np.maximum(cv2.boxFilter(grey * grey, -1, (7, 7)) - mean * mean, 0.0))
    res = frame.left_result
    # one object and one face over the whole window: its id and normal do not vary
    oid = res.object_id.astype(np.float32)
    n = np.nan_to_num(res.normal_world) @ np.array([1.0, 10.0, 100.0], np.float32)
    k = np.ones((7, 7), np.uint8)
    same = (cv2.dilate(oid, k) == cv2.erode(oid, k)) & (cv2.dilate(n, k) - cv2.erode(n, k) < 1e-3)
    sel = select(res) & same
    assert sel.sum() > 500
    return float(np.mean(std[sel] < 1.0))


def test_plain_city_materials_and_ground(plain_city):
    c = plain_city
    assert c.ground_style == GROUND_PLAIN
    mats = c.box_material[c.box_kind == KIND_BUILDING]
    plain, glass = np.mean(mats == MAT_PLAIN), np.mean(mats == MAT_GLASS)
    assert abs(plain - PLAIN_FACADE_FRACTION) < 0.12 and glass >= PLAIN_GLASS_FRACTION - 0.08
    again = generate_city(3, plain=True)
    np.testing.assert_array_equal(again.boxes, c.boxes)
    textured = generate_city(3)
    assert textured.ground_style == GROUND_CITY
    assert np.mean(textured.box_material[textured.box_kind == KIND_BUILDING] == MAT_PLAIN) < 0.25


def test_plain_surfaces_render_near_uniform(plain_city):
    rig = default_rig(320, 240)
    frame = render_stereo(plain_city, rig, street_view_pose(plain_city, 3))
    plain_boxes = 1 + np.flatnonzero(plain_city.box_material == MAT_PLAIN)
    assert _uniform_share(frame, lambda r: r.object_id == 0) > 0.8  # the ground (kerb lines aside)
    facades = lambda r: np.isin(r.object_id, plain_boxes) & (np.abs(r.normal_world[..., 2]) < 0.5)  # noqa: E731
    assert _uniform_share(frame, facades) > 0.95  # plain facades (roofs keep their kind)
    # the same view of the textured city: paving, markings and grain on the ground
    textured = generate_city(3)
    tframe = render_stereo(textured, rig, street_view_pose(textured, 3))
    assert _uniform_share(tframe, lambda r: r.object_id == 0) < 0.5
