"""Aligning models to each other: similarity from matched camera centres, ICP with or without scale.

The algorithms behind ``skyrecon align``. Frames: every transform returned is a
:class:`~skyrecon.sfm.align.Sim3` ``target_from_source`` (``p_target = s R p_source + t``); points
are (N, 3) float64 in their frame's units (metres once georeferenced).
"""

from __future__ import annotations

import numpy as np

from skyrecon.errors import EstimationError, InputError

__all__ = [
    "scene_extent",
    "check_spread",
    "fit_camera_centres",
    "point_spacing",
    "icp_plane_with_scale",
    "icp_refine",
    "subsample_cloud",
    "centroid_init",
]


def scene_extent(points: np.ndarray) -> float:
    """Largest distance of the points from their centroid x 2 (a robust, cheap scene size)."""
    if len(points) == 0:
        return 0.0
    c = points.mean(axis=0)
    return 2.0 * float(np.max(np.linalg.norm(points - c, axis=1)))


def check_spread(points: np.ndarray, what: str, names: list[str]) -> None:
    c = points - points.mean(axis=0)
    S = np.linalg.svd(c, compute_uv=False)
    listed = ", ".join(names[:4]) + (" ..." if len(names) > 4 else "")
    if S[0] <= 1e-9 * max(1.0, float(np.abs(points).max())):
        raise InputError(f"the {what} of {listed} all coincide: no alignment can be fitted")
    if S[1] < 1e-2 * S[0]:
        raise InputError(
            f"the {what} of the {len(points)} matched images ({listed}) lie on a line: the rotation about it is "
            "undetermined; use images off that line (e.g. of another flight leg)"
        )


def fit_camera_centres(
    src: np.ndarray,
    dst: np.ndarray,
    names: list[str],
    with_scale: bool,
    threshold: float | None,
    seed: int,
    what: str,
):
    """Robust similarity from matched camera centres; returns (fit, threshold used)."""
    from skyrecon.sfm.align import robust_umeyama, umeyama

    check_spread(dst, what, names)
    check_spread(src, "model's camera centres", names)
    if len(src) == 3:
        return umeyama(src, dst, with_scale), None
    thr = threshold if threshold is not None else 0.05 * scene_extent(dst)
    try:
        fit = robust_umeyama(src, dst, thr, with_scale, seed)
    except EstimationError as exc:
        raise EstimationError(
            f"{exc}: the {what} do not fit one similarity; check the names and units, or give a "
            "larger --max-distance"
        ) from None
    return fit, thr


def point_spacing(points: np.ndarray, tree, seed: int) -> float:
    """Median distance of a point to its nearest neighbour (a sample of up to 5000 points)."""
    rng = np.random.default_rng(seed)
    sub = points if len(points) <= 5000 else points[rng.choice(len(points), 5000, replace=False)]
    d, _ = tree.query(sub, k=2)
    v = d[:, 1]
    v = v[np.isfinite(v) & (v > 0)]
    return float(np.median(v)) if len(v) else 0.0


def icp_plane_with_scale(
    src: np.ndarray,
    T,
    points: np.ndarray,
    normals: np.ndarray,
    tree,
    max_distance: float,
    max_iterations: int,
    size: float,
    tolerance: float = 1e-7,
) -> tuple:
    """Point-to-plane ICP for a similarity (7 unknowns), robust (Huber weights, MAD scale).

    The library's point-to-plane ICP is rigid, and point-to-point ICP with scale is biased by how
    the target is sampled; this solves the linearised ``n . (s dR (p - c) + c + t - q) = 0`` for
    rotation, translation and scale about the matched points' centroid ``c`` at every iteration.
    Returns ``(target_from_source, iterations, converged, rmse, fitness, correspondences)``.
    """
    from skyrecon.core.rigid import orthonormalize, rotvec_to_matrix
    from skyrecon.sfm.align import Sim3

    converged, it, rmse, fitness, n_corr = False, 0, float("nan"), 0.0, 0
    for it in range(1, max_iterations + 1):  # noqa: B007  (the count is returned)
        p = T.apply(src)
        d, j = tree.query(p, k=1, distance_upper_bound=max_distance)
        ok = np.isfinite(d)
        n_corr = int(ok.sum())
        fitness = n_corr / max(len(src), 1)
        if n_corr < 7:
            raise EstimationError(
                f"ICP: only {n_corr} model points lie within {max_distance:.3g} m of the "
                "reference; give a better --init or a larger --max-distance"
            )
        p, q, n = p[ok], points[j[ok]], normals[j[ok]]
        c = p.mean(axis=0)
        pc = p - c
        r = np.sum((p - q) * n, axis=1)
        sigma = 1.4826 * float(np.median(np.abs(r))) + 1e-12
        u = np.abs(r) / sigma
        w = np.where(u <= 1.345, 1.0, 1.345 / np.maximum(u, 1e-12))
        A = np.concatenate([np.cross(pc, n), n, np.sum(n * pc, axis=1, keepdims=True)], axis=1)
        H = (A * w[:, None]).T @ A
        g = (A * w[:, None]).T @ r
        try:
            x = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(7), g)
        except np.linalg.LinAlgError:
            raise EstimationError(
                "ICP: the point-to-plane system is singular (the points lie on one plane "
                "or line); use --no-scale or another reference"
            ) from None
        s = 1.0 + float(x[6])
        if not s > 0:
            raise EstimationError("ICP: the scale update became non-positive; give a better --init")
        dR = rotvec_to_matrix(x[:3])
        step = Sim3(dR, c + x[3:6] - s * dR @ c, s)
        T = step @ T
        T = Sim3(orthonormalize(T.R), T.t, T.scale)
        rmse = float(np.sqrt(np.sum(w * r * r) / max(float(w.sum()), 1e-300)))
        if float(np.max(np.linalg.norm(step.apply(p) - p, axis=1))) < tolerance * size:
            converged = True
            break
    return T, it, converged, rmse, fitness, n_corr


