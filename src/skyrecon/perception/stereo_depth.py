"""Stereo depth for the map: rectified pair -> disparity -> filtered depth image.

One stage for every user (``skyrecon map`` / :class:`skyrecon.mapping.StereoMapper` and the
delivery loop); the rules are a :class:`~skyrecon.perception.settings.PerceptionSettings`.
Per pair:

1. disparity with the stereo matcher (built once, warmed up, kept between pairs);
2. only *measured* disparities are kept (unless ``use_filled``), with ``min_texture`` only
   those on image texture, and, with ``max_disparity_step_px``, none at a disparity
   discontinuity (full resolution);
2b. with ``plane_fill``, unmeasured segments bounded all around by one measured plane get that
   plane's disparity (:func:`skyrecon.stereo.plane_supported_fill`); with a ground plane
   given (:class:`~skyrecon.perception.GroundPlane`), plain segments whose measured border
   agrees with the ground take the ground's, and with ``ground_range_m`` they are open air
   up to that range where it stays well above the ground (+inf), unknown elsewhere and in
   the rows below anything measured nearer than the ground beside them (a plain roof that
   joined the ground's segment under noise);
3. the disparity and the mask are subsampled by ``depth_stride`` and converted with the full
   rig (disparities stay in full-resolution pixels): ``Z = f B / (d + doffs)``;
4. matches at ``d + doffs <= 0`` become +inf (``sky_is_free``) or NaN;
5. with ``near_speck_area_m2`` and a noisy image, blobs of near depth too small to be
   anything there are dropped (:func:`near_specks`).

Frames and units: images (H, W, 3) uint8 RGB (or grey) of a rectified rig; depth (h, w)
float32 metres along the left optical axis, NaN where not measured.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from skyrecon.core.image_noise import (
    excess_noise_sigma,
    gradient_noise_quantile,
    image_noise_sigma,
    noise_aware_threshold,
)
from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.perception.ground_plane import GroundPlane, below_raised
from skyrecon.perception.ground_plane import warm_kernels as warm_ground_plane
from skyrecon.perception.settings import PerceptionSettings
from skyrecon.stereo import Matcher, create_matcher, plane_supported_fill, to_grey
from skyrecon.stereo.base import prepare_pair
from skyrecon.stereo.opencv_matchers import OpenCVBMMatcher, OpenCVBMSettings
from skyrecon.stereo.plane_fill import warm_kernels as warm_plane_fill
from skyrecon.stereo.sgm import SkyreconMatcher


def strided_intrinsics(cam: Intrinsics, stride: int) -> Intrinsics:
    """The camera of ``image[::stride, ::stride]``: pixel (u, v) of the result is pixel
    ``(stride u, stride v)`` of the original (no averaging), so ``f / stride`` and ``c / stride``."""
    if stride == 1:
        return cam
    w = -(-cam.width // stride)
    h = -(-cam.height // stride)
    return Intrinsics(
        cam.fx / stride, cam.fy / stride, cam.cx / stride, cam.cy / stride, w, h, skew=cam.skew / stride
    )


def disparity_discontinuities(disparity: np.ndarray, max_step_px: float) -> np.ndarray:
    """(H, W) bool: pixels whose 3x3 neighbourhood spans more than ``max_step_px`` of disparity.

    Args:
        disparity: (H, W) float32 pixels, NaN invalid (an invalid neighbour counts as 0, so the
            pixels bordering invalid ones are flagged too).
    """
    d = np.nan_to_num(np.asarray(disparity, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    k = np.ones((3, 3), np.uint8)
    return (cv2.dilate(d, k) - cv2.erode(d, k)) > max_step_px


def texture_masks(
    image: np.ndarray, min_gradient: float, window_px: int = 7, noise_sigma: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Where the image has texture a row-wise stereo match can use, and where it has edges.

    Args:
        image: (H, W, 3) uint8 RGB or (H, W) grey.
        min_gradient: grey levels per pixel (0-255 scale), for a noise-free image.
        window_px: side of the averaging window, pixels.
        noise_sigma: the image's noise, grey levels
            (:func:`~skyrecon.core.image_noise.image_noise_sigma`); each threshold is raised so
            that pure noise of that level stays under it in all but about 1 window in 1000
            (:func:`~skyrecon.core.image_noise.noise_aware_threshold`). None: ``min_gradient``
            as given.
    Returns:
        ``(matchable, edges)``, (H, W) bool: the mean absolute horizontal grey-level gradient over
        the window is at least the threshold (texture along the epipolar lines: a horizontal
        edge alone, such as the top of a wall against the sky, matches anywhere along a row);
        the mean of the horizontal plus vertical one is (any edge).
    """
    g = to_grey(np.asarray(image)).astype(np.float32)
    gx, gy = _window_gradients(g, int(window_px))
    t_x, t_xy = _gradient_thresholds(min_gradient, noise_sigma, int(window_px))
    return gx >= t_x, gx + gy >= t_xy


