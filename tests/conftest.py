"""Shared test fixtures: the real data directory and small synthetic scenes."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run, so a CI result is reproducible.
settings.register_profile("skyrecon", derandomize=True, deadline=None)
settings.load_profile("skyrecon")

REPO_ROOT = Path(__file__).resolve().parents[1]


def data_root() -> Path:
    """``$SKYRECON_DATA``, defaulting to ``../shared/data`` beside the checkout."""
    env = os.environ.get("SKYRECON_DATA")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Root of the real benchmark data; skips the test when it is absent."""
    root = data_root()
    if not root.is_dir():
        pytest.skip(f"real data not found at {root} (set SKYRECON_DATA)")
    return root


def require(real_data: Path, relative: str) -> Path:
    """Path of one real data set or file, skipping the test when it is absent."""
    p = real_data / relative
    if not p.exists():
        pytest.skip(f"{p} not present")
    return p
