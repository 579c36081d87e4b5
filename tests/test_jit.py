"""The compile notice and the record of compiled kernels (Numba's ``numba:compile`` events)."""

from __future__ import annotations

import io
import os
import sys

import numba
import numpy as np

from skyrecon import jit
from skyrecon.jit import (
    COMPILE_NOTICE,
    CompileRecorder,
    cache_fingerprint,
    install_compile_notice,
    mark_warm,
    read_warm_groups,
)


def _kernel(module: str):
    """A fresh (uncached) jitted function that claims to live in ``module``."""

    def add_one(x):
        return x + 1

    add_one.__module__ = module
    return numba.njit(add_one)


def test_recorder_names_skyrecon_kernels_only():
    ours, theirs = _kernel("skyrecon.fake_kernels"), _kernel("someone_else")
    with CompileRecorder() as recorder:
        ours(1.0)
        theirs(1.0)
        ours(2.0)  # already compiled for float64: no new compilation
        ours(np.int64(2))  # a second specialisation
    assert recorder.names == ["skyrecon.fake_kernels._kernel.<locals>.add_one"] * 2
    _kernel("skyrecon.fake_kernels")(1.0)
    assert len(recorder.names) == 2  # inactive after the block


def test_notice_is_printed_once_before_the_first_compilation():
    stream = io.StringIO()
    try:
        install_compile_notice(stream=stream)
        _kernel("someone_else")(1.0)
        assert stream.getvalue() == ""
        _kernel("skyrecon.fake_kernels")(1.0)
        _kernel("skyrecon.fake_kernels")(1.0)
        assert stream.getvalue() == COMPILE_NOTICE + "\n"
    finally:
        install_compile_notice(enabled=False)
        jit._notice.printed = False


def test_notice_stays_silent_when_disabled_or_nobody_watches(monkeypatch):
    stream, stderr = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stderr", stderr)  # not a terminal
    try:
        install_compile_notice(enabled=False, stream=stream)
        _kernel("skyrecon.fake_kernels")(1.0)
        install_compile_notice(enabled=True)  # to stderr, only when it is a terminal
        _kernel("skyrecon.fake_kernels")(1.0)
        assert stream.getvalue() == stderr.getvalue() == "" and not jit._notice.printed
    finally:
        install_compile_notice(enabled=False)


def test_fingerprint_follows_the_sources(tmp_path):
    (tmp_path / "sub").mkdir()
    source = tmp_path / "sub" / "kernels.py"
    source.write_text("x = 1\n")
    before = cache_fingerprint(tmp_path)
    assert cache_fingerprint(tmp_path) == before
    os.utime(source, ns=(source.stat().st_atime_ns, source.stat().st_mtime_ns + 10**9))
    assert cache_fingerprint(tmp_path) != before


def test_stamp_records_groups_per_fingerprint(tmp_path):
    stamp = tmp_path / "cache" / "skyrecon-warmup.json"
    assert read_warm_groups("a", stamp) == set()
    mark_warm(["render", "stereo"], "a", stamp)
    mark_warm(["map"], "a", stamp)
    assert read_warm_groups("a", stamp) == {"render", "stereo", "map"}
    assert read_warm_groups("b", stamp) == set()  # other sources or CPU: nothing is warm
    mark_warm(["sfm"], "b", stamp)
    assert read_warm_groups("b", stamp) == {"sfm"}
    stamp.write_text("not json")
    assert read_warm_groups("b", stamp) == set()
