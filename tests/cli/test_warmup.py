"""``skyrecon warmup``: the list of groups, bad --only, and one small group run (then the stamp in
the cache makes a second warmup return at once)."""

from __future__ import annotations

import re

import pytest

from skyrecon.cli.main import main
from skyrecon.cli.warmup import GROUPS, selected_groups
from skyrecon.errors import InputError
from skyrecon.jit import cache_fingerprint, read_warm_groups


def test_list_names_every_group_and_runs_nothing(capsys):
    assert main(["warmup", "--list"]) == 0
    out = capsys.readouterr().out
    assert {line.split(":")[0] for line in out.splitlines()} == set(GROUPS)
    assert "skyrecon stereo " in out and "skyrecon plan " in out


def test_only_selects_groups_and_render_comes_first():
    assert selected_groups(None) == list(GROUPS)
    assert selected_groups("map, stereo") == ["render", "stereo", "map"]
    with pytest.raises(InputError, match="unknown group"):
        selected_groups("stereo,nope")
    assert main(["warmup", "--only", "nope"]) == 2


def test_warmup_of_one_group_then_the_stamp_makes_it_instant(capsys):
    assert main(["warmup", "--only", "stereo", "--jobs", "1", "--force"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"render +[\d.]+ s +\d+ kernels compiled", err), err
    assert re.search(r"stereo +[\d.]+ s +\d+ kernels compiled", err), err
    assert re.search(r"warmup: 2 groups in [\d.]+ s, \d+ kernels compiled", err), err
    assert {"render", "stereo"} <= read_warm_groups(cache_fingerprint())
    assert main(["warmup", "--only", "stereo"]) == 0
    assert "warmup: already done" in capsys.readouterr().err
