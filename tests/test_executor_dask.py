"""The Dask executor: its contract (order, errors, lost workers, closing), its command-line options,
and the same bytes as the serial and process executors for sfm, mvs, map of several flights and
``demo --missions``.

One 2-worker ``LocalCluster`` serves the whole module; the commands join it with ``--scheduler``
(the path a real cluster takes, with its check that the workers run this very skyrecon).
Skipped when Dask's distributed scheduler is not installed (the ``dask`` extra).
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from skyrecon.cli import demo as demo_cli  # noqa: E402
from skyrecon.cli.main import main  # noqa: E402
from skyrecon.core import Intrinsics  # noqa: E402
from skyrecon.errors import InputError  # noqa: E402
from skyrecon.eval.interrupt import compare_outputs  # noqa: E402
from skyrecon.executor import ProcessExecutor, SerialExecutor  # noqa: E402
from skyrecon.executor_dask import DaskExecutor  # noqa: E402
from skyrecon.io import write_image  # noqa: E402
from skyrecon.io.calib import write_K_txt  # noqa: E402
from skyrecon.io.task_cache import map_cached, task_key  # noqa: E402
from skyrecon.mission import small_test_config  # noqa: E402
from skyrecon.sim import generate_object_scene, orbit_views, render_views  # noqa: E402
from tests.cli.test_determinism import _strip  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture(scope="module")
def dask_ex() -> Iterator[DaskExecutor]:
    with DaskExecutor(2) as ex:
        yield ex


# ------------------------------------------------------------------------------------------------
# the executor
# ------------------------------------------------------------------------------------------------
def square_plus(x: int, offset: int = 0) -> int:
    return x * x + offset


def fail_on_three(x: int) -> int:
    if x == 3:
        raise InputError(f"item {x} is bad")
    return x


def die_once(marker: str, x: int | np.ndarray) -> int:
    """Kills its worker process the first time item 2 runs (the marker file records it)."""
    x = int(np.asarray(x).flat[0])
    if x == 2 and not os.path.exists(marker):
        Path(marker).write_text("died")
        os._exit(1)
    return 10 * x


def total(a: np.ndarray) -> float:
    return float(a.sum())


def test_results_in_input_order_with_few_tasks_in_flight(dask_ex):
    dask_ex.max_tasks_in_flight = 2
    try:
        assert dask_ex.map(functools.partial(square_plus, offset=1), range(9)) == [
            x * x + 1 for x in range(9)
        ]
    finally:
        dask_ex.max_tasks_in_flight = 8
    assert dask_ex.map(square_plus, []) == []
    assert dask_ex.workers == 2


def test_task_errors_surface_with_their_type(dask_ex):
    with pytest.raises(InputError, match="item 3 is bad"):
        dask_ex.map(fail_on_three, range(5))


def test_large_items_are_scattered_and_give_the_same_answer(dask_ex):
    arrays = [np.full(300_000, float(k)) for k in range(3)]  # 2.4 MB each, above scatter_bytes
    assert dask_ex.map(total, arrays) == [300_000.0 * k for k in range(3)]


@pytest.mark.parametrize("size", [1, 300_000])  # the large items are scattered: lost with the worker
def test_a_task_whose_worker_dies_runs_again(dask_ex, tmp_path, size):
    marker = tmp_path / "died"
    items = [np.full(size, k) for k in range(4)]
    assert dask_ex.map(functools.partial(die_once, str(marker)), items) == [0, 10, 20, 30]
    assert marker.read_text() == "died"  # the worker did die once


def test_task_cache_results_come_back_through_workspace_files(dask_ex, tmp_path):
    items = list(range(4))
    keys = [task_key(i, "sq") for i in items]
    got, cached = map_cached(dask_ex, square_plus, items, keys, tmp_path / "c")
    assert got == [0, 1, 4, 9] and cached == 0
    assert sorted(p.stem for p in (tmp_path / "c").glob("*.pkl")) == sorted(keys)
    again, cached = map_cached(dask_ex, square_plus, items, keys, tmp_path / "c")
    assert again == got and cached == 4


def test_joining_a_cluster_checks_that_its_workers_run_this_skyrecon(dask_ex, monkeypatch):
    with DaskExecutor(scheduler=dask_ex.address) as joined:
        assert joined.workers == 2 and joined._cluster is None
        assert joined.map(square_plus, [1, 2]) == [1, 4]
    import skyrecon.executor_dask as mod

    monkeypatch.setattr(mod, "code_fingerprint", lambda: "0.0.0+000000000000")  # this side only
    with pytest.raises(InputError, match="run another skyrecon"):
        DaskExecutor(scheduler=dask_ex.address)


def test_close_tears_the_local_cluster_down():
    ex = DaskExecutor(1)
    cluster = ex._cluster
    assert ex.map(square_plus, [3]) == [9]
    ex.close()
    ex.close()  # idempotent
    assert cluster.status.name == "closed"


def test_dask_is_not_imported_with_skyrecon():
    code = "import sys, skyrecon.executor, skyrecon.cli.main; print('distributed' in sys.modules or 'dask' in sys.modules)"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(SRC)},
    )
    assert proc.stdout.strip() == "False", proc.stderr


def test_without_dask_the_error_says_how_to_install(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else real(name, *a)
    )
    with pytest.raises(InputError, match=r"pip install 'skyrecon\[dask\]'"):
        DaskExecutor(2)


# ------------------------------------------------------------------------------------------------
# the command line
# ------------------------------------------------------------------------------------------------
def _cli(argv: list[str]) -> tuple[int, str]:
    se = io.StringIO()
    with contextlib.redirect_stderr(se), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, se.getvalue()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ring(tmp_path_factory) -> Path:
    """6 rendered 192x144 views around a scene with its cameras (for mvs)."""
    d = tmp_path_factory.mktemp("dask_ring")
    argv = ["render", "ring", "--views", "6", "--width", "192", "--height", "144", "--out", str(d), "--quiet"]
    assert main(argv) == 0
    return d


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """6 rendered 320x240 views on an arc around a monument and K.txt (for sfm)."""
    d = tmp_path_factory.mktemp("dask_photos")
    intr = Intrinsics.from_fov(320, 240, 70)
    scene = generate_object_scene(1)
    views = orbit_views(scene, 6, intr, seed=0, arc_deg=80)
    (d / "images").mkdir()
    for v, r in zip(views, render_views(scene, views)):
        write_image(d / "images" / v.name, r.image)
    write_K_txt(d / "K.txt", intr)
    return d


def test_unreachable_scheduler_is_one_line_and_exit_2(ring, tmp_path, monkeypatch):
    monkeypatch.setenv("SKYRECON_SCHEDULER_TIMEOUT", "1")
    address = f"tcp://127.0.0.1:{_free_port()}"
    argv = ["mvs", str(ring / "images"), "--cameras", str(ring / "sparse"), "--out", str(tmp_path / "o")]
    code, err = _cli([*argv, "--scheduler", address, "--quiet"])
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("error: cannot reach the Dask scheduler at " + address)
    code, err = _cli([*argv, "--executor", "process", "--scheduler", address, "--quiet"])
    assert code == 2 and "--scheduler needs --executor dask" in err


EXECUTORS = {
    "serial": ["--executor", "serial"],
    "process": ["--executor", "process", "--workers", "2"],
    "dask": ["--executor", "dask"],  # + --scheduler of the module's cluster
}


def _executor_argv(name: str, dask_ex: DaskExecutor) -> list[str]:
    return EXECUTORS[name] + (["--scheduler", dask_ex.address] if name == "dask" else [])


def test_sfm_same_bytes_on_every_executor(photos, dask_ex, tmp_path):
    outs = {}
    for name in EXECUTORS:
        outs[name] = tmp_path / name
        argv = ["sfm", str(photos / "images"), "--camera", str(photos / "K.txt"), "--out", str(outs[name])]
        code, err = _cli([*argv, "--max-image-size", "256", "--quiet", *_executor_argv(name, dask_ex)])
        assert code == 0, err
    assert (outs["dask"] / "sparse" / "points3D.txt").stat().st_size > 0
    assert compare_outputs(outs["process"], outs["serial"]) == []
    assert compare_outputs(outs["dask"], outs["serial"]) == []


def test_mvs_same_bytes_on_every_executor(ring, dask_ex, tmp_path):
    outs = {}
    for name in EXECUTORS:
        outs[name] = tmp_path / name
        argv = ["mvs", str(ring / "images"), "--cameras", str(ring / "sparse"), "--out", str(outs[name])]
        code, err = _cli([*argv, "--quiet", *_executor_argv(name, dask_ex)])
        assert code == 0, err
    assert sorted(p.name for p in (outs["dask"] / "depth").glob("*.pfm"))
    assert compare_outputs(outs["process"], outs["serial"]) == []
    assert compare_outputs(outs["dask"], outs["serial"]) == []


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> list[Path]:
    """Two rendered 5-frame 160x120 stereo flights (for map)."""
    out = []
    for seed in (3, 4):
        d = tmp_path_factory.mktemp(f"dask_flight{seed}")
        argv = [
            "render",
            "sequence",
            "--frames",
            "5",
            "--seed",
            str(seed),
            "--width",
            "160",
            "--height",
            "120",
        ]
        assert main([*argv, "--out", str(d), "--quiet"]) == 0
        out.append(d)
    return out


def test_map_of_several_flights_same_bytes_on_every_executor(flights, dask_ex, tmp_path):
    outs = {}
    for name in EXECUTORS:
        outs[name] = tmp_path / name
        argv = [
            "map",
            *map(str, flights),
            "--depth",
            "depth_2",
            "--voxel-size",
            "0.5",
            "--out",
            str(outs[name]),
        ]
        code, err = _cli([*argv, "--quiet", *_executor_argv(name, dask_ex)])
        assert code == 0, err
    assert (outs["dask"] / "map.json").is_file()
    assert compare_outputs(outs["process"], outs["serial"]) == []
    assert compare_outputs(outs["dask"], outs["serial"]) == []


def _mission_files(out: Path) -> dict[str, object]:
    """Every file of a batch except the pictures and reports that print loop rates; JSON without
    its timing fields."""
    files: dict[str, object] = {}
    for p in sorted(out.rglob("*")):
        rel = str(p.relative_to(out))
        if not p.is_file() or p.suffix in (".html", ".md"):
            continue
        if p.suffix == ".json":
            doc = _strip(json.loads(p.read_text()))
            files[rel] = _drop_overruns(doc)
        else:
            files[rel] = p.read_bytes()
    return files


def _drop_overruns(obj):
    """Without the loop-rate fields the determinism test's pattern misses (``loop_hz_min``,
    ``latency_overruns``): they measure the machine, not the flight."""
    if isinstance(obj, dict):
        return {k: _drop_overruns(v) for k, v in obj.items() if "overrun" not in k and "_hz" not in k}
    if isinstance(obj, list):
        return [_drop_overruns(v) for v in obj]
    return obj


def test_demo_missions_same_files_on_every_executor(dask_ex, tmp_path, monkeypatch):
    tiny = small_test_config(width=160, height=120, max_disparity=16, city_size_m=60.0,
                             min_goal_distance_m=20.0, max_goal_distance_m=35.0, map_padding_m=15.0,
                             time_limit_s=1.0)  # fmt: skip
    monkeypatch.setattr(demo_cli, "_config", lambda args: tiny)  # travels to the workers in each job
    files = {}
    for name in EXECUTORS:
        out = tmp_path / name
        code, err = _cli(["demo", "--missions", "2", "--seed", "1", "--out", str(out), "--quiet",
                          *_executor_argv(name, dask_ex)])  # fmt: skip
        assert code in (0, 1), err
        files[name] = _mission_files(out)
    assert "seed_0002/mission.json" in files["dask"]
    for name in ("process", "dask"):
        diff = [
            k
            for k in files["serial"].keys() | files[name].keys()
            if files["serial"].get(k) != files[name].get(k)
        ]
        assert diff == [], name


def test_serial_and_process_executors_still_plain(tmp_path):
    """The dask module leaves the other executors alone (no results through files)."""
    assert not getattr(SerialExecutor(), "results_via_files", False)
    assert not getattr(ProcessExecutor(2), "results_via_files", False)
