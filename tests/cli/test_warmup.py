"""``skyrecon warmup``: the list of groups, bad --only, and one small group run twice (the second
run compiles nothing: everything it needs is cached)."""

from __future__ import annotations

import re

import pytest

from skyrecon.cli.main import main
from skyrecon.cli.warmup import GROUPS, selected_groups
from skyrecon.errors import InputError


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


def test_warmup_of_one_group_is_idempotent(capsys):
    assert main(["warmup", "--only", "stereo", "--jobs", "1"]) == 0
    capsys.readouterr()
    assert main(["warmup", "--only", "stereo", "--jobs", "1"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"render .* 0 kernels compiled", err), err
    assert re.search(r"stereo .* 0 kernels compiled", err), err
    assert re.search(r"warmup: 2 groups in [\d.]+ s, 0 kernels compiled", err), err
