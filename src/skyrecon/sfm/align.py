"""Aligning reconstructions: similarity transforms (Umeyama), robust alignment to known camera
positions (GPS, ground truth), and ICP between point clouds (point-to-point or point-to-plane,
robust Huber/Tukey weights, k-d tree correspondences).

A :class:`Sim3` maps points of a source frame to a destination frame:
``p_dst = scale * R @ p_src + t`` (named ``dst_from_src`` like a :class:`~skyrecon.core.Rigid3`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from skyrecon.core.depth import PointCloud
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import Rigid3, orthonormalize, rotvec_to_matrix
from skyrecon.errors import EstimationError, InputError

__all__ = [
    "Sim3",
    "AlignmentResult",
    "umeyama",
    "robust_umeyama",
    "align_reconstruction",
    "ICPResult",
    "icp",
    "estimate_normals",
]


@dataclass(frozen=True)
class Sim3:
    """A similarity ``dst_from_src``: ``p_dst = scale * R @ p_src + t``.

    Attributes:
        R: (3, 3) rotation; t: (3,) translation (destination units); scale: > 0.
    """

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.asarray(self.R, np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, np.float64).reshape(3))
        object.__setattr__(self, "scale", float(self.scale))
        if not (self.scale > 0 and math.isfinite(self.scale)):
            raise InputError(f"a similarity needs a positive scale, got {self.scale}")

    @classmethod
    def from_rigid(cls, T: Rigid3) -> Sim3:
        return cls(T.R, T.t, 1.0)

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix ``[[s R, t], [0, 1]]``."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.R
        M[:3, 3] = self.t
        return M

    @property
    def rigid(self) -> Rigid3:
        """The rotation and translation as a Rigid3 (ignores the scale)."""
        return Rigid3(self.R, self.t)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 3) (or (3,)) source points to the destination frame (float64)."""
        p = np.asarray(points, np.float64)
        return self.scale * p @ self.R.T + self.t

    def to_json_dict(self) -> dict:
        """``scale``, ``R`` (3x3 rows), ``t`` and the 4x4 ``matrix`` as plain lists and floats."""
        return {
            "scale": self.scale,
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "matrix": self.matrix.tolist(),
        }

    def inverse(self) -> Sim3:
        """``src_from_dst``."""
        Ri = self.R.T
        return Sim3(Ri, -(Ri @ self.t) / self.scale, 1.0 / self.scale)

    def __matmul__(self, other: Sim3) -> Sim3:
        """``c_from_b @ b_from_a -> c_from_a``."""
        return Sim3(self.R @ other.R, self.scale * self.R @ other.t + self.t, self.scale * other.scale)

    def transform_pose(self, cam_from_src: Rigid3) -> Rigid3:
        """``cam_from_world`` in the source world -> ``cam_from_world`` in the destination world
        (camera-frame lengths are rescaled to destination units)."""
        Rc = cam_from_src.R @ self.R.T
        return Rigid3(Rc, self.scale * cam_from_src.t - Rc @ self.t, "cam", "world")

    def transform_reconstruction(self, rec: Reconstruction) -> Reconstruction:
        """A copy of ``rec`` with poses and points in the destination frame (intrinsics,
        keypoints and tracks unchanged)."""
        images = {
            k: Image(
                im.image_id,
                im.name,
                im.camera_id,
                self.transform_pose(im.cam_from_world),
                im.keypoints.copy(),
                im.point3d_ids.copy(),
            )
            for k, im in rec.images.items()
        }
        points = {
            k: Point3D(p.point3d_id, self.apply(p.xyz), p.color.copy(), p.error, p.track.copy())
            for k, p in rec.points3d.items()
        }
        return Reconstruction(dict(rec.cameras), images, points)


