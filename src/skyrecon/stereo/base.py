"""The matcher interface, its result type, input checks and the matcher registry.

Every dense stereo matcher takes a rectified pair and returns a :class:`DisparityResult`:

- images: (H, W, 3) uint8 RGB or (H, W) uint8 grey (uint16 accepted, see :func:`prepare_pair`),
  left and right of a rectified rig, same size;
- disparity: (H, W) float32 pixels, ``x_right = x_left - d``, NaN where there is no estimate.

Matchers are built by name with :func:`create_matcher` and are reusable across the frames of
a sequence (buffers and compiled code are kept between calls).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from skyrecon.errors import InputError

# --------------------------------------------------------------------------------------------
# result
# --------------------------------------------------------------------------------------------


@dataclass
class DisparityResult:
    """The output of a matcher.

    Attributes:
        disparity: (H, W) float32 left-view disparity in pixels, ``x_right = x_left - d``;
            NaN where the matcher gives no estimate.
        filled: (H, W) bool, True where the value was interpolated (occlusion / mismatch
            filling) rather than measured; all False for matchers that do not fill.
        method: the registered name of the matcher.
        min_disparity, max_disparity: the searched range ``min <= d < max``, pixels.
        timings_ms: wall-clock milliseconds per stage (``"total"`` included).
        diagnostics: numbers describing the run (fractions of pixels rejected by each check,
            density, the settings used...).
    """

    disparity: np.ndarray
    filled: np.ndarray
    method: str
    min_disparity: int
    max_disparity: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: pixels with a disparity (measured or filled)."""
        return np.isfinite(self.disparity)

    @property
    def measured(self) -> np.ndarray:
        """(H, W) bool: pixels with a measured (not interpolated) disparity."""
        return self.valid & ~self.filled

    @property
    def density(self) -> float:
        """Fraction of pixels with a disparity."""
        return float(np.mean(self.valid)) if self.disparity.size else 0.0

    @property
    def shape(self) -> tuple[int, int]:
        return self.disparity.shape


@runtime_checkable
class Matcher(Protocol):
    """A dense stereo matcher for rectified pairs.

    ``compute(left, right)`` takes (H, W, 3) uint8 RGB or (H, W) grey images of the same
    size and returns a :class:`DisparityResult`. The object may be reused for many frames.
    """

    name: str
    min_disparity: int
    max_disparity: int

    def compute(self, left: np.ndarray, right: np.ndarray) -> DisparityResult: ...


# --------------------------------------------------------------------------------------------
# input checks and conversions
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PreparedPair:
    """A validated pair: 8-bit grey images and, when both inputs had colour, 8-bit RGB."""

    left_grey: np.ndarray
    right_grey: np.ndarray
    left_rgb: np.ndarray | None
    right_rgb: np.ndarray | None
    converted_from_16bit: bool


def _check_image(image: Any, which: str) -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise InputError(f"the {which} image must be a numpy array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[..., :3]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        raise InputError(f"the {which} image has shape {image.shape}; expected (H, W) grey or (H, W, 3) RGB")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(
            f"the {which} image has dtype {image.dtype}; expected uint8 (or uint16), "
            "convert it (for floats in [0, 1]: (img * 255).round().astype(np.uint8))"
        )
    if image.shape[0] < 8 or image.shape[1] < 8:
        raise InputError(
            f"the {which} image is {image.shape[1]}x{image.shape[0]}; at least 8x8 pixels needed"
        )
    return image


