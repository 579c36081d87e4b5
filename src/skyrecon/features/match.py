"""Descriptor matching with Lowe's ratio test and a mutual (cross) check.

Float descriptors (SIFT/RootSIFT, unit L2 norm) are matched exactly by blocked matrix products
(BLAS) and a Numba pass that keeps the best two neighbours of every row *and* column, so the
ratio test in both directions and the mutual check cost one product. Binary descriptors use
OpenCV's Hamming brute force; ``"flann"`` uses OpenCV's approximate KD-trees for float ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numba
import numpy as np

from skyrecon.errors import InputError
from skyrecon.features.detect import Features

__all__ = ["MatchSettings", "Matches", "match_descriptors", "match_features"]

Matcher = Literal["bruteforce", "flann"]


@dataclass(frozen=True)
class MatchSettings:
    """How to match descriptors.

    Attributes:
        ratio: Lowe's ratio: keep a match when best distance < ratio x second-best distance.
        mutual: keep only mutual nearest neighbours.
        ratio_both_ways: also apply the ratio test from image 2 to image 1.
        matcher: ``"bruteforce"`` (exact; default) or ``"flann"`` (approximate, float only).
        max_distance: optional absolute cap on the descriptor distance (L2 for float, Hamming
            bits for binary).
    """

    ratio: float = 0.8
    mutual: bool = True
    ratio_both_ways: bool = False
    matcher: Matcher = "bruteforce"
    max_distance: float | None = None

    def __post_init__(self) -> None:
        if not (0.0 < self.ratio <= 1.0):
            raise InputError(f"the ratio test threshold must be in (0, 1], got {self.ratio}")
        if self.matcher not in ("bruteforce", "flann"):
            raise InputError(f"unknown matcher {self.matcher!r}; use bruteforce or flann")


@dataclass
class Matches:
    """Putative matches between two feature sets.

    Attributes:
        idx1, idx2: (M,) int64 indices into the first and second feature sets.
        distances: (M,) float32 descriptor distances.
        ratios: (M,) float32 best / second-best distance (1 when there was no second).
    """

    idx1: np.ndarray
    idx2: np.ndarray
    distances: np.ndarray
    ratios: np.ndarray

    def __len__(self) -> int:
        return len(self.idx1)

    @property
    def pairs(self) -> np.ndarray:
        """(M, 2) int64 ``[idx1, idx2]``."""
        return np.stack([self.idx1, self.idx2], axis=1)

    def select(self, mask: np.ndarray) -> Matches:
        return Matches(self.idx1[mask], self.idx2[mask], self.distances[mask], self.ratios[mask])


@numba.njit(cache=True)
def _top2(
    S: np.ndarray,
    r0: int,
    rb: np.ndarray,
    rs: np.ndarray,
    ra: np.ndarray,
    cb: np.ndarray,
    cs: np.ndarray,
    ca: np.ndarray,
) -> None:
    """Update best/second similarities of rows r0.. and of every column with the block S."""
    b, n2 = S.shape
    for i in range(b):
        best = -np.inf
        second = -np.inf
        arg = -1
        for j in range(n2):
            s = S[i, j]
            if s > best:
                second = best
                best = s
                arg = j
            elif s > second:
                second = s
            if s > cb[j]:
                cs[j] = cb[j]
                cb[j] = s
                ca[j] = r0 + i
            elif s > cs[j]:
                cs[j] = s
        rb[r0 + i] = best
        rs[r0 + i] = second
        ra[r0 + i] = arg


@numba.njit(cache=True, fastmath=True)
def _row_top2(S: np.ndarray, r0: int, rb: np.ndarray, rs: np.ndarray, ra: np.ndarray) -> None:
    """Best and second-best similarity (and best column) of each row of the block S."""
    b, n2 = S.shape
    for i in range(b):
        best = -np.inf
        second = -np.inf
        arg = -1
        row = S[i]
        for j in range(n2):
            s = row[j]
            if s > second:
                if s > best:
                    second = best
                    best = s
                    arg = j
                else:
                    second = s
        rb[r0 + i] = best
        rs[r0 + i] = second
        ra[r0 + i] = arg


@numba.njit(cache=True, fastmath=True)
def _col_max(S: np.ndarray, cb: np.ndarray) -> None:
    """Running maximum of every column over the rows of the block S."""
    b, n2 = S.shape
    for i in range(b):
        row = S[i]
        for j in range(n2):
            if row[j] > cb[j]:
                cb[j] = row[j]


def _float_mutual_fast(d1: np.ndarray, d2: np.ndarray, block: int = 1024):
    """Row best/second distances and best index, plus a mutual-nearest flag per row (exact)."""
    n1, n2 = len(d1), len(d2)
    rb = np.full(n1, -np.inf, np.float32)
    rs = np.full(n1, -np.inf, np.float32)
    ra = np.full(n1, -1, np.int64)
    cb = np.full(n2, -np.inf, np.float32)
    d2t = np.ascontiguousarray(d2.T)
    for r0 in range(0, n1, block):
        S = d1[r0 : r0 + block] @ d2t
        _row_top2(S, r0, rb, rs, ra)
        _col_max(S, cb)
    mutual = np.zeros(n1, dtype=bool)
    ok = ra >= 0
    mutual[ok] = rb[ok] >= cb[ra[ok]]
    return _dist_from_sim(rb), _dist_from_sim(rs), ra, mutual


def _dist_from_sim(s: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(2.0 - 2.0 * s, 0.0))


def _float_bruteforce(d1: np.ndarray, d2: np.ndarray, block: int = 2048):
    n1, n2 = len(d1), len(d2)
    rb = np.full(n1, -np.inf, np.float32)
    rs = np.full(n1, -np.inf, np.float32)
    ra = np.full(n1, -1, np.int64)
    cb = np.full(n2, -np.inf, np.float32)
    cs = np.full(n2, -np.inf, np.float32)
    ca = np.full(n2, -1, np.int64)
    d2t = np.ascontiguousarray(d2.T)
    for r0 in range(0, n1, block):
        S = d1[r0 : r0 + block] @ d2t
        _top2(S, r0, rb, rs, ra, cb, cs, ca)
    return _dist_from_sim(rb), _dist_from_sim(rs), ra, _dist_from_sim(cb), _dist_from_sim(cs), ca


def _knn_cv(matcher, q: np.ndarray, t: np.ndarray):
    """Best / second distance and best index of each query row via an OpenCV matcher."""
    n = len(q)
    best = np.full(n, np.inf, np.float32)
    second = np.full(n, np.inf, np.float32)
    arg = np.full(n, -1, np.int64)
    for m in matcher.knnMatch(q, t, k=2):
        if not m:
            continue
        i = m[0].queryIdx
        best[i], arg[i] = m[0].distance, m[0].trainIdx
        if len(m) > 1:
            second[i] = m[1].distance
    return best, second, arg


def match_descriptors(d1: np.ndarray, d2: np.ndarray, settings: MatchSettings = MatchSettings()) -> Matches:
    """Match two descriptor sets.

    Args:
        d1: (N1, D) descriptors of image 1 (float32 unit-norm or uint8 binary).
        d2: (N2, D) descriptors of image 2, same kind.
        settings: ratio, mutual check, matcher.
    Returns:
        Matches sorted by idx1.
    Raises:
        InputError: descriptor kinds or lengths differ.
    """
    d1 = np.asarray(d1)
    d2 = np.asarray(d2)
    if d1.ndim != 2 or d2.ndim != 2 or d1.shape[1] != d2.shape[1] or d1.dtype != d2.dtype:
        raise InputError(f"descriptors do not match: {d1.shape} {d1.dtype} vs {d2.shape} {d2.dtype}")
    empty = Matches(
        np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32)
    )
    if len(d1) == 0 or len(d2) == 0:
        return empty
    binary = d1.dtype == np.uint8
    if binary:
        bf = cv2.BFMatcher(cv2.NORM_HAMMING)
        b1, s1, a1 = _knn_cv(bf, d1, d2)
        b2, s2, a2 = _knn_cv(bf, d2, d1)
    elif settings.matcher == "flann":
        fl = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
        f1 = np.ascontiguousarray(d1, np.float32)
        f2 = np.ascontiguousarray(d2, np.float32)
        b1, s1, a1 = _knn_cv(fl, f1, f2)
        b2, s2, a2 = _knn_cv(fl, f2, f1)
    elif settings.mutual and not settings.ratio_both_ways:
        b1, s1, a1, is_mutual = _float_mutual_fast(
            np.ascontiguousarray(d1, np.float32), np.ascontiguousarray(d2, np.float32)
        )
        a2 = None
    else:
        b1, s1, a1, b2, s2, a2 = _float_bruteforce(
            np.ascontiguousarray(d1, np.float32), np.ascontiguousarray(d2, np.float32)
        )
    i1 = np.nonzero(a1 >= 0)[0]
    j = a1[i1]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(s1[i1]) & (s1[i1] > 0), b1[i1] / s1[i1], 1.0)
    keep = ratio < settings.ratio
    # a single candidate (no second neighbour) passes the ratio test
    keep |= ~np.isfinite(s1[i1])
    if settings.mutual:
        keep &= is_mutual[i1] if a2 is None else a2[j] == i1
    if settings.ratio_both_ways:
        with np.errstate(divide="ignore", invalid="ignore"):
            r2 = np.where(np.isfinite(s2[j]) & (s2[j] > 0), b2[j] / s2[j], 0.0)
        keep &= r2 < settings.ratio
    if settings.max_distance is not None:
        keep &= b1[i1] <= settings.max_distance
    i1, j, ratio = i1[keep], j[keep], ratio[keep]
    if not settings.mutual or a2 is None:
        # several image-1 features may claim the same image-2 feature: keep the closest
        order = np.lexsort((b1[i1], j))
        first = np.ones(len(order), dtype=bool)
        first[1:] = j[order][1:] != j[order][:-1]
        sel = np.sort(order[first])
        i1, j, ratio = i1[sel], j[sel], ratio[sel]
    return Matches(
        i1.astype(np.int64), j.astype(np.int64), b1[i1].astype(np.float32), ratio.astype(np.float32)
    )


def match_features(f1: Features, f2: Features, settings: MatchSettings = MatchSettings()) -> Matches:
    """Match the descriptors of two :class:`Features` (see :func:`match_descriptors`)."""
    if f1.binary != f2.binary:
        raise InputError("cannot match binary descriptors against float descriptors")
    return match_descriptors(f1.descriptors, f2.descriptors, settings)