@dataclass
class AlignmentResult:
    """A fitted similarity and how well it fits.

    Attributes:
        transform: ``dst_from_src``.
        residuals: (N,) distances ``|T(src_i) - dst_i|`` in destination units.
        inliers: (N,) bool (all True for the plain fit).
        rms: root mean square of the inlier residuals.
    """

    transform: Sim3
    residuals: np.ndarray
    inliers: np.ndarray
    rms: float

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _check_pairs(src: np.ndarray, dst: np.ndarray, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise InputError(
            f"alignment needs two (N, 3) arrays of the same shape, got {src.shape} and {dst.shape}"
        )
    if len(src) < min_points:
        raise InputError(f"alignment needs at least {min_points} point pairs, got {len(src)}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise InputError("alignment points contain NaN or infinite values")
    return src, dst


def _umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool, w: np.ndarray | None) -> Sim3:
    w = np.ones(len(src)) if w is None else np.asarray(w, np.float64)
    W = w.sum()
    if not W > 0:
        raise EstimationError("alignment weights sum to zero")
    ms = (w @ src) / W
    md = (w @ dst) / W
    a = src - ms
    b = dst - md
    cov = (b * w[:, None]).T @ a / W
    U, S, Vt = np.linalg.svd(cov)
    d = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        d[2] = -1.0
    R = (U * d) @ Vt
    var_s = float(np.sum(w * np.sum(a * a, axis=1)) / W)
    if var_s <= 1e-300:
        raise EstimationError("the source points all coincide: no alignment")
    if S[1] <= 1e-12 * max(S[0], 1e-300):
        raise EstimationError(
            "the points are (nearly) collinear: the rotation about their line is undetermined"
        )
    s = float(np.sum(S * d) / var_s) if with_scale else 1.0
    if not s > 0:
        raise EstimationError("the alignment gives a non-positive scale (the point sets do not correspond)")
    t = md - s * R @ ms
    return Sim3(R, t, s)


def umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = True, weights: np.ndarray | None = None
) -> AlignmentResult:
    """Least-squares similarity (or rigid) transform mapping ``src`` onto ``dst`` (Umeyama 1991).

    Minimises ``sum w_i |dst_i - (s R src_i + t)|^2`` in closed form (SVD of the cross-covariance,
    with the reflection correction).

    Args:
        src: (N, 3) points in the source frame (e.g. reconstructed camera centres).
        dst: (N, 3) corresponding points in the destination frame (e.g. GPS / ground truth).
        with_scale: estimate the scale (similarity); else rigid (scale 1).
        weights: optional (N,) non-negative weights.
    Returns:
        AlignmentResult with ``transform = dst_from_src``.
    Raises:
        InputError: fewer than 3 pairs, mismatched shapes, NaN.
        EstimationError: degenerate configurations (coincident or collinear points).
    """
    src, dst = _check_pairs(src, dst, 3)
    T = _umeyama(src, dst, with_scale, weights)
    res = np.linalg.norm(T.apply(src) - dst, axis=1)
    return AlignmentResult(T, res, np.ones(len(src), bool), float(np.sqrt(np.mean(res**2))))


