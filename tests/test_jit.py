"""The compile notice and the record of compiled kernels (Numba's ``numba:compile`` events)."""

from __future__ import annotations

import io
import sys

import numba
import numpy as np

from skyrecon import jit
from skyrecon.jit import COMPILE_NOTICE, CompileRecorder, install_compile_notice


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
