"""Atomic writes: the usual file permissions (mkstemp alone gives owner-only files)."""

import os
import stat

from skyrecon.io.atomic import write_text_atomic


def test_written_files_get_the_usual_permissions(tmp_path):
    mask = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644


def test_a_full_disk_leaves_nothing_and_names_the_file(tmp_path, monkeypatch):
    import errno

    import pytest

    from skyrecon.io import atomic

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", full)
    target = tmp_path / "points.ply"
    with pytest.raises(atomic.DiskFullError, match="disk is full") as info:
        atomic.write_bytes_atomic(target, b"x" * 1000)
    assert "points.ply" in str(info.value)
    assert list(tmp_path.iterdir()) == []  # neither the file nor its temporary


def test_a_full_disk_is_one_error_line_from_the_command_line(tmp_path, monkeypatch, capsys):
    import errno

    from skyrecon.cli.main import main
    from skyrecon.io import atomic

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", full)
    out = tmp_path / "scene"
    assert main(["render", "stereo", "--width", "160", "--height", "120", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "disk is full" in err[0]
    assert [p for p in out.rglob("*") if p.is_file()] == []


def test_a_real_full_disk(tmp_path, capsys):
    """On a 1 MB tmpfs (needs permission to mount; skipped otherwise)."""
    import subprocess

    import pytest

    from skyrecon.cli.main import main

    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True
    ).returncode:
        pytest.skip("cannot mount a small tmpfs here")
    try:
        code = main(
            ["render", "stereo", "--width", "640", "--height", "480", "--out", str(mnt / "s"), "--quiet"]
        )
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "disk is full" in err[0], err
        leftovers = [p.name for p in (mnt / "s").rglob("*") if p.is_file()]
        assert all(not n.startswith(".") for n in leftovers), leftovers  # no temporaries
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_stale_temporaries_of_dead_runs_are_swept(tmp_path):
    import os
    import subprocess

    from skyrecon.io.atomic import sweep_stale_temps

    dead = subprocess.Popen(["true"])
    dead.wait()
    (tmp_path / "sub").mkdir()
    stale = [
        tmp_path / f".points.ply.{dead.pid}.abc123.tmp",
        tmp_path / "sub" / f".depth.pfm.{dead.pid}.x_y.tmp",
    ]
    mine = tmp_path / f".fused.ply.{os.getpid()}.zzz.tmp"
    for p in [*stale, mine]:
        p.write_bytes(b"half")
    (tmp_path / f".map.{dead.pid}.q1w2").mkdir()  # a directory being built by a dead run
    keep = [tmp_path / "points.ply", tmp_path / ".hidden_but_mine"]
    for p in keep:
        p.write_bytes(b"ok")
    assert sweep_stale_temps(tmp_path) == 3
    assert mine.exists() and all(p.exists() for p in keep) and not any(p.exists() for p in stale)


def test_temporaries_of_a_zombie_are_swept(tmp_path):
    """A killed run's worker can stay a zombie (dead, not yet reaped: some container inits never
    reap orphans); it will never finish its temporary, so the next run sweeps it."""
    import subprocess
    import sys
    import time

    import pytest

    from skyrecon.io.atomic import sweep_stale_temps

    if not os.path.exists("/proc/self/stat"):
        pytest.skip("needs /proc to tell a zombie")
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        for _ in range(200):  # exited but not waited for: a zombie
            if open(f"/proc/{child.pid}/stat").read().rsplit(")", 1)[-1].split()[0] == "Z":
                break
            time.sleep(0.05)
        else:
            pytest.fail("the child did not become a zombie")
        stale = tmp_path / f".points.ply.{child.pid}.abc123.tmp"
        stale.write_bytes(b"half")
        assert sweep_stale_temps(tmp_path) == 1
        assert not stale.exists()
    finally:
        child.wait()
