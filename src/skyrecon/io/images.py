"""Image reading and writing. In memory, colour images are RGB (OpenCV's BGR is converted here).

Supported: PNG (8/16-bit; grey, grey+alpha, RGB, RGBA, palette), JPEG, PGM/PPM.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from PIL import Image as PILImage
from PIL import UnidentifiedImageError

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic

Mode = Literal["rgb", "gray", "unchanged"]


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found; check the path", path)
    if path.is_dir():
        raise InputError("is a directory, expected a file", path)
    if path.stat().st_size == 0:
        raise InputError("file is empty", path)


def read_image_with_alpha(path: str | Path, mode: Mode = "rgb") -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image and its alpha channel, if any.

    Args:
        path: image file.
        mode: ``"rgb"`` -> (H, W, 3); ``"gray"`` -> (H, W) (ITU-R 601 luma);
            ``"unchanged"`` -> (H, W) for grey files, (H, W, 3) for colour ones.
            ``"rgb"`` and ``"gray"`` return uint8, scaling 16-bit data by 1/257;
            ``"unchanged"`` keeps uint16 for 16-bit files.
    Returns:
        (image, alpha): alpha is (H, W) of the image's dtype, or None.
    Raises:
        InputError: missing, empty, truncated or undecodable file.
    """
    path = Path(path)
    _check_file(path)
    if _is_16bit_colour_png(path):
        arr, alpha = _read_16bit_colour_png(path)
        pil_mode = "RGB16"
    else:
        arr, alpha, pil_mode = _read_with_pil(path)
    if pil_mode == "LA":
        arr, alpha = arr[..., 0], arr[..., 1]
    elif pil_mode == "RGBA":
        arr, alpha = arr[..., :3], arr[..., 3]

    if mode == "unchanged":
        return np.ascontiguousarray(arr), alpha
    if arr.dtype == np.uint16:
        arr = ((arr.astype(np.uint32) + 128) // 257).astype(np.uint8)
        if alpha is not None:
            alpha = ((alpha.astype(np.uint32) + 128) // 257).astype(np.uint8)
    if mode == "rgb":
        if arr.ndim == 2:
            arr = np.repeat(arr[..., None], 3, axis=2)
        return np.ascontiguousarray(arr), alpha
    if mode == "gray":
        return to_gray(arr), alpha
    raise ValueError(f"unknown mode {mode!r}")


def _is_16bit_colour_png(path: Path) -> bool:
    """True for a PNG whose IHDR says 16 bits per sample and colour (with or without alpha)."""
    with open(path, "rb") as f:
        head = f.read(26)
    return len(head) == 26 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[24] == 16 and head[25] in (2, 6)


def _read_16bit_colour_png(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Pillow keeps only 8 bits of 16-bit colour PNGs; OpenCV reads them whole (BGR[A] -> RGB)."""
    arr = cv2.imdecode(np.fromfile(path, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.ndim != 3:
        raise InputError("cannot decode image; the file is corrupt or truncated", path)
    alpha = arr[..., 3].copy() if arr.shape[2] == 4 else None
    return np.ascontiguousarray(arr[..., 2::-1]), alpha


def _read_with_pil(path: Path) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Decode with Pillow; returns (array, alpha placeholder None, Pillow mode after normalising)."""
    try:
        with PILImage.open(path) as opened:
            opened.load()
            im: PILImage.Image = opened
            pil_mode = im.mode
            if pil_mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
                pil_mode = im.mode
            if pil_mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.array(im).astype(np.uint16) if pil_mode != "I" else np.array(im)
                if pil_mode == "I":
                    if arr.min() < 0 or arr.max() > 65535:
                        raise InputError("32-bit integer image with values outside 0..65535", path)
                    arr = arr.astype(np.uint16)
            elif pil_mode == "1":
                arr = np.array(im.convert("L"))
            elif pil_mode in ("L", "LA", "RGB", "RGBA"):
                arr = np.array(im)
            elif pil_mode == "F":
                raise InputError("floating-point image; read it as PFM instead", path)
            else:
                arr = np.array(im.convert("RGB"))
                pil_mode = "RGB"
    except InputError:
        raise
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise InputError(f"cannot decode image ({exc}); the file is corrupt or truncated", path) from None
    return arr, None, pil_mode


def read_image(path: str | Path, mode: Mode = "rgb") -> np.ndarray:
    """Read an image, dropping any alpha channel. See :func:`read_image_with_alpha`."""
    return read_image_with_alpha(path, mode)[0]


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) RGB or (H, W) grey -> (H, W) grey of the same dtype (ITU-R 601 luma)."""
    if image.ndim == 2:
        return image
    w = np.array([0.299, 0.587, 0.114], dtype=np.float32)
    g = image[..., :3].astype(np.float32) @ w
    info = np.iinfo(image.dtype) if np.issubdtype(image.dtype, np.integer) else None
    if info is not None:
        return np.clip(np.rint(g), info.min, info.max).astype(image.dtype)
    return g.astype(image.dtype)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W) or (H, W, 3|4) uint8/uint16 image (RGB[A] order)."""
    arr = np.asarray(image)
    if arr.dtype not in (np.uint8, np.uint16):
        raise InputError(f"PNG needs uint8 or uint16 data, got {arr.dtype}")
    if arr.ndim == 3 and arr.shape[2] == 3:
        arr = arr[..., ::-1]
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., [2, 1, 0, 3]]
    elif arr.ndim != 2:
        raise InputError(f"cannot write an image of shape {arr.shape}")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(arr), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise InputError("PNG encoding failed")
    return buf.tobytes()


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image atomically. PNG for ``.png``; JPEG (quality 95) for ``.jpg``/``.jpeg``."""
    path = Path(path)
    if path.suffix.lower() in (".jpg", ".jpeg"):
        arr = np.asarray(image)
        if arr.ndim == 3:
            arr = arr[..., ::-1]
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(arr), [cv2.IMWRITE_JPEG_QUALITY, 95])
        if not ok:
            raise InputError("JPEG encoding failed", path)
        write_bytes_atomic(path, buf.tobytes())
    else:
        write_bytes_atomic(path, encode_png(image))
