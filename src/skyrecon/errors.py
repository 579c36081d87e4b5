"""The exception family of skyrecon.

``InputError`` is raised for bad user input (missing or corrupt files, wrong
calibration, mismatched sizes, NaNs): the command line turns it into exit
status 2 and one ``error: ...`` line. ``EstimationError`` is raised when an
estimation fails on valid input (too few matches, degenerate motion) and says why.
"""

from __future__ import annotations

from pathlib import Path


class SkyreconError(Exception):
    """Root of every error skyrecon raises on purpose."""


class InputError(SkyreconError):
    """Bad user input. The message names the file (if any) and what to do.

    Args:
        message: what is wrong and, where possible, what to do about it.
        path: the offending file or directory, prefixed to the message.
    """

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else Path(path)
        self.reason = message
        super().__init__(f"{path}: {message}" if path is not None else message)


class EstimationError(SkyreconError):
    """An estimation failed on valid input; the message says why."""