def _window_gradients(grey: np.ndarray, window_px: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 mean absolute horizontal and vertical gradients of the float32 grey image
    over a ``window_px`` square, in ksize=1 Sobel units (twice the central difference)."""
    k = (window_px, window_px)
    gx = cv2.boxFilter(np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=1)), -1, k)
    gy = cv2.boxFilter(np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=1)), -1, k)
    return gx, gy


def _gradient_thresholds(
    min_gradient: float, noise_sigma: float | None, window_px: int
) -> tuple[np.float32, np.float32]:
    """The thresholds of :func:`texture_masks` in :func:`_window_gradients`' units: on the
    horizontal gradient, and on the sum of both."""
    # a ksize=1 Sobel is twice the central difference per pixel
    t_x = 2.0 * noise_aware_threshold(min_gradient, noise_sigma, gradient_noise_quantile(window_px))
    t_xy = 2.0 * noise_aware_threshold(
        min_gradient, noise_sigma, gradient_noise_quantile(window_px, both_axes=True)
    )
    return np.float32(t_x), np.float32(t_xy)


@dataclass(eq=False)
class _TextureTest:
    """One frame's texture test at ``texture_scale`` k (see :meth:`StereoDepth.compute`).

    Attributes:
        grey: (h, w) uint8 left image reduced by k (an area average, as the fast matcher's).
        noise: its noise, grey levels (the full image's divided by k; None: not measured).
        gx, gy: (h, w) float32 window gradients (:func:`_window_gradients`).
        matchable, edges: (h, w) bool masks of :func:`texture_masks`.
    """

    grey: np.ndarray
    noise: float | None
    gx: np.ndarray
    gy: np.ndarray
    matchable: np.ndarray
    edges: np.ndarray


#: open sky (see :meth:`StereoDepth.compute`, ``horizon_row_px``) lies at least this far above
#: the horizon, degrees
SKY_MARGIN_DEG = 1.0


#: the edges that separate open sky from the rest stand this many times farther above the
#: noise than the texture test's (a test at about 1 window in 1000 leaves specks of noise in a
#: plain sky that cut it into islands; a drone against the sky has far more contrast)
SKY_EDGE_NOISE_FACTOR = 1.5


#: the range (metres) within which measured depth frames a plain segment (see
#: :func:`open_sky`) when the settings give no ``horizon_far_m``
SKY_NEAR_RANGE_M = 20.0
#: a plain segment whose lower rim is measured nearer than the map's range on at least this
#: share of its length is a surface, not sky (see :func:`open_sky`)
SKY_ENCLOSED_SHARE = 0.5
#: ... looking this many pixels (of the separators' grid) under the rim: the edge between them
SKY_RIM_PX = 8
#: ... or at the first measured pixel under the rim, through unmeasured (plain) pixels, up to
#: this many pixels of the separators' grid under it (64: 22 degrees at 640 x 480 and 90 degrees)
SKY_FRAME_REACH_PX = 64


def open_sky(
    separators: np.ndarray,
    horizon_row_px: float,
    camera: Intrinsics,
    scale: int = 1,
    shape: tuple[int, ...] | None = None,
    measured: np.ndarray | None = None,
    near: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W) bool: the plain segments of an image that reach its top row and lie wholly above
    the horizon (at least :data:`SKY_MARGIN_DEG` above it): open sky.

    With ``near``, a segment whose lower rim lies on measured depth nearer than the map's range
    (within :data:`SKY_RIM_PX` under it) along at least :data:`SKY_ENCLOSED_SHARE` of its
    length is not sky, unless it reaches down to within :data:`HORIZON_BAND_DEG` of the horizon
    (it opens onto the far view there): a plain panel framed by what stands near, such as the
    glass panes of a tower that fill the top of the image, each bounded by its window frames
    (noisy plain delivery seed 8 and textured seed 3: the upper panes of a glass tower 10 m
    ahead were taken for sky, and the map carved free space through the tower). The sky lies
    above a skyline of roofs, most of them beyond the range, or reaches down to the horizon
    beside a near roof (noisy plain seed 8 again: the sky beside a plain wall's roof line,
    refused, left the drone without depth and it turned home); sky seen only above near roofs
    taller than the drone is refused, which costs the air above them.

    With ``measured`` as well, a rim pixel is also framed when the first measured pixel under it
    (through unmeasured pixels, up to :data:`SKY_FRAME_REACH_PX` under it) is near: a plain
    band across a near facade, bounded below by another plain band, is framed by what is
    measured under that (a red sign band across the top of a textured tower 6 m ahead, a plain
    grey band under it, the windows under that measured: random noisy view of city 45 in
    ``benchmarks/mission/probe_carve_through.py``, 6755 pixels of open air through the tower,
    a third of the textured probe's carving through).

    Args:
        separators: (h, w) bool, the pixels with texture or an edge, at the image's resolution
            divided by ``scale`` (they separate the segments; :func:`texture_masks`' ``edges``).
        horizon_row_px: the image row of the horizon (full resolution), pixels.
        camera: the full-resolution camera (its ``fy``).
        scale: the reduction of ``separators``; shape: the full-resolution (H, W) (default
            ``scale`` times the separators').
        measured: optional (h, w) bool on the separators' grid: measured depth (any range;
            read only with ``near``).
        near: optional (h, w) bool on the separators' grid: measured depth nearer than the
            map's range.
    """
    t = np.ascontiguousarray(np.asarray(separators, bool))
    full_shape = shape if shape is not None else (t.shape[0] * scale, t.shape[1] * scale)
    n, labels, stats, _ = cv2.connectedComponentsWithStats((~t).view(np.uint8), connectivity=4)
    last_row = horizon_row_px - camera.fy * np.tan(np.radians(SKY_MARGIN_DEG))  # full resolution
    top = stats[:, cv2.CC_STAT_TOP]
    bottom = (top + stats[:, cv2.CC_STAT_HEIGHT]) * scale  # one past the last full-res row
    sky = (top == 0) & (bottom <= last_row)
    sky[0] = False  # the textured pixels
    if near is not None and sky.any():
        # a segment reaching down towards the horizon opens onto the far view: sky, framed or not
        to_horizon = bottom >= horizon_row_px - camera.fy * np.tan(np.radians(HORIZON_BAND_DEG))
        framed = _enclosed_from_below(
            labels, n, np.asarray(near, bool), None if measured is None else np.asarray(measured, bool)
        )
        sky &= to_horizon | ~framed
    # a pixel off the sky's rim: where an edge is faint (a roof corner at the image's top) the
    # segment may take in a pixel or two of what stands there
    full = cv2.erode(sky[labels].view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    return _upsample_mask(full, scale, full_shape) if scale > 1 else full


def _enclosed_from_below(
    labels: np.ndarray, n: int, near: np.ndarray, measured: np.ndarray | None = None
) -> np.ndarray:
    """(n,) bool per segment of ``labels`` (h, w): its lower rim (its pixels whose lower
    neighbour is not its own) has a ``near`` pixel within :data:`SKY_RIM_PX` under it, or (with
    ``measured``) its first ``measured`` pixel under it within :data:`SKY_FRAME_REACH_PX` is
    ``near``, on at least :data:`SKY_ENCLOSED_SHARE` of its pixels."""
    for name, mask in (("near", near), ("measured", measured)):
        if mask is not None and mask.shape != labels.shape:
            raise InputError(f"{name} mask {mask.shape} does not match the separators {labels.shape}")
    rim = np.ones(labels.shape, bool)  # the bottom row's pixels have nothing under them
    rim[:-1] = labels[:-1] != labels[1:]
    under = np.zeros(labels.shape, bool)
    for k in range(1, SKY_RIM_PX + 1):
        under[:-k] |= near[k:]
    if measured is not None:
        under |= _first_measured_below_is_near(measured, near, SKY_FRAME_REACH_PX)
    total = np.bincount(labels[rim], minlength=n)
    framed = np.bincount(labels[rim & under], minlength=n)
    return framed >= SKY_ENCLOSED_SHARE * np.maximum(total, 1)


def _first_measured_below_is_near(measured: np.ndarray, near: np.ndarray, reach_px: int) -> np.ndarray:
    """(h, w) bool: the first ``measured`` pixel under each pixel in its column (rows r + 1 ...
    r + ``reach_px``) exists and is ``near``; both masks (h, w) bool."""
    h = measured.shape[0]
    rows = np.arange(h, dtype=np.int32)[:, None]
    first = np.where(measured, rows, np.int32(h))
    first = np.minimum.accumulate(first[::-1], axis=0)[::-1]  # first measured at or under each row
    below = np.full(measured.shape, h, np.int32)
    below[:-1] = first[1:]
    near_below = np.take_along_axis(near, np.minimum(below, h - 1), axis=0)
    return (below < h) & (below - rows <= reach_px) & near_below


#: the open sky must reach within this many degrees of the horizon for :func:`horizon_band`
HORIZON_BAND_DEG = 4.0
#: ... the far measured ground below it within this many degrees under the horizon ...
HORIZON_GROUND_DEG = 15.0
#: ... and the only edge between them (the horizon's) within this many degrees of the horizon
HORIZON_EDGE_DEG = 3.0
#: ... and the ground measured far on at least this share of the GROUND_BOX_PX square under
#: (and centred on the column of) the first measured pixel
GROUND_DENSITY = 0.5
GROUND_BOX_PX = 9


def horizon_band(
    sky: np.ndarray,
    separators: np.ndarray,
    measured: np.ndarray,
    disparity_px: np.ndarray,
    range_disparity_px: float,
    far_disparity_px: float,
    horizon_row_px: float,
    camera: Intrinsics,
    scale: int = 1,
    border_px: int = 8,
) -> np.ndarray:
    """(H, W) bool: the unmeasured pixels between open sky and far ground across the horizon.

    The horizon is a horizontal edge between the sky and ground too far away to have a
    disparity: stereo cannot match along it, and a real camera's noise drowns the faint texture
    of the far ground under it, so a band of several degrees around it stays without depth.
    That band is where a level flight's own altitude projects, at every distance: without it
    nothing shows the air beside and ahead of the drone free wherever the view is open, and
    the drone waits for its path to be seen (noisy delivery seed 0 hovered 30 s that way, its
    path ahead verified for 1.5 m, and turned back).

    A column's pixels from the bottom of its open sky (``sky``, reaching down from the top, to
    within :data:`HORIZON_BAND_DEG` of the horizon) down to its first ``measured`` pixel are
    taken when that pixel lies within :data:`HORIZON_GROUND_DEG` under the horizon with most
    of the :data:`GROUND_BOX_PX` square under it measured far (disparity at most
    ``far_disparity_px``; :data:`GROUND_DENSITY`), the matcher's values in the gap (measured
    or not) lie beyond the range (``range_disparity_px``), and the gap holds no
    ``separators`` (edges, texture) but one run within :data:`HORIZON_EDGE_DEG` of the
    horizon: the horizon's own edge. Anything nearer standing in the gap would bring edges of
    its own (a beam or a roof line across the sky) or a nearer measured pixel under it (the
    wall under a roof edge at the flight altitude, the street in front of a plain wall), or no
    measured pixel at all (``benchmarks/mission/probe_horizon_band.py``: on 1000 random views
    of ten cities, textured and plain, at 1.5 and 3 grey levels of noise, none of 8.6 million
    band pixels lay on anything within the range).
    What the rule cannot tell is an object as plain as the sky above and the ground below it
    whose edges merge with the horizon's (a wire along it), as stereo cannot anyway.

    Args:
        sky: (H, W) bool open sky (:func:`open_sky`), full resolution.
        separators: (h, w) bool pixels with texture or an edge at the reduced resolution
            (every ``scale``-th row and column, as the texture test computes them).
        measured: (H, W) bool measured pixels (after the texture test).
        disparity_px: (H, W) disparity, full-resolution pixels.
        range_disparity_px: the disparity at the map's range, pixels.
        far_disparity_px: the largest disparity that counts as far, pixels (the range's, less
            the disparity error: a surface just within the range measured a little off is not far).
        horizon_row_px: image row of the horizon, full resolution.
        camera: the full-resolution camera (its ``fy``).
        scale: the rule works on every ``scale``-th row and column (the resolution the matcher
            and the texture test work at) and repeats its answer over each ``scale`` square.
        border_px: columns this near the image's sides are left out (the separators' window
            filters see nothing beyond the image: a roof edge cut by the side went unseen).
    """
    H, W = sky.shape
    out = np.zeros((H, W), bool)
    k = int(scale)

    def row_at(deg: float) -> float:  # at the reduced resolution
        return (horizon_row_px + camera.fy * np.tan(np.radians(deg))) / k

    g = GROUND_BOX_PX
    r0 = max(0, int(np.floor(row_at(-HORIZON_BAND_DEG))))
    r1 = min(-(-H // k), int(np.floor(row_at(HORIZON_GROUND_DEG))) + g)
    if r1 - r0 < g + 2:
        return out
    # the band's rows at the reduced resolution (the matcher's and the texture test's)
    sky_k, sep_k = sky[r0 * k : r1 * k : k, ::k], separators[r0:r1]
    meas_k, disp_k = measured[r0 * k : r1 * k : k, ::k], disparity_px[r0 * k : r1 * k : k, ::k]
    h = sky_k.shape[0]
    rows = np.arange(h)[:, None]
    # the first row under the open sky that reaches down from the top of each column
    take = sky[0, ::k] & sky_k[0] & ~sky_k[-1]
    border = -(-border_px // k)
    take[:border] = take[len(take) - border :] = False  # the edge filters see nothing beyond the image
    cols = np.flatnonzero(take)
    if not len(cols):
        return out
    start = np.argmin(sky_k[:, cols], axis=0)
    below = meas_k[:, cols] & (rows >= start)
    stop = np.argmax(below, axis=0)
    ok = below[stop, np.arange(len(cols))] & (stop + g <= h)
    with np.errstate(invalid="ignore"):
        # far ground, not a speck of noise that passed the texture test: most of the box
        # under the first measured pixel is measured far
        far = (meas_k & (disp_k <= far_disparity_px)).view(np.uint8)
        density = cv2.boxFilter(far, cv2.CV_32F, (g, g), anchor=(g // 2, 0), borderType=cv2.BORDER_CONSTANT)
        ok &= density[np.minimum(stop, h - 1), cols] >= GROUND_DENSITY
        gap = (rows >= start) & (rows < stop)
        # the matcher's guesses in the gap too: nothing within the range
        ok &= ~np.any(gap & (disp_k[:, cols] > range_disparity_px), axis=0)
    edge = sep_k[:, cols] & gap
    # the texture of the far ground fades in above its first measured pixel: not an edge
    plain = gap & ~edge
    last_plain = np.where(plain.any(axis=0), h - 1 - np.argmax(plain[::-1], axis=0), start - 1)
    edge &= rows <= last_plain
    runs = np.count_nonzero(edge[1:] & ~edge[:-1], axis=0) + edge[0]
    off_horizon = np.abs(rows + r0 - row_at(0.0)) > camera.fy * np.tan(np.radians(HORIZON_EDGE_DEG)) / k
    ok &= (runs <= 1) & ~np.any(edge & off_horizon, axis=0)
    if not ok.any():
        return out
    band = np.zeros((h, len(take)), bool)
    band[:, cols[ok]] = gap[:, ok]
    full = _upsample_mask(band, k, (h * k, W)) if k > 1 else band
    out[r0 * k : r0 * k + full.shape[0]] = full[: H - r0 * k]
    return out


#: the ground prior's band at a plain segment's border: this many times the matcher's disparity
#: error (``disparity_error_px``) ...
GROUND_TOLERANCE_ERRORS = 2.0
#: ... plus this share of the ground's disparity (the ground level's own error, a few per cent
#: of the drone's height)
GROUND_TOLERANCE_REL = 0.05
#: the ground prior's open air keeps at least this share of the camera's height above the
#: ground: an object standing on the ground h_o high differs from it by h_o / (h - h_o) of the
#: disparity, so the band above lets through objects up to about 12 % of the height h (at the
#: map's range, 2.8 px of disparity at half resolution, the band is 14 %)
GROUND_CLEARANCE_SHARE = 0.15
#: the ground prior's open air keeps this far (pixels of the depth grid, a 5 x 5 erosion) inside
#: its segments: the outermost rows of a segment can graze what bounds it (the truth probe, noise 3,
#: city 29: 8 pixels of a road's segment on the top edge of a tree's crown 15 m away), the image's
#: border included: what bounds a segment there is out of view (city 39 at 3 grey levels: a
#: sliver of a plain roof in the image's first 3 columns)
GROUND_INSET_KERNEL = np.ones((5, 5), np.uint8)
#: ... and off the pixels straight below a measured pixel nearer than the ground by more than
#: this many times its band (:func:`~skyrecon.perception.ground_plane.below_raised`): under
#: noise the edge between a plain roof or platform and the street beyond it can vanish, one
#: segment then holds both, and most of its border still agrees with the ground (the truth
#: probe, noise 3, city 29: a plain roof 10 m away merged with the street under it, 1275
#: pixels of open air through it) ...
GROUND_RAISED_BANDS = 2.0
#: ... those measured pixels grown by this kernel first (rows x columns of the depth grid): the
#: plane fill's segments keep a seal of a few pixels off measured pixels, and a roof's far edge
#: is measured in pieces, least near its corners (city 29's roof: its last 6-8 columns)
GROUND_RAISED_KERNEL = np.ones((9, 17), np.uint8)
#: ... and the pixels below them followed through holes in the segment up to this wide (depth-
#: grid pixels: the specks a noisy matcher measures inside a plain surface, with their seal)
GROUND_RAISED_HOLES_PX = 12
#: ... and this far beside them along the rows (depth-grid pixels): a raised top's far edge is
#: measured in pieces and its sides not at all (they border ground beyond, as the ground would),
#: so a column's reach leaves the top's ends in the open (the truth probe: city 29's roof, its
#: last 6-8 columns; city 34 at 1.5 grey levels, a roof's last 13 columns at the image's border;
#: twice the worst). Whole rows of the segment cost half the open air (and deliveries).
GROUND_RAISED_ASIDE_PX = 26


#: the near ranges whose specks :func:`near_specks` drops, metres: each range's blobs are judged
#: by the pixel area at that range (the largest a pixel nearer covers)
NEAR_SPECK_RANGES_M = (5.0, 2.5)


def near_specks(
    depth_m: np.ndarray, fx_px: float, focal_baseline_px_m: float, min_area_m2: float
) -> np.ndarray:
    """(h, w) bool: the finite ``depth_m`` pixels (metres along the axis; NaN, inf ignored)
    in blobs too small to be anything near the camera. A blob is a set of 8-connected pixels
    whose disparities (``focal_baseline_px_m / depth``, pixels) step by at most 1 pixel; for
    each range ``r`` of :data:`NEAR_SPECK_RANGES_M`, a blob of the pixels nearer than ``r``
    covering less than ``min_area_m2`` (square metres, each pixel ``(r / fx_px)^2`` at most)
    is a speck. Under a camera's noise a few pixels on plain sky or ground pass the texture
    test and match at a large disparity: specks 1.6-4 m from a hovering drone (noisy plain
    delivery seeds 1 and 8, session 49), each a phantom obstacle inside its clearance that no
    later ray clears (nothing behind it is measured), until the drone could not plan. Anything
    real that near is a blob of hundreds of pixels (a 2 cm wire 30 cm long at 2.5 m: 60)."""
    out = np.zeros(depth_m.shape, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        finite = np.isfinite(depth_m)
        q = np.where(finite, 16.0 * focal_baseline_px_m / depth_m, -1.0)
    for r in NEAR_SPECK_RANGES_M:
        near = finite & (depth_m < r)
        if not near.any():
            continue
        smallest = int(math.ceil(min_area_m2 / (r / fx_px) ** 2))  # pixels of the smallest blob kept
        blobs = np.where(near, np.minimum(q, 32000.0), -1.0).astype(np.int16)
        cv2.filterSpeckles(blobs, -1, smallest - 1, 16)  # blobs of < smallest pixels become -1
        out |= near & (blobs < 0)
    return out


def _upsample_mask(mask: np.ndarray, k: int, shape: tuple[int, ...]) -> np.ndarray:
    """(H, W) = ``shape`` bool: each pixel of ``mask`` repeated k x k times (cropped)."""
    H, W = shape[0], shape[1]
    h, w = mask.shape
    big = cv2.resize(
        np.ascontiguousarray(mask).view(np.uint8), (w * k, h * k), interpolation=cv2.INTER_NEAREST
    )
    return big[:H, :W].view(bool)


#: the fine matcher's disparity must exceed the coarse one by this much to count, pixels
FINE_MIN_GAIN_PX = 0.5
#: a fine match is ambiguous when a farther disparity (2 or more pixels less) costs less than
#: this factor times its own cost (plus this, grey levels): the aliases of a periodic texture
AMBIGUITY_RATIO = 1.2
#: :meth:`PairMatches.region_alias_ratio` looks at most at this many depth-grid pixels of a region
ALIAS_REGION_PX = 400
#: :meth:`PairMatches.region_alias_ratio` judges only a region whose median cost over all
#: shifts is at least this many times its own (plus one grey level): a periodic patch has deep
#: valleys between high costs; a region plain along the rows matches about as well everywhere.
#: Session 57: noise-free dynamic seed 118 met a drone on a collision course whose clusters,
#: plain along the rows, were all called aliases (ratio 0.53-0.98, median / own 0.67-1.84):
#: it flew into the drone. On noisy seed 103 this keeps all 81 clusters on a mover (7 were
#: dropped before) and still drops 110 of the 171 elsewhere (132 before).
ALIAS_MIN_DISTINCT = 2.0


def unambiguous_matches(
    left: np.ndarray,
    right: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    disparity_px: np.ndarray,
    n_disparities: int,
    block_px: int,
) -> np.ndarray:
    """(N,) bool: which left-image matches have no near-equal alternative farther away.

    A block matcher on a periodic texture (rows of windows 40 m away) may pick an alias some
    pixels off the true disparity, a phantom surface metres in front of the facade. Per pixel,
    the zero-mean sum of absolute differences of the ``block_px`` window is computed for every
    integer disparity ``0 .. n_disparities - 1``; the match is kept when every disparity at
    least 2 pixels smaller costs more than ``AMBIGUITY_RATIO`` times (its cost + 1). On recorded
    frames this kept 76-90 % of the pixels of drones 13-20 m away and removed 8 of 10 phantom
    clusters whole.

    Args:
        left, right: (H, W) uint8 grey rectified images.
        rows, cols: (N,) int pixel coordinates in ``left``.
        disparity_px: (N,) their disparities, pixels.
        n_disparities: the disparities tried; block_px: odd window side, pixels.
    """
    n = len(rows)
    disp = np.asarray(disparity_px, np.float64)
    if n == 0 or not np.isfinite(disp).any():
        return np.zeros(n, bool)
    H, W = left.shape
    off = np.arange(block_px) - block_px // 2
    rr = np.clip(rows[:, None] + off, 0, H - 1)[:, :, None]  # (N, B, 1)
    lp = left[rr, np.clip(cols[:, None] + off, 0, W - 1)[:, None, :]].astype(np.float32)
    lp -= lp.mean(axis=(1, 2), keepdims=True)
    # only the disparities up to the largest own one (and the one above it) are compared
    n_eval = int(min(n_disparities, max(np.floor(np.nanmax(disp)), 0) + 2))
    costs = np.full((n, n_disparities), np.inf, np.float32)
    for d in range(n_eval):
        rp = right[rr, np.clip(cols[:, None] - d + off, 0, W - 1)[:, None, :]].astype(np.float32)
        rp -= rp.mean(axis=(1, 2), keepdims=True)
        costs[:, d] = np.abs(lp - rp).mean(axis=(1, 2))
    finite = np.isfinite(disp)
    lo = np.clip(np.floor(np.where(finite, disp, 0.0)).astype(np.intp), 0, n_disparities - 1)
    hi = np.minimum(lo + 1, n_disparities - 1)
    idx = np.arange(n)
    own = np.minimum(costs[idx, lo], costs[idx, hi])
    farther = np.arange(n_disparities)[None, :] <= disp[:, None] - 2.0
    best_farther = np.where(farther, costs, np.inf).min(axis=1)
    return finite & (best_farther > AMBIGUITY_RATIO * (own + 1.0))


@dataclass(eq=False)
class PairMatches:
    """The disparities behind a depth frame and the pair they were matched from, to check a few
    of them for aliases on demand (:meth:`unambiguous` per pixel, :meth:`region_alias_ratio` per
    region; the grey pair is made on first use, unless the pair is grey already).

    Attributes:
        disparity_px: (h, w) float32 disparity of each depth-grid pixel, full-resolution pixels
            (the matcher's, or the plane fill's where it filled; NaN none).
        left, right: the rectified pair as given to :meth:`StereoDepth.compute` ((H, W, 3) RGB
            or (H, W) grey).
        stride: the depth grid is ``[::stride, ::stride]`` of the full image.
        n_disparities, block_px: the disparities compared and the window, pixels.
    """

    disparity_px: np.ndarray
    left: np.ndarray
    right: np.ndarray
    stride: int
    n_disparities: int
    block_px: int

    def __post_init__(self) -> None:
        grey = all(x.ndim == 2 and x.dtype == np.uint8 for x in (self.left, self.right))
        self._grey: tuple[np.ndarray, np.ndarray] | None = (self.left, self.right) if grey else None

    def grey(self) -> tuple[np.ndarray, np.ndarray]:
        """The (H, W) uint8 grey pair (made once)."""
        if self._grey is None:
            pair = prepare_pair(np.asarray(self.left), np.asarray(self.right))
            self._grey = (pair.left_grey, pair.right_grey)
        return self._grey

    def unambiguous(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N,) bool for depth-grid pixels (N,) (rows, cols): see :func:`unambiguous_matches`
        (False where there is no disparity)."""
        r = np.asarray(rows, np.intp)
        c = np.asarray(cols, np.intp)
        k = self.stride
        return unambiguous_matches(
            *self.grey(), r * k, c * k, self.disparity_px[r, c], self.n_disparities, self.block_px
        )

    def region_alias_ratio(self, rows: np.ndarray, cols: np.ndarray) -> float:
        """How much worse the best farther match of a whole region is than its own: a region
        (depth-grid pixels (N,) ``rows``, ``cols``, each its ``stride`` x ``stride`` block of
        full-resolution pixels; at most :data:`ALIAS_REGION_PX` of them, evenly spread) is
        shifted as one by every disparity in the right image; ``own`` is the lowest mean
        absolute difference (each side less its mean) within a pixel of its median disparity,
        ``farther`` the lowest at least 2 pixels smaller. Returns ``farther / (own + 1)``
        (inf when nothing is farther or no pixel has a disparity, and when the region is not
        distinctive: its median cost over all shifts below :data:`ALIAS_MIN_DISTINCT` times
        ``own + 1``).

        Why a region: a patch of a periodic texture (rows of windows, a zebra crossing)
        matched a period off is matched as well, as a whole, at the true disparity (ratio
        near 1 or below), while an object in front of a background is not: the region's
        outline moves against what lies behind it (a drone's panels, plain along the rows,
        match anywhere pixel by pixel, but not as a whole). A region that matches about as
        well at most shifts (the inside of a drone whose panels are banded along the rows,
        left without its outline by the depth-edge test) says nothing either way: it is not
        called an alias (a mover missed is worse than a phantom)."""
        r = np.asarray(rows, np.intp)
        c = np.asarray(cols, np.intp)
        if r.size > ALIAS_REGION_PX:
            pick = np.linspace(0, r.size - 1, ALIAS_REGION_PX).astype(np.intp)
            r, c = r[pick], c[pick]
        disp = self.disparity_px[r, c]
        disp = disp[np.isfinite(disp)]
        if disp.size == 0:
            return float("inf")
        d_own = float(np.median(disp))
        if d_own < 2.0:
            return float("inf")
        left, right = self.grey()
        k = self.stride
        dy, dx = np.divmod(np.arange(k * k), k)
        ys = np.minimum((r[:, None] * k + dy).reshape(-1), left.shape[0] - 1)
        xs = np.minimum((c[:, None] * k + dx).reshape(-1), left.shape[1] - 1)
        lv = left[ys, xs].astype(np.float32)
        top = min(int(math.ceil(d_own)) + 1, self.n_disparities - 1)
        costs = np.full(top + 1, np.inf)
        a_all = lv - lv.mean()
        for d in range(top + 1):
            if d <= xs.min():  # every pixel has its match in the image
                a, yd, xd = a_all, ys, xs - d
            else:
                ok = xs >= d
                if not ok.any():
                    continue
                a, yd, xd = lv[ok] - lv[ok].mean(), ys[ok], xs[ok] - d
            b = right[yd, xd].astype(np.float32)
            costs[d] = float(np.abs(a - (b - b.mean())).mean())
        own = costs[max(int(math.floor(d_own)) - 1, 0) :].min()  # within a pixel of the median
        if np.median(costs[np.isfinite(costs)]) < ALIAS_MIN_DISTINCT * (own + 1.0):
            return float("inf")  # matched about as well at most shifts: nothing to judge by
        farther = costs[: int(math.floor(d_own - 2.0)) + 1].min()
        return float(farther / (own + 1.0))


@dataclass(eq=False)
class FineDepth(PairMatches):
    """The full-resolution block matcher's view of one pair, on the depth grid: its matches
    (:class:`PairMatches`, ``left`` and ``right`` the grey pair) and their depth.

    Attributes:
        depth_m: (h, w) float32 depth where the block matcher sees a surface nearer than the
            coarse matcher (or where that has none), metres; NaN elsewhere. Not yet checked for
            ambiguity: :meth:`unambiguous` does that for the pixels a user keeps (it costs
            about 10 microseconds a pixel, too much for every pixel of every frame).
        disparity_px: (h, w) float32 its disparity there, full-resolution pixels (NaN elsewhere).
        n_disparities, block_px: the block matcher's disparity range and window.
    """

    depth_m: np.ndarray


@dataclass(eq=False)
class DepthFrame:
    """The depth of one stereo pair, ready for the map.

    Attributes:
        depth_m: (h, w) float32 depth along the left optical axis, metres, NaN where not kept,
            +inf for matches beyond any range when ``sky_is_free``; (h, w) is the image size
            divided by the depth stride.
        intrinsics: the camera of ``depth_m``.
        disparity: (H, W) float32 full-resolution disparity of the matcher, pixels, NaN invalid.
        measured_fraction: share of pixels with a measured disparity.
        stereo_ms: wall-clock milliseconds of matching and conversion.
        plane_fraction: share of pixels that got a plane-supported disparity (``plane_fill``).
        guess_depth_m: with ``guesses``, (h, w) float32 depth of the matcher's values that
            ``depth_m`` does not keep (filled, or measured on no texture), away from depth
            edges, metres; NaN elsewhere. Evidence of a surface, but not of free space.
        fine: with ``fine_max_disparity``, the full-resolution block matcher's depth where it
            sees a surface nearer than the matcher's (:class:`FineDepth`): for small near objects
            the half-resolution matcher lost (the mover tracker), not for the map.
        image_noise_sigma: the left image's noise, grey levels, as given to
            :meth:`StereoDepth.compute` or measured there for the texture test (None: neither).
        from_ground: with a ground plane given to :meth:`StereoDepth.compute` and the plane
            fill, (h, w) bool: the pixels of ``depth_m`` that took the ground's plane (not
            measured: not evidence of where the ground lies; with ``ground_range_m`` they are
            +inf or NaN in ``depth_m``). None otherwise.
        matches: the disparities of ``depth_m``'s grid and the pair (:class:`PairMatches`), for
            checking a few pixels for aliases of a periodic texture (the mover tracker's
            clusters).
        from_plane: with the plane fill, (h, w) bool: the pixels of ``depth_m`` that took a
            plane (their own segment's or the ground's), not measured there. None otherwise.
    """

    depth_m: np.ndarray
    intrinsics: Intrinsics
    disparity: np.ndarray
    measured_fraction: float
    stereo_ms: float
    plane_fraction: float = 0.0
    guess_depth_m: np.ndarray | None = None
    fine: FineDepth | None = None
    image_noise_sigma: float | None = None
    from_ground: np.ndarray | None = None
    matches: PairMatches | None = None
    from_plane: np.ndarray | None = None


class StereoDepth:
    """A reusable stereo-to-depth stage for one rectified rig.

    Args:
        rig: the rectified rig the pairs come from (``rig.left`` is the depth's camera).
        settings: the rules (default :meth:`PerceptionSettings.mapping`).
        matcher: optional matcher to use instead of building one from the settings (e.g. one
            already warmed up by another stage); otherwise built and warmed up on first use.
    """

    def __init__(
        self, rig: StereoRig, settings: PerceptionSettings | None = None, matcher: Matcher | None = None
    ):
        if not rig.is_rectified:
            raise InputError("the stereo rig is not rectified; stereo depth needs a rectified pair")
        self.rig = rig
        self.settings = settings or PerceptionSettings.mapping()
        self.stride = int(self.settings.depth_stride)
        self.intrinsics = strided_intrinsics(rig.left, self.stride)
        self._matcher = matcher
        self._unit_rays: np.ndarray | None = None  # (h, w, 3) of the depth grid, made on first use
        self._fine: OpenCVBMMatcher | None = None
        # the disparity at the map's range (``horizon_far_m``, else SKY_NEAR_RANGE_M), full-
        # resolution pixels: what frames a sky segment from below, and the horizon band's range
        self._range_px = float(
            self.rig.depth_to_disparity(np.array([self.settings.horizon_far_m or SKY_NEAR_RANGE_M]))[0]
        )
        if self.settings.fine_max_disparity:
            self._fine = OpenCVBMMatcher(
                int(self.settings.fine_max_disparity),
                settings=OpenCVBMSettings(
                    block_size=int(self.settings.fine_block_px),
                    pre_filter_type="xsobel",
                    texture_threshold=5,
                    uniqueness_ratio=10,
                    speckle_window_size=20,  # drops specks of fewer pixels: a far drone has 150 or more
                    speckle_range=2,
                ),
            )

    @property
    def matcher(self) -> Matcher:
        """The stereo matcher (created, and warmed up, on first use)."""
        if self._matcher is None:
            s = self.settings
            self._matcher = create_matcher(s.method, int(s.max_disparity), **s.matcher_kwargs())
            warmup = getattr(self._matcher, "warmup", None)
            if warmup is not None:
                warmup()
        return self._matcher

    def warm_up(self) -> None:
        """Build (and warm up) the matcher and load the kernels of the plane fill and the
        ground prior, which a noisy frame's depth runs: a flight calls this before its first
        cycle, which would otherwise pay their loading (about 50 ms)."""
        _ = self.matcher
        warm_plane_fill()
        warm_ground_plane()

    def compute(
        self,
        left: np.ndarray,
        right: np.ndarray,
        after_match: Callable[[], object] | None = None,
        noise_sigma: float | None = None,
        horizon_row_px: float | None = None,
        ground: GroundPlane | None = None,
    ) -> DepthFrame:
        """Depth of one rectified pair, each (H, W, 3) uint8 RGB (or (H, W) grey).

        ``after_match``, if given, is called once the matcher is done and before the rest (the
        texture masks, the plane fill and the conversion to depth, single-threaded): the
        moment to start other work on another thread without slowing the matcher, which uses
        every core (:class:`skyrecon.mapping.StereoMapper` integrates the previous frame then).
        ``noise_sigma``: the left image's noise, grey levels, if already measured (the mission's
        health check does); otherwise measured here when the texture test (``min_texture``
        with ``noise_aware_texture``) or the skyrecon matcher's census tolerance needs it.
        ``horizon_row_px``: the image row of the horizon (rows above it look up; the camera
        level, not rolled: ``cy - fy tan(pitch down)``). With ``sky_is_free`` and a texture
        test that drops pixels, a plain segment that reaches the top of the image and lies
        wholly above the horizon (:data:`SKY_MARGIN_DEG`) is open sky: no return up to the
        map's range. On a noise-free render the matcher finds the sky at disparity 0 from the
        faint steps of its gradient; a real camera's noise drowns them, and without this rule
        nothing would show the air ahead of a flying drone free. A plain facade reaches below
        the horizon (it stands on the ground) and is not taken for sky. With
        ``horizon_far_m`` too, the unmeasured band across the horizon between open sky and
        ground measured beyond that range is open air as well (:func:`horizon_band`).
        """
        t0 = time.perf_counter()
        self.rig.left.check_image(np.asarray(left), "left image")
        s = self.settings
        noise = None if noise_sigma is None else float(noise_sigma)
        grey_left = None  # converted once for the noise, the texture masks and the plane fill
        if noise is None and self._needs_noise:
            grey_left = to_grey(np.asarray(left))
            noise = image_noise_sigma(grey_left)
        if isinstance(self.matcher, SkyreconMatcher):
            result = self.matcher.compute(left, right, noise_sigma=noise)
        else:
            result = self.matcher.compute(left, right)
        if after_match is not None:
            after_match()
        measured = result.measured
        tex = None  # the texture test, when it takes pixels out (else no plain segment to fill)
        if self._texture_applies(noise):
            grey_left = to_grey(np.asarray(left)) if grey_left is None else grey_left
            tex = self._texture(grey_left, noise)
            measured = measured & self._full(tex.matchable)
            if s.sky_is_free and horizon_row_px is not None:
                separators = self._separators(tex)
                measured_k, near_k = self._measured_and_near_on_grid(measured, result.disparity)
                sky = open_sky(
                    separators,
                    horizon_row_px,
                    self.rig.left,
                    int(s.texture_scale),
                    measured.shape,
                    measured=measured_k,
                    near=near_k,
                )
                if sky.any() and s.horizon_far_m is not None:
                    band = horizon_band(
                        sky,
                        separators,
                        measured,
                        result.disparity,
                        self._range_px,
                        self._range_px - 2.0 * s.disparity_error_px,
                        horizon_row_px,
                        self.rig.left,
                        int(s.texture_scale),
                        (int(s.texture_window_px) // 2 + 1) * int(s.texture_scale),
                    )
                    sky = sky | band
                if sky.any():
                    measured = measured | sky
                    sky_disparity = np.float32(-self.rig.doffs_px)
                    result = replace(result, disparity=np.where(sky, sky_disparity, result.disparity))
        keep = result.valid if s.use_filled else measured
        edge = None
        if s.max_disparity_step_px is not None:
            edge = disparity_discontinuities(result.disparity, s.max_disparity_step_px)
            keep = keep & ~edge
        disp = result.disparity
        plane = 0.0
        from_ground = from_plane = None
        if s.plane_fill and not s.use_filled and (tex is not None or s.min_texture is None):
            grey_left = grey_left if grey_left is not None else to_grey(np.asarray(left))
            disp, accepted, on_ground = self._plane_fill(disp, measured, tex, grey_left, right, ground)
            keep = keep | accepted
            plane = float(np.count_nonzero(accepted) / accepted.size)
            from_plane = accepted[:: self.stride, :: self.stride]
            from_ground = None if on_ground is None else on_ground[:: self.stride, :: self.stride]
        k = self.stride
        # one conversion for the kept pixels and the guesses (+inf: sky, only ever kept)
        all_depth = self._depth(disp[::k, ::k], s.sky_is_free)
        nan = np.float32(np.nan)
        guess = None
        if s.guesses:
            # the matcher's other values (filled, or smoothed over plain surfaces): not depth edges
            g = result.valid & ~keep if edge is None else result.valid & ~keep & ~edge
            guess = np.where(g[::k, ::k] & np.isfinite(all_depth), all_depth, nan)
        depth = np.where(keep[::k, ::k], all_depth, nan)
        if from_ground is not None and ground is not None and s.ground_range_m is not None:
            # open air only inside the segments: their outer pixels may graze what bounds them
            inner = cv2.erode(
                np.ascontiguousarray(from_ground).view(np.uint8),
                GROUND_INSET_KERNEL,
                borderType=cv2.BORDER_CONSTANT,
                borderValue=0,
            ).view(bool)
            hidden = self._below_raised(ground, result.disparity[::k, ::k], measured[::k, ::k], from_ground)
            depth[from_ground] = nan
            depth[inner & ~hidden & self._clear_of_ground(ground)] = np.inf
        if tex is not None and s.near_speck_area_m2 is not None:
            fb = self.intrinsics.fx * self.rig.baseline_m
            depth[near_specks(depth, self.intrinsics.fx, fb, s.near_speck_area_m2)] = nan
        fine = None if self._fine is None else self._fine_depth(left, right, result.disparity)
        ms = 1e3 * (time.perf_counter() - t0)
        return DepthFrame(
            depth,
            self.intrinsics,
            result.disparity,
            float(np.count_nonzero(measured) / measured.size),
            ms,
            plane,
            guess,
            fine,
            noise,
            from_ground,
            PairMatches(  # the fine depth's grey pair, when there is one, serves for both
                disp[::k, ::k],
                left if fine is None else fine.left,
                right if fine is None else fine.right,
                k,
                int(s.max_disparity),
                int(s.fine_block_px),
            ),
            from_plane,
        )

    def _plane_fill(
        self,
        disp: np.ndarray,
        measured: np.ndarray,
        tex: _TextureTest | None,
        grey_left: np.ndarray,
        right: np.ndarray,
        ground: GroundPlane | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """:func:`~skyrecon.stereo.plane_supported_fill` of the (H, W) disparity, its segments
        bounded by the texture test's edges (``tex``; None: no test): ``(disp, accepted,
        on_ground)``, the disparity with the accepted segments' planes, the (H, W) bool mask of
        those pixels and, with ``ground`` (the prior plane), the (H, W) mask of those that took
        the ground's (None without).
        With the texture test and the depth both at ``k = texture_scale = depth_stride`` > 1
        (the flight loop), the fill runs on that grid (disparities and pixel tolerances divided
        by k, the test's reduced images): the only pixels the depth keeps, a quarter of the
        work."""
        s = self.settings
        k = int(s.texture_scale)
        step = s.max_disparity_step_px or 1.0
        floor = self._ground_horizon_px
        if tex is None or k == 1 or k != self.stride:
            prior = None if ground is None else ground.disparity_coefficients(self.rig)
            on_prior = None if prior is None else np.zeros(disp.shape, bool)
            planar, accepted = plane_supported_fill(
                disp,
                measured,
                boundary=None if tex is None else self._full(tex.edges),
                left=grey_left,
                right=to_grey(np.asarray(right)),
                tolerance_px=s.plane_tolerance_px,
                min_inlier_fraction=s.plane_min_inlier_fraction,
                max_guess_gap_px=s.plane_max_guess_gap_px,
                max_step_px=step,
                prior_plane=prior,
                prior_min_disparity=floor,
                prior_tolerance_px=GROUND_TOLERANCE_ERRORS * s.disparity_error_px,
                prior_tolerance_rel=GROUND_TOLERANCE_REL,
                min_support_area_px=int(s.plane_min_support_px),
                open_borders=s.plane_open_borders,
                prior_guess_check=s.plane_prior_guess_check,
                prior_mask=on_prior,
            )
            return np.where(accepted, planar, disp), accepted, on_prior
        H, W = disp.shape
        gap = s.plane_max_guess_gap_px
        prior = None if ground is None else ground.disparity_coefficients(self.rig, k)
        small_ground = None if prior is None else np.zeros(measured[::k, ::k].shape, bool)
        planar, small = plane_supported_fill(
            disp[::k, ::k] / np.float32(k),
            measured[::k, ::k],
            boundary=tex.edges,
            left=tex.grey,
            right=self._reduced(to_grey(np.asarray(right))),
            tolerance_px=s.plane_tolerance_px / k,
            min_inlier_fraction=s.plane_min_inlier_fraction,
            max_guess_gap_px=None if gap is None else gap / k,
            max_step_px=step / k,
            prior_plane=prior,
            prior_min_disparity=floor / k,
            prior_tolerance_px=GROUND_TOLERANCE_ERRORS * s.disparity_error_px / k,
            prior_tolerance_rel=GROUND_TOLERANCE_REL,
            min_support_area_px=int(s.plane_min_support_px) // (k * k),
            open_borders=s.plane_open_borders,
            prior_guess_check=s.plane_prior_guess_check,
            prior_mask=small_ground,
        )
        out = disp.copy()
        out[::k, ::k] = np.where(small, planar * np.float32(k), out[::k, ::k])
        accepted = np.zeros((H, W), bool)
        accepted[::k, ::k] = small
        on_ground = None
        if small_ground is not None:
            on_ground = np.zeros((H, W), bool)
            on_ground[::k, ::k] = small_ground
        return out, accepted, on_ground

    def _below_raised(
        self, ground: GroundPlane, matched: np.ndarray, measured: np.ndarray, from_ground: np.ndarray
    ) -> np.ndarray:
        """(h, w) bool on the depth grid: the pixels of ``from_ground`` straight below a
        ``measured`` pixel (both (h, w) bool) whose disparity ``matched`` ((h, w), full-
        resolution pixels) lies more than :data:`GROUND_RAISED_BANDS` times the ground prior's
        band above the ``ground``'s there, below the ground's horizon
        (:func:`~skyrecon.perception.ground_plane.below_raised`)."""
        s = self.settings
        k = self.stride
        a, b, c = ground.disparity_coefficients(self.rig)
        h, w = from_ground.shape
        ground_px = (
            np.float32(a * k) * np.arange(w, dtype=np.float32)[None, :]
            + np.float32(b * k) * np.arange(h, dtype=np.float32)[:, None]
            + np.float32(c)
        )
        band = GROUND_TOLERANCE_ERRORS * s.disparity_error_px + GROUND_TOLERANCE_REL * np.abs(ground_px)
        floor = self._ground_horizon_px
        with np.errstate(invalid="ignore"):
            raised = measured & (ground_px > floor) & (matched - ground_px > GROUND_RAISED_BANDS * band)
        grown = cv2.dilate(raised.view(np.uint8), GROUND_RAISED_KERNEL).view(bool)
        return below_raised(grown, from_ground, GROUND_RAISED_HOLES_PX, GROUND_RAISED_ASIDE_PX)

    def _measured_and_near_on_grid(
        self, measured: np.ndarray, disparity: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(measured, near)``, (h, w) bool at ``texture_scale``: the ``measured`` pixels
        ((H, W) bool), and those whose ``disparity`` ((H, W), full-resolution pixels) puts them
        nearer than the map's range (``horizon_far_m``, else :data:`SKY_NEAR_RANGE_M`); what
        :func:`open_sky` takes as ``measured`` and ``near``."""
        k = int(self.settings.texture_scale)
        on_grid = measured[::k, ::k]
        with np.errstate(invalid="ignore"):
            return on_grid, on_grid & (disparity[::k, ::k] > self._range_px)

    @property
    def _ground_horizon_px(self) -> float:
        """The ground's disparity at its horizon (full-resolution pixels): the ground is in view
        where its plane's disparity lies above this."""
        return max(0.0, -float(self.rig.doffs_px))

    def _clear_of_ground(self, ground: GroundPlane) -> np.ndarray:
        """(h, w) bool on the depth grid: the rays still ``ground_clearance_m`` (at least
        :data:`GROUND_CLEARANCE_SHARE` of the camera's height) above the ``ground`` at
        ``ground_range_m`` from the camera."""
        s = self.settings
        assert s.ground_range_m is not None
        if self._unit_rays is None:
            K = self.intrinsics
            v, u = np.mgrid[0 : K.height, 0 : K.width].astype(np.float64)
            rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1)
            self._unit_rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).astype(np.float32)
        clearance = max(float(s.ground_clearance_m), GROUND_CLEARANCE_SHARE * ground.height_m)
        rise = self._unit_rays @ np.asarray(ground.up_cam, np.float32)  # metres up per metre along
        return ground.height_m + float(s.ground_range_m) * rise >= clearance

    @property
    def _needs_noise(self) -> bool:
        """Whether a frame's noise is measured: for the noise-aware texture test or the
        skyrecon matcher's automatic census tolerance (``matcher_kwargs`` sets it only for
        the skyrecon matchers)."""
        s = self.settings
        texture = s.min_texture is not None and s.noise_aware_texture
        return texture or s.matcher_kwargs().get("census_tolerance", 0) is None

    def _texture_applies(self, noise: float | None) -> bool:
        """Whether the texture test can take a pixel out: ``min_texture`` above 0, or more
        noise at ``texture_scale`` than a noise-free image has (``min_texture`` 0, the flight
        loop: every pixel of a noise-free image passes, and nothing is computed)."""
        s = self.settings
        if s.min_texture is None:
            return False
        if s.min_texture > 0:
            return True
        k = int(s.texture_scale)
        return s.noise_aware_texture and noise is not None and excess_noise_sigma(noise / k) > 0

    def _texture(self, grey: np.ndarray, noise: float | None) -> _TextureTest:
        """The texture test (:func:`texture_masks`) of the full-resolution grey left image at
        ``texture_scale`` k, its noise there ``noise / k`` (``noise`` is the full image's; an
        area average of k x k pixels)."""
        s = self.settings
        k = int(s.texture_scale)
        g = self._reduced(grey)
        noise_k = None if noise is None else noise / k
        w = int(s.texture_window_px)
        gx, gy = _window_gradients(g.astype(np.float32), w)
        t_x, t_xy = _gradient_thresholds(
            float(s.min_texture or 0.0), noise_k if s.noise_aware_texture else None, w
        )
        return _TextureTest(g, noise_k, gx, gy, gx >= t_x, gx + gy >= t_xy)

    def _separators(self, tex: _TextureTest) -> np.ndarray:
        """(h, w) bool at ``texture_scale``: the texture test's pixels with texture or an edge that
        stands :data:`SKY_EDGE_NOISE_FACTOR` times farther above the noise than its own
        threshold; they separate the plain segments (:func:`open_sky`, :func:`horizon_band`)."""
        s = self.settings
        factor = SKY_EDGE_NOISE_FACTOR if s.noise_aware_texture else 1.0
        noise = None if tex.noise is None else tex.noise * factor
        _, t_xy = _gradient_thresholds(float(s.min_texture or 0.0), noise, int(s.texture_window_px))
        return tex.gx + tex.gy >= t_xy

    def _reduced(self, grey: np.ndarray) -> np.ndarray:
        """A full-resolution grey image at ``texture_scale`` k (an area average)."""
        k = int(self.settings.texture_scale)
        if k == 1:
            return grey
        H, W = grey.shape
        return cv2.resize(grey, (-(-W // k), -(-H // k)), interpolation=cv2.INTER_AREA)

    def _full(self, mask: np.ndarray) -> np.ndarray:
        """A mask at ``texture_scale`` k as a full-resolution (H, W) mask (each pixel k x k)."""
        k = int(self.settings.texture_scale)
        if k == 1:
            return mask
        H, W = self.rig.left.height, self.rig.left.width
        return _upsample_mask(mask, k, (H, W))

    def _fine_depth(self, left: np.ndarray, right: np.ndarray, coarse_px: np.ndarray) -> FineDepth:
        """The full-resolution block matcher's depth on the depth grid where it is nearer than
        the coarse matcher's disparity ``coarse_px`` (H, W) (or where that has none) and at least
        a quarter of its disparity range (:class:`FineDepth`)."""
        assert self._fine is not None
        pair = prepare_pair(np.asarray(left), np.asarray(right))
        k = self.stride
        disp = self._fine.compute(pair.left_grey, pair.right_grey).disparity[::k, ::k]  # NaN: no match
        n = int(self.settings.fine_max_disparity)
        with np.errstate(invalid="ignore"):
            keep = (disp >= n / 4) & ~(disp < coarse_px[::k, ::k] + FINE_MIN_GAIN_PX)
        disp = np.where(keep, disp, np.float32(np.nan))
        return FineDepth(
            disp,
            pair.left_grey,
            pair.right_grey,
            k,
            n,
            int(self.settings.fine_block_px),
            self._depth(disp, False),
        )

    def _depth(self, disp: np.ndarray, sky_is_free: bool) -> np.ndarray:
        """(h, w) float32 depth of full-resolution disparities (NaN kept), metres; with
        ``sky_is_free``, +inf where ``d + doffs <= 0``."""
        depth = self.rig.disparity_to_depth(disp)
        if sky_is_free:
            with np.errstate(invalid="ignore"):
                depth[np.isfinite(disp) & (disp + self.rig.doffs_px <= 0)] = np.inf
        return np.ascontiguousarray(depth, dtype=np.float32)

    def depth(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """(h, w) float32 depth of one pair, metres (see :meth:`compute`)."""
        return self.compute(left, right).depth_m
