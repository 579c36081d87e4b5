"""PFM (Portable Float Map) images, Middlebury conventions.

File layout::

    Pf | PF          grey (1 channel) or colour (3 channels)
    W H              width and height in pixels
    scale            a float whose sign gives the byte order: negative = little-endian
    <W*H*C float32>  rows stored bottom-up (the first row in the file is the image's last row)

In memory, arrays are top-down float32, (H, W) or (H, W, 3), and invalid values are
NaN. In files invalid values are +inf (Middlebury's convention), so the reader turns
every infinity into NaN and the writer turns NaN into +inf. The magnitude of the
scale is ignored (Middlebury always writes 1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic

_WHITESPACE = b" \t\r\n\v\f"


def _next_token(data: bytes, pos: int) -> tuple[bytes, int]:
    """The next whitespace-delimited token at or after ``pos`` and the position just after it."""
    n = len(data)
    while pos < n and data[pos] in _WHITESPACE:
        pos += 1
    start = pos
    while pos < n and data[pos] not in _WHITESPACE:
        pos += 1
    return data[start:pos], pos


def _parse_header(data: bytes, path: Path) -> tuple[int, int, int, str, int]:
    """Parse the header: (width, height, channels, numpy byte order, data offset)."""
    magic, pos = _next_token(data, 0)
    if magic not in (b"Pf", b"PF"):
        shown = magic[:8].decode("latin-1", "replace")
        raise InputError(f"not a PFM file: header starts with {shown!r}, expected 'Pf' or 'PF'", path)
    channels = 3 if magic == b"PF" else 1
    tokens = []
    for what in ("width", "height", "scale"):
        tok, pos = _next_token(data, pos)
        if not tok:
            raise InputError(f"truncated PFM header: missing the {what}", path)
        tokens.append(tok)
    try:
        width, height = int(tokens[0]), int(tokens[1])
        scale = float(tokens[2])
    except ValueError:
        raise InputError(
            f"bad PFM header: size {tokens[0]!r} {tokens[1]!r} and scale {tokens[2]!r} must be numbers", path
        ) from None
    if width <= 0 or height <= 0:
        raise InputError(f"bad PFM header: image size {width}x{height} must be positive", path)
    if scale == 0 or not np.isfinite(scale):
        raise InputError(
            f"bad PFM header: scale {scale} must be a non-zero number (its sign is the byte order)", path
        )
    if pos >= len(data) or data[pos] not in _WHITESPACE:
        raise InputError("truncated PFM file: no pixel data after the header", path)
    return width, height, channels, "<" if scale < 0 else ">", pos + 1


def read_pfm(path: str | Path) -> np.ndarray:
    """Read a PFM file.

    Args:
        path: the ``.pfm`` file.
    Returns:
        (H, W) float32 for ``Pf`` files, (H, W, 3) float32 for ``PF`` files, rows
        top-down, infinities replaced by NaN.
    Raises:
        InputError: missing, empty or truncated file, or a bad header.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("PFM file not found; check the path", path)
    data = path.read_bytes()
    if not data:
        raise InputError("PFM file is empty", path)
    width, height, channels, order, offset = _parse_header(data, path)
    count = width * height * channels
    available = (len(data) - offset) // 4
    if available < count:
        raise InputError(
            f"truncated PFM file: {width}x{height}x{channels} needs {count} floats, found {available}", path
        )
    values = np.frombuffer(data, dtype=f"{order}f4", count=count, offset=offset)
    shape = (height, width, channels) if channels == 3 else (height, width)
    image = values.reshape(shape)[::-1].astype(np.float32)  # bottom-up -> top-down, native order, copy
    image[np.isinf(image)] = np.nan
    return image


def encode_pfm(array: np.ndarray) -> bytes:
    """PFM bytes (little-endian, bottom-up, NaN -> +inf) of an (H, W) or (H, W, 3) float array."""
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise InputError(f"PFM holds (H, W) or (H, W, 3) arrays, got shape {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"cannot write an empty {a.shape} array as PFM")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer) or a.dtype == bool):
        raise InputError(f"PFM holds numbers, got dtype {a.dtype}")
    out = np.array(a[::-1], dtype="<f4", order="C", copy=True)  # never modify the caller's array
    out[np.isnan(out)] = np.inf
    magic = "PF" if a.ndim == 3 else "Pf"
    header = f"{magic}\n{a.shape[1]} {a.shape[0]}\n-1\n".encode("ascii")
    return header + out.tobytes()


def write_pfm(path: str | Path, array: np.ndarray) -> None:
    """Write an (H, W) or (H, W, 3) array as a little-endian PFM file, atomically.

    Rows are written bottom-up and NaN becomes +inf, so that :func:`read_pfm` gives
    back exactly the same float32 array (finite values and NaN; +/-inf also read
    back as NaN).
    """
    path = Path(path)
    try:
        data = encode_pfm(array)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    write_bytes_atomic(path, data)
