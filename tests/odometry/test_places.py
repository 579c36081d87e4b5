"""Place recognition and the geometric check on rendered frames, and the command's loop diagnostics."""

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyrecon.cli.main import main
from skyrecon.core.rigid import Rigid3
from skyrecon.io.sequence import write_sequence
from skyrecon.odometry.checks import to_grey
from skyrecon.odometry.frontend import detect_corners, disparity_lookup
from skyrecon.odometry.places import PlaceDatabase, verify_loop
from skyrecon.sim import flight_poses, render_stereo


def _describe(db, flight, k, left, disparity, keyframe, path_m):
    rig = flight.rig
    grey = to_grey(left)
    uv = detect_corners(grey, np.zeros((0, 2), np.float32), 300, (8, 6), 8.0).astype(np.float64)
    d = disparity_lookup(disparity, uv.astype(np.float32))
    L = rig.left
    with np.errstate(invalid="ignore", divide="ignore"):
        z = L.fx * rig.baseline_m / (d + rig.doffs_px)
    z[~(d > 0.5)] = np.nan
    cam = np.column_stack([(uv[:, 0] - L.cx) / L.fx * z, (uv[:, 1] - L.cy) / L.fy * z, z])
    return db.describe(keyframe, k, grey, uv, cam, path_m)


def _check(db, flight, query, world_from_query):
    poses = [p.matrix for p in flight.world_from_left[:21]] + [world_from_query] * 80
    cands = db.candidates(query, poses, min_matches=30)
    L = flight.rig.left
    out = []
    for cand, pairs in cands:
        m = verify_loop(query, cand, pairs, (L.fx, L.fy), (L.cx, L.cy), (L.width, L.height), min_inliers=30)
        out.append((cand, m))
    return out


@pytest.fixture(scope="module")
def places(flight):
    # appearance alone decides here: every old keyframe is a candidate wherever it is
    db = PlaceDatabase(
        (flight.rig.left.width, flight.rig.left.height), min_keyframe_gap=1, min_path_m=0.0, gate_m=1e4
    )
    for k in range(0, 21):
        db.add(_describe(db, flight, k, flight.left[k], flight.disparity[k], k, 0.0))
    return db


def test_revisit_is_found_with_its_relative_pose(city, flight, places):
    # come back near frame 6: 0.4 m to the side, 0.3 m higher, turned 3 degrees
    true = flight.world_from_left[6].matrix.copy()
    true[:3, 3] += true[:3, :3] @ np.array([0.4, -0.3, 0.0])
    true[:3, :3] = Rotation.from_euler("z", 3.0, degrees=True).as_matrix() @ true[:3, :3]  # yaw, world z up
    frame = render_stereo(city, flight.rig, Rigid3.from_matrix(true, "world", "left").inverse())
    query = _describe(places, flight, 100, frame.left, frame.disparity_left_px, 100, 100.0)
    checked = _check(places, flight, query, true)
    found = [(c, m) for c, m in checked if not isinstance(m, str)]
    assert found, ("the revisit was not recognised", [(c.frame, m) for c, m in checked])
    cand, m = found[0]
    assert abs(cand.frame - 6) <= 4
    expected = np.linalg.inv(flight.world_from_left[cand.frame].matrix) @ true
    assert np.linalg.norm(m.candidate_from_current[:3, 3] - expected[:3, 3]) < 0.1
    R = m.candidate_from_current[:3, :3].T @ expected[:3, :3]
    assert math.degrees(math.acos(np.clip((np.trace(R) - 1) / 2, -1, 1))) < 0.5
    assert m.inliers >= 30


def test_elsewhere_in_the_city_no_loop(city, flight, places):
    far = flight_poses(city, 1, seed=11, speed_mps=5.0, fps=10.0)[0]
    assert np.linalg.norm(far.t - flight.world_from_left[0].t) > 30.0
    frame = render_stereo(city, flight.rig, far.inverse())
    query = _describe(places, flight, 100, frame.left, frame.disparity_left_px, 100, 100.0)
    assert all(isinstance(m, str) for _, m in _check(places, flight, query, far.matrix))


def test_command_writes_the_loop_diagnostics(flight, tmp_path):
    seq = tmp_path / "seq"
    write_sequence(
        seq, flight.rig, list(zip(flight.left[:12], flight.right[:12])), flight.world_from_left[:12]
    )
    for extra, enabled in (([], True), (["--no-loop-closure"], False)):
        out = tmp_path / f"out{len(extra)}"
        assert main(["odometry", str(seq), "--out", str(out), "--quiet", *extra]) == 0
        doc = json.loads((out / "odometry.json").read_text())
        lc = doc["summary"]["loop_closure"]
        assert lc["enabled"] is enabled and doc["options"]["loop_closure"] is enabled
        if enabled:
            assert lc["searches"] >= 1 and lc["accepted"] == 0 and "rejected_reasons" in lc
            assert "Loop closure" in (out / "report.html").read_text()
