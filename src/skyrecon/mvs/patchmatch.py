"""PatchMatch multi-view stereo for one reference view and several source views.

Slanted-plane hypotheses (depth + normal per pixel), random initialisation, red-black
checkerboard propagation with near and far neighbours, random refinement, and a robust
multi-view cost: bilateral-weighted NCC against every source, averaging the ``topk`` best
(occlusion-robust). The Numba kernels are in :mod:`skyrecon.mvs._pm_kernels`.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from skyrecon.errors import InputError
from skyrecon.mvs import _pm_kernels as K
from skyrecon.mvs.frames import WorkingView

__all__ = ["PatchMatchSettings", "PatchMatchResult", "patchmatch_depth", "texture_mask", "brightness_gain"]


@dataclass(frozen=True)
class PatchMatchSettings:
    """Settings of the PatchMatch depth estimation.

    Attributes:
        iterations: red-black sweeps at the working resolution (each updates both colours).
        levels: image pyramid levels (1: working resolution only; 2: half size first).
        coarse_iterations: sweeps at each coarser level.
        min_level_size: no coarser level is made whose shorter side would be below this.
        max_hole_fraction: unmatched areas (flat, e.g. the inside of uniform tiles) that are
            enclosed by matched pixels and cover at most this fraction of the image take the
            coarser level's planes.
        window_radius: half size of the matching window, pixels (working resolution).
        window_step: spacing of the window samples, pixels (2 samples every other pixel).
        sigma_color: bilateral colour sigma, grey levels (0..255; Gaussian weight).
        sigma_space: bilateral spatial sigma, pixels.
        topk: number of best source views averaged into the cost (occlusion robustness).
        max_cost: pixels whose final cost (1 - NCC, averaged over the ``topk`` best views)
            exceeds this are left without depth.
        min_texture_std: pixels whose window standard deviation is below this (grey levels)
            are not estimated (no reliable match in flat regions). This and
            ``min_weighted_std`` are divided by :func:`brightness_gain` for dark images.
        min_weighted_std: pixels whose window, weighted by the bilateral weights, has a smaller
            standard deviation (grey levels) are not estimated: this drops flat pixels next
            to strong edges (dark background beside a bright object), whose plain window looks
            textured only because of the edge.
        depth_perturbation: refinement perturbation of inverse depth, fraction of the
            inverse-depth range (halved every iteration).
        normal_perturbation: refinement perturbation of the normal, about radians (halved every
            iteration).
        far_neighbors: largest distance (pixels, odd) of the far propagation candidates.
        candidates: how many propagation candidates are evaluated per pixel and sweep: the
            lowest-cost ones among the 4 direct neighbours and the best far pixel of each
            direction (at most 8).
        refinements: random refinement trials per pixel and sweep, cycling through a random
            depth, a random normal and a joint perturbation (0..3).
        max_incidence_deg: largest angle between a hypothesis normal and the direction to the
            camera.
        min_source_var: smallest grey-level variance of a source window to be matched.
        missing_view_penalty: sources whose image does not contain the projected window are
            left out of the ``topk`` mean; each missing one adds this to the cost (a surface
            seen by one source only can still be estimated if it matches well).
        threads: threads per view (rows split between them); 1 when views run in parallel
            processes.
    """

    iterations: int = 3
    levels: int = 3
    coarse_iterations: int = 4
    min_level_size: int = 96
    max_hole_fraction: float = 0.01
    window_radius: int = 4
    window_step: int = 2
    sigma_color: float = 12.0
    sigma_space: float = 3.0
    topk: int = 2
    max_cost: float = 0.45
    min_texture_std: float = 1.5
    min_weighted_std: float = 4.0
    depth_perturbation: float = 0.02
    normal_perturbation: float = 0.3
    far_neighbors: int = 9
    candidates: int = 4
    refinements: int = 2
    max_incidence_deg: float = 80.0
    min_source_var: float = 0.5
    missing_view_penalty: float = 0.15
    threads: int = 1

    def __post_init__(self) -> None:
        if self.levels < 1 or self.coarse_iterations < 1:
            raise InputError(
                f"levels and coarse_iterations must be >= 1, got {self.levels}, {self.coarse_iterations}"
            )
        if self.iterations < 1:
            raise InputError(f"patchmatch iterations must be >= 1, got {self.iterations}")
        if self.window_radius < 1 or self.window_step < 1 or self.window_step > self.window_radius:
            raise InputError(
                f"need window_radius >= window_step >= 1, got radius {self.window_radius}, step {self.window_step}"
            )
        if self.topk < 1:
            raise InputError(f"topk must be >= 1, got {self.topk}")
        if not (0 < self.max_cost <= 2):
            raise InputError(f"max_cost must be in (0, 2], got {self.max_cost}")
        if self.far_neighbors < 1 or self.far_neighbors % 2 == 0:
            raise InputError(f"far_neighbors must be a positive odd number, got {self.far_neighbors}")
        if not (0 < self.max_incidence_deg < 90):
            raise InputError(f"max_incidence_deg must be in (0, 90), got {self.max_incidence_deg}")
        if not 1 <= self.candidates <= 8:
            raise InputError(f"candidates must be in 1..8, got {self.candidates}")
        if not 0 <= self.refinements <= 3:
            raise InputError(f"refinements must be in 0..3, got {self.refinements}")
        if self.threads < 1:
            raise InputError(f"threads must be >= 1, got {self.threads}")


@dataclass
class PatchMatchResult:
    """Depth of one reference view.

    Attributes:
        depth: (H, W) float32 metres along the reference optical axis, NaN where no estimate.
        normal: (H, W, 3) float32 unit normals in the reference camera frame, NaN where none.
        cost: (H, W) float32 final aggregated cost (1 - NCC of the ``topk`` best sources), 2
            where not estimated.
        timings_ms: per stage.
    """

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)


def _offsets(radius: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(-radius, radius + 1, step)
    if r[-1] != radius:  # keep the window symmetric
        r = np.unique(np.concatenate([r, -r]))
    dv, du = np.meshgrid(r, r, indexing="ij")
    return du.ravel().astype(np.float64), dv.ravel().astype(np.float64)


def texture_mask(grey: np.ndarray, valid: np.ndarray, radius: int, min_std: float) -> np.ndarray:
    """(H, W) bool: pixels whose (2r+1)^2 window is inside the image, has data, and has texture.

    Args:
        grey: (H, W) float32 grey levels.
        valid: (H, W) bool image-data mask (alpha).
        radius: window half size, pixels.
        min_std: smallest window standard deviation, grey levels.
    """
    H, W = grey.shape
    k = 2 * radius + 1
    g = grey.astype(np.float32)
    m = cv2.boxFilter(g, cv2.CV_32F, (k, k), borderType=cv2.BORDER_REFLECT)
    m2 = cv2.boxFilter(g * g, cv2.CV_32F, (k, k), borderType=cv2.BORDER_REFLECT)
    std = np.sqrt(np.maximum(m2 - m * m, 0.0))
    ok = std >= min_std
    v = (
        cv2.erode(
            valid.astype(np.uint8), np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0
        )
        > 0
    )
    ok &= v
    ok[:radius] = False
    ok[H - radius :] = False
    ok[:, :radius] = False
    ok[:, W - radius :] = False
    return ok


#: Texture thresholds are meant for images whose bright end (99.5th percentile) is at this grey level.
REFERENCE_BRIGHTNESS = 200.0


def brightness_gain(view: WorkingView, max_gain: float = 4.0) -> float:
    """How much darker than :data:`REFERENCE_BRIGHTNESS` the view's bright end is (>= 1).

    The texture thresholds (grey-level standard deviations) are divided by it, so that a dark
    image set (e.g. grey levels 0..100) is not judged textureless.
    """
    g = view.grey[view.valid] if view.valid.any() else view.grey.ravel()
    hi = float(np.percentile(g, 99.5)) if g.size else 0.0
    if hi <= 0:
        return 1.0
    return float(np.clip(REFERENCE_BRIGHTNESS / hi, 1.0, max_gain))


def _source_arrays(ref: WorkingView, sources: list[WorkingView]) -> tuple[np.ndarray, ...]:
    Hs = max(s.shape[0] for s in sources)
    Ws = max(s.shape[1] for s in sources)
    srcs = np.zeros((len(sources), Hs, Ws), np.float32)
    wh = np.zeros((len(sources), 2), np.int64)
    A = np.zeros((len(sources), 3, 3))
    b = np.zeros((len(sources), 3))
    Kr_inv = np.linalg.inv(ref.intrinsics.K)
    world_from_ref = ref.cam_from_world.inverse()
    for k, s in enumerate(sources):
        h, w = s.shape
        g = s.grey.copy()
        g[~s.valid] = 0.0
        srcs[k, :h, :w] = g
        # invalid (alpha 0) source pixels: pretend out of image by shrinking nothing; NCC handles them
        wh[k] = (w, h)
        src_from_ref = s.cam_from_world @ world_from_ref
        Ks = s.intrinsics.K
        A[k] = Ks @ src_from_ref.R @ Kr_inv
        b[k] = Ks @ src_from_ref.t
    return srcs, wh, A, b


def _run_rows(kernel, H: int, threads: int, *args) -> None:
    if threads <= 1 or H < 64:
        kernel(0, H, *args)
        return
    chunks = threads * 4
    bounds = [H * i // chunks for i in range(chunks + 1)]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futs = [pool.submit(kernel, a, bnd, *args) for a, bnd in zip(bounds[:-1], bounds[1:]) if bnd > a]
        for f in futs:
            f.result()


@dataclass
class _Level:
    """Raw state of one level: planes, costs and masks (nothing filtered yet)."""

    depth: np.ndarray  # (H, W) float32 metres, NaN where never estimated
    normal: np.ndarray  # (H, W, 3) float32 reference-camera frame
    cost: np.ndarray  # (H, W) float32
    textured: np.ndarray  # (H, W) bool: passed the plain texture test
    estimated: np.ndarray  # (H, W) bool: estimated (textured and not flat once weighted)


def _downsampled(view: WorkingView) -> WorkingView:
    """The view at half size (grey and alpha only), intrinsics scaled accordingly."""
    intr = view.intrinsics.scaled(0.5)
    size = (intr.width, intr.height)
    grey = cv2.resize(view.grey, size, interpolation=cv2.INTER_AREA)
    valid = cv2.resize(view.valid.astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA) >= 255
    return replace(
        view,
        intrinsics=intr,
        grey=grey,
        valid=valid,
        rgb=np.zeros((0, 0, 3), np.uint8),
        scale=view.scale * 0.5,
    )


def _planes_to(fine: WorkingView, coarse: WorkingView, lvl: _Level) -> tuple[np.ndarray, ...]:
    """Carry the coarse planes to the fine pixels (nearest coarse pixel, plane re-intersected).

    Returns (depth (H, W) float32, normal (H, W, 3) float32, cost (H, W) float32) at the fine size.
    """
    H, W = fine.shape
    Hc, Wc = coarse.shape
    u = np.arange(W, dtype=np.float64)
    v = np.arange(H, dtype=np.float64)
    uc = np.clip(np.rint((u + 0.5) * Wc / W - 0.5), 0, Wc - 1).astype(np.int64)
    vc = np.clip(np.rint((v + 0.5) * Hc / H - 0.5), 0, Hc - 1).astype(np.int64)
    d = lvl.depth[vc[:, None], uc[None, :]].astype(np.float64)
    n = lvl.normal[vc[:, None], uc[None, :]].astype(np.float64)
    kc, kf = coarse.intrinsics, fine.intrinsics
    xc = np.stack(
        np.broadcast_arrays(
            ((uc - kc.cx) / kc.fx)[None, :], ((vc - kc.cy) / kc.fy)[:, None], np.ones((1, 1))
        ),
        axis=-1,
    )
    rf = np.stack(
        np.broadcast_arrays(((u - kf.cx) / kf.fx)[None, :], ((v - kf.cy) / kf.fy)[:, None], np.ones((1, 1))),
        axis=-1,
    )
    h = d * np.sum(n * xc, axis=-1)
    den = np.sum(n * rf, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        df = np.where(den < -1e-6, h / den, d)
    return df.astype(np.float32), n.astype(np.float32), lvl.cost[vc[:, None], uc[None, :]]


def _solve_level(
    ref: WorkingView,
    sources: list[WorkingView],
    near: float,
    far: float,
    s: PatchMatchSettings,
    iterations: int,
    seed: int,
    init: tuple[np.ndarray, np.ndarray] | None,
) -> _Level:
    H, W = ref.shape
    du, dv = _offsets(s.window_radius, s.window_step)
    gain = brightness_gain(ref)
    textured = texture_mask(ref.grey, ref.valid, s.window_radius, s.min_texture_std / gain)
    mask = textured.astype(np.uint8)
    srcs, wh, A, b = _source_arrays(ref, sources)
    intr = np.array([ref.intrinsics.fx, ref.intrinsics.fy, ref.intrinsics.cx, ref.intrinsics.cy])
    params = np.zeros(K.N_PARAMS)
    params[K.P_DMIN] = near
    params[K.P_DMAX] = far
    params[K.P_SIGMA_COLOR] = s.sigma_color
    params[K.P_SIGMA_SPACE] = s.sigma_space
    params[K.P_TOPK] = min(s.topk, len(sources))
    params[K.P_PERTURB] = s.depth_perturbation
    params[K.P_NORMAL_PERTURB] = s.normal_perturbation
    params[K.P_MIN_VAR] = s.min_source_var
    params[K.P_FAR] = s.far_neighbors
    params[K.P_MAX_INCIDENCE] = np.cos(np.radians(s.max_incidence_deg))
    params[K.P_CANDIDATES] = s.candidates
    params[K.P_REFINE] = s.refinements
    params[K.P_MIN_REF_STD] = s.min_weighted_std / gain
    params[K.P_MISSING] = s.missing_view_penalty
    if init is None:
        depth = np.full((H, W), np.nan, np.float32)
        normal = np.zeros((H, W, 3), np.float32)
        normal[..., 2] = -1.0
    else:
        depth = np.array(init[0], np.float32)
        normal = np.array(init[1], np.float32)
        bad = ~np.all(np.isfinite(normal), axis=-1)
        depth[bad] = np.nan
        normal[bad] = (0.0, 0.0, -1.0)
    cost = np.full((H, W), K.BAD_COST, np.float32)
    grey = np.ascontiguousarray(ref.grey, dtype=np.float32)
    seed64 = np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF)
    _run_rows(
        K.pm_init, H, s.threads, seed64, grey, mask, depth, normal, cost, srcs, wh, A, b, intr, du, dv, params
    )
    for it in range(iterations):
        for color in (0, 1):
            # a warm start (from a coarser level) skips the large early perturbations
            step = it + (s.coarse_iterations if init is not None else 0)
            _run_rows(
                K.pm_sweep,
                H,
                s.threads,
                color,
                step,
                seed64,
                grey,
                mask,
                depth,
                normal,
                cost,
                srcs,
                wh,
                A,
                b,
                intr,
                du,
                dv,
                params,
            )
    return _Level(depth, normal, cost, textured, mask.astype(bool))


def _enclosed_holes(holes: np.ndarray, max_fraction: float) -> np.ndarray:
    """(H, W) bool: the pixels of 8-connected components of ``holes`` that do not touch the image
    border and cover at most ``max_fraction`` of the image."""
    H, W = holes.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats(holes.astype(np.uint8), connectivity=8)
    x, y, w, h, area = stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3], stats[:, 4]
    ok = (area <= max_fraction * H * W) & (x > 0) & (y > 0) & (x + w < W) & (y + h < H)
    ok[0] = False  # background label (not a hole)
    return ok[labels]


def _solve(
    ref: WorkingView,
    sources: list[WorkingView],
    near: float,
    far: float,
    s: PatchMatchSettings,
    seed: int,
    levels: int,
    iterations: int,
) -> _Level:
    """Coarse to fine: the half-size solution initialises this level and fills its small flat holes."""
    H, W = ref.shape
    if levels <= 1 or min(H, W) < 2 * s.min_level_size:
        return _solve_level(ref, sources, near, far, s, iterations, seed, None)
    cref = _downsampled(ref)
    coarse = _solve(
        cref, [_downsampled(v) for v in sources], near, far, s, seed + 7919, levels - 1, s.coarse_iterations
    )
    d0, n0, c0 = _planes_to(ref, cref, coarse)
    lvl = _solve_level(ref, sources, near, far, s, iterations, seed, (d0, n0))
    # flat here but matched at the coarser level (e.g. the inside of uniform tiles): keep the
    # coarse plane; not where the window is textured only because of an edge (halo)
    # only small holes enclosed by matched pixels: a hole that reaches the image border or is
    # large (dark background around an object, where coarse windows fatten the silhouette) is
    # left empty
    fill = _enclosed_holes(ref.valid & ~(lvl.estimated & (lvl.cost <= s.max_cost)), s.max_hole_fraction)
    fill &= (c0 <= s.max_cost) & np.isfinite(d0) & (d0 >= near) & (d0 <= far)
    lvl.depth[fill] = d0[fill]
    lvl.normal[fill] = n0[fill]
    lvl.cost[fill] = c0[fill]
    lvl.estimated |= fill
    return lvl


def patchmatch_depth(
    ref: WorkingView,
    sources: list[WorkingView],
    depth_range: tuple[float, float],
    settings: PatchMatchSettings = PatchMatchSettings(),
    seed: int = 0,
) -> PatchMatchResult:
    """Estimate the depth map of ``ref`` from ``sources`` with PatchMatch.

    With ``settings.levels > 1`` the images are solved at half size first (``coarse_iterations``
    sweeps); the coarse planes initialise the finer level, and pixels that are flat at the finer
    level but were matched at the coarser one keep the coarse plane.

    Args:
        ref: the reference view (working resolution).
        sources: its source views (1 or more), same world frame.
        depth_range: (near, far) metres along the reference optical axis, 0 < near < far.
        settings: see :class:`PatchMatchSettings`.
        seed: random seed (results are identical for any thread count).
    Returns:
        PatchMatchResult at the reference's working resolution.
    Raises:
        InputError: no sources or a bad depth range.
    """
    t0 = time.perf_counter()
    if not sources:
        raise InputError(f"view {ref.name}: PatchMatch needs at least one source view")
    near, far = float(depth_range[0]), float(depth_range[1])
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
        raise InputError(f"view {ref.name}: bad depth range ({near}, {far}); need 0 < near < far")
    s = settings
    lvl = _solve(ref, sources, near, far, s, seed, s.levels, s.iterations)
    depth, normal, cost = lvl.depth, lvl.normal, lvl.cost
    bad = ~lvl.estimated | ~(cost <= s.max_cost)
    depth[bad] = np.nan
    normal[bad] = np.nan
    cost[~lvl.estimated] = K.BAD_COST
    return PatchMatchResult(depth, normal, cost, {"total": (time.perf_counter() - t0) * 1e3})
