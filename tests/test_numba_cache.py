"""Where Numba's cache goes: the user's or Makefile's ``NUMBA_CACHE_DIR``, beside writable sources,
or a per-user directory for a read-only install."""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import numba
import pytest

from skyrecon import numba_cache
from skyrecon.numba_cache import choose_cache_dir, configure_numba_cache, package_is_writable, user_cache_dir


def _read_only_package(tmp_path: Path) -> Path:
    pkg = tmp_path / "site-packages" / "skyrecon"
    pkg.mkdir(parents=True)
    pkg.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    return pkg


def test_user_cache_dir_follows_xdg(tmp_path):
    assert user_cache_dir({"XDG_CACHE_HOME": str(tmp_path), "HOME": "/h"}) == tmp_path / "skyrecon" / "numba"
    assert user_cache_dir({"HOME": "/h"}) == Path("/h/.cache/skyrecon/numba")
    # the XDG spec says a relative path is invalid and must be ignored
    assert user_cache_dir({"XDG_CACHE_HOME": "rel", "HOME": "/h"}) == Path("/h/.cache/skyrecon/numba")


def test_explicit_numba_cache_dir_and_writable_package_keep_numbas_choice(tmp_path):
    assert choose_cache_dir({"NUMBA_CACHE_DIR": "/somewhere", "HOME": "/h"}, tmp_path) is None
    assert choose_cache_dir({"HOME": "/h"}, tmp_path) is None  # writable: __pycache__ beside the sources


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only directories")
def test_read_only_package_uses_the_per_user_cache(tmp_path):
    pkg = _read_only_package(tmp_path)
    try:
        assert not package_is_writable(pkg)
        env = {"HOME": str(tmp_path / "home"), "XDG_CACHE_HOME": str(tmp_path / "xdg")}
        assert choose_cache_dir(env, pkg) == tmp_path / "xdg" / "skyrecon" / "numba"
        assert choose_cache_dir({**env, "NUMBA_CACHE_DIR": "/x"}, pkg) is None
    finally:
        pkg.chmod(stat.S_IRWXU)


def test_read_only_package_as_seen_by_os_access(tmp_path, monkeypatch):
    """The same choice when the package is read-only for this user (works under root too)."""
    pkg = tmp_path / "pkg"
    (pkg / "__pycache__").mkdir(parents=True)
    monkeypatch.setattr(numba_cache.os, "access", lambda path, mode: Path(path) != pkg / "__pycache__")
    assert not package_is_writable(pkg)
    assert choose_cache_dir({"HOME": str(tmp_path)}, pkg) == tmp_path / ".cache" / "skyrecon" / "numba"


def test_configure_sets_the_environment_and_a_live_numba_config(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)
    monkeypatch.setattr(numba_cache, "package_is_writable", lambda package_dir: False)
    monkeypatch.setattr(numba_cache, "checkout_cache_dir", lambda package_dir: None)
    chosen = configure_numba_cache()
    assert chosen == tmp_path / "xdg" / "skyrecon" / "numba"
    assert os.environ["NUMBA_CACHE_DIR"] == str(chosen) == numba.config.CACHE_DIR
    assert "numba" in sys.modules


def test_configure_leaves_an_explicit_choice_alone(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(numba_cache, "package_is_writable", lambda package_dir: False)
    assert configure_numba_cache() is None
    assert os.environ["NUMBA_CACHE_DIR"] == str(tmp_path)


def test_a_checkout_warmed_by_make_uses_its_cache(tmp_path):
    from skyrecon.numba_cache import choose_cache_dir

    pkg = tmp_path / "src" / "skyrecon"
    pkg.mkdir(parents=True)
    assert choose_cache_dir({}, pkg) is None  # writable, not warmed: Numba's own choice
    (tmp_path / ".numba_cache").mkdir()
    assert choose_cache_dir({}, pkg) == tmp_path / ".numba_cache"
    assert choose_cache_dir({"NUMBA_CACHE_DIR": "/elsewhere"}, pkg) is None
