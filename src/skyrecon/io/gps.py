"""GPS fixes in local metres: ``time_s, x, y, z[, accuracy_m]`` per line (CSV).

Positions are in a local metric frame (e.g. ENU around an origin, or the synthetic city's world:
z up, metres); ``accuracy_m`` is the receiver's stated 1-sigma horizontal accuracy in metres (when
missing, :data:`DEFAULT_ACCURACY_M`). A first line that is not numbers is a header; ``#`` starts a
comment.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.text import parse_numbers

__all__ = ["GpsFix", "DEFAULT_ACCURACY_M", "read_gps_csv", "write_gps_csv", "format_gps_csv"]

DEFAULT_ACCURACY_M = 5.0


@dataclass(frozen=True)
class GpsFix:
    """One GPS position.

    Attributes:
        time_s: seconds, on the camera clock.
        position: (3,) local metres.
        accuracy_m: stated 1-sigma accuracy, metres (> 0).
    """

    time_s: float
    position: np.ndarray
    accuracy_m: float = DEFAULT_ACCURACY_M

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"a GPS position needs 3 finite numbers, got {p.tolist()}")
        if not (np.isfinite(self.accuracy_m) and self.accuracy_m > 0):
            raise InputError(f"a GPS accuracy must be a positive number of metres, got {self.accuracy_m}")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "time_s", float(self.time_s))
        object.__setattr__(self, "accuracy_m", float(self.accuracy_m))


def read_gps_csv(path: str | Path) -> list[GpsFix]:
    """Fixes of a GPS CSV file in time order.

    Raises:
        InputError: naming the file and line of a malformed row, or decreasing times.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("GPS file not found", path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the GPS file ({exc})", path) from None
    fixes: list[GpsFix] = []
    first = True
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split("#", 1)[0].replace(",", " ").split()
        if not words:
            continue
        if first and not _is_number(words[0]):
            first = False
            continue  # header
        first = False
        if len(words) not in (4, 5):
            raise InputError(
                f"line {lineno}: expected 'time_s, x, y, z[, accuracy_m]', found {len(words)} values", path
            )
        v = parse_numbers(words, path, lineno, "the GPS fix")
        try:
            fixes.append(GpsFix(v[0], v[1:4], v[4] if len(v) == 5 else DEFAULT_ACCURACY_M))
        except InputError as exc:
            raise InputError(f"line {lineno}: {exc.reason}", path) from None
        if len(fixes) > 1 and fixes[-1].time_s < fixes[-2].time_s:
            raise InputError(f"line {lineno}: GPS times must not decrease", path)
    if not fixes:
        raise InputError("no GPS fixes in the file", path)
    return fixes


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def format_gps_csv(fixes: Sequence[GpsFix]) -> str:
    """CSV text with a header: ``time_s,x,y,z,accuracy_m``."""
    rows = ["time_s,x,y,z,accuracy_m\n"]
    rows += [",".join(repr(float(v)) for v in (f.time_s, *f.position, f.accuracy_m)) + "\n" for f in fixes]
    return "".join(rows)


def write_gps_csv(path: str | Path, fixes: Sequence[GpsFix]) -> None:
    """Write fixes atomically (see :func:`format_gps_csv`)."""
    write_text_atomic(path, format_gps_csv(fixes))
