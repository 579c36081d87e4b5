"""The plain object scene (``generate_object_scene(plain=True)``): low-texture ground and walls."""

from __future__ import annotations

import cv2
import numpy as np

from skyrecon.core import Intrinsics
from skyrecon.sim import generate_object_scene, render_views, ring_views
from skyrecon.sim.texture import GROUND_PLAIN_PLAZA, GROUND_PLAZA, MAT_GLASS, MAT_PLAIN


def _local_std(grey: np.ndarray, k: int = 9) -> np.ndarray:
    g = grey.astype(np.float32)
    m = cv2.boxFilter(g, -1, (k, k))
    return np.sqrt(np.maximum(cv2.boxFilter(g * g, -1, (k, k)) - m * m, 0.0))


def test_plain_keeps_the_geometry_and_changes_the_materials():
    rich, plain = generate_object_scene(4), generate_object_scene(4, plain=True)
    assert rich.ground_style == GROUND_PLAZA and plain.ground_style == GROUND_PLAIN_PLAZA
    # same boxes (the glass panel comes last) and cylinders
    np.testing.assert_array_equal(plain.boxes[: len(rich.boxes)], rich.boxes)
    np.testing.assert_array_equal(plain.cylinders, rich.cylinders)
    assert len(plain.boxes) == len(rich.boxes) + 1
    assert plain.box_material[-1] == MAT_GLASS and (plain.box_material == MAT_GLASS).sum() == 1
    assert (plain.box_material == MAT_PLAIN).sum() >= 2
    assert not (rich.box_material == MAT_PLAIN).any()
    # deterministic
    again = generate_object_scene(4, plain=True)
    np.testing.assert_array_equal(again.boxes, plain.boxes)
    np.testing.assert_array_equal(again.box_albedo, plain.box_albedo)


def test_plain_ground_renders_near_uniform():
    cam = Intrinsics.from_fov(160, 120, 60.0)
    out = {}
    for plain in (False, True):
        city = generate_object_scene(1, plain=plain)
        view = ring_views(city.center, 8.0, city.center[2] + 5.0, 4, cam)[0]
        (r,) = render_views(city, [view])
        grey = cv2.cvtColor(r.image, cv2.COLOR_RGB2GRAY)
        ground = (r.object_id == 0) & (cv2.erode((r.object_id == 0).astype(np.uint8), np.ones((9, 9))) > 0)
        out[plain] = (grey, ground)
    grey, ground = out[True]
    assert ground.mean() > 0.3
    std = _local_std(grey)[ground]
    assert np.median(std) < 1.0  # no fine texture: a real plain surface
    g = grey[ground].astype(float)
    assert 60 < g.mean() < 200 and g.std() < 12  # grey, only mild shading across the image
    grey_r, ground_r = out[False]
    assert np.median(_local_std(grey_r)[ground_r]) > 3.0  # the paved plaza is textured
