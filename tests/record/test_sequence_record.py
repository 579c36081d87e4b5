"""``skyrecon map --record`` and ``skyrecon odometry --record`` on a 4-frame rendered flight.

map: every frame's camera and image, depth every 5th frame (the first), the occupied voxels at
frame 0 and at the end; odometry: every frame's estimated camera and image, the tracks."""

from __future__ import annotations

import pytest

from skyrecon.cli.main import main

from .readers import mcap_topics, rrd_frames, rrd_rows

pytest.importorskip("rerun")
pytest.importorskip("foxglove")
pytest.importorskip("mcap")

SMALL = ["--width", "320", "--height", "240", "--seed", "3", "--quiet"]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("flight")
    assert main(["render", "sequence", "--frames", "4", "--out", str(out), *SMALL]) == 0
    return out


def _map(flight, out, record, *extra):
    args = ["map", str(flight), "--out", str(out), "--voxel-size", "0.5", "--quiet", "--record", str(record)]
    assert main([*args, *extra]) == 0


def test_map_records_rrd(flight, tmp_path):
    _map(flight, tmp_path / "map", tmp_path / "map.rrd")
    rows = rrd_rows(tmp_path / "map.rrd")
    assert rows[("/world/camera", "Transform3D")] == 4
    assert rows[("/world/camera/image", "EncodedImage")] == 4
    assert rows[("/world/camera/depth", "DepthImage")] == 1
    assert rows[("/images/camera/disparity", "EncodedImage")] == 1
    assert rows[("/world/map/occupied", "Boxes3D")] == 2
    assert rows[("/world/path/camera", "LineStrips3D")] == 1
    assert rrd_frames(tmp_path / "map.rrd", "/world/camera") == [0, 1, 2, 3]
    assert (tmp_path / "map" / "map.json").exists()


def test_map_from_depth_records_mcap(flight, tmp_path):
    _map(flight, tmp_path / "map", tmp_path / "map.mcap", "--depth", "depth_2")
    topics = mcap_topics(tmp_path / "map.mcap")
    assert topics["/camera/image"] == ("foxglove.CompressedImage", 4)
    assert topics["/camera/frustum"] == ("foxglove.SceneUpdate", 4)
    assert topics["/camera/depth"] == ("foxglove.RawImage", 1)
    assert topics["/map/occupied"] == ("foxglove.SceneUpdate", 2)
    assert topics["/tf"] == ("foxglove.FrameTransform", 4)


def test_map_unknown_extension(flight, tmp_path, capsys):
    args = ["map", str(flight), "--out", str(tmp_path / "m"), "--record", str(tmp_path / "m.txt")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "m.txt" in err and ".rrd" in err


def test_odometry_records_rrd_and_mcap(flight, tmp_path):
    for name in ("vo.rrd", "vo.mcap"):
        args = [
            "odometry",
            str(flight),
            "--out",
            str(tmp_path / "vo"),
            "--quiet",
            "--record",
            str(tmp_path / name),
        ]
        assert main(args) == 0
    rows = rrd_rows(tmp_path / "vo.rrd")
    assert rows[("/world/camera", "Transform3D")] == 4
    assert rows[("/world/camera/image", "EncodedImage")] == 4
    assert rows[("/world/path/odometry", "LineStrips3D")] == 1  # the refined track (online: every 20)
    assert rows[("/world/path/truth", "LineStrips3D")] == 1
    assert rrd_frames(tmp_path / "vo.rrd", "/world/camera") == [0, 1, 2, 3]
    topics = mcap_topics(tmp_path / "vo.mcap")
    assert topics["/camera/image"] == ("foxglove.CompressedImage", 4)
    assert topics["/tf"] == ("foxglove.FrameTransform", 4)
    assert topics["/path/odometry"] == ("foxglove.SceneUpdate", 1)
    assert topics["/path/truth"] == ("foxglove.SceneUpdate", 1)


def test_map_without_the_library_says_how_to_install_it(flight, tmp_path, monkeypatch, capsys):
    import builtins

    real_import = builtins.__import__

    def no_rerun(mod, *args, **kwargs):
        if mod == "rerun" or mod.startswith("rerun."):
            raise ImportError("No module named 'rerun'")
        return real_import(mod, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rerun)
    args = ["map", str(flight), "--out", str(tmp_path / "m"), "--record", str(tmp_path / "m.rrd")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'skyrecon[rerun]'" in err, err
    assert not list(tmp_path.iterdir())