def _to_8bit(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One linear map for both uint16 images: the joint 0.5..99.5 percentiles -> 0..255."""
    sample = np.concatenate([left[::4, ::4].ravel(), right[::4, ::4].ravel()])
    lo, hi = np.percentile(sample, [0.5, 99.5])
    if hi <= lo:
        lo, hi = float(sample.min()), float(sample.max())
    scale = 255.0 / max(hi - lo, 1.0)

    def conv(img: np.ndarray) -> np.ndarray:
        return np.clip((img.astype(np.float32) - lo) * scale + 0.5, 0, 255).astype(np.uint8)

    return conv(left), conv(right)


def to_grey(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (H, W) uint8 grey (ITU-R 601 luma, as OpenCV); grey passes."""
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def prepare_pair(left: np.ndarray, right: np.ndarray) -> PreparedPair:
    """Validate a rectified pair and convert it to what the matchers use.

    - Shapes: (H, W) grey, (H, W, 3) RGB (an alpha channel (H, W, 4) is dropped); both images
      must have the same height and width. A grey image may be paired with a colour one:
      both are then matched in grey.
    - dtypes: uint8, or uint16 for both images; 16-bit pairs are mapped to 8 bits with one
      linear map common to both images, from the joint 0.5 and 99.5 percentiles of their
      values to 0 and 255 (values outside are clipped), which keeps the brightness relation
      between the two images. Mixed 8/16-bit pairs are refused.

    Raises:
        InputError: naming the problem and what to do.
    """
    left = _check_image(left, "left")
    right = _check_image(right, "right")
    if left.shape[:2] != right.shape[:2]:
        raise InputError(
            f"the left image is {left.shape[1]}x{left.shape[0]} but the right one is "
            f"{right.shape[1]}x{right.shape[0]}; a rectified pair must have the same size "
            "(rectify both with the same rig first)"
        )
    if left.dtype != right.dtype:
        raise InputError(
            f"the left image is {left.dtype} but the right one is {right.dtype}; give both "
            "images the same bit depth"
        )
    converted = False
    if left.dtype == np.uint16:
        left, right = _to_8bit(left, right)
        converted = True
    both_colour = left.ndim == 3 and right.ndim == 3
    return PreparedPair(
        to_grey(left),
        to_grey(right),
        np.ascontiguousarray(left) if both_colour else None,
        np.ascontiguousarray(right) if both_colour else None,
        converted,
    )


def check_disparity_range(min_disparity: int, max_disparity: int, width: int | None = None) -> None:
    """Raise InputError unless ``min_disparity < max_disparity`` and the range fits the width."""
    if int(max_disparity) != max_disparity or int(min_disparity) != min_disparity:
        raise InputError(f"disparities must be whole pixels, got min {min_disparity}, max {max_disparity}")
    if max_disparity <= min_disparity:
        raise InputError(
            f"max_disparity ({max_disparity}) must be larger than min_disparity ({min_disparity})"
        )
    if width is not None and max_disparity - min_disparity >= width:
        raise InputError(
            f"the disparity range {min_disparity}..{max_disparity} ({max_disparity - min_disparity} "
            f"levels) is as wide as the image ({width} px); lower --max-disparity below the image width"
        )
    if width is not None and (max_disparity <= -width or min_disparity >= width):
        raise InputError(
            f"the disparity range {min_disparity}..{max_disparity} lies outside a {width}-pixel-wide image"
        )


# --------------------------------------------------------------------------------------------
# settings helpers
# --------------------------------------------------------------------------------------------


def settings_from_kwargs(cls: type, name: str, kwargs: dict[str, Any]):
    """Build the settings dataclass ``cls`` from keyword overrides, refusing unknown names."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(kwargs) - names)
    if unknown:
        raise InputError(
            f"unknown setting(s) {', '.join(unknown)} for matcher {name!r}; valid: {', '.join(sorted(names))}"
        )
    try:
        return cls(**kwargs)
    except TypeError as exc:  # pragma: no cover - dataclass signature errors
        raise InputError(f"bad settings for matcher {name!r}: {exc}") from None


class Stopwatch:
    """Collects stage timings in milliseconds."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.last = self.t0
        self.ms: dict[str, float] = {}

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.ms[stage] = self.ms.get(stage, 0.0) + (now - self.last) * 1e3
        self.last = now

    def total(self) -> dict[str, float]:
        self.ms["total"] = (time.perf_counter() - self.t0) * 1e3
        return self.ms


# --------------------------------------------------------------------------------------------
# registry
# --------------------------------------------------------------------------------------------

_REGISTRY: dict[str, tuple[Callable[..., Matcher], str]] = {}


def register_matcher(name: str, factory: Callable[..., Matcher], summary: str) -> None:
    """Register ``factory(max_disparity, min_disparity=..., **settings) -> Matcher`` under ``name``."""
    _REGISTRY[name] = (factory, summary)


def available_matchers() -> dict[str, str]:
    """Registered matcher names and one-line summaries."""
    _ensure_registered()
    return {k: v[1] for k, v in sorted(_REGISTRY.items())}


def _ensure_registered() -> None:
    # importing the modules registers their matchers; imported here, not at the top, because both
    # import this module (a real cycle: base <- sgm, opencv_matchers)
    from skyrecon.stereo import opencv_matchers, sgm  # noqa: F401


def create_matcher(
    name: str = "skyrecon", max_disparity: int = 128, *, min_disparity: int = 0, **settings: Any
) -> Matcher:
    """Build a matcher by name.

    Args:
        name: ``"skyrecon"`` (default: census + semi-global matching, most accurate),
            ``"skyrecon-fast"`` (the same at half resolution, for obstacle detection),
            ``"opencv-sgbm"`` or ``"opencv-bm"``. See :func:`available_matchers`.
        max_disparity: disparities searched are ``min_disparity <= d < max_disparity``, pixels.
        min_disparity: smallest disparity searched, pixels (may be negative).
        **settings: fields of the matcher's settings dataclass
            (:class:`~skyrecon.stereo.sgm.SkyreconSettings`,
            :class:`~skyrecon.stereo.opencv_matchers.OpenCVSGBMSettings`,
            :class:`~skyrecon.stereo.opencv_matchers.OpenCVBMSettings`), or ``settings=`` an
            instance of it.
    Raises:
        InputError: unknown name or setting, or an empty disparity range.
    """
    _ensure_registered()
    if name not in _REGISTRY:
        raise InputError(f"unknown stereo method {name!r}; choose one of {', '.join(sorted(_REGISTRY))}")
    check_disparity_range(min_disparity, max_disparity)
    return _REGISTRY[name][0](int(max_disparity), min_disparity=int(min_disparity), **settings)
