"""skyrecon's own matcher: census transform + semi-global matching + occlusion-aware filling.

Pipeline (grey images, see :func:`~skyrecon.stereo.base.prepare_pair`):

1. sparse census transform over a 9x7 window (31 bits per pixel, checkerboard sampling):
   robust to gain, bias and vignetting differences between the two cameras;
2. matching cost = Hamming distance of census codes, computed on the fly row by row;
   matches falling outside the right image get a neutral cost so that smoothness decides;
3. semi-global aggregation along 2, 4 (down, down-right and their opposites; the fast
   setting) or 6 paths (plus the other diagonal pair; the default), with the jump penalty P2
   lowered at intensity edges; these advance row by row, so one step is a vector operation
   over all columns, and the paths' states are stored in 8 bits when they fit (with the default penalties: the
   two rows of states of a wide image with many disparities then stay in the L2 cache, which
   halved the aggregation time on KITTI at 192 disparities).
   Optionally (``horizontal_paths``) also left-to-right and right-to-left along each row,
   for a camera looking down at plain ground: there the costs tie at every disparity, the
   paths coming down the image carry the disparity of what lies beyond the street (far
   facades), and the ground's disparity came out 1.3 px too small at a median over the plain
   streets of a drone flight; the horizontal paths carry it from the kerbs and the feet of
   walls on the same row, which share it (0.5 px). On street-level pairs (Cones, KITTI, the
   synthetic street views) they change the error little either way (bad-1 of Cones 9.5 ->
   10.0 %, flying pairs 12.6 -> 11.8 %) and cost about 60 % more time at full resolution, so
   the default leaves them off; the stereo mapper turns them on. The image is split into
   bands of rows processed on separate threads, two by two: the bands of a pair hand their
   paths' state across their common edge (each first runs one sweep, then the other sweep
   from where its partner's ended), so a pair aggregates exactly what one band would; pairs
   (more than two threads) start their paths ``band_margin`` rows outside;
4. winner-takes-all with equiangular (or parabola) sub-pixel refinement, optional
   uniqueness test, left-right consistency check;
5. speckle removal, occlusion-aware filling (invalid runs of a row continue the surface of
   the farther of their two neighbours, a line fitted to the valid pixels beyond it:
   occlusions belong to the background, which may be slanted; then the pixels between the
   two sides of a depth edge take a colour-guided weighted median of the valid pixels
   around them, never nearer than that) and a 5x5 median filter.

The ``fast`` setting runs the same at half resolution and upsamples (for obstacle detection
at video rate). The matcher keeps its buffers between frames; the Numba kernels are compiled
once per machine (``cache=True``) for one set of argument types.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, replace
from functools import partial
from typing import Any, Literal

import cv2
import numpy as np

from skyrecon.core.image_noise import excess_noise_sigma, image_noise_sigma
from skyrecon.errors import InputError
from skyrecon.stereo import _kernels as K
from skyrecon.stereo.base import (
    DisparityResult,
    Stopwatch,
    check_disparity_range,
    prepare_pair,
    register_matcher,
    settings_from_kwargs,
)
from skyrecon.threads import available_cores

_PATH_OFFSETS = {2: (0,), 4: (0, -1), 6: (0, -1, 1)}
_MAX_BAND_BYTES = 256 << 20  # cost buffer of the bands in flight at once (one per thread)
_SUBPIXEL = {"none": 0, "parabola": 1, "equiangular": 2}
# guided fill (see _kernels.guided_fill_candidates), at full resolution: depth-edge gate (pixels),
# guide-difference scale (8-bit levels, summed over colour channels), weight decay per
# step, and the longest search per direction (pixels)
_GUIDE_GATE = 3.0
_GUIDE_SIGMA = 20.0
_GUIDE_DECAY = 0.02
_GUIDE_STEPS = 100
#: the guided fill's directions go to several threads from this many targets per thread (a
#: FlyingThings-style pair with 20000 targets: 15.7 -> 14.3 ms on 2 cores; from 1024 no faster)
_GUIDE_TARGETS_PER_THREAD = 4096
#: whole-image post-processing steps (the guided fill's search for targets and its last step,
#: the median filter) go to several threads from this many pixels per thread
_POST_PIXELS_PER_THREAD = 1 << 16


#: the automatic census tolerance (``SkyreconSettings.census_tolerance`` None), in standard
#: deviations of the image's noise: two noisy values of a plain surface differ by more than 3
#: sigma (their difference has sqrt(2) sigma) in 1.7 % of the comparisons
CENSUS_NOISE_SIGMAS = 3.0

#: edge-aware P2 reduction (``SkyreconSettings.p2_edge_alpha``) at full and at half resolution
DEFAULT_EDGE_ALPHA = 0.05
FAST_EDGE_ALPHA = 0.5


@dataclass(frozen=True)
class SkyreconSettings:
    """Settings of the skyrecon semi-global matcher.

    Attributes:
        fast: compute at half resolution, then upsample (about 5x faster, coarser edges;
            images under 64 pixels on a side are matched at full resolution).
        census_width, census_height: census window, odd. Windows of more than 33 pixels are
            sampled in a checkerboard pattern (a sparse census, 31 bits for the default 9x7);
            at most 32 bits are used.
        paths: aggregation paths: 2 (vertical), 4 (+ the top-left/bottom-right diagonal) or
            6 (+ both diagonals); None: 6 at full resolution, 4 when ``fast``. The third pair
            of paths (down-left and up-right) carries a surface's disparity past what cuts the
            other two: over 20 FlyingThings-style pairs (``skyrecon.sim.flying`` seeds 1-20)
            the error above half of OpenCV SGBM's went from 6 pairs (seeds 3, 4, 6, 10, 14, 16)
            to 3 (6, 10, 16: a striped background, see ``benchmarks/stereo``), flying-3 0.56
            -> 0.49 of OpenCV's, for about 12 % more time (still below OpenCV's on every
            benchmark pair). Elsewhere it changed little (Cones 0.43 -> 0.43, KITTI 000046
            0.28 -> 0.32, the synthetic street views 0.12-0.23 -> 0.18-0.23 of OpenCV's).
        horizontal_paths: also aggregate along each row, left to right and right to left
            (what a downward-looking camera needs on plain ground, see the module docstring).
            Their jump penalty is capped at 111 (they run in 8-bit arithmetic), which needs
            P1 < 110.
        P1: penalty of a one-pixel disparity change between neighbours (census-bit units).
        P2: penalty of a larger jump, lowered at intensity edges to
            ``max(P1 + 1, P2 / (1 + p2_edge_alpha * |I(p) - I(p - r)|))``.
        p2_edge_alpha: strength of the edge-aware P2 reduction (0: constant P2); None: 0.05, or
            0.5 when ``fast``. The strong reduction lets a plain object in front of a textured
            background keep its own disparity: its inside matches every disparity alike, and
            with a mild one the paths coming down from the background above and up from below
            carry the background's disparity across its horizontal edges (the half-resolution
            matcher put 96 % of a plain drone 6.6 m away at the disparity of the building
            behind it, and the tracker never saw it: held-out dynamic mission 155 collided;
            0.5 puts 74 % of it within 2 px, 1.0 88 %). 1.0 also matched the thin mullions
            of a glass facade to their neighbours (blobs at 2 m in front of a drone 8 m away,
            which then never took off: dynamic mission 122); 0.5 has as few such blobs as 0.05.
            At full resolution the census window already spans such edges and a stronger
            reduction raised the error on KITTI (0.30 -> 0.38 of OpenCV's at 0.2).
        out_of_image_cost: cost of a match that falls outside the right image; None uses a
            third of the census bits (a neutral value that lets smoothness decide).
        uniqueness: reject a pixel when a non-adjacent disparity costs within this fraction
            of the best (0 disables).
        subpixel: ``"equiangular"`` (V-shaped fit: less pixel-locking on census costs),
            ``"parabola"`` or ``"none"``.
        lr_check: left-right consistency tolerance in pixels; negative disables the check.
        speckle_size: connected regions smaller than this many pixels (at full resolution)
            whose disparity differs from their surroundings are removed; 0 disables.
        speckle_range: largest disparity step inside one connected region, pixels.
        fill: fill rejected pixels (the ``filled`` mask of the result marks them): each invalid
            run of a row continues the surface of its farther side (a line fitted to up to
            ``fill_span`` valid pixels beyond it), see :func:`fill_invalid`.
        fill_span: pixels (at full resolution) fitted beyond an invalid run; 0 fills with the
            farther neighbour's value.
        guided_fill: refill the invalid pixels between the two sides of a depth edge (row
            neighbours more than 3 px apart) from the first valid pixel in each of 8
            directions, weighted by colour likeness in the left image and distance (a
            weighted median, never nearer than the row fill); None: on unless ``fast``.
            Needs a disparity range that fits 16-bit fixed point (all but huge ranges).
        fill_nearer_left_px: an invalid run of a row whose left side is nearer than its right
            side by more than this (pixels) continues its left side rather than the farther one
            (in the left view an occlusion lies left of a nearer surface, so such a run is a
            mismatch at the far edge of a nearer surface or inside it); inf: always the farther
            side. None: 1 px (``_kernels.FILL_NEARER_LEFT_PX``), or inf when ``fast``: the
            flight loop's matcher keeps the farther side (flown on dynamic seeds 420-439 with
            the rule, one mission saw a mover that was not there for 30 s and returned).
        median: median filter size after filling: 0 (off), 3 or 5.
        band_margin: warm-up rows outside each pair of bands of rows (a band's paths start
            that far outside it where it does not continue its partner's).
        left_band_restart: the diagonal paths that run rightwards restart at the column of
            the largest disparity, as at the image border (OpenCV's SGBM does not match left of
            it at all). Left of that column a surface nearer than the column's disparity has no
            match in the right image; on a periodic texture (stripes) its pixels take an alias
            that lies inside the right image, and the paths carried that alias into the
            matched part of the surface (a striped square of a FlyingThings-style pair was
            wrong over 100 of its 165 columns, 64 with the restart: flying-3 error 0.66 ->
            0.60 of OpenCV's; the other benchmark pairs within 0.01).
        census_tolerance: a census bit is set only where the neighbour is darker than the
            centre by more than this, grey levels (0: the classic census, darker at all). On
            a plain surface the classic census of a real camera's image is its noise: random
            bits, random costs, and a disparity that is noise too (a plain city at 1.5 grey
            levels of noise: 14 % of the pixels measured instead of 93 %; the delivery demo's
            map two to four times as full, phantom obstacles in the air). With a
            tolerance above the noise, a plain surface's codes tie again as in a noise-free
            image and its disparity comes from the paths (Stein's ternary census, one bit
            kept). None: :data:`CENSUS_NOISE_SIGMAS` times the image's own noise at matching
            resolution (measured on the full left image, :mod:`skyrecon.core.image_noise`,
            divided by 2 when ``fast``): 0 on noise-free renders, so they match exactly as
            with the classic census. The estimate
            needs flat areas (sky, walls, road: outdoor scenes have them); on an image of fine
            texture everywhere it reads texture as noise and the tolerance throws real contrast
            away (a FlyingThings-style pair: 1.7 grey levels read, bad-1 0.32 -> 0.91 of OpenCV's;
            Cones 0.43 -> 0.52, KITTI 000046 D1 0.32 -> 0.35). So the default is 0, and the
            perception layer (``skyrecon map``, the flight loop), which looks at outdoor scenes
            from a real camera, asks for None. Applying it only on plain windows kept the
            FlyingThings-style pair no better (0.86) and lost the map's precision on noisy
            flights (precision@surface 0.80 -> 0.48): the noise scrambles the textured windows'
            small differences too.
        threads: worker threads; None uses every core this process may run on.
    """

    fast: bool = False
    census_width: int = 9
    census_height: int = 7
    paths: Literal[2, 4, 6] | None = None
    horizontal_paths: bool = False
    P1: int = 5
    P2: int = 100
    p2_edge_alpha: float | None = None
    out_of_image_cost: int | None = None
    uniqueness: float = 0.0
    subpixel: Literal["parabola", "equiangular", "none"] = "equiangular"
    lr_check: float = 1.0
    speckle_size: int = 50
    speckle_range: float = 2.0
    fill: bool = True
    fill_span: int = K.FILL_SPAN
    fill_nearer_left_px: float | None = None
    guided_fill: bool | None = None
    median: int = 5
    band_margin: int = 32
    left_band_restart: bool = True
    census_tolerance: float | None = 0.0
    threads: int | None = None

    @property
    def edge_alpha(self) -> float:
        """The edge-aware P2 reduction in use (``p2_edge_alpha`` resolved)."""
        if self.p2_edge_alpha is not None:
            return float(self.p2_edge_alpha)
        return FAST_EDGE_ALPHA if self.fast else DEFAULT_EDGE_ALPHA

    @property
    def nearer_left_px(self) -> float:
        """The row fill's nearer-left rule in use (``fill_nearer_left_px`` resolved; inf: off)."""
        if self.fill_nearer_left_px is not None:
            return float(self.fill_nearer_left_px)
        return float("inf") if self.fast else K.FILL_NEARER_LEFT_PX

    @property
    def n_paths(self) -> int:
        """The aggregation paths in use (``paths`` resolved: 6, or 4 when ``fast``)."""
        if self.paths is not None:
            return int(self.paths)
        return 4 if self.fast else 6

    @property
    def census_checker(self) -> bool:
        """Whether the census window is sampled sparsely (more than 33 pixels)."""
        return self.census_width * self.census_height > 33

    @property
    def census_bits(self) -> int:
        """Bits per census code (the largest matching cost)."""
        return K.census_bits(self.census_width, self.census_height, self.census_checker)

    def __post_init__(self) -> None:
        for n in ("census_width", "census_height"):
            v = getattr(self, n)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1 or v % 2 == 0:
                raise InputError(f"setting {n} must be a positive odd integer, got {v!r}")
        if K.census_bits(self.census_width, self.census_height, self.census_checker) > 32:
            raise InputError(
                f"a {self.census_width}x{self.census_height} census window needs more than 32 bits; "
                "use at most 9x7 (sampled sparsely) or 5x5"
            )
        if self.census_width * self.census_height < 9:
            raise InputError("the census window needs at least 9 pixels (3x3)")
        if self.paths is not None and self.paths not in _PATH_OFFSETS:
            raise InputError(f"setting paths must be 2, 4 or 6, got {self.paths!r}")
        if self.census_tolerance is not None and not 0 <= self.census_tolerance <= 64:
            raise InputError(
                f"census_tolerance must lie in [0, 64] grey levels or be None, got {self.census_tolerance}"
            )
        if not (0 < self.P1 < self.P2 <= 2000):
            raise InputError(f"need 0 < P1 < P2 <= 2000, got P1={self.P1}, P2={self.P2}")
        if self.horizontal_paths and self.P1 >= K.H_MAX_JUMP - 1:
            raise InputError(
                f"the horizontal paths need P1 < {K.H_MAX_JUMP - 1}, got P1={self.P1}; "
                "lower P1 or set horizontal_paths=False"
            )
        if self.p2_edge_alpha is not None and not (self.p2_edge_alpha >= 0):
            raise InputError(f"setting p2_edge_alpha must be >= 0, got {self.p2_edge_alpha}")
        if self.out_of_image_cost is not None and not (0 <= self.out_of_image_cost <= 32):
            raise InputError(f"setting out_of_image_cost must be in 0..32, got {self.out_of_image_cost}")
        if not (0 <= self.uniqueness < 10):
            raise InputError(f"setting uniqueness must be in [0, 10), got {self.uniqueness}")
        if self.subpixel not in _SUBPIXEL:
            raise InputError(f"setting subpixel must be one of {', '.join(_SUBPIXEL)}, got {self.subpixel!r}")
        if self.speckle_size < 0 or self.speckle_range < 0:
            raise InputError("settings speckle_size and speckle_range must be >= 0")
        if self.median not in (0, 1, 3, 5):
            raise InputError(f"setting median must be 0, 3 or 5, got {self.median!r}")
        if self.fill_nearer_left_px is not None and not self.fill_nearer_left_px >= 0:
            raise InputError(
                f"setting fill_nearer_left_px must be >= 0 (inf: off), got {self.fill_nearer_left_px}"
            )
        if self.fill_span < 0:
            raise InputError(f"setting fill_span must be >= 0, got {self.fill_span}")
        if self.band_margin < 0:
            raise InputError(f"setting band_margin must be >= 0, got {self.band_margin}")
        if self.threads is not None and self.threads < 1:
            raise InputError(f"setting threads must be >= 1, got {self.threads}")


#: The ``skyrecon-fast`` preset: half resolution, 4 paths.
FAST_SETTINGS = SkyreconSettings(fast=True)


# --------------------------------------------------------------------------------------------
# threads
# --------------------------------------------------------------------------------------------
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(
                max_workers=max(1, available_cores() - 1) + 1, thread_name_prefix="skyrecon-stereo"
            )
        return _POOL


def _run_all(tasks: list[Callable[[], Any]], max_workers: int | None = None) -> None:
    """Run the tasks, at most ``max_workers`` at a time (default: all at once): in each wave
    the first runs in this thread and the others on the pool."""
    step = max(1, max_workers or len(tasks))
    for i in range(0, len(tasks), step):
        wave = tasks[i : i + step]
        futures = [_pool().submit(t) for t in wave[1:]]
        try:
            wave[0]()
        finally:
            for f in futures:
                f.result()


def _bands(n_rows: int, parts: int) -> list[tuple[int, int]]:
    return [(n_rows * i // parts, n_rows * (i + 1) // parts) for i in range(parts)]


def _median_blur(image: np.ndarray, ksize: int, nthreads: int) -> np.ndarray:
    """``cv2.medianBlur`` (which runs on one thread) of an (H, W) image on bands of rows in
    parallel, each with ``ksize // 2`` rows of its neighbours: the same result."""
    H = image.shape[0]
    parts = max(1, min(nthreads, image.size // _POST_PIXELS_PER_THREAD, H // ksize))
    if parts == 1:
        return cv2.medianBlur(image, ksize)
    out = np.empty_like(image)
    r = ksize // 2

    def band(a: int, b: int) -> None:
        lo, hi = max(0, a - r), min(H, b + r)
        out[a:b] = cv2.medianBlur(image[lo:hi], ksize)[a - lo : b - lo]

    _run_all([partial(band, a, b) for a, b in _bands(H, parts)])
    return out


def _band_pairs(parts: int, nthreads: int) -> dict[int, tuple[threading.Barrier, bool, int]]:
    """Which bands of rows hand their SGM paths across their common edge (``sgm_band``'s
    phases 1 and 2, exact there, no warm-up margin): bands 2j and 2j + 1 of each wave of
    ``nthreads`` bands that :func:`_run_all` runs at once (both halves must run together, as
    each waits for the other). Per band: (the pair's barrier, whether it is the upper band,
    the index of the other band)."""
    out: dict[int, tuple[threading.Barrier, bool, int]] = {}
    if nthreads < 2:
        return out
    for w in range(0, parts, nthreads):
        for i in range(w, min(w + nthreads, parts) - 1, 2):
            barrier = threading.Barrier(2)
            out[i] = (barrier, True, i + 1)
            out[i + 1] = (barrier, False, i)
    return out


# --------------------------------------------------------------------------------------------
# post-processing (public: usable on any disparity map)
# --------------------------------------------------------------------------------------------
def _fixed_scale(dmin: float, dmax: float) -> float | None:
    """Fixed-point scale for int16 post-processing, or None when the range does not fit."""
    m = max(abs(dmin), abs(dmax)) + 4
    for scale in (32.0, 16.0, 8.0):
        if m * scale < 32000:
            return scale
    return None


def remove_speckles(disparity: np.ndarray, max_size: int, max_step_px: float) -> np.ndarray:
    """Set to NaN the connected regions of fewer than ``max_size`` pixels.

    Neighbouring pixels belong to one region when their disparities differ by at most
    ``max_step_px``. Works in place on (H, W) float32 disparity (NaN invalid) and returns it.
    """
    if max_size <= 0:
        return disparity
    valid = np.isfinite(disparity)
    fixed = np.full(disparity.shape, K.INVALID16, np.int16)
    fixed[valid] = np.clip(np.rint(disparity[valid] * 16.0), -32767, 32767).astype(np.int16)
    cv2.filterSpeckles(fixed, K.INVALID16, int(max_size), max(1, int(round(max_step_px * 16))))
    disparity[valid & (fixed == K.INVALID16)] = np.nan
    return disparity


def fill_invalid(
    disparity: np.ndarray,
    threads: int = 1,
    span: int = K.FILL_SPAN,
    nearer_left_px: float = K.FILL_NEARER_LEFT_PX,
) -> np.ndarray:
    """Fill NaN pixels from their row neighbours, continuing the farther (smaller) side.

    Invalid runs next to a depth edge are occlusions of the background, so the farther side
    is the better guess (unless the nearer side is on the left, where no occlusion of the left
    view lies: then the left side, see ``_kernels._fill_rows``); its surface is continued into the run along a line fitted to up to
    ``span`` valid pixels beyond it (slanted backgrounds), never rising above the nearer
    side nor falling below the smallest valid disparity (see ``_kernels._fill_rows``). Rows
    with no valid pixel are then filled the same way along columns.

    Args:
        disparity: (H, W) float32, NaN invalid.
        threads: worker threads.
        span: pixels fitted beyond a run (0: constant fill with the farther neighbour).
        nearer_left_px: a run whose left side is nearer by more than this takes the left side
            (inf: always the farther side).
    Returns:
        (H, W) float32 filled copy (NaN only if the whole map is invalid).
    """
    disp = np.ascontiguousarray(disparity, dtype=np.float32)
    out = np.empty_like(disp)
    if not np.isfinite(disp).any():
        out[:] = np.nan
        return out
    lo = float(np.nanmin(disp))
    H = disp.shape[0]
    parts = max(1, min(threads, H // 64))
    fill = partial(K.fill_background, lo=lo, span=int(span), max_slope=K.FILL_MAX_SLOPE)
    _run_all([partial(fill, disp, out, a, b, nearer_left_px=nearer_left_px) for a, b in _bands(H, parts)])
    if np.isnan(out).any():  # along columns: no left view, always the farther side
        t = np.ascontiguousarray(out.T)
        t2 = np.empty_like(t)
        fill(t, t2, 0, t.shape[0], nearer_left_px=np.inf)
        out = np.ascontiguousarray(t2.T)
    return out


def _upsample2(half: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Upsample a half-resolution disparity map 2x (values doubled): bilinear where the 3x3
    neighbourhood is smooth (within 1 half-resolution pixel), nearest at depth edges so that
    foreground and background are not blended."""
    d = half * np.float32(2.0)
    finite = np.isfinite(d)
    z = np.where(finite, d, np.float32(0.0))
    k = np.ones((3, 3), np.uint8)
    spread = cv2.dilate(z, k) - cv2.erode(z, k)
    smooth = (spread < 2.0) & (cv2.erode(finite.view(np.uint8), k) > 0)
    near = cv2.resize(d, size, interpolation=cv2.INTER_NEAREST)
    lin = cv2.resize(z, size, interpolation=cv2.INTER_LINEAR)
    use_lin = cv2.resize(smooth.view(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
    return np.where(use_lin, lin, near)


# --------------------------------------------------------------------------------------------
# the matcher
# --------------------------------------------------------------------------------------------
class SkyreconMatcher:
    """Census + semi-global matcher (see the module docstring).

    Args:
        max_disparity: disparities searched are ``min_disparity <= d < max_disparity``.
        min_disparity: smallest disparity, pixels.
        settings: a :class:`SkyreconSettings`, or individual fields as keywords.

    The matcher keeps its buffers between calls (reuse it for the frames of a sequence);
    concurrent ``compute`` calls on one matcher are serialised (use one matcher per thread to
    run in parallel; each already uses every core).
    """

    name = "skyrecon"

    def __init__(
        self,
        max_disparity: int,
        min_disparity: int = 0,
        settings: SkyreconSettings | None = None,
        **kwargs: Any,
    ) -> None:
        check_disparity_range(min_disparity, max_disparity)
        if settings is not None and kwargs:
            settings = replace(settings, **kwargs)
        self.settings = settings or settings_from_kwargs(SkyreconSettings, self.name, kwargs)
        self.min_disparity = int(min_disparity)
        self.max_disparity = int(max_disparity)
        if self.settings.fast:
            self.name = "skyrecon-fast"
        self._buffers: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()
        s = self.settings
        self._offsets = tuple(int(o) for o in _PATH_OFFSETS[s.n_paths])
        self._up_offsets = tuple(-o for o in self._offsets)
        self._guided = bool(s.guided_fill if s.guided_fill is not None else not s.fast)
        self._ooi_cost = int(s.out_of_image_cost if s.out_of_image_cost is not None else s.census_bits // 3)
        fits8 = K.states_fit_uint8(max(s.census_bits, self._ooi_cost), s.P1, s.P2)
        self._state_dtype = np.uint8 if fits8 else np.int16  # SGM path states

    # ----- buffers -------------------------------------------------------------------------
    def _buf(self, key: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        b = self._buffers.get(key)
        if b is None or b.shape != shape or b.dtype != dtype:
            b = np.empty(shape, dtype)
            self._buffers[key] = b
        return b

    def _threads(self) -> int:
        return self.settings.threads or available_cores()

    def _census_tolerance(
        self, grey: np.ndarray, noise_sigma: float | None, scale: int, diag: dict[str, Any]
    ) -> int:
        """The census tolerance for this pair, grey levels (``census_tolerance`` resolved: with
        None, :data:`CENSUS_NOISE_SIGMAS` times the noise beyond what a noise-free image reads,
        at matching resolution: the full-resolution ``grey`` left image's noise (``noise_sigma``
        if given, else measured on it) divided by ``scale``); recorded in ``diag``."""
        t = self.settings.census_tolerance
        if t is None:
            sigma = image_noise_sigma(grey) if noise_sigma is None else float(noise_sigma)
            diag["image_noise"] = round(sigma, 3)
            t = CENSUS_NOISE_SIGMAS * excess_noise_sigma(sigma / scale)  # k x k area average: sigma / k
        tol = min(int(round(t)), 64)
        diag["census_tolerance"] = tol
        return tol

    # ----- core ----------------------------------------------------------------------------
    def _match(
        self,
        gl: np.ndarray,
        gr: np.ndarray,
        guide: np.ndarray | None,
        dmin: int,
        dmax: int,
        scale: int,
        sw: Stopwatch,
        diag: dict[str, Any],
        tolerance: int = 0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Disparity of an 8-bit grey pair: (disparity, measured mask); ``tolerance``: the
        census tolerance, grey levels (see :class:`SkyreconSettings`).

        The image is split into bands of rows, one per thread; each band task runs the census
        transform (its rows and margins), the semi-global matching (the two bands of a pair
        meet halfway: see :func:`_band_pairs` and ``_kernels.sgm_band``; on a 2-core machine
        there are no margins and the aggregation does not depend on the split), the conversion to int16
        fixed point (1/32 px for ranges under 1000 px, so that OpenCV's SIMD filters apply),
        speckle removal and row-wise filling of its rows. The median filter and the
        conversion back to float run on the whole image afterwards.
        """
        s = self.settings
        H, W = gl.shape
        D = dmax - dmin
        rh, rw = s.census_height // 2, s.census_width // 2
        pl = cv2.copyMakeBorder(gl, rh, rh, rw, rw, cv2.BORDER_REPLICATE)
        pr = cv2.copyMakeBorder(gr, rh, rh, rw, rw, cv2.BORDER_REPLICATE)
        # a census bit is set where the neighbour is darker than the centre by more than this
        tol8 = np.uint8(tolerance)
        cl_centres = np.maximum(pl, tol8) - tol8 if tolerance else pl  # saturating at 0
        cr_centres = np.maximum(pr, tol8) - tol8 if tolerance else pr
        wp = -(-W // K.LANES) * K.LANES
        cr_pad = max(dmax, 0) + K.LANES
        cr_width = cr_pad + wp + max(-dmin, 0) + K.LANES
        chk = s.census_checker
        nthreads = self._threads()
        margin = int(s.band_margin)
        # one band of rows per thread; more bands (run by the same threads in turn) when one
        # thread's cost buffer would exceed _MAX_BAND_BYTES
        parts = max(1, min(nthreads, H // max(2 * margin, 16)))
        parts = max(parts, -(-(H * D * wp * nthreads) // _MAX_BAND_BYTES))
        parts = min(parts, max(1, H // 8))
        if parts == 1:
            margin = 0
        bands = _bands(H, parts)
        max_rows = max(b - a for a, b in bands)
        fs = _fixed_scale(dmin, dmax)
        speckle = int(round(s.speckle_size / (scale * scale)))
        speckle_step = max(1, int(round(s.speckle_range / scale * (fs or 16.0))))
        disp = self._buf("disp", (H, W), np.float32)
        right = self._buf("right", (H, W), np.int32)
        fixed = self._buf("fixed", (H, W), np.int16)
        filled = self._buf("filled", (H, W), np.int16)
        do_fill = fs is not None and (s.fill or s.median > 1)
        span = int(s.fill_span) // scale
        fill_args = (float(fs or 1.0), float(dmin * (fs or 1.0)), span, K.FILL_MAX_SLOPE)
        task_ms: list[dict[str, float]] = [{} for _ in bands]
        n_state, n16, nu16, n8 = K.band_workspace_sizes(
            D, wp, len(self._offsets), bool(s.horizontal_paths), dmin
        )
        left_start = max(0, dmax) if s.left_band_restart else 0

        slots: queue.SimpleQueue[int] = queue.SimpleQueue()
        for k in range(min(nthreads, parts)):
            slots.put(k)
        pairs = _band_pairs(parts, nthreads)
        hand_n = K.handoff_size(D, wp, len(self._offsets))
        no_hand = np.zeros(0, np.int16)

        def band_task(i: int, a: int, b: int) -> None:
            # buffers belong to a worker slot (one per concurrent task), so extra bands reuse them
            tid = slots.get()
            try:
                run_band(i, a, b, tid)
            except BaseException:
                if i in pairs:
                    pairs[i][0].abort()  # the other band of the pair must not wait for ever
                raise
            finally:
                slots.put(tid)

        def run_band(i: int, a: int, b: int, tid: int) -> None:
            t0 = time.perf_counter()
            pair = pairs.get(i)
            upper = pair is not None and pair[1]  # the upper band of a pair (mirrored)
            top = 0 if pair is not None and not upper else margin
            bottom = 0 if upper else margin
            lo, hi = max(0, a - top), min(H, b + bottom)
            cl = self._buf(f"cl@{tid}", (max_rows + 2 * margin, wp), np.uint32)[: hi - lo]
            cr = self._buf(f"cr@{tid}", (max_rows + 2 * margin, cr_width), np.uint32)[: hi - lo]
            K.census_transform(pl, cl_centres, rh, rw, chk, cl, 0, lo, hi, lo)
            K.census_transform(pr, cr_centres, rh, rw, chk, cr, cr_pad, lo, hi, lo)
            t1 = time.perf_counter()
            S = self._buf(f"S@{tid}", (max_rows, D * wp), np.uint8)[: b - a]
            args = (
                cl,
                cr,
                cr_pad,
                lo,
                gl,
                int(dmin),
                self._ooi_cost,
                int(s.P1),
                float(s.P2),
                s.edge_alpha,
                self._offsets,
                self._up_offsets,
                int(a),
                int(b),
                top,
                bottom,
                float(s.uniqueness),
                _SUBPIXEL[s.subpixel],
                float(s.lr_check),
                bool(s.horizontal_paths),
                S,
                disp,
                right,
                self._buf(f"w16@{tid}", (n16,), np.int16),
                self._buf(f"wu16@{tid}", (nu16,), np.uint16),
                self._buf(f"w8@{tid}", (n8,), np.uint8),
                self._buf(f"state@{tid}", (n_state,), self._state_dtype),
                left_start,
            )
            if pair is None:
                K.sgm_band(*args, 0, False, no_hand)
            else:  # store, hand the state at the common edge over, select from the other's
                barrier, _, other = pair
                K.sgm_band(*args, 1, upper, self._buf(f"hand{i}", (hand_n,), np.int16))
                barrier.wait()
                K.sgm_band(*args, 2, upper, self._buf(f"hand{other}", (hand_n,), np.int16))
            t2 = time.perf_counter()
            if fs is not None:
                K.to_fixed(disp, np.float32(fs), fixed, a, b)
                if speckle > 0:
                    cv2.filterSpeckles(fixed[a:b], K.INVALID16, speckle, speckle_step)
                if do_fill:
                    K.fill_background_fixed(fixed, filled, a, b, *fill_args, s.nearer_left_px)
            t3 = time.perf_counter()
            task_ms[i].update(census=(t1 - t0) * 1e3, sgm=(t2 - t1) * 1e3, post=(t3 - t2) * 1e3)

        _run_all([partial(band_task, i, a, b) for i, (a, b) in enumerate(bands)], nthreads)
        sw.lap("match")
        diag["threads"] = min(nthreads, parts)
        diag["bands"] = parts
        diag["band_ms"] = task_ms
        lr_valid = float(np.count_nonzero(np.isfinite(disp)) / disp.size)
        diag["lr_rejected"] = 1.0 - lr_valid
        if fs is None:  # huge disparity range: float post-processing
            work = remove_speckles(disp.copy(), speckle, s.speckle_range / scale)
            measured = np.isfinite(work)
            out = work
            if (s.fill or s.median > 1) and measured.any():
                f = fill_invalid(work, nthreads, span, s.nearer_left_px)
                if s.median > 1:
                    f = cv2.medianBlur(f, int(s.median))
                out = f if s.fill else np.where(measured, f, np.float32(np.nan))
            diag["speckle_rejected"] = lr_valid - float(np.count_nonzero(measured) / measured.size)
            sw.lap("postprocess")
            return out, measured
        measured = fixed != K.INVALID16
        diag["speckle_rejected"] = lr_valid - float(np.count_nonzero(measured) / measured.size)
        result = fixed
        if do_fill and measured.any():
            result = filled
            if guide is not None:
                result = self._guided_fill(fixed, filled, guide, fs, scale, nthreads)
            if (result == K.INVALID16).any():  # rows without any match: fill along columns
                # (no left view along a column: always the farther side)
                t = np.ascontiguousarray(result.T)
                t2 = np.empty_like(t)
                K.fill_background_fixed(t, t2, 0, t.shape[0], *fill_args, np.inf)
                result = np.ascontiguousarray(t2.T)
            if s.median > 1:
                result = _median_blur(result, int(s.median), nthreads)
        keep = np.empty((0, 0), np.int16) if (s.fill or result is fixed) else fixed
        out = np.empty((H, W), np.float32)
        K.from_fixed(result, keep, np.float32(1.0 / fs), out, 0, H)
        sw.lap("postprocess")
        return out, measured

    def _guided_fill(
        self, fixed: np.ndarray, filled: np.ndarray, guide: np.ndarray, fs: float, scale: int, nthreads: int
    ) -> np.ndarray:
        """The guided refill of the pixels between depth edges (see
        ``_kernels.guided_fill_candidates``) of an (H, W) int16 fixed-point map (``fs`` per
        pixel of disparity) at 1/``scale`` resolution; the 8 search directions, then the
        target pixels, are shared among the threads. Half of the targets (a checkerboard)
        are computed, the others take their smallest computed neighbour."""
        H, W = fixed.shape
        out = self._buf("guided", (H, W), np.int16)
        rowptr = self._buf("rowptr", (H + 1,), np.int64)
        rows = _bands(H, max(1, min(nthreads, H * W // _POST_PIXELS_PER_THREAD)))
        found: list[tuple[np.ndarray, np.ndarray]] = [(np.zeros(0, np.int64),) * 2] * len(rows)

        def find(i: int, a: int, b: int) -> None:
            found[i] = K.guided_fill_targets(fixed, filled, out, fs, _GUIDE_GATE / scale, rowptr, a, b)

        _run_all([partial(find, i, a, b) for i, (a, b) in enumerate(rows)])
        offset = 0  # each range's row pointers count from its start
        for (a, b), (t, _) in zip(rows, found):
            rowptr[a:b] += offset
            offset += t.size
        rowptr[H] = offset
        targets = np.concatenate([t for t, _ in found])
        others = np.concatenate([o for _, o in found])
        if targets.size == 0:
            return out
        nd = len(K.GUIDE_DY)
        cv = np.empty((nd, targets.size), np.float32)
        cw = np.empty((nd, targets.size), np.float32)
        # threads only pay off for enough targets (handing work to the pool costs about as
        # much as a thousand targets)
        parts = max(1, min(nthreads, nd, targets.size // _GUIDE_TARGETS_PER_THREAD))
        args = (fs, _GUIDE_SIGMA, _GUIDE_DECAY * scale, _GUIDE_STEPS // scale)
        tasks: list[Callable[[], Any]] = [
            partial(
                K.guided_fill_candidates,
                fixed,
                filled,
                guide,
                targets,
                rowptr,
                k0,
                k1,
                *args,
                self._buf(f"nsteps@{i}", (H, W), np.int16),
                cv,
                cw,
            )
            for i, (k0, k1) in enumerate(_bands(nd, parts))
        ]
        _run_all(tasks)
        G = targets.size
        _run_all([partial(K.guided_fill_median, targets, cv, cw, out, a, b) for a, b in _bands(G, parts)])
        done = self._buf("guided_done", (H, W), np.uint8)
        done[:] = 0
        done.reshape(-1)[targets] = 1
        # each other target reads only computed pixels and writes only itself: any split works
        spread = _bands(others.size, len(rows))
        _run_all([partial(K.guided_fill_spread, others[a:b], done, out) for a, b in spread])
        return out

    def compute(
        self, left: np.ndarray, right: np.ndarray, noise_sigma: float | None = None
    ) -> DisparityResult:
        """Disparity of a rectified pair.

        Args:
            left, right: (H, W, 3) uint8 RGB or (H, W) grey (uint16 accepted), same size.
            noise_sigma: the left image's noise, grey levels, if already measured (for
                ``census_tolerance`` None; otherwise measured here).
        Returns:
            DisparityResult with (H, W) float32 disparity (``x_right = x_left - d``), NaN
            where no estimate (only when ``fill`` is off or the whole map failed), and the
            ``filled`` mask of interpolated pixels.
        Raises:
            InputError: bad images or a disparity range at least as wide as the image.
        """
        with self._lock:
            return self._compute(left, right, noise_sigma)

    def _compute(
        self, left: np.ndarray, right: np.ndarray, noise_sigma: float | None = None
    ) -> DisparityResult:
        s = self.settings
        sw = Stopwatch()
        pair = prepare_pair(left, right)
        H, W = pair.left_grey.shape
        check_disparity_range(self.min_disparity, self.max_disparity, W)
        diag: dict[str, Any] = {
            "settings": asdict(s),
            "paths": s.n_paths,  # ``settings["paths"]`` resolved
            "converted_from_16bit": pair.converted_from_16bit,
        }
        gl, gr = pair.left_grey, pair.right_grey
        tolerance = self._census_tolerance(gl, noise_sigma, 2 if s.fast and min(H, W) >= 64 else 1, diag)
        dmin, dmax = self.min_disparity, self.max_disparity
        scale = 1
        if s.fast and min(H, W) >= 64:  # tiny images are matched at full resolution
            scale = 2
            h2, w2 = (H + 1) // 2, (W + 1) // 2
            gl = cv2.resize(gl, (w2, h2), interpolation=cv2.INTER_AREA)
            gr = cv2.resize(gr, (w2, h2), interpolation=cv2.INTER_AREA)
            dmin, dmax = int(np.floor(dmin / 2)), int(np.ceil(dmax / 2))
            if dmax - dmin >= w2:
                dmax = dmin + w2 - 1
        sw.lap("prepare")

        guide = None
        if self._guided:  # the left image (colour when given), smoothed, at matching resolution
            guide = pair.left_rgb if pair.left_rgb is not None else pair.left_grey
            if scale != 1:
                guide = cv2.resize(guide, (gl.shape[1], gl.shape[0]), interpolation=cv2.INTER_AREA)
            guide = cv2.blur(guide, (3, 3)).reshape(gl.shape[0], gl.shape[1], -1)
        out, measured = self._match(gl, gr, guide, dmin, dmax, scale, sw, diag, tolerance)
        if scale != 1:
            out = _upsample2(out, (W, H))
            measured = cv2.resize(measured.view(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(
                bool
            )
            sw.lap("upsample")
        out = np.ascontiguousarray(out, dtype=np.float32)
        filled_mask = np.isfinite(out) & ~measured
        diag["density"] = float(np.count_nonzero(np.isfinite(out)) / out.size)
        diag["measured_density"] = float(np.count_nonzero(measured) / measured.size)
        return DisparityResult(
            out, filled_mask, self.name, self.min_disparity, self.max_disparity, sw.total(), diag
        )

    def warmup(self) -> None:
        """Compile (or load from the cache) the kernels on a tiny pair, so that the first real
        frame is not slowed by the JIT."""
        rng = np.random.default_rng(0)
        img = rng.integers(0, 255, (48, 64), dtype=np.uint8)
        # full resolution on the tiny pair, with this matcher's paths (``fast`` resolves them)
        m = SkyreconMatcher(16, settings=replace(self.settings, fast=False, paths=self.settings.n_paths))
        m.compute(img, np.roll(img, -3, axis=1))
        if m._guided:  # a tiny pair may have no depth edge: run the guided fill on its own
            fixed = np.full((8, 16), K.INVALID16, np.int16)
            fixed[:, :4] = 320
            fixed[:, 12:] = 64
            filled = np.empty_like(fixed)
            K.fill_background_fixed(
                fixed, filled, 0, 8, 32.0, 0.0, 8, K.FILL_MAX_SLOPE, K.FILL_NEARER_LEFT_PX
            )
            m._guided_fill(fixed, filled, np.zeros((8, 16, 1), np.uint8), 32.0, 1, 1)


def _factory(fast: bool) -> Callable[..., SkyreconMatcher]:
    def make(
        max_disparity: int, min_disparity: int = 0, settings: SkyreconSettings | None = None, **kwargs: Any
    ) -> SkyreconMatcher:
        if settings is None:
            kwargs.setdefault("fast", fast)
        elif fast and not settings.fast:
            settings = replace(settings, fast=True)
        return SkyreconMatcher(max_disparity, min_disparity, settings=settings, **kwargs)

    return make


register_matcher("skyrecon", _factory(False), "census + semi-global matching (default, most accurate)")
register_matcher(
    "skyrecon-fast", _factory(True), "skyrecon at half resolution (obstacle detection, video rate)"
)
