"""City generation: determinism, layout ranges, free street corridors."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.sim import generate_city, generate_object_scene
from skyrecon.sim.city import KIND_BEAM, KIND_BUILDING, KIND_POLE
from skyrecon.sim.texture import MAT_PLAIN


def test_same_seed_same_city_different_seed_different_city(city):
    again = generate_city(3)
    assert again.fingerprint() == city.fingerprint()
    for name in ("boxes", "box_material", "box_albedo", "box_params", "cylinders", "blocks_x", "blocks_y"):
        assert np.array_equal(getattr(again, name), getattr(city, name)), name
    other = generate_city(4)
    assert other.fingerprint() != city.fingerprint()
    assert other.boxes.shape != city.boxes.shape or not np.array_equal(other.boxes, city.boxes)
    assert generate_object_scene(2).fingerprint() == generate_object_scene(2).fingerprint()
    assert generate_object_scene(2).fingerprint() != generate_object_scene(3).fingerprint()


def test_layout_ranges(city):
    b = city.boxes[city.box_kind == KIND_BUILDING]
    foot = np.stack([b[:, 3] - b[:, 0], b[:, 4] - b[:, 1]], axis=1)
    print(
        f"\ncity seed 3: {city.num_buildings} buildings, {len(city.boxes)} boxes, {len(city.cylinders)} cylinders, "
        f"footprint {foot.min():.1f}-{foot.max():.1f} m, height {b[:, 5].min():.1f}-{b[:, 5].max():.1f} m, "
        f"{np.sum(city.box_material == MAT_PLAIN)} plain facades"
    )
    assert 80 <= city.num_buildings <= 300
    assert foot.min() >= 5.0 - 1e-9 and foot.max() <= 30.0 + 1e-9
    assert b[:, 5].max() <= 60.0 + 1e-9 and b[b[:, 2] == 0, 5].min() >= 6.0 - 1e-9
    poles = city.cylinders[city.cyl_kind == KIND_POLE]
    assert len(poles) >= 120
    assert np.all((poles[:, 2] >= 0.1) & (poles[:, 2] <= 0.3))
    assert np.all((poles[:, 4] >= 4.0) & (poles[:, 4] <= 10.0)) and np.all(poles[:, 3] == 0)
    beams = city.boxes[city.box_kind == KIND_BEAM]
    assert len(beams) >= 1 and np.all(beams[:, 5] < 10.0)
    assert np.all(np.sort(beams[:, 3:] - beams[:, :3], axis=1)[:, :2] <= 0.2)  # thin in two directions
    assert np.any(city.box_material[city.box_kind == KIND_BUILDING] == MAT_PLAIN)  # some low-texture facades
    x0, y0, x1, y1 = city.extent
    lo = np.concatenate([city.boxes[:, :2], city.cylinders[:, :2] - city.cylinders[:, 2:3]])
    hi = np.concatenate([city.boxes[:, 3:5], city.cylinders[:, :2] + city.cylinders[:, 2:3]])
    assert np.all(lo >= [x0, y0]) and np.all(hi <= [x1, y1])
    assert np.all(city.boxes[:, 2] >= 0)


def test_street_corridors_are_free_from_10_to_40_m(city):
    xs, ys = city.street_centers
    wx, wy = city.street_widths
    assert np.all(wx >= 10.0) and np.all(wy >= 10.0)
    s = np.linspace(city.extent[0] + 1, city.extent[2] - 1, 120)
    pts = []
    for z in (12.0, 20.0, 30.0, 40.0):
        for x in xs:
            pts.append(np.column_stack([np.full_like(s, x), s, np.full_like(s, z)]))
        for y in ys:
            pts.append(np.column_stack([s, np.full_like(s, y), np.full_like(s, z)]))
    d = city.distance(np.vstack(pts), include_ground=True)
    print(f"\nstreet centre lines at 12-40 m: clearance min {d.min():.2f} m, median {np.median(d):.2f} m")
    assert d.min() >= 2.0


def test_object_scene(object_scene):
    s = object_scene
    assert len(s.boxes) >= 4 and s.ground_style == 1
    top = s.boxes[:, 5].max()
    span = max(s.boxes[:, 3].max() - s.boxes[:, 0].min(), s.boxes[:, 4].max() - s.boxes[:, 1].min())
    assert 2.0 <= top <= 8.0 and 3.0 <= span <= 15.0
    assert s.distance(s.center) < 0  # the centre is inside the monument
    assert s.view_radius_m > 0


def test_bad_arguments():
    with pytest.raises(InputError):
        generate_city(0, size_m=10.0)
    with pytest.raises(InputError):
        generate_object_scene(0, size_m=0.0)
