"""Multi-view triangulation of feature tracks with outlier rejection and acceptance checks.

Each track is triangulated from its observations in posed images: linear DLT on all
observations, Gauss-Newton refinement of the reprojection error, then iterative removal of
observations with a large reprojection error or negative depth. When the all-observation
estimate is not consistent, every pair of observations (up to a limit) is tried as a hypothesis
and the best-supported one is refined (a deterministic RANSAC over pairs). A point is accepted
with at least two consistent observations whose largest triangulation angle reaches the minimum.

Inputs are undistorted normalised coordinates (z = 1 plane) and ``cam_from_world`` poses; errors
are converted to pixels with each image's focal length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = ["TriangulationResult", "triangulate_tracks", "max_triangulation_angles_deg"]


@dataclass
class TriangulationResult:
    """Triangulated tracks.

    Attributes:
        points: (n_tracks, 3) float64 world points (NaN where not accepted).
        ok: (n_tracks,) bool: accepted.
        inliers: (n_obs,) bool per input observation: consistent with the accepted point.
        errors_px: (n_obs,) reprojection error of every observation, pixels (inf behind a camera
            or without a point).
        angles_deg: (n_tracks,) largest triangulation angle among the inlier observations (for a
            track the O(L) cone bounds decide, a bound on the same side of ``min_angle_deg``).
    """

    points: np.ndarray
    ok: np.ndarray
    inliers: np.ndarray
    errors_px: np.ndarray
    angles_deg: np.ndarray


@nb.njit(cache=True)
def _dlt(
    idx: np.ndarray, m: int, xn: np.ndarray, img: np.ndarray, R: np.ndarray, t: np.ndarray
) -> np.ndarray:
    A = np.zeros((4, 4))
    row = np.empty(4)
    for k in range(m):
        o = idx[k]
        i = img[o]
        for r in range(2):
            c = xn[o, r]
            for j in range(3):
                row[j] = c * R[i, 2, j] - R[i, r, j]
            row[3] = c * t[i, 2] - t[i, r]
            nrm = np.sqrt(row[0] ** 2 + row[1] ** 2 + row[2] ** 2 + row[3] ** 2)
            if nrm == 0.0:
                continue
            for a in range(4):
                for b in range(4):
                    A[a, b] += row[a] * row[b] / (nrm * nrm)
    _, vecs = np.linalg.eigh(A)
    v = vecs[:, 0]
    out = np.full(3, np.nan)
    if abs(v[3]) > 1e-12 * (abs(v[0]) + abs(v[1]) + abs(v[2])):
        out[0] = v[0] / v[3]
        out[1] = v[1] / v[3]
        out[2] = v[2] / v[3]
    return out


@nb.njit(cache=True)
def _refine(
    X: np.ndarray,
    idx: np.ndarray,
    m: int,
    xn: np.ndarray,
    img: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    iterations: int,
) -> np.ndarray:
    """Gauss-Newton on the normalised reprojection error (damped slightly)."""
    X = X.copy()
    for _ in range(iterations):
        H = np.zeros((3, 3))
        g = np.zeros(3)
        for k in range(m):
            o = idx[k]
            i = img[o]
            P = R[i] @ X + t[i]
            if P[2] <= 0:
                continue
            iz = 1.0 / P[2]
            ex = P[0] * iz - xn[o, 0]
            ey = P[1] * iz - xn[o, 1]
            j0 = (R[i, 0] - P[0] * iz * R[i, 2]) * iz
            j1 = (R[i, 1] - P[1] * iz * R[i, 2]) * iz
            for a in range(3):
                g[a] += j0[a] * ex + j1[a] * ey
                for b in range(3):
                    H[a, b] += j0[a] * j0[b] + j1[a] * j1[b]
        for a in range(3):
            H[a, a] *= 1.0 + 1e-6
            H[a, a] += 1e-15
        d = np.linalg.solve(H, g)
        X = X - d
        if np.sqrt(d @ d) < 1e-12 * (np.sqrt(X @ X) + 1e-12):
            break
    return X


@nb.njit(cache=True)
def _errors(
    X: np.ndarray,
    start: int,
    stop: int,
    xn: np.ndarray,
    img: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    focal: np.ndarray,
    err: np.ndarray,
) -> None:
    for o in range(start, stop):
        i = img[o]
        P = R[i] @ X + t[i]
        if not P[2] > 0 or not np.isfinite(P[2]):
            err[o] = np.inf
        else:
            err[o] = np.hypot(P[0] / P[2] - xn[o, 0], P[1] / P[2] - xn[o, 1]) * focal[i]


@nb.njit(cache=True)
def _max_angle(
    X: np.ndarray, start: int, stop: int, inl: np.ndarray, img: np.ndarray, C: np.ndarray, enough_deg: float
) -> float:
    """Largest angle between the rays from the camera centres of the inlier observations to
    ``X``, degrees, as far as a comparison with ``enough_deg`` needs it: the exact maximum
    (``enough_deg`` infinite, or when the bounds below cannot decide), else a bound on the same
    side of ``enough_deg`` as the maximum. The bounds cost O(L) instead of the O(L^2) pair
    search, which matters for long tracks (a flight's far facades are seen by 100+ frames):
    every ray lies within angle ``a`` of the rays' mean direction, so no pair is more than
    ``2a`` apart; and the ray furthest from the mean is as far from some other ray as the
    largest angle it makes with them."""
    n = 0
    for o in range(start, stop):
        if inl[o]:
            n += 1
    if n < 2:
        return 0.0
    U = np.empty((n, 3))
    m = np.zeros(3)
    j = 0
    for o in range(start, stop):
        if not inl[o]:
            continue
        d = X - C[img[o]]
        nd = np.sqrt(d @ d) + 1e-300
        for c in range(3):
            U[j, c] = d[c] / nd
            m[c] += U[j, c]
        j += 1
    if enough_deg < 180.0:
        nm = np.sqrt(m @ m)
        if nm > 1e-9 * n:
            m /= nm
            c_far = 1.0
            j_far = 0
            for j in range(n):
                c = U[j, 0] * m[0] + U[j, 1] * m[1] + U[j, 2] * m[2]
                if c < c_far:
                    c_far = c
                    j_far = j
            upper = 2.0 * np.degrees(np.arccos(min(1.0, max(-1.0, c_far))))
            if upper < enough_deg:
                return upper
            c_low = 1.0
            for j in range(n):
                c = U[j, 0] * U[j_far, 0] + U[j, 1] * U[j_far, 1] + U[j, 2] * U[j_far, 2]
                if c < c_low:
                    c_low = c
            lower = np.degrees(np.arccos(min(1.0, max(-1.0, c_low))))
            if lower >= enough_deg:
                return lower
    best = 1.0  # the smallest cosine seen
    for a in range(n):
        for b in range(a + 1, n):
            c = U[a, 0] * U[b, 0] + U[a, 1] * U[b, 1] + U[a, 2] * U[b, 2]
            if c < best:
                best = c
    return np.degrees(np.arccos(min(1.0, max(-1.0, best))))


@nb.njit(cache=True)
def _triangulate_all(  # noqa: C901  (Numba kernel: one flat loop nest)
    ptr, xn, img, R, t, focal, C, max_err, min_angle_deg, max_pairs, X_out, ok, inl, err, ang
):
    n_tracks = ptr.shape[0] - 1
    for k in range(n_tracks):
        start = ptr[k]
        stop = ptr[k + 1]
        L = stop - start
        ok[k] = False
        ang[k] = 0.0
        for o in range(start, stop):
            inl[o] = False
            err[o] = np.inf
        X_out[k, 0] = np.nan
        X_out[k, 1] = np.nan
        X_out[k, 2] = np.nan
        if L < 2:
            continue
        idx = np.arange(start, stop)
        X = _dlt(idx, L, xn, img, R, t)
        best_X = X
        best_n = 0
        if np.isfinite(X[0]):
            X = _refine(X, idx, L, xn, img, R, t, 3)
            _errors(X, start, stop, xn, img, R, t, focal, err)
            n_in = 0
            for o in range(start, stop):
                if err[o] < max_err:
                    n_in += 1
            best_X = X
            best_n = n_in
        if best_n < L:
            # hypotheses from pairs of observations
            tried = 0
            pair = np.empty(2, np.int64)
            for a in range(start, stop):
                for b in range(a + 1, stop):
                    if tried >= max_pairs:
                        break
                    tried += 1
                    pair[0] = a
                    pair[1] = b
                    Xh = _dlt(pair, 2, xn, img, R, t)
                    if not np.isfinite(Xh[0]):
                        continue
                    _errors(Xh, start, stop, xn, img, R, t, focal, err)
                    n_in = 0
                    for o in range(start, stop):
                        if err[o] < max_err:
                            n_in += 1
                    if n_in > best_n:
                        best_n = n_in
                        best_X = Xh
                if tried >= max_pairs:
                    break
        if best_n < 2 or not np.isfinite(best_X[0]):
            continue
        X = best_X
        # refine on inliers, re-select, repeat
        sel = np.empty(L, np.int64)
        for _ in range(3):
            _errors(X, start, stop, xn, img, R, t, focal, err)
            m = 0
            for o in range(start, stop):
                if err[o] < max_err:
                    sel[m] = o
                    m += 1
            if m < 2:
                break
            Xn = _dlt(sel, m, xn, img, R, t)
            if not np.isfinite(Xn[0]):
                Xn = X
            Xn = _refine(Xn, sel, m, xn, img, R, t, 5)
            X = Xn
        _errors(X, start, stop, xn, img, R, t, focal, err)
        m = 0
        for o in range(start, stop):
            inl[o] = err[o] < max_err
            if inl[o]:
                m += 1
        if m < 2:
            for o in range(start, stop):
                inl[o] = False
            continue
        a_deg = _max_angle(X, start, stop, inl, img, C, min_angle_deg)
        ang[k] = a_deg
        if a_deg < min_angle_deg:
            for o in range(start, stop):
                inl[o] = False
            continue
        ok[k] = True
        X_out[k, 0] = X[0]
        X_out[k, 1] = X[1]
        X_out[k, 2] = X[2]


def triangulate_tracks(
    ptr: np.ndarray,
    xn: np.ndarray,
    obs_image: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    focal_px: np.ndarray,
    max_error_px: float = 4.0,
    min_angle_deg: float = 1.5,
    max_pair_hypotheses: int = 32,
) -> TriangulationResult:
    """Triangulate tracks given as CSR observation lists.

    Args:
        ptr: (n_tracks + 1,) int64 offsets: the observations of track k are ``ptr[k]:ptr[k+1]``.
        xn: (n_obs, 2) float64 undistorted normalised coordinates of each observation.
        obs_image: (n_obs,) int64 index into ``R``/``t``/``focal_px`` of each observation's image.
        R, t: (n_images, 3, 3), (n_images, 3) ``cam_from_world`` poses.
        focal_px: (n_images,) focal length used to express errors in pixels.
        max_error_px: largest reprojection error of an inlier observation, pixels.
        min_angle_deg: smallest acceptable largest triangulation angle, degrees.
        max_pair_hypotheses: pairs of observations tried when the all-observation fit is not
            fully consistent.
    Returns:
        TriangulationResult.
    """
    ptr = np.ascontiguousarray(ptr, np.int64)
    xn = np.ascontiguousarray(xn, np.float64).reshape(-1, 2)
    img = np.ascontiguousarray(obs_image, np.int64)
    R = np.ascontiguousarray(R, np.float64).reshape(-1, 3, 3)
    t = np.ascontiguousarray(t, np.float64).reshape(-1, 3)
    focal = np.ascontiguousarray(focal_px, np.float64).reshape(-1)
    C = -np.einsum("kji,kj->ki", R, t)
    n_tracks = len(ptr) - 1
    X = np.empty((n_tracks, 3))
    ok = np.zeros(n_tracks, bool)
    inl = np.zeros(len(xn), bool)
    err = np.full(len(xn), np.inf)
    ang = np.zeros(n_tracks)
    if n_tracks:
        _triangulate_all(
            ptr,
            xn,
            img,
            R,
            t,
            focal,
            C,
            float(max_error_px),
            float(min_angle_deg),
            int(max_pair_hypotheses),
            X,
            ok,
            inl,
            err,
            ang,
        )
    return TriangulationResult(X, ok, inl, err, ang)


@nb.njit(cache=True)
def _angles(ptr, X, img, C, active, enough_deg, out):
    for k in range(ptr.shape[0] - 1):
        out[k] = _max_angle(X[k], ptr[k], ptr[k + 1], active, img, C, enough_deg)


def max_triangulation_angles_deg(
    ptr: np.ndarray,
    points: np.ndarray,
    obs_image: np.ndarray,
    centers: np.ndarray,
    active: np.ndarray,
    enough_deg: float = np.inf,
) -> np.ndarray:
    """(n_tracks,) largest angle in degrees between the rays from the camera centres of the active
    observations of each track to its point.

    Args:
        ptr: (n_tracks + 1,) CSR offsets; points: (n_tracks, 3) world points;
        obs_image: (n_obs,) image index per observation; centers: (n_images, 3) camera centres;
        active: (n_obs,) bool.
        enough_deg: the threshold the angles will be compared with: an angle may then be a bound
            on the same side of it as the exact one (much faster on long tracks); infinite
            (default): exact angles.
    """
    out = np.zeros(len(ptr) - 1)
    if len(out):
        _angles(
            np.ascontiguousarray(ptr, np.int64),
            np.ascontiguousarray(points, np.float64),
            np.ascontiguousarray(obs_image, np.int64),
            np.ascontiguousarray(centers, np.float64),
            np.ascontiguousarray(active, np.bool_),
            float(enough_deg),
            out,
        )
    return out
