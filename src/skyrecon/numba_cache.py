"""Where Numba keeps the compiled kernels of skyrecon (chosen before Numba is imported).

Numba caches a kernel compiled with ``cache=True`` beside its source file (``__pycache__``) or,
when ``$NUMBA_CACHE_DIR`` is set, under that directory. A package installed read-only (a system
site-packages, a container layer) cannot write beside its sources, so every run would compile
again. :func:`configure_numba_cache` (called by ``skyrecon/__init__.py``) then points Numba at a
per-user directory, ``$XDG_CACHE_HOME/skyrecon/numba`` (``~/.cache/skyrecon/numba`` by default).

This module imports only the standard library: it must run before anything imports Numba.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
"""The installed ``skyrecon`` package directory (where the kernels' sources live)."""


def user_cache_dir(environ: Mapping[str, str]) -> Path:
    """``$XDG_CACHE_HOME/skyrecon/numba``, or ``~/.cache/skyrecon/numba`` when that is unset or relative."""
    xdg = environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path(environ.get("HOME") or Path.home()) / ".cache"
    return base / "skyrecon" / "numba"


def package_is_writable(package_dir: Path) -> bool:
    """True when Numba can write its cache beside the sources (the package dir and its ``__pycache__``)."""
    if not os.access(package_dir, os.W_OK | os.X_OK):
        return False
    pycache = package_dir / "__pycache__"
    return not pycache.exists() or os.access(pycache, os.W_OK | os.X_OK)


def checkout_cache_dir(package_dir: Path) -> Path | None:
    """``<checkout>/.numba_cache`` when the package runs from a source checkout (``src/skyrecon``)
    whose cache ``make`` has warmed (``skyrecon warmup``), else None."""
    if package_dir.parent.name != "src":
        return None
    cache = package_dir.parent.parent / ".numba_cache"
    return cache if cache.is_dir() else None


def choose_cache_dir(environ: Mapping[str, str], package_dir: Path = PACKAGE_DIR) -> Path | None:
    """The directory to give Numba as ``NUMBA_CACHE_DIR``, or None to leave Numba's choice alone.

    None when ``NUMBA_CACHE_DIR`` is already set (the user's or the Makefile's choice wins). In a
    source checkout whose ``.numba_cache`` the Makefile warmed, that one (so that ``.venv/bin/skyrecon``
    run by hand after ``make demo`` finds the kernels compiled). Else None when the package directory
    is writable (Numba's default ``__pycache__`` works); otherwise the per-user directory of
    :func:`user_cache_dir`.
    """
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    checkout = checkout_cache_dir(package_dir)
    if checkout is not None:
        return checkout
    if package_is_writable(package_dir):
        return None
    return user_cache_dir(environ)


def configure_numba_cache(package_dir: Path = PACKAGE_DIR) -> Path | None:
    """Apply :func:`choose_cache_dir` to this process (and the worker processes it starts).

    Sets ``os.environ["NUMBA_CACHE_DIR"]``; if Numba was imported already, also its live
    ``numba.config.CACHE_DIR`` (read when a kernel's cache is first opened). Returns the
    directory chosen, or None when Numba's own choice stands.
    """
    chosen = choose_cache_dir(os.environ, package_dir)
    if chosen is None:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(chosen)
    numba = sys.modules.get("numba")
    if numba is not None:  # imported before skyrecon: its config has read the environment already
        numba.config.CACHE_DIR = str(chosen)
    return chosen
