"""The matcher's horizontal aggregation paths: the kernel against a NumPy reference, and what
they are for (a plain ground seen from above, whose disparity changes from row to row)."""

import numpy as np
import pytest
from numba import njit

from skyrecon.errors import InputError
from skyrecon.stereo import SkyreconSettings, create_matcher
from skyrecon.stereo import _kernels as K
from tests.stereo.conftest import random_texture, warp_pair


@njit(cache=False)
def _run_rows(cl, cr, cr_pad, dmin, oc, D, W, grey, P1, P2, alpha, s_out, row_len):
    """All rows of the little images through ``_horizontal_paths`` with fresh buffers."""
    wp = s_out.shape[0] // (grey.shape[0] * D)
    fwd = np.zeros(wp * D, np.uint8)
    costs = np.zeros(wp * D, np.uint8)
    sums = np.zeros(wp * D, np.uint8)
    prev = np.zeros(D + 2, np.uint8)
    cur = np.zeros(D + 2, np.uint8)
    pen = np.zeros(wp, np.uint8)
    for y in range(grey.shape[0]):
        K._horizontal_paths(
            cl[y], cr[y], cr_pad, dmin, oc, D, W, grey[y], P1, P2, alpha, fwd, prev, cur, pen, costs, sums,
            s_out, y * row_len,
        )  # fmt: skip


def _reference(cl, cr, cr_pad, dmin, oc, D, W, grey, P1, P2, alpha, s_in):
    """The same in plain NumPy (int64, plane order k, block-major output)."""
    H = grey.shape[0]
    wp = s_in.shape[0] // (H * D)
    out = s_in.astype(np.int64).reshape(H, wp // 32, D, 32).copy()
    for y in range(H):
        cost = np.full((W, D), oc, np.int64)
        for x in range(W):
            for k in range(D):
                xr = x - (dmin + k)
                if 0 <= xr < W:
                    cost[x, k] = bin(int(cl[y, x]) ^ int(cr[y, cr_pad + xr])).count("1")
        dI = np.abs(np.diff(grey[y].astype(np.float64)))
        pen = np.minimum(K.H_MAX_JUMP, np.maximum(P1 + 1, P2 / (1.0 + alpha * dI))).astype(np.int64)

        def sweep(order, cost=cost, pen=pen):
            L = np.zeros((W, D), np.int64)
            prev = None
            for x in order:
                if prev is None:
                    L[x] = cost[x]
                else:
                    p = L[prev]
                    m = p.min()
                    near = np.minimum(np.r_[10**6, p[:-1]], np.r_[p[1:], 10**6]) + P1
                    jump = pen[min(x, prev)]  # the edge between columns prev and x
                    L[x] = cost[x] + np.minimum(np.minimum(p, near), m + jump) - m
                prev = x
            return L

        total = np.minimum(sweep(range(W)) + sweep(range(W - 1, -1, -1)), 255)
        for x in range(W):
            out[y, x // 32, :, x % 32] = np.minimum(out[y, x // 32, :, x % 32] + total[x], 255)
    return out.reshape(-1)


@pytest.mark.parametrize("dmin, D, W", [(0, 32, 40), (-3, 40, 70), (2, 7, 33)])
def test_kernel_matches_a_numpy_reference(dmin, D, W):
    """Costs, both sweeps, the penalty at intensity edges, the 32x32 tile transposes (D a
    multiple of 32 or not, W not a multiple of 32) and the saturation at 255."""
    rng = np.random.default_rng(D + W)
    H = 3
    wp = -(-W // 32) * 32
    cr_pad = max(dmin + D, 0) + 32
    cl = rng.integers(0, 2**31, (H, wp)).astype(np.uint32)
    cr = rng.integers(0, 2**31, (H, cr_pad + wp + max(-dmin, 0) + 32)).astype(np.uint32)
    grey = rng.integers(0, 256, (H, W)).astype(np.uint8)
    s = rng.integers(0, 200, H * D * wp).astype(np.uint8)  # the upward paths' sums already there
    want = _reference(cl, cr, cr_pad, dmin, 10, D, W, grey, 5, 100.0, 0.05, s)
    got = s.copy()
    _run_rows(cl, cr, cr_pad, dmin, 10, D, W, grey, 5, 100.0, 0.05, got, D * wp)
    assert np.array_equal(got.astype(np.int64), want)


def _plain_ground(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plain ground seen from above with a textured facade far beyond it (rows 0-29 at
    2 px). The ground's disparity grows from 4 px by 0.05 px per row and is the same along
    every row; it is one plain grey (the matching costs tie at every disparity) but for
    textured strips along the columns every 50 pixels (kerbs and the feet of walls)."""
    H, W, top = 120, 200, 30
    y = np.arange(H, dtype=np.float32)[:, None]
    d = np.where(y < top, 2.0, 4.0 + 0.05 * (y - top)).astype(np.float32).repeat(W, 1)
    left, right = warp_pair(d, seed=seed)
    # the texture is painted in the right image's coordinates: a strip there is a strip in
    # the left image shifted by the disparity
    rows = np.arange(H)[:, None] < top
    strip_r = rows | ((np.arange(W)[None, :] % 50) < 10)
    strip_l = rows | ((np.floor(np.arange(W)[None, :] - d).astype(int) % 50) < 10)
    out = []
    for im, strip in ((left, strip_l), (right, strip_r)):
        out.append(np.where(strip, im, 128).astype(np.uint8))
    return out[0], out[1], d


@pytest.mark.parametrize("seed", [3, 4])
def test_horizontal_paths_find_a_plain_ground(seed):
    left, right, d = _plain_ground(seed)
    inner = (slice(40, -10), slice(40, -10))  # the ground
    strips = (np.arange(200) % 50) < 16  # near the strips both find it
    err = {}
    for on in (False, True):  # four other paths, as in the stereo mapper
        r = create_matcher("skyrecon", 32, paths=4, horizontal_paths=on).compute(left, right)
        e = np.abs(r.disparity - d)[inner][:, ~strips[inner[1]]]
        err[on] = float(np.nanmedian(e))
    assert err[True] < 0.5 * err[False], err


def test_settings():
    assert not SkyreconSettings().horizontal_paths and not SkyreconSettings(fast=True).horizontal_paths
    with pytest.raises(InputError, match="horizontal"):
        SkyreconSettings(horizontal_paths=True, P1=120, P2=200)
    SkyreconSettings(P1=120, P2=200)  # fine without them


def test_the_stereo_mapper_turns_them_on():
    from skyrecon.perception import PerceptionSettings

    assert PerceptionSettings().matcher_kwargs()["horizontal_paths"] is True
    assert "horizontal_paths" not in PerceptionSettings.flight().matcher_kwargs()  # the flight loop: off


def test_random_texture_is_still_matched_alike():
    """On a well-textured pair the horizontal paths change little."""
    H, W = 100, 160
    d = (6.0 + 0.02 * np.arange(W, dtype=np.float32)[None, :]).repeat(H, 0)
    left, right = warp_pair(d, seed=9)
    assert random_texture(4, 4, 0).shape == (4, 4)
    inner = (slice(8, -8), slice(40, -8))
    for on in (False, True):
        r = create_matcher("skyrecon", 32, horizontal_paths=on).compute(left, right)
        assert np.median(np.abs(r.disparity[inner] - d[inner])) < 0.15
