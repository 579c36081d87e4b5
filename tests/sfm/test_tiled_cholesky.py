"""Tiled sparse Cholesky of block systems: the dense answer, held columns, fill, failures."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from skyrecon.sfm.tiled_cholesky import factor_tiles, tile_pattern, warm_kernels


def _block_system(seed: int, n_pose: int, n_intr: int, band: int, n_far: int):
    """A random SPD block matrix shaped like a flight's reduced camera system: pose blocks
    coupled within ``band`` of each other, ``n_far`` loop couplings, intrinsics blocks coupled
    to every pose. Returns (blk_a, blk_b, values, sizes, dense)."""
    rng = np.random.default_rng(seed)
    nb = n_pose + n_intr
    sizes = np.array([6] * n_pose + [3] * n_intr)
    start = np.concatenate([[0], np.cumsum(sizes)])
    n = int(start[-1])
    pairs = {(a, a) for a in range(nb)}
    pairs |= {(a, b) for a in range(n_pose) for b in range(a + 1, min(n_pose, a + band + 1))}
    far = rng.integers(0, n_pose, size=(n_far, 2))
    pairs |= {(int(min(a, b)), int(max(a, b))) for a, b in far}
    pairs |= {(a, b) for a in range(n_pose) for b in range(n_pose, nb)}
    pairs |= {(a, b) for a in range(n_pose, nb) for b in range(n_pose, nb)}  # both orders, as stored
    mask = np.zeros((n, n), bool)
    for a, b in pairs:
        mask[start[a] : start[a + 1], start[b] : start[b + 1]] = True
        mask[start[b] : start[b + 1], start[a] : start[a + 1]] = True
    A = rng.normal(size=(n, n)) * mask
    A = A @ A.T * mask + n * np.eye(n)  # symmetric, positive definite, zero outside the pattern
    blk = sorted(pairs)
    blk_a = np.array([p[0] for p in blk])
    blk_b = np.array([p[1] for p in blk])
    values = np.zeros((len(blk), 6, 6))
    for s, (a, b) in enumerate(blk):
        values[s, : sizes[a], : sizes[b]] = A[start[a] : start[a + 1], start[b] : start[b + 1]]
    return blk_a, blk_b, values, sizes, A


@pytest.mark.parametrize("tile_columns", [6, 30, 64, 1000])
def test_solve_gives_the_dense_answer_in_any_order(tile_columns):
    blk_a, blk_b, values, sizes, A = _block_system(0, 40, 2, band=4, n_far=6)
    rhs = np.random.default_rng(1).normal(size=len(A))
    order = np.random.default_rng(2).permutation(len(sizes))
    pattern = tile_pattern(blk_a, blk_b, sizes, order, tile_columns=tile_columns)
    assert pattern.width <= max(tile_columns, 6)
    store = pattern.scatter(values, blk_a, blk_b, np.zeros(0, np.int64))
    factor_tiles(store, pattern)
    np.testing.assert_allclose(pattern.solve(store, rhs), np.linalg.solve(A, rhs), rtol=1e-9, atol=1e-12)


def test_factor_is_the_cholesky_factor_of_the_permuted_matrix():
    blk_a, blk_b, values, sizes, A = _block_system(3, 30, 0, band=3, n_far=1)
    pattern = tile_pattern(blk_a, blk_b, sizes, np.arange(len(sizes)), tile_columns=24)
    store = pattern.scatter(values, blk_a, blk_b, np.zeros(0, np.int64))
    factor_tiles(store, pattern)
    nt, w = len(pattern.tile_start) - 1, pattern.width
    L = np.zeros((nt * w, nt * w))
    for i in range(nt):
        for j in range(i + 1):
            if pattern.tile_id[i, j] >= 0:
                L[i * w : (i + 1) * w, j * w : (j + 1) * w] = store[pattern.tile_id[i, j]]
    widths = np.diff(pattern.tile_start)
    cols = np.concatenate([t * w + np.arange(widths[t]) for t in range(nt)])
    L = L[np.ix_(cols, cols)]
    P = A[np.ix_(pattern.perm, pattern.perm)]
    np.testing.assert_allclose(L, np.linalg.cholesky(P), atol=1e-9)
    # the factor's non-zero tiles are all stored (it matched), and a band leaves the rest out
    assert pattern.n_stored < nt * (nt + 1) // 2


def test_held_columns_are_zeroed_with_a_unit_diagonal():
    blk_a, blk_b, values, sizes, A = _block_system(5, 20, 1, band=3, n_far=2)
    held = np.array([0, 1, 2, 3, 4, 5, 9, len(A) - 2])
    rhs = np.random.default_rng(6).normal(size=len(A))
    rhs[held] = 0.0
    B = A.copy()
    B[held, :] = 0.0
    B[:, held] = 0.0
    B[held, held] = 1.0
    pattern = tile_pattern(blk_a, blk_b, sizes, np.arange(len(sizes))[::-1], tile_columns=18)
    store = pattern.scatter(values, blk_a, blk_b, held)
    factor_tiles(store, pattern)
    x = pattern.solve(store, rhs)
    np.testing.assert_allclose(x, scipy.linalg.solve(B, rhs, assume_a="pos"), rtol=1e-9, atol=1e-12)
    assert np.all(x[held] == 0.0)


def test_not_positive_definite_raises():
    blk_a, blk_b, values, sizes, _ = _block_system(7, 10, 0, band=2, n_far=0)
    values[3] = -values[3]  # a negative diagonal block
    pattern = tile_pattern(blk_a, blk_b, sizes, np.arange(len(sizes)), tile_columns=12)
    store = pattern.scatter(values, blk_a, blk_b, np.zeros(0, np.int64))
    with pytest.raises(np.linalg.LinAlgError):
        factor_tiles(store, pattern)


def test_warm_kernels_runs():
    warm_kernels()
