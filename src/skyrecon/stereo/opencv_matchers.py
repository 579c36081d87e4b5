"""OpenCV's block matcher and semi-global block matcher behind the :class:`Matcher` interface.

Every OpenCV option is a typed field of a settings dataclass; names follow OpenCV's
(``numDisparities`` is derived from the disparity range). OpenCV returns 16x fixed-point
disparities with ``(minDisparity - 1) * 16`` for "no match"; here they become float32 pixels
with NaN.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal, TypeVar

import cv2
import numpy as np

from skyrecon.errors import InputError
from skyrecon.stereo.base import (
    DisparityResult,
    Stopwatch,
    check_disparity_range,
    prepare_pair,
    register_matcher,
    settings_from_kwargs,
)

SGBMMode = Literal["sgbm", "hh", "sgbm_3way", "hh4"]
_SGBM_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}
BMPreFilter = Literal["xsobel", "normalized_response"]
_BM_PREFILTERS = {
    "xsobel": cv2.STEREO_BM_PREFILTER_XSOBEL,
    "normalized_response": cv2.STEREO_BM_PREFILTER_NORMALIZED_RESPONSE,
}


#: The reference OpenCV SGBM configuration our stereo error ratios are measured against
#: (``create_matcher("opencv-sgbm", D, **SGBM_REFERENCE)``): SGBM_3WAY, block 5,
#: P1 = 8*3*5^2, P2 = 32*3*5^2, uniqueness 10, speckle window 100 / range 2, disp12MaxDiff 1, colour.
SGBM_REFERENCE: dict[str, object] = dict(
    mode="sgbm_3way",
    block_size=5,
    P1=8 * 3 * 5**2,
    P2=32 * 3 * 5**2,
    uniqueness_ratio=10,
    speckle_window_size=100,
    speckle_range=2,
    disp12_max_diff=1,
    use_colour=True,
)


def num_disparities_for(min_disparity: int, max_disparity: int) -> int:
    """OpenCV's ``numDisparities``: the range ``max - min`` rounded up to a multiple of 16."""
    n = max_disparity - min_disparity
    return int(-(-n // 16) * 16)


def _check_int(
    name: str, value: Any, lo: int | None = None, hi: int | None = None, odd: bool = False
) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"setting {name} must be an integer, got {value!r}")
    if lo is not None and value < lo:
        raise InputError(f"setting {name} must be at least {lo}, got {value}")
    if hi is not None and value > hi:
        raise InputError(f"setting {name} must be at most {hi}, got {value}")
    if odd and value % 2 == 0:
        raise InputError(f"setting {name} must be odd, got {value}")


@dataclass(frozen=True)
class OpenCVSGBMSettings:
    """All options of ``cv2.StereoSGBM`` (see OpenCV's documentation).

    Attributes:
        block_size: matched block size, odd, >= 1 (3..11 is typical).
        P1: penalty of a disparity change of 1 between neighbours; None -> ``8 * cn * block_size**2``
            (cn = 3 for colour matching, 1 for grey).
        P2: penalty of larger changes (> P1); None -> ``32 * cn * block_size**2``.
        disp12_max_diff: left-right check tolerance in pixels; negative disables it.
        pre_filter_cap: clip of the x-derivative pre-filter (1..63); 0 lets OpenCV pick (15),
            as ``cv2.StereoSGBM_create`` does by default.
        uniqueness_ratio: margin in percent by which the best cost must win (0 disables).
        speckle_window_size: largest speckle (connected region) removed, pixels; 0 disables.
        speckle_range: largest disparity step within a connected region, pixels (OpenCV
            multiplies it by 16 internally).
        mode: ``"sgbm"`` (5 directions), ``"hh"`` (full 8-direction two-pass), ``"sgbm_3way"``
            (3 directions, fastest) or ``"hh4"`` (4 directions).
        use_colour: match in colour when both images are colour (OpenCV sums the channels);
            False matches grey images.
    """

    block_size: int = 5
    P1: int | None = None
    P2: int | None = None
    disp12_max_diff: int = 1
    pre_filter_cap: int = 0
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    mode: SGBMMode = "sgbm_3way"
    use_colour: bool = True

    def __post_init__(self) -> None:
        _check_int("block_size", self.block_size, 1, 255, odd=True)
        for n in ("P1", "P2"):
            if getattr(self, n) is not None:
                _check_int(n, getattr(self, n), 0)
        if self.P1 is not None and self.P2 is not None and self.P2 <= self.P1:
            raise InputError(f"setting P2 ({self.P2}) must be larger than P1 ({self.P1})")
        _check_int("disp12_max_diff", self.disp12_max_diff)
        _check_int("pre_filter_cap", self.pre_filter_cap, 0, 63)
        _check_int("uniqueness_ratio", self.uniqueness_ratio, 0, 100)
        _check_int("speckle_window_size", self.speckle_window_size, 0)
        _check_int("speckle_range", self.speckle_range, 0)
        if self.mode not in _SGBM_MODES:
            raise InputError(f"setting mode must be one of {', '.join(_SGBM_MODES)}, got {self.mode!r}")


@dataclass(frozen=True)
class OpenCVBMSettings:
    """All options of ``cv2.StereoBM`` (grey images only; colour inputs are converted).

    Attributes:
        block_size: matched block size, odd, 5..255.
        pre_filter_type: ``"xsobel"`` or ``"normalized_response"``.
        pre_filter_size: window of the normalised-response pre-filter, odd, 5..255.
        pre_filter_cap: clip of the pre-filtered values, 1..63.
        texture_threshold: minimum block texture (sum of |derivative|) for a match.
        uniqueness_ratio: margin in percent by which the best cost must win.
        speckle_window_size: largest speckle removed, pixels; 0 disables.
        speckle_range: largest disparity step within a speckle, pixels.
        disp12_max_diff: left-right check tolerance in pixels; negative disables it.
    """

    block_size: int = 15
    pre_filter_type: BMPreFilter = "xsobel"
    pre_filter_size: int = 9
    pre_filter_cap: int = 31
    texture_threshold: int = 10
    uniqueness_ratio: int = 15
    speckle_window_size: int = 0
    speckle_range: int = 0
    disp12_max_diff: int = -1

    def __post_init__(self) -> None:
        _check_int("block_size", self.block_size, 5, 255, odd=True)
        if self.pre_filter_type not in _BM_PREFILTERS:
            raise InputError(
                f"setting pre_filter_type must be one of {', '.join(_BM_PREFILTERS)}, got {self.pre_filter_type!r}"
            )
        _check_int("pre_filter_size", self.pre_filter_size, 5, 255, odd=True)
        _check_int("pre_filter_cap", self.pre_filter_cap, 1, 63)
        _check_int("texture_threshold", self.texture_threshold, 0)
        _check_int("uniqueness_ratio", self.uniqueness_ratio, 0, 100)
        _check_int("speckle_window_size", self.speckle_window_size, 0)
        _check_int("speckle_range", self.speckle_range, 0)
        _check_int("disp12_max_diff", self.disp12_max_diff)


def _from_fixed_point(raw: np.ndarray, min_disparity: int) -> np.ndarray:
    disp = raw.astype(np.float32) * np.float32(1.0 / 16.0)
    disp[raw < min_disparity * 16] = np.nan
    return disp


_SettingsT = TypeVar("_SettingsT")


def _resolve_settings(
    cls: type[_SettingsT], name: str, settings: _SettingsT | None, kwargs: dict[str, Any]
) -> _SettingsT:
    """``settings`` itself, or the settings dataclass built from keyword fields (not both)."""
    if settings is not None and kwargs:
        raise InputError("give either settings= or individual settings, not both")
    return settings or settings_from_kwargs(cls, name, kwargs)


def _opencv_range(min_disparity: int, max_disparity: int) -> tuple[int, int, int]:
    """``(minDisparity, numDisparities, max_disparity)`` OpenCV searches for ``min <= d < max``, pixels."""
    check_disparity_range(min_disparity, max_disparity)
    num = num_disparities_for(min_disparity, max_disparity)
    return int(min_disparity), num, int(min_disparity) + num


def _result(
    raw: np.ndarray, name: str, min_disparity: int, max_disparity: int, sw: Stopwatch, diag: dict[str, Any]
) -> DisparityResult:
    """A :class:`DisparityResult` from OpenCV's (H, W) int16 fixed-point output (times in ``sw``)."""
    disp = _from_fixed_point(raw, min_disparity)
    sw.lap("convert")
    diagnostics = {"density": float(np.isfinite(disp).mean()), **diag}
    return DisparityResult(
        disp, np.zeros(disp.shape, bool), name, min_disparity, max_disparity, sw.total(), diagnostics
    )


class OpenCVSGBMMatcher:
    """``cv2.StereoSGBM`` with :class:`OpenCVSGBMSettings`.

    The searched range is ``min_disparity <= d < min_disparity + numDisparities`` with
    ``numDisparities`` = ``max_disparity - min_disparity`` rounded up to a multiple of 16.
    """

    name = "opencv-sgbm"

    def __init__(
        self,
        max_disparity: int,
        min_disparity: int = 0,
        settings: OpenCVSGBMSettings | None = None,
        **kwargs: Any,
    ) -> None:
        self.min_disparity, self.num_disparities, self.max_disparity = _opencv_range(
            min_disparity, max_disparity
        )
        self.settings = _resolve_settings(OpenCVSGBMSettings, self.name, settings, kwargs)
        self._sgbm: dict[int, Any] = {}

    def _engine(self, channels: int):
        if channels not in self._sgbm:
            s = self.settings
            area = s.block_size * s.block_size
            self._sgbm[channels] = cv2.StereoSGBM.create(
                minDisparity=self.min_disparity,
                numDisparities=self.num_disparities,
                blockSize=s.block_size,
                P1=s.P1 if s.P1 is not None else 8 * channels * area,
                P2=s.P2 if s.P2 is not None else 32 * channels * area,
                disp12MaxDiff=s.disp12_max_diff,
                preFilterCap=s.pre_filter_cap,
                uniquenessRatio=s.uniqueness_ratio,
                speckleWindowSize=s.speckle_window_size,
                speckleRange=s.speckle_range,
                mode=_SGBM_MODES[s.mode],
            )
        return self._sgbm[channels]

    def compute(self, left: np.ndarray, right: np.ndarray) -> DisparityResult:
        """Disparity of a rectified pair; see the module docstring for conventions."""
        sw = Stopwatch()
        pair = prepare_pair(left, right)
        check_disparity_range(self.min_disparity, self.max_disparity, pair.left_grey.shape[1])
        if self.settings.use_colour and pair.left_rgb is not None:
            a, b, cn = pair.left_rgb, pair.right_rgb, 3
        else:
            a, b, cn = pair.left_grey, pair.right_grey, 1
        sw.lap("prepare")
        raw = self._engine(cn).compute(a, b)
        sw.lap("match")
        diag = {"channels": cn, "settings": asdict(self.settings)}
        return _result(raw, self.name, self.min_disparity, self.max_disparity, sw, diag)


class OpenCVBMMatcher:
    """``cv2.StereoBM`` with :class:`OpenCVBMSettings` (grey matching).

    The searched range is as for :class:`OpenCVSGBMMatcher`.
    """

    name = "opencv-bm"

    def __init__(
        self,
        max_disparity: int,
        min_disparity: int = 0,
        settings: OpenCVBMSettings | None = None,
        **kwargs: Any,
    ) -> None:
        self.min_disparity, self.num_disparities, self.max_disparity = _opencv_range(
            min_disparity, max_disparity
        )
        self.settings = _resolve_settings(OpenCVBMSettings, self.name, settings, kwargs)
        s = self.settings
        bm = cv2.StereoBM.create(numDisparities=self.num_disparities, blockSize=s.block_size)
        bm.setMinDisparity(self.min_disparity)
        bm.setPreFilterType(_BM_PREFILTERS[s.pre_filter_type])
        bm.setPreFilterSize(s.pre_filter_size)
        bm.setPreFilterCap(s.pre_filter_cap)
        bm.setTextureThreshold(s.texture_threshold)
        bm.setUniquenessRatio(s.uniqueness_ratio)
        bm.setSpeckleWindowSize(s.speckle_window_size)
        bm.setSpeckleRange(s.speckle_range)
        bm.setDisp12MaxDiff(s.disp12_max_diff)
        self._bm = bm

    def compute(self, left: np.ndarray, right: np.ndarray) -> DisparityResult:
        """Disparity of a rectified pair; see the module docstring for conventions."""
        sw = Stopwatch()
        pair = prepare_pair(left, right)
        width = pair.left_grey.shape[1]
        check_disparity_range(self.min_disparity, self.max_disparity, width)
        if self.settings.block_size >= min(pair.left_grey.shape):
            raise InputError(
                f"block_size {self.settings.block_size} is not smaller than the image; use a smaller block"
            )
        sw.lap("prepare")
        raw = self._bm.compute(pair.left_grey, pair.right_grey)
        sw.lap("match")
        diag = {"settings": asdict(self.settings)}
        return _result(raw, self.name, self.min_disparity, self.max_disparity, sw, diag)


register_matcher("opencv-sgbm", OpenCVSGBMMatcher, "OpenCV StereoSGBM (semi-global block matching)")
register_matcher("opencv-bm", OpenCVBMMatcher, "OpenCV StereoBM (local block matching, grey)")
