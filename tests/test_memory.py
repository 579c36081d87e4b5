"""Tests for skyrecon.memory: freed heap pages go back to the operating system."""

from __future__ import annotations

import sys

import pytest

from skyrecon.memory import release_free_memory


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def test_release_is_safe_to_call_repeatedly() -> None:
    first = release_free_memory()
    assert release_free_memory() is first


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="resident size read from /proc")
def test_freed_heap_blocks_leave_the_resident_size() -> None:
    if not release_free_memory():
        pytest.skip("the C library has no malloc_trim (not glibc)")
    # 5000 blocks of 60 kB (below glibc's mmap threshold: they live in the heap); the last one
    # stays allocated, so the heap's top cannot simply shrink: the pages in between must be returned
    blocks = [bytes(bytearray(60_000)) for _ in range(5000)]
    last = blocks[-1]
    del blocks
    before = _rss_bytes()
    release_free_memory()
    after = _rss_bytes()
    assert len(last) == 60_000
    assert before - after > 150e6, f"resident size {before / 1e6:.0f} MB -> {after / 1e6:.0f} MB"
