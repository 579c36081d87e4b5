"""Numbers on a line of a text file: one parser, one set of error messages, for every reader in ``io/``.

Every text reader (calibration files, multi-view camera files, COLMAP models, sequence poses) turns
whitespace-separated words into numbers with :func:`parse_numbers`, so a bad file is always reported
the same way: an :class:`~skyrecon.errors.InputError` naming the file, the line and the offending word.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError

__all__ = ["parse_numbers"]

# above this many words, convert through one NumPy call (COLMAP keypoint and track lines)
_VECTORISE_FROM = 32


def _where(line_no: int | None) -> str:
    return f"line {line_no}: " if line_no is not None else ""


def _first_bad(words: Sequence[str], kind: type[int] | type[float]) -> str:
    for word in words:
        try:
            kind(word)
        except ValueError:
            return word
    return words[0]  # pragma: no cover - only called after a conversion failed


def _convert(words: Sequence[str], kind: type[int] | type[float]) -> np.ndarray:
    """float64 or int64 array of ``words``; ValueError (or OverflowError) when one is not a number."""
    dtype = np.float64 if kind is float else np.int64
    if len(words) >= _VECTORISE_FROM:
        return np.asarray(words, dtype=str).astype(dtype)
    return np.array([kind(w) for w in words], dtype=dtype)


def parse_numbers(
    words: str | Sequence[str],
    path: str | Path | None,
    line_no: int | None,
    what: str | None = None,
    *,
    count: int | None = None,
    kind: type[int] | type[float] = float,
) -> np.ndarray:
    """Parse whitespace-separated numbers of one line (or one field) of a text file.

    Args:
        words: the text (split on whitespace) or its words.
        path: the file, named in the error (None: not a file).
        line_no: 1-based line number named in the error, or None (a whole-file field).
        what: what the values are, for the error (``"the pose"``, ``"X Y Z"``); None shows the text.
        count: the number of values required, or None for any.
        kind: ``float`` (finite float64 values) or ``int`` (int64 values; ``1.5`` is refused).
    Returns:
        (N,) float64 or int64 array.
    Raises:
        InputError: a word that is not a number (or not an integer), NaN or infinity, or the
            wrong count, naming the file, the line and the word.
    """
    tokens = words.split() if isinstance(words, str) else list(words)
    where = _where(line_no)
    if count is not None and len(tokens) != count:
        noun = "number" if count == 1 else "numbers"
        if what is None:
            raise InputError(f"{where}expected {count} {noun}, found {len(tokens)}", path)
        raise InputError(f"{where}{what} needs {count} {noun}, found {len(tokens)}", path)
    try:
        values = _convert(tokens, kind)
    except (ValueError, OverflowError):
        bad = _first_bad(tokens, kind)
        expected, problem = (
            ("integers", "is not a valid int") if kind is int else ("numbers", "is not a number")
        )
        if what is None:
            raise InputError(f"{where}expected {expected}, {bad!r} {problem}", path) from None
        raise InputError(f"{where}{what}: {bad!r} {problem}; expected {expected}", path) from None
    if kind is float and not np.all(np.isfinite(values)):
        if what is None:
            raise InputError(f"{where}NaN or infinite value in {' '.join(tokens)!r}", path)
        raise InputError(f"{where}{what} contains NaN or infinite values", path)
    return values
