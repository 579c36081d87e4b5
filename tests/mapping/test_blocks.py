"""The sparse voxel-block pool: growth and shrinking keep every block's voxels."""

from __future__ import annotations

import numpy as np

from skyrecon.mapping.blocks import BlockGrid


def _fill(grid: BlockGrid, coords: np.ndarray) -> np.ndarray:
    ids = grid.ensure(coords)
    grid.data[ids] = np.arange(len(ids), dtype=np.float32)[:, None] + 0.5
    return ids


def test_growth_and_shrink_keep_the_blocks_and_release_the_spare_rows() -> None:
    grid = BlockGrid(4, np.nan, capacity=16)
    rng = np.random.default_rng(2)
    coords = np.unique(rng.integers(-50, 50, (3000, 3)), axis=0).astype(np.int32)
    ids = _fill(grid, coords[:1000])  # grows in place, several times
    assert grid.count == 1000 and grid.coords.shape[0] > 1000
    grid.shrink_to_fit()
    assert grid.data.shape[0] == grid.coords.shape[0] == 1000
    np.testing.assert_array_equal(grid.find(coords[:1000]), ids)
    np.testing.assert_array_equal(grid.data[ids, 0], np.arange(1000) + 0.5)
    np.testing.assert_array_equal(grid.coords[ids], coords[:1000])
    # the pool grows again after a shrink; new blocks are filled, old ones untouched
    more = grid.ensure(coords[1000:])
    assert grid.count == len(coords)
    assert np.isnan(grid.data[more]).all()
    np.testing.assert_array_equal(grid.data[ids, 0], np.arange(1000) + 0.5)
    np.testing.assert_array_equal(grid.find(coords), np.r_[ids, more])


def test_a_view_of_the_pool_makes_growth_copy_instead() -> None:
    grid = BlockGrid(4, 0.0, capacity=16)
    ids = _fill(grid, np.array([[0, 0, 0], [1, 0, 0]], np.int32))
    view = grid.data[:2]  # a live view: resizing in place would leave it dangling
    grid.ensure(np.stack([np.arange(100), np.zeros(100), np.ones(100)], 1).astype(np.int32))
    assert grid.data.shape[0] >= 102
    np.testing.assert_array_equal(view[:, 0], [0.5, 1.5])
    np.testing.assert_array_equal(grid.data[ids, 0], [0.5, 1.5])
