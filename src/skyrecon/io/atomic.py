"""Atomic file output: write to a temporary file beside the target, then rename.

An interrupted run leaves either the old file or nothing, never half a file under the target's
name. Temporaries are hidden and carry the writer's process id (``.points.ply.<pid>.<random>.tmp``,
directories ``.<name>.<pid>.<random>``), so a run killed outright (SIGKILL, power loss) leaves
only hidden temporaries, which :func:`sweep_stale_temps` removes on the next run once their
process is gone. A full disk (``ENOSPC``/``EDQUOT``) becomes :class:`DiskFullError`, naming the
file, with the temporary removed.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from skyrecon.errors import InputError

__all__ = [
    "DiskFullError",
    "atomic_write",
    "make_temp_dir",
    "sweep_stale_temps",
    "write_bytes_atomic",
    "write_text_atomic",
]

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
# .<name>.<pid>.<random>[.tmp] (files and directories made here)
_TEMP_NAME = re.compile(r"^\..+\.(\d+)\.[A-Za-z0-9_]+(\.tmp)?$")


class DiskFullError(InputError):
    """The disk (or quota) filled up while writing ``path``; nothing was left under its name."""


def _disk_full(exc: OSError, path: Path) -> DiskFullError:
    return DiskFullError(
        "the disk is full (no space left while writing this file); free some space or choose another "
        "--out, then run the command again (finished work is reused where the command supports resuming)",
        path,
    )


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file for writing; on success rename it onto ``path``.

    Creates missing parent directories. On error the temporary file is removed
    and ``path`` is left untouched.

    Example:
        >>> with atomic_write(out / "points.ply") as f:
        ...     f.write(data)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    try:
        encoding, newline = (None, None) if "b" in mode else ("utf-8", "\n")
        with os.fdopen(fd, mode, encoding=encoding, newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes owner-only files; give the usual permissions
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno in _DISK_FULL:
            raise _disk_full(exc, path) from None
        raise


def make_temp_dir(parent: str | Path, name: str) -> Path:
    """A new hidden directory ``parent/.<name>.<pid>.<random>`` to build outputs in before they
    are moved into place (see :func:`sweep_stale_temps`)."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{name}.{os.getpid()}.", dir=parent))


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs. A zombie does not: a killed run's worker whose parent
    died stays a zombie until init reaps it (some container inits never do), and it will never
    finish its temporary."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True  # no /proc (macOS, Windows): the signal check is all there is
    return stat.rsplit(")", 1)[-1].split()[:1] != ["Z"]


def sweep_stale_temps(directory: str | Path, recursive: bool = True) -> int:
    """Remove the temporaries an interrupted run left in ``directory`` (hidden files and folders
    named as this module names them whose process no longer runs). Returns how many were removed.
    Temporaries of a run still going are kept."""
    directory = Path(directory)
    if not directory.is_dir():
        return 0
    removed = 0
    stack = [directory]
    while stack:
        d = stack.pop()
        try:
            entries = list(os.scandir(d))
        except OSError:
            continue
        for e in entries:
            m = _TEMP_NAME.match(e.name)
            if m and not _alive(int(m.group(1))):
                if e.is_dir(follow_symlinks=False):
                    shutil.rmtree(e.path, ignore_errors=True)
                else:
                    with contextlib.suppress(OSError):
                        os.unlink(e.path)
                removed += 1
            elif recursive and e.is_dir(follow_symlinks=False) and not e.name.startswith("."):
                stack.append(Path(e.path))
    return removed


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_write(path, "wb") as f:
        f.write(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    with atomic_write(path, "w") as f:
        f.write(text)
