"""Each backend logs a known small run; its own library reads it back with the expected
entities / topics and counts."""

from __future__ import annotations

import builtins
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.record import NullRecorder, RecordSettings, open_recorder
from skyrecon.record.prepare import cap_points, frustum_lines

from .readers import mcap_topics, rrd_frames, rrd_rows

pytest.importorskip("rerun")
pytest.importorskip("foxglove")
pytest.importorskip("mcap")

K = Intrinsics.from_fov(64, 48, 60.0)


def _log_known(path, settings=None):
    """3 frames of a camera (image, depth, disparity) and a pose; one cloud of 100 points (10 of
    them NaN), 10 voxels, a path and a thumbnail."""
    rng = np.random.default_rng(0)
    with open_recorder(path, settings) as r:
        for i in range(3):
            r.set_time(0.1 * i, i)
            pose = Rigid3(np.eye(3), np.array([float(i), 0.0, 10.0]))
            r.log_camera("camera", K, pose, np.full((48, 64, 3), 40 * i, np.uint8))
            r.log_depth("camera", np.full((24, 32), 5.0, np.float32), K.scaled(0.5))
            r.log_disparity("camera", np.full((48, 64), 3.0, np.float32), 16)
            r.log_pose("drone", pose)
        cloud = rng.normal(size=(110, 3))
        cloud[:10] = np.nan
        r.log_points("cloud", cloud, rng.integers(0, 255, (110, 3), dtype=np.uint8))
        r.log_voxels("map/voxels", rng.normal(size=(10, 3)), 0.5)
        r.log_path("path/flown", np.array([[0, 0, 10], [1, 0, 10], [2, 0, 10.0]]), (0, 255, 0))
        r.log_image("thumb", np.zeros((10, 10), np.uint8))
    return path


def test_rerun_recording_reads_back(tmp_path):
    path = _log_known(tmp_path / "run.rrd")
    rows = rrd_rows(path)
    assert rows[("/world", "ViewCoordinates:static")] == 1
    assert rows[("/world/camera", "Transform3D")] == 3
    assert rows[("/world/camera/image", "Pinhole")] == 1  # logged when it changes
    assert rows[("/world/camera/image", "EncodedImage")] == 3
    assert rows[("/world/camera/depth", "DepthImage")] == 3
    assert rows[("/images/camera/disparity", "EncodedImage")] == 3
    assert rows[("/world/drone", "Transform3D")] == 3
    assert rows[("/world/cloud", "Points3D")] == 1
    assert rows[("/world/map/voxels", "Boxes3D")] == 1
    assert rows[("/world/path/flown", "LineStrips3D")] == 1
    assert rows[("/images/thumb", "EncodedImage")] == 1
    assert rrd_frames(path, "/world/camera") == [0, 1, 2]
    # the cloud's 100 finite points and the 10 voxels
    from rerun.chunk import RrdReader

    sizes = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for col in ("Points3D:positions", "Boxes3D:centers"):
            if col in batch.schema.names:
                sizes[col] = len(batch.column(col)[0])
    assert sizes == {"Points3D:positions": 100, "Boxes3D:centers": 10}
    assert not list(tmp_path.glob(".run.rrd.*"))  # no temporary left beside it
    # the viewer's own check of every archetype against its schema
    rerun_cli = Path(sys.executable).with_name("rerun")
    if rerun_cli.exists():
        proc = subprocess.run(
            [str(rerun_cli), "rrd", "verify", str(path)],
            capture_output=True,
            text=True,
            env={**os.environ, "RERUN_ANALYTICS": "0"},
            timeout=120,
        )
        assert proc.returncode == 0 and "verified without error" in proc.stdout + proc.stderr, proc.stderr


def test_mcap_recording_reads_back(tmp_path):
    path = _log_known(tmp_path / "run.mcap")
    topics = mcap_topics(path)
    assert topics == {
        "/tf": ("foxglove.FrameTransform", 6),
        "/camera/calibration": ("foxglove.CameraCalibration", 1),
        "/camera/frustum": ("foxglove.SceneUpdate", 3),
        "/camera/image": ("foxglove.CompressedImage", 3),
        "/camera/depth": ("foxglove.RawImage", 3),
        "/camera/disparity": ("foxglove.CompressedImage", 3),
        "/drone/pose": ("foxglove.PoseInFrame", 3),
        "/cloud": ("foxglove.PointCloud", 1),
        "/map/voxels": ("foxglove.SceneUpdate", 1),
        "/path/flown": ("foxglove.SceneUpdate", 1),
        "/thumb": ("foxglove.CompressedImage", 1),
    }
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        times = [m.log_time for _, c, m in make_reader(f).iter_messages(topics=["/camera/image"])]
    assert times == [0, 100_000_000, 200_000_000]  # the recorder's time, nanoseconds


