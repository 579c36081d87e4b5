"""Distance field: exact transform, brute-force agreement, incremental updates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from skyrecon.errors import InputError
from skyrecon.mapping import DistanceField, OccupancyMap
from skyrecon.mapping._edt import bounded_distance, squared_edt
from skyrecon.mapping.distance import brute_force_distance


def test_edt_equals_scipy():
    rng = np.random.default_rng(1)
    for shape, p in (((23, 17, 11), 0.03), ((9, 40, 5), 0.005), ((6, 6, 6), 0.0)):
        occ = rng.random(shape) < p
        d2 = squared_edt(occ)
        if occ.any():
            np.testing.assert_allclose(d2, distance_transform_edt(~occ) ** 2, atol=1e-9)
        else:
            assert np.all(np.isinf(d2))


@pytest.mark.parametrize(
    "shape, p, voxel, max_d",
    [
        ((23, 17, 11), 0.03, 0.5, 3.43),
        ((9, 40, 5), 0.005, 0.5, 2.0),
        ((40, 30, 20), 0.01, 0.3, 1.7),
        ((12, 12, 12), 0.0, 0.5, 3.0),
        ((20, 21, 22), 0.002, 1.0, 0.6),
    ],
)
def test_bounded_distance_equals_clipped_scipy(shape, p, voxel, max_d):
    """The windowed transform is exact below the clip (the windows cover every source that near)."""
    occ = np.random.default_rng(3).random(shape) < p
    d = bounded_distance(occ, voxel, max_d)
    assert d.dtype == np.float32 and d.shape == shape
    ref = np.full(shape, max_d) if not occ.any() else np.minimum(distance_transform_edt(~occ) * voxel, max_d)
    np.testing.assert_allclose(d, ref, atol=1e-5)


@pytest.mark.parametrize("unknown_is_occupied", [False, True])
def test_distance_field_matches_brute_force(unknown_is_occupied):
    rng = np.random.default_rng(2)
    occ = rng.random((30, 26, 14)) < 0.02
    v = 0.5
    lo_v = np.array([-6, 4, -2])
    m = OccupancyMap.from_occupancy_grid(occ, lo_v * v, voxel_size_m=v)
    df = DistanceField(m, max_distance_m=2.0, unknown_is_occupied=unknown_is_occupied)
    # query voxel centres in and around the grid (outside it the map is unknown)
    q_vox = rng.integers(lo_v - 3, lo_v + np.array(occ.shape) + 3, size=(600, 3))
    q = (q_vox + 0.5) * v
    obst = m.occupied_centers()
    if unknown_is_occupied:
        ring = np.stack(
            np.meshgrid(*[np.arange(a - 8, a + s + 8) for a, s in zip(lo_v, occ.shape)], indexing="ij"), -1
        )
        ring = ring.reshape(-1, 3)
        inside = np.all((ring >= lo_v) & (ring < lo_v + np.array(occ.shape)), axis=1)
        # unknown voxels within reach of the queries (the clipping radius is 4 voxels)
        near = np.all((ring >= lo_v - 8) & (ring < lo_v + np.array(occ.shape) + 8), axis=1)
        obst = np.concatenate([obst, (ring[~inside & near] + 0.5) * v])
    ref = brute_force_distance(obst, q, 2.0)
    np.testing.assert_allclose(df.query_distance(q), ref, atol=1e-5)
    # interpolation reproduces the values at voxel centres
    np.testing.assert_allclose(df.query_distance(q, interpolate=True), ref, atol=1e-5)


def test_incremental_update_equals_full_recompute():
    rng = np.random.default_rng(3)
    m = OccupancyMap(voxel_size_m=0.5, max_range_m=40.0)
    origin = np.array([0.2, 0.1, 5.3])
    m.integrate_points(rng.uniform([-12, -12, 0], [12, 12, 10], size=(200, 3)), origin)
    m.pop_changed_blocks()
    df = DistanceField(m, max_distance_m=2.0, unknown_is_occupied=False, tile_blocks=2, max_box_voxels=1)
    for _ in range(2):  # new obstacles appear (and carve free space on the way)
        m.integrate_points(rng.uniform([-15, -3, 0], [15, 3, 10], size=(30, 3)), origin)
        changed = m.pop_changed_blocks()
        assert len(changed) > 0
        df.update(changed)
    full = DistanceField(m, max_distance_m=2.0, unknown_is_occupied=False)
    lo, hi = m.voxel_bounds()
    lo, hi = lo - 16, hi + 16
    np.testing.assert_array_equal(df.dense(lo, tuple(hi - lo)), full.dense(lo, tuple(hi - lo)))


def test_query_validation():
    m = OccupancyMap.from_occupancy_grid(np.zeros((4, 4, 4), bool), np.zeros(3), voxel_size_m=0.5)
    df = DistanceField(m, 1.0)
    with pytest.raises(InputError):
        df.query_distance(np.zeros((3, 2)))
    with pytest.raises(InputError):
        df.query_distance(np.array([[np.nan, 0, 0]]))
    with pytest.raises(InputError):
        DistanceField(m, -1.0)
