"""Progress bars for long stages (tqdm on stderr).

Disabled with ``SKYRECON_PROGRESS=0`` or :func:`set_progress_enabled`; by default
bars are shown when stderr is a terminal.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import Any

from tqdm import tqdm

_enabled: bool | None = None


def set_progress_enabled(enabled: bool | None) -> None:
    """Force progress bars on (True), off (False) or automatic (None: when stderr is a TTY)."""
    global _enabled
    _enabled = enabled


def progress_enabled() -> bool:
    env = os.environ.get("SKYRECON_PROGRESS")
    if env is not None:
        return env not in ("0", "false", "no", "")
    if _enabled is not None:
        return _enabled
    return sys.stderr.isatty()


def progress(
    iterable: Iterable | None = None, *, desc: str | None = None, total: int | None = None, **kw: Any
) -> tqdm:
    """A tqdm bar over ``iterable`` (or a manual one with ``total``) that respects the settings."""
    return tqdm(
        iterable,
        desc=desc,
        total=total,
        disable=not progress_enabled(),
        file=sys.stderr,
        dynamic_ncols=True,
        leave=False,
        **kw,
    )
