"""Give freed memory back to the operating system between the stages of long runs.

A survey or a multi-view run allocates and frees gigabytes of arrays of a few megabytes each
(depth maps, costs, chunks of point clouds). With glibc's allocator most of them live in the
heap (its mmap threshold rises to 32 MB after the first large free), and freed heap pages stay
in the process's resident memory until ``malloc_trim`` hands them back. On the 400-photo survey
the heap held gigabytes of free pages while the map was built. :func:`release_free_memory`,
called at the end of each stage, makes the resident size follow what the run really holds.

Other platforms (and a C library without ``malloc_trim``) make it a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
from typing import Any

_trim: Any = None  # the C function, False where there is none


def _malloc_trim() -> Any:
    global _trim
    if _trim is None:
        _trim = False
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                _trim = libc.malloc_trim
                _trim.argtypes = [ctypes.c_size_t]
                _trim.restype = ctypes.c_int
            except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
                _trim = False
    return _trim


def release_free_memory() -> bool:
    """Return the allocator's free pages to the operating system (glibc ``malloc_trim(0)``).

    Cheap (milliseconds for gigabytes of free heap) and safe to call at any point; it changes no
    data. Returns True when the C library has the call (Linux with glibc), else False (no-op).
    """
    trim = _malloc_trim()
    if not trim:
        return False
    trim(0)
    return True
