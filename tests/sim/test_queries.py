"""Ground-truth queries against brute force: signed distance, occupancy, ray casting."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from tests.sim.reference import raycast_brute, sdf_brute


def _random_points(city, rng, n):
    x0, y0, x1, y1 = city.extent
    pts = np.column_stack(
        [rng.uniform(x0 - 10, x1 + 10, n), rng.uniform(y0 - 10, y1 + 10, n), rng.uniform(-1, 70, n)]
    )
    # and points near surfaces: on box faces and pole sides, nudged in and out
    k = rng.integers(len(city.boxes), size=n // 2)
    b = city.boxes[k]
    near = b[:, :3] + rng.random((len(k), 3)) * (b[:, 3:] - b[:, :3])
    axis = rng.integers(3, size=len(k))
    side = rng.integers(2, size=len(k))
    near[np.arange(len(k)), axis] = np.where(
        side == 1, b[np.arange(len(k)), axis + 3], b[np.arange(len(k)), axis]
    )
    near += rng.normal(0, 0.05, near.shape)
    c = city.cylinders[rng.integers(len(city.cylinders), size=n // 4)]
    a = rng.uniform(0, 2 * np.pi, len(c))
    r = c[:, 2] + rng.normal(0, 0.05, len(c))
    z = rng.uniform(c[:, 3] - 0.5, c[:, 4] + 0.5)
    pole = np.column_stack([c[:, 0] + r * np.cos(a), c[:, 1] + r * np.sin(a), z])
    return np.vstack([pts, near, pole])


@pytest.mark.parametrize("include_ground", [False, True])
def test_distance_matches_brute_force(city, include_ground):
    rng = np.random.default_rng(1)
    p = _random_points(city, rng, 3000)
    got = city.distance(p, include_ground=include_ground)
    ref = sdf_brute(city, p, include_ground)
    err = np.abs(got - ref)
    print(
        f"\ndistance vs brute force (ground={include_ground}): {len(p)} points, max |error| {err.max():.2e} m, "
        f"{np.mean(ref < 0) * 100:.1f} % inside"
    )
    assert err.max() < 1e-9
    assert np.array_equal(city.is_occupied(p, include_ground), ref <= 0)


def test_occupancy_grid_matches_point_and_box_queries(city):
    rng = np.random.default_rng(2)
    origin = np.array([-37.3, -41.9, -0.4])
    vs, shape = 0.7, (90, 80, 40)
    occ = city.occupancy_grid(origin, vs, shape)
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), axis=-1).reshape(-1, 3)
    centres = origin + (idx + 0.5) * vs
    centre_occ = city.is_occupied(centres).reshape(shape)
    # a voxel whose centre is inside an obstacle overlaps it; the reverse fails only at boundaries
    assert np.all(occ[centre_occ])
    extra = occ & ~centre_occ
    print(
        f"\noccupancy grid {shape} at {vs} m: {occ.mean() * 100:.2f} % occupied, {centre_occ.mean() * 100:.2f} % "
        f"by centre, {extra.sum()} voxels occupied only off-centre"
    )
    d = city.distance(centres[extra.ravel()])
    assert np.all(d <= vs * np.sqrt(3) / 2 + 1e-9)  # within half a voxel diagonal of an obstacle
    sample = idx[rng.integers(len(idx), size=400)]
    sample = np.vstack(
        [sample, np.argwhere(extra)[:100], np.argwhere(occ)[rng.integers(occ.sum(), size=100)]]
    )
    for i, j, k in sample:
        lo = origin + np.array([i, j, k]) * vs
        assert occ[i, j, k] == city.box_occupied(lo, lo + vs), (i, j, k)
    ground = city.occupancy_grid(origin, vs, shape, include_ground=True)
    assert np.all(ground[:, :, 0]) and np.array_equal(ground[:, :, 1:], occ[:, :, 1:])


def test_raycast_matches_brute_force_and_lands_on_surfaces(city):
    rng = np.random.default_rng(3)
    n = 3000
    o = _random_points(city, rng, n)[:n]
    o[:, 2] = np.abs(o[:, 2]) + 0.5
    o = o[city.distance(o, include_ground=True) > 0.05]
    d = rng.normal(size=(len(o), 3))
    d[: len(o) // 3, 2] = -np.abs(d[: len(o) // 3, 2]) - 0.3  # plenty of rays going down
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = city.raycast(o, d)
    ref = raycast_brute(city, o, d)
    hit = np.isfinite(ref)
    assert np.array_equal(np.isfinite(t), hit)
    rel = np.abs(t[hit] - ref[hit]) / np.maximum(ref[hit], 1.0)
    p = o[hit] + t[hit, None] * d[hit]
    on = np.abs(city.distance(p, include_ground=True))
    print(
        f"\nraycast: {len(o)} rays, {hit.mean() * 100:.1f} % hit; vs brute force max rel error {rel.max():.1e}; "
        f"|distance| at hit points: median {np.median(on):.1e} m, max {on.max():.1e} m"
    )
    assert rel.max() < 1e-9
    assert on.max() < 1e-6
    # the segment up to the hit is free space
    for f in (0.25, 0.5, 0.9):
        assert np.all(city.distance(o[hit] + f * t[hit, None] * d[hit], include_ground=True) > -1e-9)
    hits = city.raycast_hits(o, d)
    assert np.array_equal(hits.distance_m, t)
    assert np.all(np.sum(hits.normal[hit] * d[hit], axis=1) < 0)  # we hit the outside of every surface
    assert np.all(hits.object_id[~hit] == -1) and np.all(hits.object_id[hit] >= 0)
    assert np.allclose(np.linalg.norm(hits.normal[hit], axis=1), 1.0)


def test_raycast_misses_and_ground_option(city):
    o = np.array([[0.0, 0.0, 100.0]] * 3)
    d = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    t = city.raycast(o, d)
    assert np.isinf(t[0]) and np.isinf(t[1]) and np.isfinite(t[2])
    far = np.array([[city.extent[2] + 50, 0.0, 5.0]])
    assert city.raycast(far, [[0, 0, -1.0]])[0] == pytest.approx(5.0)
    assert np.isinf(city.raycast(far, [[0, 0, -1.0]], include_ground=False)[0])
    assert np.isinf(city.raycast(far, [[0, 0, -1.0]], max_range_m=4.0)[0])


def test_query_input_errors(city):
    with pytest.raises(InputError):
        city.distance(np.array([[0.0, np.nan, 1.0]]))
    with pytest.raises(InputError):
        city.raycast(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError):
        city.distance(np.zeros((4, 2)))
    with pytest.raises(InputError):
        city.occupancy_grid(np.zeros(3), 0.0, (2, 2, 2))
