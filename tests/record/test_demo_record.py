"""``skyrecon demo --record``: a short flight (4 simulated seconds, 40 cycles) on a timeline."""

from __future__ import annotations

import contextlib
import io

import pytest

from skyrecon.cli.main import main

from .readers import mcap_topics, rrd_frames, rrd_rows

pytest.importorskip("rerun")
pytest.importorskip("foxglove")
pytest.importorskip("mcap")

SHORT = ["--seed", "0", "--city-size", "80", "--width", "320", "--time-limit", "4", "--quiet"]
CYCLES = 40


def _demo(tmp_path, record):
    se = io.StringIO()
    with contextlib.redirect_stderr(se), contextlib.redirect_stdout(io.StringIO()):
        code = main(["demo", *SHORT, "--out", str(tmp_path / "out"), "--record", str(record)])
    return code, se.getvalue()


def test_demo_records_rrd(tmp_path):
    code, err = _demo(tmp_path, tmp_path / "demo.rrd")
    assert code == 1, err  # the time limit ends the flight before the goal: still recorded
    rows = rrd_rows(tmp_path / "demo.rrd")
    assert rows[("/world/drone/camera", "Transform3D")] == CYCLES
    assert rows[("/world/drone/camera/image", "EncodedImage")] == CYCLES
    assert rows[("/world/drone/camera/depth", "DepthImage")] == CYCLES // 5
    assert rows[("/images/drone/camera/disparity", "EncodedImage")] == CYCLES // 5
    assert rows[("/world/map/occupied", "Boxes3D")] == 3  # cycles 0 and 20, and the end
    assert rows[("/world/path/planned", "LineStrips3D")] >= 1
    assert rows[("/world/path/flown", "LineStrips3D")] >= 2
    assert rows[("/world/truth/drone", "Transform3D")] == CYCLES
    assert rows[("/world/movers/tracked", "Points3D")] == CYCLES  # movers on: tracked every cycle
    assert rrd_frames(tmp_path / "demo.rrd", "/world/drone/camera") == list(range(CYCLES))


def test_demo_records_mcap(tmp_path):
    code, err = _demo(tmp_path, tmp_path / "demo.mcap")
    assert code == 1, err
    topics = mcap_topics(tmp_path / "demo.mcap")
    assert topics["/drone/camera/image"] == ("foxglove.CompressedImage", CYCLES)
    assert topics["/drone/camera/frustum"] == ("foxglove.SceneUpdate", CYCLES)
    assert topics["/drone/camera/calibration"] == ("foxglove.CameraCalibration", 1)
    assert topics["/drone/camera/depth"] == ("foxglove.RawImage", CYCLES // 5)
    assert topics["/map/occupied"] == ("foxglove.SceneUpdate", 3)
    assert topics["/path/planned"][0] == "foxglove.SceneUpdate"
    assert topics["/tf"] == ("foxglove.FrameTransform", 2 * CYCLES)  # the camera and the true pose
    assert topics["/movers/tracked"] == ("foxglove.PointCloud", CYCLES)


def test_record_refuses_an_unknown_extension_in_one_line(tmp_path, capsys):
    code = main(["demo", *SHORT, "--out", str(tmp_path / "out"), "--record", str(tmp_path / "x.bag")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "x.bag" in err and ".rrd" in err and ".mcap" in err
    assert not (tmp_path / "out").exists()


def test_record_is_for_one_mission(tmp_path, capsys):
    argv = [
        "demo",
        *SHORT,
        "--missions",
        "2",
        "--out",
        str(tmp_path / "o"),
        "--record",
        str(tmp_path / "x.rrd"),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--record records one mission" in err, err
    assert not (tmp_path / "x.rrd").exists()
