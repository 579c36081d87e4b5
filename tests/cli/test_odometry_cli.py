"""``skyrecon odometry`` end to end on small synthetic sequences (KITTI and EuRoC layouts).

The command's plumbing (readers, outputs, metrics, GPS, report) is checked with a stand-in engine
that replays the ground truth with a known error; the real engine runs in the tests marked below.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

import skyrecon.cli.odometry as odometry_cli
from skyrecon.cli.main import main
from skyrecon.core.rigid import Rigid3
from skyrecon.io.gps import GpsFix, write_gps_csv
from skyrecon.io.sequence import parse_poses, write_sequence
from skyrecon.io.trajectory import read_tum
from skyrecon.odometry.types import FrameEstimate, TrackingState
from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo
from skyrecon.sim.euroc import write_synthetic_euroc

HAS_ENGINE = importlib.util.find_spec("skyrecon.odometry.engine") is not None


@pytest.fixture(scope="module")
def kitti_seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("odo") / "seq"
    city = generate_city(3, size_m=120.0)
    rig = default_rig(192, 144, baseline_m=0.5)
    poses = flight_poses(city, 12, seed=3, speed_mps=5.0, fps=10.0)
    frames = [render_stereo(city, rig, p.inverse()) for p in poses]
    write_sequence(root, rig, [(f.left, f.right) for f in frames], poses)
    return root, poses


class ReplayEngine:
    """Replays a known trajectory with a 1 % scale error; frame 5 is lost."""

    def __init__(self, truth: list[Rigid3], init: Rigid3 | None):
        first = truth[0].with_frames(None, None).inverse()
        base = (init or Rigid3.identity()).with_frames(None, None)
        rel = [first @ p.with_frames(None, None) for p in truth]
        self.poses = [base @ Rigid3(r.R, 1.01 * r.t) for r in rel]
        self.estimates: list[FrameEstimate] = []

    def track(self, left, right, timestamp_s):
        k = len(self.estimates)
        lost = k == 5
        e = FrameEstimate(
            k,
            timestamp_s,
            self.poses[k].with_frames("world", "left"),
            TrackingState.LOST if lost else TrackingState.OK,
            reason="12 inliers (< 30)" if lost else "",
            n_features=200,
            n_stereo=150,
            n_tracked=120,
            n_inliers=12 if lost else 100,
            timings_ms={"total": 5.0, "pnp": 1.0},
        )
        self.estimates.append(e)
        return e

    def trajectory(self):
        return [e.world_from_left for e in self.estimates]


@pytest.fixture
def replay(monkeypatch, kitti_seq):
    _, truth = kitti_seq

    def fake(rig, init, loop_closure):
        return ReplayEngine(truth, init), {"replay": True, "loop_closure": loop_closure}

    monkeypatch.setattr(odometry_cli, "make_engine", fake)


def test_outputs_and_metrics(kitti_seq, replay, tmp_path, capsys):
    root, truth = kitti_seq
    out = tmp_path / "vo"
    assert main(["odometry", str(root), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "odometry: 12 frames" in err and "1 lost" in err and "ATE" in err
    poses = parse_poses((out / "poses.txt").read_text(), out / "poses.txt")
    assert len(poses) == 12 and poses[0].allclose(Rigid3.identity())  # first frame = world
    tum = read_tum(out / "trajectory.txt")
    assert np.allclose(tum.timestamps_s, np.arange(12) / 10.0)
    assert np.allclose([p.t for p in tum.poses], [p.t for p in poses])
    doc = json.loads((out / "odometry.json").read_text())
    assert doc["summary"]["frames"] == 12 and doc["summary"]["lost"] == 1
    assert doc["summary"]["reasons"]["lost"] == {"12 inliers (< 30)": 1}
    assert set(doc["summary"]["track_ms"]) == {"p50", "p95", "p99", "max"}
    assert len(doc["frames"]) == 12 and doc["frames"][5]["state"] == "lost"
    assert doc["ground_truth"] == "poses.txt" and doc["times_assumed_10hz"]
    m = doc["metrics"]
    # 1 % scale error over a ~5.5 m flight: a few centimetres after alignment
    assert 0.001 < m["ate_rmse_m"] < 0.05
    assert m["rpe_1s"]["pairs"] == 2 and m["drift"]["segments"] == 0
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "Tracking state" in html


def test_init_pose_gt_and_gps_fusion(kitti_seq, replay, tmp_path):
    root, truth = kitti_seq
    gps = [GpsFix(0.1 * k, p.t + np.array([0.3, -0.2, 0.1]), 2.0) for k, p in enumerate(truth)]
    gps[6] = GpsFix(0.6, truth[6].t + np.array([20.0, 0.0, 0.0]), 2.0)  # a multipath jump
    write_gps_csv(tmp_path / "gps.csv", gps)
    out = tmp_path / "vo"
    assert (
        main(
            [
                "odometry",
                str(root),
                "--out",
                str(out),
                "--init-pose",
                "gt",
                "--gps",
                str(tmp_path / "gps.csv"),
            ]
        )
        == 0
    )
    poses = parse_poses((out / "poses_odometry.txt").read_text(), out / "poses_odometry.txt")
    assert poses[0].allclose(truth[0], atol=1e-9)  # the odometry starts in the ground truth's world
    doc = json.loads((out / "odometry.json").read_text())
    g = doc["summary"]["gps"]
    assert g["fixes"] == 12 and g["rejected"] == 1
    fused = parse_poses((out / "poses.txt").read_text(), out / "poses.txt")
    assert max(np.linalg.norm(f.t - t.t) for f, t in zip(fused, truth)) < 1.0
    assert doc["metrics"]["fused"]["rmse_m"] < 1.0


def test_bad_inputs_exit_2_naming_the_file(kitti_seq, tmp_path, capsys):
    root, _ = kitti_seq
    assert main(["odometry", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "nope" in capsys.readouterr().err
    (tmp_path / "gt.txt").write_text("1 2 3\n")
    assert main(["odometry", str(root), "--out", str(tmp_path / "o"), "--gt", str(tmp_path / "gt.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "gt.txt" in err and len(err.splitlines()) == 1
    assert main(["odometry", str(root), "--out", str(root)]) == 2
    with pytest.raises(SystemExit) as exit_:
        main(["odometry", "--help"])
    assert exit_.value.code == 0
    assert "Examples:" in capsys.readouterr().out


def test_euroc_groundtruth_in_the_command(tmp_path, replay, monkeypatch):
    syn = write_synthetic_euroc(tmp_path / "euroc", n_frames=4, seed=4, width=128, height=96)
    from skyrecon.io.euroc import read_euroc

    truth = [p for p in read_euroc(syn.root).world_from_left]  # type: ignore[union-attr]
    monkeypatch.setattr(
        odometry_cli,
        "make_engine",
        lambda rig, init, lc: (ReplayEngine(truth, init), {}),  # type: ignore[arg-type]
    )
    out = tmp_path / "vo"
    assert main(["odometry", str(syn.root), "--out", str(out)]) == 0
    doc = json.loads((out / "odometry.json").read_text())
    assert doc["layout"] == "euroc" and doc["metrics"]["frames"] == 4
    assert doc["rig"]["width"] == 128 and doc["summary"]["frames"] == 4
    tum = read_tum(out / "trajectory.txt")
    assert np.allclose(np.diff(tum.timestamps_s), 0.05, atol=1e-6)


@pytest.mark.skipif(not HAS_ENGINE, reason="the odometry engine (skyrecon.odometry.engine) is not merged yet")
def test_real_engine_on_a_rendered_flight(kitti_seq, tmp_path):
    root, _ = kitti_seq
    out = tmp_path / "vo"
    assert main(["odometry", str(root), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "odometry.json").read_text())
    assert doc["summary"]["lost"] == 0
    assert doc["metrics"]["ate_rmse_m"] < 0.3  # a 5.5 m flight


def test_map_with_poses_from_odometry(kitti_seq, replay, tmp_path, capsys):
    import shutil

    root, truth = kitti_seq
    seq = tmp_path / "no_poses"
    shutil.copytree(root, seq)
    (seq / "poses.txt").unlink()
    assert main(["map", str(seq), "--out", str(tmp_path / "m0")]) == 2
    assert "--poses odometry" in capsys.readouterr().err
    out = tmp_path / "map"
    assert main(["map", str(seq), "--out", str(out), "--poses", "odometry", "--voxel-size", "0.5"]) == 0
    summary = json.loads((out / "map_summary.json").read_text())
    assert summary["poses_from"] == "odometry" and summary["odometry"]["lost"] == 1
    assert summary["voxels"]["occupied"] > 0
    # with poses.txt the odometry starts from its first pose: the same world as the true map
    out2 = tmp_path / "map2"
    assert main(["map", str(root), "--out", str(out2), "--poses", "odometry", "--voxel-size", "0.5"]) == 0
    flown = np.array(json.loads((out2 / "map_summary.json").read_text())["odometry"]["distance_m"])
    true_len = sum(np.linalg.norm(b.t - a.t) for a, b in zip(truth, truth[1:]))
    assert flown == pytest.approx(1.01 * true_len, rel=1e-3)


@pytest.mark.skipif(not HAS_ENGINE, reason="the odometry engine (skyrecon.odometry.engine) is not merged yet")
def test_real_engine_on_a_distorted_euroc_flight(tmp_path):
    syn = write_synthetic_euroc(
        tmp_path / "euroc", n_frames=10, seed=4, width=320, height=240, baseline_m=0.6
    )
    out = tmp_path / "vo"
    assert main(["odometry", str(syn.root), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "odometry.json").read_text())
    assert doc["summary"]["lost"] == 0 and doc["metrics"]["frames"] == 10
    # 10 frames at 20 Hz and 4 m/s: 1.8 m; rectification errors would show as centimetres of drift
    assert doc["metrics"]["ate_rmse_m"] < 0.05, doc["metrics"]["ate_rmse_m"]