def test_mcap_messages_decode_with_their_schemas(tmp_path):
    """The Foxglove protobuf schemas in the file decode the messages: 100 points, 10 cubes of
    0.5 m, a 3-point path, the pinhole's K."""
    pytest.importorskip("mcap_protobuf")
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = _log_known(tmp_path / "run.mcap")
    got = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(
            topics=["/cloud", "/map/voxels", "/path/flown", "/camera/calibration"]
        ):
            got[channel.topic] = msg
    cloud = got["/cloud"]
    assert cloud.frame_id == "world" and len(cloud.data) == 100 * cloud.point_stride == 1600
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "red", "green", "blue", "alpha"]
    cubes = got["/map/voxels"].entities[0].cubes
    assert len(cubes) == 10 and cubes[0].size.x == 0.5
    assert len(got["/path/flown"].entities[0].lines[0].points) == 3
    calib = got["/camera/calibration"]
    assert (calib.width, calib.height, calib.frame_id) == (64, 48, "camera")
    assert np.allclose(np.reshape(calib.K, (3, 3)), K.K)


def test_caps_are_deterministic_and_respected(tmp_path):
    xyz = np.random.default_rng(1).normal(size=(1000, 3))
    a, _ = cap_points(xyz, None, 100)
    b, _ = cap_points(xyz, None, 100)
    assert len(a) == 100 and np.array_equal(a, b)
    path = _log_known(tmp_path / "capped.mcap", RecordSettings(max_points=20, max_voxels=4))
    assert mcap_topics(path)["/cloud"][1] == 1


def test_frustum_starts_at_the_camera_centre():
    pose = Rigid3(np.eye(3), np.array([1.0, 2.0, 3.0]))
    seg = frustum_lines(K, pose, 2.0)
    assert seg.shape == (16, 3)
    assert np.allclose(seg[0], [1, 2, 3]) and np.allclose(seg[1][2], 5.0)


def test_unknown_extension_is_one_clear_error(tmp_path):
    with pytest.raises(InputError, match=r"unknown recording extension '\.bag'.*\.rrd.*\.mcap"):
        open_recorder(tmp_path / "run.bag")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("name", "module", "extra"), [("x.rrd", "rerun", "rerun"), ("x.mcap", "foxglove", "foxglove")]
)
def test_missing_library_gives_the_install_line(tmp_path, monkeypatch, name, module, extra):
    real_import = builtins.__import__

    def fake_import(mod, *args, **kwargs):
        if mod == module or mod.startswith(module + "."):
            raise ImportError(f"No module named '{module}'")
        return real_import(mod, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(InputError, match=rf"pip install 'skyrecon\[{extra}\]'"):
        open_recorder(tmp_path / name)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["run.rrd", "run.mcap"])
def test_an_interrupted_run_leaves_no_recording(tmp_path, name):
    from skyrecon.io.atomic import _TEMP_NAME

    with pytest.raises(RuntimeError), open_recorder(tmp_path / name) as r:
        # named as the other temporaries: one left by a killed run is swept on the next
        assert _TEMP_NAME.match(r.tmp_path.name) and r.tmp_path.parent == tmp_path
        r.set_time(0.0, 0)
        r.log_path("p", np.zeros((2, 3)))
        raise RuntimeError("interrupted")
    assert not list(tmp_path.iterdir())


def test_null_recorder_takes_everything():
    r = open_recorder(None)
    assert isinstance(r, NullRecorder) and not r.enabled
    with r:
        r.set_time(1.0, 1)
        r.log_camera("c", K, Rigid3(), np.zeros((48, 64, 3), np.uint8))
        r.log_points("p", np.zeros((3, 3)))


def test_depth_units_keep_the_range():
    from skyrecon.record.prepare import depth_units

    near = np.array([[0.0, 1.2341, 60.0]], np.float32)
    units, per_m = depth_units(near)
    assert per_m == 1000.0 and units.dtype == np.uint16 and units.tolist() == [[0, 1234, 60000]]
    units, per_m = depth_units(near * 10)
    assert per_m == 100.0 and units[0, 2] == 60000
    units, per_m = depth_units(near * 1000)
    assert per_m == 1.0 and units.dtype == np.float32
