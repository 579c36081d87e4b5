"""Keep-out volumes for moving obstacles: capsules the planner must avoid for one query.

A mover tracked by the drone (another drone, a crane boom) is not part of the static map: its
hits are kept out of the occupancy map so that it leaves no phantom trail. The planner still
has to keep clear of where it is going, so each mover becomes a *capsule*: the segment from its
position now to its predicted position ``horizon_s`` later, inflated by its size (and the track's
uncertainty). For one planning query the capsules are written into the planner's dense grid
(:meth:`~skyrecon.planning.grid.PlanningGrid` distances are lowered to the capsules' surface
distance where that is smaller) and restored afterwards, so the distance field of the static map
is never touched.

Capsules: (K, 7) float64 ``[x0, y0, z0, x1, y1, z1, radius_m]``, world frame, metres. A negative
radius keeps the planner that much less than its clearance from the segment (space nobody has
seen, :mod:`skyrecon.mission.unseen`, needs less room than a thing known to be there); it must
not take away more than the clearance.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from numba import njit

from skyrecon.errors import InputError


def as_capsules(capsules: np.ndarray | None) -> np.ndarray:
    """(K, 7) float64 capsules (see the module docstring); None or empty gives (0, 7)."""
    if capsules is None:
        return np.zeros((0, 7))
    c = np.asarray(capsules, dtype=np.float64).reshape(-1, 7) if np.size(capsules) else np.zeros((0, 7))
    if not np.all(np.isfinite(c)):
        raise InputError("keep-out capsules must be finite")
    return c


def capsule_distance(points: np.ndarray, capsules: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest capsule surface (negative inside), metres.

    Args:
        points: (N, 3) world points, metres.
        capsules: (K, 7) ``[x0, y0, z0, x1, y1, z1, radius]``.
    Returns:
        (N,) float64; ``inf`` when there are no capsules.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    c = as_capsules(capsules)
    out = np.full(len(p), np.inf)
    for a, b, r in zip(c[:, :3], c[:, 3:6], c[:, 6]):
        ab = b - a
        L2 = float(ab @ ab)
        t = np.zeros(len(p)) if L2 < 1e-12 else np.clip((p - a) @ ab / L2, 0.0, 1.0)
        e = p - (a + t[:, None] * ab)
        d = np.sqrt(np.einsum("ij,ij->i", e, e)) - r
        np.minimum(out, d, out=out)
    return out


def path_conflict(path: np.ndarray, capsules: np.ndarray, threshold_m: float, step_m: float) -> float:
    """Arc length along ``path`` (K, 3) of the first sample closer than ``threshold_m`` to a
    capsule, metres; ``inf`` when the whole path keeps clear (samples every ``step_m``)."""
    c = as_capsules(capsules)
    if len(c) == 0 or len(path) < 2:
        return float("inf")
    seg = np.diff(path, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.arange(0.0, cum[-1] + 1e-9, step_m)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    u = np.where(seg_len[k] > 0, (s - cum[k]) / np.maximum(seg_len[k], 1e-12), 0.0)
    pts = path[k] + u[:, None] * seg[k]
    bad = np.flatnonzero(capsule_distance(pts, c) < threshold_m)
    return float(s[bad[0]]) if len(bad) else float("inf")


def _capsule_region(grid, cap: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Voxel box ``[lo, hi)`` of ``grid`` a capsule (7,) can lower (None if it misses the grid)."""
    v = grid.voxel
    pad = max(cap[6] + grid.threshold, 0.0) + 2 * v
    lo_w = np.minimum(cap[:3], cap[3:6]) - pad
    hi_w = np.maximum(cap[:3], cap[3:6]) + pad
    lo_w[2] = max(lo_w[2], grid.zmin - 2 * v)  # below or above the band nothing is flyable anyway
    hi_w[2] = min(hi_w[2], grid.zmax + 2 * v)
    shape = np.array(grid.shape)
    lo = np.clip(np.floor((lo_w - grid.origin) / v).astype(np.int64), 0, shape)
    hi = np.clip(np.ceil((hi_w - grid.origin) / v).astype(np.int64) + 1, 0, shape)
    return (lo, hi) if np.all(hi > lo) else None


@njit(cache=True)
def _stamp(dist, flyable, lo, hi, origin, voxel, cap, threshold, zmin, zmax):
    """Lower ``dist`` (NX, NY, NZ) float32 to the capsule's (7,) surface distance over the voxel
    box ``[lo, hi)`` and recompute ``flyable`` there; returns how many voxels were lowered."""
    ax, ay, az = cap[0], cap[1], cap[2]
    bx, by, bz = cap[3] - ax, cap[4] - ay, cap[5] - az
    L2 = bx * bx + by * by + bz * bz
    lowered = 0
    for i in range(lo[0], hi[0]):
        x = origin[0] + (i + 0.5) * voxel - ax
        for j in range(lo[1], hi[1]):
            y = origin[1] + (j + 0.5) * voxel - ay
            for k in range(lo[2], hi[2]):
                zw = origin[2] + (k + 0.5) * voxel
                z = zw - az
                t = 0.0
                if L2 >= 1e-12:
                    t = min(max((x * bx + y * by + z * bz) / L2, 0.0), 1.0)
                ex, ey, ez = x - t * bx, y - t * by, z - t * bz
                d = np.float32(np.sqrt(ex * ex + ey * ey + ez * ez) - cap[6])
                if d < dist[i, j, k]:
                    dist[i, j, k] = d
                    lowered += 1
                ok = dist[i, j, k] >= threshold and zw >= zmin and zw <= zmax
                flyable[i, j, k] = 1 if ok else 0
    return lowered


def warm_kernels() -> None:
    """Compile (or load) the stamping kernel on a tiny grid (``skyrecon warmup``)."""
    dist = np.full((3, 3, 3), 5.0, np.float32)
    fly = np.ones((3, 3, 3), np.uint8)
    lo = np.zeros(3, np.int64)
    hi = np.full(3, 3, np.int64)
    _stamp(dist, fly, lo, hi, np.zeros(3), 1.0, np.array([1.5, 1.5, 1.5, 1.5, 1.5, 2.5, 0.5]), 1.0, 0.0, 3.0)


@contextmanager
def keep_out(grid, capsules: np.ndarray | None) -> Iterator[int]:
    """Within the ``with`` block, ``grid`` (a :class:`~skyrecon.planning.grid.PlanningGrid`)
    treats the capsules as obstacles; everything is restored on exit.

    Each capsule touches only the voxels within its radius plus the planner's threshold (and
    inside the altitude band), and the search levels only over that box, so the cost grows
    with the capsules' size, not with the grid's.

    Yields:
        The number of grid voxels whose distance was lowered.
    """
    c = as_capsules(capsules)
    regions = [(cap, r) for cap in c if (r := _capsule_region(grid, cap)) is not None]
    if not regions:
        yield 0
        return
    saved: list[tuple[tuple, np.ndarray, np.ndarray]] = []
    saved_safe: list[list[tuple]] = []
    lowered = 0
    try:
        for cap, (lo, hi) in regions:
            box = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))
            saved.append((box, grid.dist[box].copy(), grid.flyable[box].copy()))
            args = (grid.origin, grid.voxel, cap, grid.threshold, grid.zmin, grid.zmax)
            lowered += int(_stamp(grid.dist, grid.flyable, lo, hi, *args))
            saved_safe.append(grid.recompute_safe(lo, hi, save=True))
        yield lowered
    finally:
        for old in reversed(saved_safe):
            grid.restore(old)
        for box, dist, fly in reversed(saved):
            grid.dist[box], grid.flyable[box] = dist, fly
