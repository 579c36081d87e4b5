"""The two-arbitrary-views pipeline: features -> matches -> relative pose -> sparse and dense model.

result = reconstruct_two_view(img1, img2, K1, K2, TwoViewSettings(), seed=0)
result.R, result.t            # cam2_from_cam1, |t| = 1 (None when not recoverable)
result.warnings               # why a pose is missing or doubtful
result.sparse, result.dense   # coloured clouds in camera 1's frame
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError, InputError
from skyrecon.features.detect import Features, detect_features
from skyrecon.features.match import match_features
from skyrecon.geometry.triangulation import TriangulationFilter, filter_points, triangulate
from skyrecon.twoview.dense import dense_model
from skyrecon.twoview.estimate import estimate_two_view_geometry
from skyrecon.twoview.result import DenseResult, TwoViewGeometry, TwoViewResult
from skyrecon.twoview.settings import TwoViewSettings

__all__ = ["reconstruct_two_view", "detect_pair", "sparse_cloud"]


def _check_image(image: np.ndarray, intr: Intrinsics, what: str) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise InputError(f"{what} must be an (H, W) or (H, W, 3) array, got shape {img.shape}")
    if img.size == 0:
        raise InputError(f"{what} is empty")
    if not isinstance(intr, Intrinsics):
        raise InputError(f"the intrinsics of {what} must be an Intrinsics, got {type(intr).__name__}")
    intr.check_image(img, what)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    return img


def detect_pair(
    image1: np.ndarray, image2: np.ndarray, settings: TwoViewSettings
) -> tuple[Features, Features]:
    """Features of both images (two threads when ``settings.parallel_features``)."""
    if settings.parallel_features:
        # one OpenCV thread per detection: the two detections already use both cores
        n = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            with ThreadPoolExecutor(2) as ex:
                f1, f2 = ex.map(lambda im: detect_features(im, settings.features), (image1, image2))
        finally:
            cv2.setNumThreads(n)
        return f1, f2
    return detect_features(image1, settings.features), detect_features(image2, settings.features)


def _colors_at(image: np.ndarray, x: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    ij = np.clip(np.round(x).astype(np.int64), 0, [w - 1, h - 1])
    c = image[ij[:, 1], ij[:, 0]]
    if c.ndim == 1:
        c = np.repeat(c[:, None], 3, axis=1)
    if c.dtype != np.uint8:
        c = np.clip(c.astype(np.float64) / (257.0 if c.dtype == np.uint16 else 1.0), 0, 255)
    return c[:, :3]


def sparse_cloud(
    image1: np.ndarray,
    geo: TwoViewGeometry,
    x1: np.ndarray,
    x2: np.ndarray,
    intr1: Intrinsics,
    intr2: Intrinsics,
    settings: TwoViewSettings,
    working_scale: float,
) -> tuple[PointCloud, np.ndarray]:
    """Triangulate the pose inliers and keep the trustworthy ones.

    Returns:
        ``(cloud, index)``: points in camera 1's frame (baseline units or metres) coloured from
        image 1, and the (K,) rows of the match arrays they came from.
    """
    if not geo.has_pose:
        return PointCloud(np.zeros((0, 3), np.float32)), np.zeros(0, np.int64)
    assert geo.R is not None and geo.t is not None
    s = 1.0 if settings.baseline_m is None else settings.baseline_m
    idx = np.nonzero(geo.inliers)[0]
    t = geo.t * s
    X = triangulate(geo.R, t, intr1.normalized(x1[idx]), intr2.normalized(x2[idx]), settings.triangulation)  # type: ignore[arg-type]
    flt = TriangulationFilter(settings.max_reprojection_px / working_scale, settings.min_parallax_deg)
    # reprojection is checked on undistorted pixels: x = K * normalized(x)
    u1 = intr1.normalized(x1[idx]) * [intr1.fx, intr1.fy] + [intr1.cx, intr1.cy]
    u2 = intr2.normalized(x2[idx]) * [intr2.fx, intr2.fy] + [intr2.cx, intr2.cy]
    ok = filter_points(X, geo.R, t, intr1.K, intr2.K, u1, u2, flt)
    return PointCloud(X[ok].astype(np.float32), _colors_at(image1, x1[idx[ok]])), idx[ok]


def reconstruct_two_view(
    image1: np.ndarray,
    image2: np.ndarray,
    intrinsics1: Intrinsics,
    intrinsics2: Intrinsics,
    settings: TwoViewSettings | None = None,
    seed: int | np.random.Generator | None = 0,
) -> TwoViewResult:
    """Relative pose, sparse and dense model of two photos with known intrinsics.

    Args:
        image1, image2: (H, W, 3) uint8 RGB (or (H, W) grey) images; sizes must match the
            intrinsics.
        intrinsics1, intrinsics2: full-resolution cameras (distortion is handled).
        settings: pipeline settings (default :class:`TwoViewSettings`).
        seed: seed or Generator for every random choice (deterministic for a given seed).
    Returns:
        TwoViewResult. Degenerate pairs do not raise: they return a status other than ``"ok"``
        and say why in ``warnings`` (identical images / pure rotation: R without t; unrelated
        images: no pose; wrong K: pose flagged ``"uncertain"``).
    Raises:
        InputError: bad images or intrinsics.
        EstimationError: fewer than 8 feature matches.
    """
    settings = settings or TwoViewSettings()
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    img1 = _check_image(image1, intrinsics1, "image 1")
    img2 = _check_image(image2, intrinsics2, "image 2")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)

    t0 = time.perf_counter()
    f1, f2 = detect_pair(img1, img2, settings)
    timings["features"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    m = match_features(f1, f2, settings.matching)
    timings["matching"] = time.perf_counter() - t0
    matches = m.pairs
    x1 = f1.keypoints[m.idx1]
    x2 = f2.keypoints[m.idx2]
    if len(matches) < 8:
        raise EstimationError(
            f"only {len(matches)} feature matches between the two images ({len(f1)} and {len(f2)} "
            "keypoints; at least 8 matches are needed): the images may not overlap or have too little texture"
        )
    ws = float(np.sqrt(f1.scale * f2.scale))

    t0 = time.perf_counter()
    geo = estimate_two_view_geometry(
        x1, x2, intrinsics1, intrinsics2, settings, rng, ws, f1.scales[m.idx1], f2.scales[m.idx2]
    )
    timings["geometry"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sparse, sparse_idx = sparse_cloud(img1, geo, x1, x2, intrinsics1, intrinsics2, settings, ws)
    timings["sparse"] = time.perf_counter() - t0

    dense: DenseResult | None = None
    if settings.dense and geo.has_pose:
        t0 = time.perf_counter()
        try:
            dense = dense_model(
                img1, img2, intrinsics1, intrinsics2, geo, x1[geo.inliers], x2[geo.inliers], settings
            )
            geo.warnings.extend(dense.warnings)
        except EstimationError as exc:
            geo.warnings.append(f"no dense model: {exc}")
        timings["dense"] = time.perf_counter() - t0
    elif settings.dense:
        geo.warnings.append("no dense model: the relative pose (with translation) is unknown")
    timings["total"] = time.perf_counter() - t_start
    return TwoViewResult(
        geo,
        intrinsics1,
        intrinsics2,
        f1.keypoints,
        f2.keypoints,
        matches,
        sparse,
        sparse_idx,
        dense,
        timings,
        settings.baseline_m,
    )