def icp_refine(
    src: np.ndarray, target, T0, with_scale: bool, max_distance: float | None, max_iterations: int, seed: int
) -> tuple:
    """ICP from ``T0`` (target_from_source), in a frame centred on the target.

    A coarse stage (point-to-point with scale, or point-to-plane without) at a generous distance,
    then a fine point-to-plane stage (with scale: :func:`icp_plane_with_scale`) at a tight one.
    Returns ``(target_from_source Sim3, stats)``."""
    from scipy.spatial import cKDTree

    from skyrecon.core.depth import PointCloud
    from skyrecon.sfm.align import Sim3, estimate_normals, icp

    tgt = np.asarray(target.points, np.float64)
    shift = tgt.mean(axis=0)
    local_pts = tgt - shift
    tree = cKDTree(local_pts)
    normals = (
        np.asarray(target.normals, np.float64)
        if target.normals is not None
        else estimate_normals(local_pts, 12, tree)
    )
    local = PointCloud(local_pts, None, normals)
    T = Sim3(T0.R, T0.t - shift, T0.scale)
    spacing = point_spacing(local_pts, tree, seed)
    size = scene_extent(tgt)
    d1 = max_distance if max_distance is not None else max(0.1 * size, 10 * spacing)
    if len(src) > 50_000:  # enough for 7 unknowns; keeps every iteration fast
        src = src[np.sort(np.random.default_rng(seed).choice(len(src), 50_000, replace=False))]

    def stage(kind: str, d: float, r, iterations: int, converged: bool) -> dict:
        return {
            "kind": kind,
            "max_distance_m": d,
            "iterations": iterations,
            "converged": converged,
            "rmse_m": r.rmse,
            "fitness": r.fitness,
            "num_correspondences": r.num_correspondences,
        }

    first = icp(
        src,
        local,
        init=T,
        point_to_plane=not with_scale,
        with_scale=with_scale,
        robust=True,
        max_distance=d1,
        max_iterations=max_iterations,
        seed=seed,
    )
    stages = [
        stage(
            "point-to-point with scale" if with_scale else "point-to-plane",
            d1,
            first,
            first.iterations,
            bool(first.converged),
        )
    ]
    d2 = max_distance if max_distance is not None else max(3.0 * first.rmse, 3.0 * spacing, 1e-9 * size)
    T = first.transform
    if not with_scale:
        last = icp(
            src,
            local,
            init=T,
            point_to_plane=True,
            robust=True,
            max_distance=d2,
            max_iterations=max_iterations,
            seed=seed,
        )
        stages.append(stage("point-to-plane", d2, last, last.iterations, bool(last.converged)))
        T, converged = last.transform, bool(last.converged)
    else:
        T, iterations, converged, rmse, fitness, n_corr = icp_plane_with_scale(
            src, T, local_pts, normals, tree, d2, max_iterations, size
        )
        stages.append(
            {
                "kind": "point-to-plane with scale",
                "max_distance_m": d2,
                "iterations": iterations,
                "converged": converged,
                "rmse_m": rmse,
                "fitness": fitness,
                "num_correspondences": n_corr,
            }
        )
    world = Sim3(T.R, T.t + shift, T.scale)
    p = T.apply(src)
    dist, j = tree.query(p, k=1)
    inl = dist <= d2
    plane = np.abs(np.sum((p - local_pts[j]) * normals[j], axis=1))
    stats = {
        "converged": converged,
        "stages": stages,
        "max_distance_m": d2,
        "fitness": float(inl.mean()) if len(inl) else 0.0,
        "num_correspondences": int(inl.sum()),
        "point_to_plane_rms_m": float(np.sqrt(np.mean(plane[inl] ** 2))) if inl.any() else float("nan"),
        "point_to_plane_median_m": float(np.median(plane[inl])) if inl.any() else float("nan"),
        "nearest_point_median_m": float(np.median(dist[inl])) if inl.any() else float("nan"),
        "target_spacing_m": spacing,
    }
    return world, stats


def subsample_cloud(cloud, n_max: int, seed: int):
    if len(cloud) <= n_max:
        return cloud
    idx = np.sort(np.random.default_rng(seed).choice(len(cloud), n_max, replace=False))
    return cloud.select(idx)


def centroid_init(src: np.ndarray, tgt: np.ndarray, with_scale: bool):
    from skyrecon.sfm.align import Sim3

    ms, mt = np.median(src, axis=0), np.median(tgt, axis=0)
    ss = float(np.median(np.linalg.norm(src - ms, axis=1)))
    st = float(np.median(np.linalg.norm(tgt - mt, axis=1)))
    s = st / ss if with_scale and ss > 0 and st > 0 else 1.0
    return Sim3(np.eye(3), mt - s * ms, s)
