"""Brute-force numpy references for the simulator's ground-truth queries (every obstacle, no grid)."""

from __future__ import annotations

import numpy as np


def sdf_brute(city, p: np.ndarray, include_ground: bool) -> np.ndarray:
    """(N,) signed distance from (N, 3) points to the union of boxes and cylinders (and ground)."""
    out = np.full(len(p), np.inf)
    if include_ground:
        out = p[:, 2].copy()
    for b in city.boxes:
        q = np.maximum(b[:3] - p, p - b[3:])
        d = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
        out = np.minimum(out, d)
    for c in city.cylinders:
        qr = np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) - c[2]
        qz = np.maximum(c[3] - p[:, 2], p[:, 2] - c[4])
        d = np.hypot(np.maximum(qr, 0), np.maximum(qz, 0)) + np.minimum(np.maximum(qr, qz), 0)
        out = np.minimum(out, d)
    return out


def raycast_brute(city, o: np.ndarray, d: np.ndarray, include_ground: bool = True) -> np.ndarray:
    """(N,) distance along unit rays (N, 3) from origins (N, 3) to the first surface entered; inf for none."""
    best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        if include_ground:
            tg = -o[:, 2] / d[:, 2]
            ok = (d[:, 2] < 0) & (o[:, 2] >= 0)
            best = np.where(ok, tg, best)
        inv = 1.0 / np.where(np.abs(d) < 1e-30, 1e-30, d)
        for b in city.boxes:
            t1 = (b[:3] - o) * inv
            t2 = (b[3:] - o) * inv
            tn = np.minimum(t1, t2).max(axis=1)
            tf = np.maximum(t1, t2).min(axis=1)
            hit = (tn <= tf) & (tn >= 0)
            best = np.where(hit & (tn < best), tn, best)
        for c in city.cylinders:
            px, py = o[:, 0] - c[0], o[:, 1] - c[1]
            a = d[:, 0] ** 2 + d[:, 1] ** 2
            bb = px * d[:, 0] + py * d[:, 1]
            cc = px**2 + py**2 - c[2] ** 2
            disc = bb * bb - a * cc
            t = (-bb - np.sqrt(np.maximum(disc, 0))) / a
            z = o[:, 2] + t * d[:, 2]
            side = (disc >= 0) & (a > 0) & (t >= 0) & (z >= c[3]) & (z <= c[4])
            best = np.where(side & (t < best), t, best)
            for zc, sgn in ((c[4], -1), (c[3], 1)):
                t = (zc - o[:, 2]) / d[:, 2]
                hx, hy = px + t * d[:, 0], py + t * d[:, 1]
                cap = (np.sign(d[:, 2]) == sgn) & (t >= 0) & (hx**2 + hy**2 <= c[2] ** 2)
                best = np.where(cap & (t < best), t, best)
    return best
