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