def robust_umeyama(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float,
    with_scale: bool = True,
    seed: int | np.random.Generator = 0,
    max_iterations: int = 1000,
) -> AlignmentResult:
    """Similarity from correspondences with outliers (e.g. GPS glitches): RANSAC over minimal
    3-point samples, then a least-squares refit on the inliers (repeated until stable).

    Args:
        src, dst: (N, 3) corresponding points.
        threshold: inlier distance in destination units.
        with_scale: estimate the scale.
        seed: seed or Generator of the sampling.
        max_iterations: samples drawn.
    Raises:
        EstimationError: fewer than 3 consistent correspondences.
    """
    src, dst = _check_pairs(src, dst, 3)
    if not threshold > 0:
        raise InputError(f"threshold must be positive, got {threshold}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    n = len(src)
    best = np.zeros(n, bool)
    best_cost = np.inf
    for _ in range(max_iterations if n > 3 else 1):
        idx = rng.choice(n, 3, replace=False)
        try:
            T = _umeyama(src[idx], dst[idx], with_scale, None)
        except EstimationError:
            continue
        r = np.linalg.norm(T.apply(src) - dst, axis=1)
        cost = float(np.minimum(r, threshold).sum())
        if cost < best_cost:
            best_cost, best = cost, r < threshold
    if best.sum() < 3:
        raise EstimationError(
            f"fewer than 3 of {n} correspondences agree on one alignment within {threshold:g}"
        )
    inl = best
    for _ in range(10):
        T = _umeyama(src[inl], dst[inl], with_scale, None)
        r = np.linalg.norm(T.apply(src) - dst, axis=1)
        new = r < threshold
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    return AlignmentResult(T, r, inl, float(np.sqrt(np.mean(r[inl] ** 2))))


def align_reconstruction(
    rec: Reconstruction,
    positions: dict[str, np.ndarray],
    with_scale: bool = True,
    robust_threshold: float | None = None,
    seed: int = 0,
) -> tuple[Reconstruction, AlignmentResult]:
    """Move a reconstruction into a frame where some camera centres are known.

    Args:
        rec: the reconstruction (its own gauge).
        positions: image name -> (3,) known camera centre in the destination frame (metres).
        with_scale: estimate the scale (SfM has no metric scale by itself).
        robust_threshold: when given, RANSAC with this inlier distance (destination units).
        seed: RANSAC seed.
    Returns:
        ``(aligned copy, fit)``; the fit's residuals follow the order of the matched images.
    Raises:
        InputError: fewer than 3 registered images with known positions.
    """
    names = [
        im.name for im in sorted(rec.images.values(), key=lambda im: im.image_id) if im.name in positions
    ]
    if len(names) < 3:
        raise InputError(
            f"only {len(names)} registered images have known positions; at least 3 are needed to align"
        )
    src = np.stack([rec.image_by_name(n).center_world for n in names])
    dst = np.stack([np.asarray(positions[n], np.float64).reshape(3) for n in names])
    fit = (
        umeyama(src, dst, with_scale)
        if robust_threshold is None
        else robust_umeyama(src, dst, robust_threshold, with_scale, seed)
    )
    return fit.transform.transform_reconstruction(rec), fit


# ----------------------------------------------------------------------------------------------
# ICP
# ----------------------------------------------------------------------------------------------
@dataclass
class ICPResult:
    """The outcome of ICP.

    Attributes:
        transform: ``target_from_source`` (scale 1 unless ``with_scale``).
        rmse: root mean square distance of the inlier correspondences (point-to-plane distance
            for ``point_to_plane``), target units.
        fitness: share of source points with a correspondence within ``max_distance``.
        num_correspondences: inlier correspondences of the last iteration.
        iterations: iterations run.
        converged: the update fell below the tolerance before ``max_iterations``.
        history: rmse after each iteration.
    """

    transform: Sim3
    rmse: float
    fitness: float
    num_correspondences: int
    iterations: int
    converged: bool
    history: list[float] = field(default_factory=list)


def estimate_normals(points: np.ndarray, k: int = 12, tree: cKDTree | None = None) -> np.ndarray:
    """(N, 3) unit normals from the PCA of each point's ``k`` nearest neighbours (N, 3) points.
    The sign is arbitrary (irrelevant for point-to-plane distances)."""
    pts = np.asarray(points, np.float64)
    k = int(min(max(3, k), len(pts)))
    tree = tree or cKDTree(pts)
    _, idx = tree.query(pts, k=k)
    nb = pts[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def _robust_weights(r: np.ndarray, kind: str) -> np.ndarray:
    """IRLS weights of residuals r with a MAD-based scale (Huber k = 1.345, Tukey c = 4.685)."""
    if kind == "none" or len(r) == 0:
        return np.ones(len(r))
    sigma = 1.4826 * float(np.median(np.abs(r))) + 1e-12
    u = np.abs(r) / sigma
    if kind == "huber":
        k = 1.345
        return np.where(u <= k, 1.0, k / np.maximum(u, 1e-12))
    c = 4.685
    return np.where(u < c, (1.0 - (u / c) ** 2) ** 2, 0.0)


def icp(
    source: PointCloud | np.ndarray,
    target: PointCloud | np.ndarray,
    init: Sim3 | Rigid3 | None = None,
    point_to_plane: bool = True,
    robust: bool = True,
    loss: Literal["huber", "tukey"] = "huber",
    max_distance: float | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-7,
    with_scale: bool = False,
    normal_neighbors: int = 12,
    max_points: int | None = 50000,
    seed: int = 0,
) -> ICPResult:
    """Iterative closest point: the transform that moves ``source`` onto ``target``.

    Each iteration matches every (sampled) source point to its nearest target point (k-d tree),
    drops pairs farther than ``max_distance``, and solves for the update: point-to-plane
    (linearised, 6 unknowns, distances along the target normals) or point-to-point (Umeyama,
    optionally with scale), weighted by Huber or Tukey IRLS weights with a MAD scale.

    Args:
        source, target: point clouds (or (N, 3) arrays) in their own frames, same units.
        init: initial ``target_from_source``.
        point_to_plane: use the target normals (estimated by PCA when the cloud has none).
        robust: IRLS weights (``loss``); else plain least squares.
        loss: ``"huber"`` or ``"tukey"``.
        max_distance: correspondences farther apart are ignored (default: no limit beyond the
            robust weights).
        max_iterations, tolerance: stop when the update moves points by less than
            ``tolerance`` times the cloud's size.
        with_scale: estimate a scale too (point-to-point only).
        normal_neighbors: neighbours of the normal estimation.
        max_points: source points used per iteration (a seeded random subset beyond that).
        seed: seed of the subsampling.
    Returns:
        ICPResult (``transform = target_from_source``).
    Raises:
        InputError: empty clouds, scale with point-to-plane.
        EstimationError: no correspondences within ``max_distance``.
    """
    src = np.asarray(source.points if isinstance(source, PointCloud) else source, np.float64).reshape(-1, 3)
    tgt = np.asarray(target.points if isinstance(target, PointCloud) else target, np.float64).reshape(-1, 3)
    if len(src) < 3 or len(tgt) < 3:
        raise InputError(f"ICP needs at least 3 points in each cloud, got {len(src)} and {len(tgt)}")
    if with_scale and point_to_plane:
        raise InputError("ICP with scale is only supported point-to-point (point_to_plane=False)")
    if loss not in ("huber", "tukey"):
        raise InputError(f"unknown ICP loss {loss!r}; use huber or tukey")
    rng = np.random.default_rng(seed)
    if max_points and len(src) > max_points:
        src = src[np.sort(rng.choice(len(src), max_points, replace=False))]
    tree = cKDTree(tgt)
    normals = None
    if point_to_plane:
        tn = target.normals if isinstance(target, PointCloud) else None
        normals = (
            np.asarray(tn, np.float64) if tn is not None else estimate_normals(tgt, normal_neighbors, tree)
        )
    T = Sim3() if init is None else (Sim3.from_rigid(init) if isinstance(init, Rigid3) else init)
    size = float(np.linalg.norm(np.ptp(tgt, axis=0))) or 1.0
    kind = loss if robust else "none"
    history: list[float] = []
    converged = False
    it = 0
    n_corr = 0
    fitness = 0.0
    rmse = float("nan")
    for it in range(1, max_iterations + 1):  # noqa: B007  (the count is returned)
        p = T.apply(src)
        d, j = tree.query(p, k=1, distance_upper_bound=np.inf if max_distance is None else max_distance)
        ok = np.isfinite(d)
        if max_distance is not None:
            ok &= d <= max_distance
        n_corr = int(ok.sum())
        fitness = n_corr / len(src)
        if n_corr < 6:
            raise EstimationError(
                f"ICP: only {n_corr} source points have a target point within {max_distance}; "
                "give a better initial alignment or a larger max_distance"
            )
        ps, q = p[ok], tgt[j[ok]]
        if point_to_plane:
            assert normals is not None
            n = normals[j[ok]]
            r = np.sum((ps - q) * n, axis=1)
            w = _robust_weights(r, kind)
            A = np.concatenate([np.cross(ps, n), n], axis=1)
            H = (A * w[:, None]).T @ A
            g = (A * w[:, None]).T @ r
            try:
                x = -np.linalg.solve(H + 1e-12 * np.eye(6) * np.trace(H), g)
            except np.linalg.LinAlgError:
                raise EstimationError(
                    "ICP: the point-to-plane system is singular (a plane or a line)"
                ) from None
            dR = rotvec_to_matrix(x[:3])
            step = Sim3(dR, x[3:], 1.0)
        else:
            r = np.linalg.norm(ps - q, axis=1)
            w = _robust_weights(r, kind)
            step = _umeyama(ps, q, with_scale, w)
        T = step @ T
        T = Sim3(orthonormalize(T.R), T.t, T.scale)
        rmse = float(np.sqrt(np.sum(w * r * r) / max(w.sum(), 1e-300)))
        history.append(rmse)
        move = float(np.max(np.linalg.norm(step.apply(ps) - ps, axis=1)))
        if move < tolerance * size:
            converged = True
            break
    return ICPResult(T, rmse, fitness, n_corr, it, converged, history)
