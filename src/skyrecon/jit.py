"""Watching Numba compile skyrecon's kernels: a one-line notice, and a count of what was compiled.

Numba announces every real compilation with a ``numba:compile`` event; a kernel loaded from the
on-disk cache raises none. So a listener sees exactly the kernels a run pays to compile:

* :func:`install_compile_notice` prints, once per process, one line on stderr (when it is a
  terminal) the first time a skyrecon kernel is compiled (a fresh install, a changed source, a new
  CPU), so that a slow first run says why.
* :class:`CompileRecorder` collects the names of the skyrecon kernels compiled while it is active
  (``skyrecon warmup`` reports them, tests check that a warm cache compiles nothing).
* :func:`read_warm_groups` / :func:`mark_warm`: a stamp in the cache recording which warmup groups
  were compiled for these sources, this Numba and this CPU, so a second warmup can stop at once.

Where the cache lives is decided in :mod:`skyrecon.numba_cache`, before Numba is imported.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

import llvmlite.binding as llvm  # type: ignore[import-untyped]  # llvmlite ships no type information
import numba
from numba.core import event

from skyrecon import __version__
from skyrecon.numba_cache import PACKAGE_DIR

COMPILE_NOTICE = (
    "skyrecon: compiling kernels for this machine (once, up to a minute per command; "
    "run `skyrecon warmup` after installing to do it ahead)"
)


def kernel_name(ev: Any) -> str | None:
    """``module.qualname`` of the kernel a ``numba:compile`` event is about, or None when not skyrecon's."""
    data = ev.data if isinstance(ev.data, dict) else {}
    py_func = getattr(data.get("dispatcher"), "py_func", None)
    module = getattr(py_func, "__module__", None) or ""
    if not module.startswith("skyrecon."):
        return None
    return f"{module}.{getattr(py_func, '__qualname__', '?')}"


class _CompileNotice(event.Listener):
    """Prints :data:`COMPILE_NOTICE` at the start of the first skyrecon compilation, then stays quiet."""

    def __init__(self) -> None:
        self.stream: TextIO | None = None
        self.enabled = True
        self.printed = False

    def on_start(self, ev: event.Event) -> None:
        if not self.enabled or self.printed or kernel_name(ev) is None:
            return
        stream = self.stream or sys.stderr
        if self.stream is None and not stream.isatty():  # nobody watching: logs and tests stay clean
            return
        self.printed = True
        print(COMPILE_NOTICE, file=stream, flush=True)

    def on_end(self, ev: event.Event) -> None:
        pass


_notice = _CompileNotice()
_notice_registered = False


def install_compile_notice(enabled: bool = True, stream: TextIO | None = None) -> None:
    """Print :data:`COMPILE_NOTICE` once per process, before the first skyrecon kernel compiles.

    With ``stream`` None the notice goes to stderr, and only when stderr is a terminal; a given
    ``stream`` always receives it. Calling again updates the settings (one listener stays).
    ``enabled=False`` (e.g. for ``--quiet``) silences it.
    """
    global _notice_registered
    _notice.enabled = enabled
    _notice.stream = stream
    if not _notice_registered:
        event.register("numba:compile", _notice)
        _notice_registered = True


def set_compile_notice_enabled(enabled: bool) -> None:
    """Silence (or restore) the notice, e.g. while ``skyrecon warmup`` reports compilation itself."""
    _notice.enabled = enabled


class CompileRecorder(event.Listener):
    """Context manager: ``names`` lists the skyrecon kernels compiled (not loaded from cache) inside it.

    One name per compiled specialisation (a kernel compiled for two argument types appears twice).
    """

    def __init__(self) -> None:
        self.names: list[str] = []

    def on_start(self, ev: event.Event) -> None:
        name = kernel_name(ev)
        if name is not None:
            self.names.append(name)

    def on_end(self, ev: event.Event) -> None:
        pass

    def __enter__(self) -> CompileRecorder:
        event.register("numba:compile", self)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        event.unregister("numba:compile", self)


def warm_stamp_path() -> Path:
    """The warmup stamp: in ``$NUMBA_CACHE_DIR``, else in the package's ``__pycache__`` (Numba's default
    cache location), so that deleting the cache deletes the stamp too."""
    cache_dir = getattr(numba.config, "CACHE_DIR", "")
    return (Path(cache_dir) if cache_dir else PACKAGE_DIR / "__pycache__") / "skyrecon-warmup.json"


def cache_fingerprint(package_dir: Path = PACKAGE_DIR) -> str:
    """Hash of what Numba's cache depends on: the sources (path, mtime, size), the versions of
    skyrecon, Numba and Python, and the CPU the kernels are compiled for."""
    h = hashlib.sha256()
    for part in (
        __version__,
        numba.__version__,
        sys.version,
        llvm.get_process_triple(),
        llvm.get_host_cpu_name(),
    ):
        h.update(part.encode() + b"\0")
    h.update(llvm.get_host_cpu_features().flatten().encode() + b"\0")
    for path in sorted(package_dir.rglob("*.py")):
        st = path.stat()
        h.update(f"{path.relative_to(package_dir)}:{st.st_mtime_ns}:{st.st_size}\0".encode())
    return h.hexdigest()


def read_warm_groups(fingerprint: str, stamp: Path | None = None) -> set[str]:
    """The warmup groups recorded as compiled for ``fingerprint`` (empty when the stamp is missing,
    unreadable or for other sources)."""
    try:
        doc = json.loads((stamp or warm_stamp_path()).read_text())
    except (OSError, ValueError):
        return set()
    if not isinstance(doc, dict) or doc.get("fingerprint") != fingerprint:
        return set()
    return set(doc.get("groups", []))


def mark_warm(groups: Iterable[str], fingerprint: str, stamp: Path | None = None) -> None:
    """Record ``groups`` as compiled for ``fingerprint`` (added to those already recorded)."""
    stamp = stamp or warm_stamp_path()
    done = sorted(read_warm_groups(fingerprint, stamp) | set(groups))
    stamp.parent.mkdir(parents=True, exist_ok=True)
    tmp = stamp.with_suffix(".tmp")
    tmp.write_text(json.dumps({"fingerprint": fingerprint, "groups": done}) + "\n")
    tmp.replace(stamp)
