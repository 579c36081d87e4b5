"""Disparity and depth maps on disk: KITTI 16-bit PNG, Middlebury 8-bit PGM/PNG, PFM; pictures.

In memory a disparity map is (H, W) float32 pixels with ``x_right = x_left - d`` and NaN
where unknown; a depth map is (H, W) float32 metres along the optical axis, NaN where
unknown. File encodings:

- KITTI: 16-bit grey PNG, ``disparity = value / 256``, value 0 = no ground truth.
- Middlebury 2001/2003: 8-bit grey PGM (or PNG), ``disparity = value / scale`` with scale 4
  for the 2003 quarter-size sets (Cones, Teddy) and 8 for the 2001 sets; value 0 = unknown.
- PFM (Middlebury 2014 and skyrecon's own output): float32, +inf = unknown.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic
from skyrecon.io.images import encode_png, read_image_with_alpha
from skyrecon.io.pfm import read_pfm

KITTI_SCALE = 256.0
MIDDLEBURY_DEFAULT_SCALE = 4.0


def _read_grey(path: Path) -> np.ndarray:
    """(H, W) uint8 or uint16 grey image, as stored; colour images are refused."""
    image, _ = read_image_with_alpha(path, mode="unchanged")
    if image.ndim != 2:
        raise InputError(
            f"a disparity image must be single-channel grey, this one has shape {image.shape}", path
        )
    return image


def _decode_scaled(values: np.ndarray, scale: float) -> np.ndarray:
    """Integer codes (H, W) -> float32 disparity ``value / scale`` with 0 -> NaN."""
    disp = values.astype(np.float32) / np.float32(scale)
    disp[values == 0] = np.nan
    return disp


def read_kitti_disparity_png(path: str | Path) -> np.ndarray:
    """Read a KITTI disparity PNG.

    Args:
        path: 16-bit grey PNG (``disp_occ_0/000046_10.png``).
    Returns:
        (H, W) float32 disparity in pixels, ``value / 256``; NaN where the value is 0.
    Raises:
        InputError: missing/corrupt file, or not a 16-bit grey image.
    """
    path = Path(path)
    values = _read_grey(path)
    if values.dtype != np.uint16:
        raise InputError(
            "a KITTI disparity PNG must be 16-bit grey; this one is 8-bit "
            "(for Middlebury 8-bit maps use read_middlebury_disparity_pgm)",
            path,
        )
    return _decode_scaled(values, KITTI_SCALE)


def encode_kitti_disparity(disp: np.ndarray) -> np.ndarray:
    """(H, W) float disparity -> (H, W) uint16 KITTI codes.

    NaN, infinities and values <= 0 become 0 (unknown); valid values are rounded to 1/256 px,
    kept at least 1 (so that they stay valid) and clipped to 65535 (255.996 px).
    """
    d = np.asarray(disp, dtype=np.float64)
    if d.ndim != 2:
        raise InputError(f"a disparity map must be (H, W), got shape {d.shape}")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0)
        codes = np.clip(np.rint(np.where(valid, d, 0.0) * KITTI_SCALE), 1, 65535)
    return np.where(valid, codes, 0).astype(np.uint16)


def write_kitti_disparity_png(path: str | Path, disp: np.ndarray) -> None:
    """Write (H, W) float disparity, pixels, as a KITTI 16-bit PNG (see :func:`encode_kitti_disparity`).

    Reading it back is exact for disparities that are multiples of 1/256 in [1/256, 65535/256].
    """
    path = Path(path)
    try:
        data = encode_png(encode_kitti_disparity(disp))
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    write_bytes_atomic(path, data)


def read_middlebury_disparity_pgm(path: str | Path, scale: float = MIDDLEBURY_DEFAULT_SCALE) -> np.ndarray:
    """Read a Middlebury 2001/2003 8-bit disparity map.

    Args:
        path: 8-bit grey PGM or PNG (``cones/disp2.pgm``).
        scale: the data set's scale factor: 4 for the 2003 quarter-size sets, 8 for 2001.
    Returns:
        (H, W) float32 disparity in pixels, ``value / scale``; NaN where the value is 0.
    """
    path = Path(path)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"the disparity scale must be positive, got {scale}", path)
    values = _read_grey(path)
    if values.dtype != np.uint8:
        raise InputError(
            "a Middlebury disparity map must be 8-bit grey; this one is 16-bit "
            "(for KITTI maps use read_kitti_disparity_png)",
            path,
        )
    return _decode_scaled(values, scale)


def _sniff(path: Path) -> str:
    """'pfm', 'png', 'pnm' or 'unknown' from the first bytes of the file."""
    if not path.is_file():
        raise InputError("disparity file not found; check the path", path)
    with open(path, "rb") as f:
        head = f.read(8)
    if not head:
        raise InputError("disparity file is empty", path)
    if head[:2] in (b"Pf", b"PF"):
        return "pfm"
    if head.startswith(b"\x89PNG"):
        return "png"
    if head[:2] in (b"P2", b"P5"):
        return "pnm"
    return "unknown"


def read_disparity(path: str | Path) -> np.ndarray:
    """Read a disparity map in any supported format, chosen by the file's content.

    - PFM (``Pf``): float32 as stored, inf -> NaN. Colour PFMs are refused.
    - 16-bit grey PNG/PGM: KITTI, ``value / 256``, 0 -> NaN.
    - 8-bit grey PNG/PGM: Middlebury 2003, ``value / 4``, 0 -> NaN. For other scales
      (8 for Middlebury 2001) call :func:`read_middlebury_disparity_pgm` directly.

    Returns:
        (H, W) float32 disparity in pixels, NaN where unknown.
    """
    path = Path(path)
    kind = _sniff(path)
    if kind == "pfm":
        disp = read_pfm(path)
        if disp.ndim != 2:
            raise InputError("a disparity PFM must be single-channel ('Pf'), this one has 3 channels", path)
        return disp
    if kind == "unknown":
        raise InputError("unknown disparity format: expected PFM, PNG or PGM", path)
    values = _read_grey(path)
    if values.dtype == np.uint16:
        return _decode_scaled(values, KITTI_SCALE)
    return _decode_scaled(values, MIDDLEBURY_DEFAULT_SCALE)


def _colorize01(t: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W) values in [0, 1] -> (H, W, 3) uint8 RGB turbo colours; invalid pixels black."""
    codes = np.clip(np.rint(np.where(valid, t, 0.0) * 255.0), 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(codes, cv2.COLORMAP_TURBO)[..., ::-1]
    rgb = np.ascontiguousarray(rgb)
    rgb[~valid] = 0
    return rgb


def _normalise(values: np.ndarray, valid: np.ndarray, vmin: float | None, vmax: float | None) -> np.ndarray:
    """Map ``values`` linearly so that vmin -> 0 and vmax -> 1 (defaults: range of the valid values)."""
    if vmin is None:
        vmin = float(values[valid].min()) if valid.any() else 0.0
    if vmax is None:
        vmax = float(values[valid].max()) if valid.any() else 1.0
    span = vmax - vmin if vmax > vmin else 1.0
    with np.errstate(invalid="ignore"):
        return np.clip((values - vmin) / span, 0.0, 1.0)


def colorize_disparity(disp: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """A picture of a disparity map (turbo colormap: far = blue, near = red).

    Args:
        disp: (H, W) float disparity, pixels, NaN (or inf) where unknown.
        vmin, vmax: disparities mapped to the ends of the colormap; default: the range of
            the finite values.
    Returns:
        (H, W, 3) uint8 RGB, black where the disparity is not finite.
    """
    d = np.asarray(disp, dtype=np.float64)
    if d.ndim != 2:
        raise InputError(f"a disparity map must be (H, W), got shape {d.shape}")
    valid = np.isfinite(d)
    return _colorize01(_normalise(d, valid, vmin, vmax), valid)


def colorize_depth(depth_m: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """A picture of a depth map, coloured by inverse depth (near = red, far = blue).

    Args:
        depth_m: (H, W) float depth along the optical axis, metres, NaN where unknown.
        vmin, vmax: nearest and farthest depths of the colour scale, metres; default:
            the range of the valid depths.
    Returns:
        (H, W, 3) uint8 RGB, black where the depth is not finite and positive.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    if z.ndim != 2:
        raise InputError(f"a depth map must be (H, W), got shape {z.shape}")
    with np.errstate(invalid="ignore", divide="ignore"):
        valid = np.isfinite(z) & (z > 0)
        inv = np.where(valid, 1.0 / np.where(valid, z, 1.0), np.nan)
    inv_min = None if vmax is None else 1.0 / vmax
    inv_max = None if vmin is None else 1.0 / vmin
    return _colorize01(_normalise(inv, valid, inv_min, inv_max), valid)
