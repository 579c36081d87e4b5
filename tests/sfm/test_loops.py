"""Loop closure in the incremental mapper: a synthetic flight around a ring of walls that comes
back to where it started (tracks from exact correspondences plus noise, no rendering)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skyrecon.core import Intrinsics, Rigid3
from skyrecon.eval.sfm_metrics import evaluate_sfm_poses
from skyrecon.sfm.mapper import IncrementalMapper, MapperInput, MapperOutput
from skyrecon.sfm.matching import PairGeometry
from skyrecon.sfm.settings import BundleSettings, MapperSettings
from skyrecon.sfm.tracks import build_tracks

CAM = Intrinsics.from_fov(320, 240, 70)


def _loop_flight(n_frames: int = 64, seed: int = 0) -> tuple[MapperInput, dict[str, Rigid3]]:
    """Cameras on a 6 m circle looking outward at a 20 m ring of wall points, 1.1 turns (the
    last frames see what the first ones saw); 0.5 px keypoint noise; pairs within 3 frames plus
    the revisit pairs."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, 3000)
    pts = np.stack([20 * np.cos(a), 20 * np.sin(a), rng.uniform(-4, 4, 3000)], axis=1)
    names, gt, kps, ids = [], {}, [], []
    for k in range(n_frames):
        th = 1.1 * 2 * np.pi * k / n_frames
        eye = np.array([6 * np.cos(th), 6 * np.sin(th), 0.0])
        wfc = Rigid3.look_at(eye, eye + np.array([np.cos(th + 0.5), np.sin(th + 0.5), 0.0]))
        cfw = wfc if wfc.dst == "cam" else wfc.inverse()
        P = pts @ cfw.R.T + cfw.t
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = P[:, :2] / P[:, 2:] * [CAM.fx, CAM.fy] + [CAM.cx, CAM.cy]
        vis = (
            (P[:, 2] > 1)
            & (uv[:, 0] > 0)
            & (uv[:, 0] < CAM.width - 1)
            & (uv[:, 1] > 0)
            & (uv[:, 1] < CAM.height - 1)
        )
        vis &= rng.random(len(pts)) < 0.8
        names.append(f"frame_{k:03d}.png")
        gt[names[-1]] = cfw
        kps.append(uv[vis] + rng.normal(0, 0.5, (int(vis.sum()), 2)))
        ids.append(np.nonzero(vis)[0])
    pairs, track_pairs = [], []
    for i in range(n_frames):
        for j in range(i + 1, n_frames):
            if j - i > 3 and not (j - i > n_frames - 12):
                continue
            _, ii, jj = np.intersect1d(ids[i], ids[j], return_indices=True)
            if len(ii) < 20:
                continue
            m = np.stack([ii, jj], axis=1).astype(np.int32)
            rel = gt[names[j]] @ gt[names[i]].inverse()
            t = rel.t / np.linalg.norm(rel.t)
            pairs.append(PairGeometry(i, j, "ok", len(m), m, rel.R, t, 6.0))
            track_pairs.append((i, j, m))
    tracks = build_tracks([len(k) for k in kps], track_pairs, kps)
    data = MapperInput(
        names,
        kps,
        [np.full(len(k), 4.0, np.float32) for k in kps],
        [np.zeros((len(k), 3), np.uint8) for k in kps],
        [CAM],
        np.zeros(n_frames, np.int64),
        tracks,
        pairs,
        np.ones(n_frames, bool),
    )
    return data, gt


def _run(data: MapperInput, **kw) -> MapperOutput:
    s = replace(MapperSettings(init_min_inliers=50, focal_check_tolerance=0.0, loop_min_gap=20), **kw)
    return IncrementalMapper(data, s, BundleSettings(), seed=0).run()


def _max_center_pct(out: MapperOutput, data: MapperInput, gt: dict[str, Rigid3]) -> float:
    est = {data.names[i]: Rigid3(out.R[i], out.t[i]) for i in np.nonzero(out.registered)[0]}
    return evaluate_sfm_poses(est, gt).summary()["center_max_pct"]


@pytest.fixture(scope="module")
def flight():
    return _loop_flight()


def test_loop_is_detected_and_closed(flight):
    data, gt = flight
    out = _run(data, loop_consistent_error_ratio=0.0)  # adjust every loop
    assert out.registered.all()
    d = out.diagnostics
    assert d["loops_detected"] >= 1 and d["loop_global_ba"] == d["loops_detected"]
    assert all(ev["accepted"] and ev["adjusted"] for ev in d["loops"])
    runs = d["global_ba_runs"]
    assert len(runs) == d["global_ba"] and runs[-1]["final"] and runs[-1]["images"] == len(data.names)
    assert all(r["iterations"] >= 1 and 0 < r["solver_s"] <= r["seconds"] for r in runs)
    assert d["loop_fallbacks"] == 0
    without = _run(data, loop_min_gap=0)
    assert without.diagnostics["loops_detected"] == 0
    assert _max_center_pct(out, data, gt) <= 1.1 * _max_center_pct(without, data, gt) + 0.05


def test_a_loop_that_already_fits_is_not_adjusted(flight):
    """This flight drifts too little for its loop to show: the loop's points fit all their views
    about as well as the model's, so no global adjustment runs for it, and the model is as good
    as with one."""
    data, gt = flight
    out = _run(data)
    d = out.diagnostics
    assert d["loops_detected"] >= 1 and d["loop_global_ba"] == 0
    assert all(not ev["adjusted"] and ev["loop_rms_px"] <= 1.5 * ev["rms_before_px"] for ev in d["loops"])
    adjusted = _run(data, loop_consistent_error_ratio=0.0)
    assert _max_center_pct(out, data, gt) <= 1.1 * _max_center_pct(adjusted, data, gt) + 0.05


def test_a_loop_that_shows_drift_is_adjusted(flight, monkeypatch):
    """The same flight with a drift put in before the loop is handled (each registration's
    camera, and the points it saw, shifted 1 cm further than the last one's, 0.5 m at the
    loop): the loop's points no longer fit their first views, so the global adjustment runs and
    brings the model back to the undrifted one's accuracy."""
    data, gt = flight
    original = IncrementalMapper._close_loop

    def drifted(self, image, loop_tracks):
        shift = np.clip(self.rank - 5, 0, None)[:, None] * np.array([0.01, 0.0, 0.0])
        self.t[self.reg] -= np.einsum("kij,kj->ki", self.R[self.reg], shift[self.reg])
        obs = np.nonzero(self.active)[0]
        cnt = np.bincount(self.obs_track[obs], minlength=self.n_tracks)
        for a in range(3):
            moved = np.bincount(self.obs_track[obs], shift[self.obs_img[obs], a], minlength=self.n_tracks)
            self.X[:, a] += np.where(self.has_pt, moved / np.maximum(cnt, 1), 0.0)
        return original(self, image, loop_tracks)

    clean = _run(data)
    monkeypatch.setattr(IncrementalMapper, "_close_loop", drifted)
    out = _run(data)
    d = out.diagnostics
    assert d["loops_detected"] >= 1 and d["loop_global_ba"] >= 1
    first = d["loops"][0]
    assert first["adjusted"] and first["accepted"]
    assert first["loop_rms_px"] > 1.5 * first["rms_before_px"]
    assert _max_center_pct(out, data, gt) < 2 * max(_max_center_pct(clean, data, gt), 0.05)


def test_a_loop_step_that_fits_worse_is_undone(flight, monkeypatch):
    """A global adjustment that ruins the model (here: one that shifts every camera) is rolled
    back, the loop's observations are dropped, and the result says so."""
    data, gt = flight
    good = _run(data, loop_min_gap=0)
    original = IncrementalMapper._global_ba

    def broken(self, rounds=1, max_iterations=None, final=False, function_tolerance=None):
        rep = original(self, rounds, max_iterations, final, function_tolerance)
        if not final and max_iterations == self.b.global_max_iterations:
            self.t[self.reg] += 0.5  # a bad loop: the model no longer fits its observations
        return rep

    monkeypatch.setattr(IncrementalMapper, "_global_ba", broken)
    out = _run(data, loop_consistent_error_ratio=0.0)
    d = out.diagnostics
    assert d["loops_detected"] >= 1
    assert d["loop_fallbacks"] == d["loops_detected"]
    assert not any(ev["accepted"] for ev in d["loops"])
    assert any("loop closure" in w and "undone" in w for w in out.warnings)
    assert out.registered.all()
    assert _max_center_pct(out, data, gt) < 2 * max(_max_center_pct(good, data, gt), 0.05)


def _mapper_with_first_frames(data: MapperInput, registered: int, reach: int) -> IncrementalMapper:
    """A mapper whose first ``registered`` frames are in the model with every point they see."""
    m = IncrementalMapper(replace(data, sequence_reach=reach), MapperSettings(), BundleSettings(), seed=0)
    m.reg[:registered] = True
    seen = np.unique(m.obs_track[m.obs_img < registered])
    m.has_pt[seen] = True
    m.X[seen] = 0.0
    return m


def test_a_flight_grows_along_the_sequence_before_loop_pairs(flight):
    """A frame that only loop pairs reach (here a revisit that sees more model points than the
    next frame of the flight) waits until the frames along the flight have been tried: loop
    pairs between look-alike places must not decide where the flight goes next."""
    data, _ = flight
    unordered = _mapper_with_first_frames(data, 12, reach=0)._next_candidates()
    revisits = [i for i in unordered if i > 40]
    assert revisits and unordered.index(revisits[0]) < unordered.index(12)  # the case at stake
    cand = _mapper_with_first_frames(data, 12, reach=3)._next_candidates()
    along = [i for i in cand if i <= 11 + 3]
    assert cand[0] == 12 and cand[: len(along)] == along
    assert sorted(cand) == sorted(unordered)  # nothing is dropped, only reordered


def test_a_flight_with_sequence_reach_still_closes_its_loop(flight):
    data, gt = flight
    out = IncrementalMapper(
        replace(data, sequence_reach=3),
        MapperSettings(init_min_inliers=50, focal_check_tolerance=0.0, loop_min_gap=20),
        BundleSettings(),
        seed=0,
    ).run()
    assert out.registered.all()
    assert out.diagnostics["loops_detected"] >= 1 and out.diagnostics["loop_fallbacks"] == 0
    order = out.registration_order
    assert all(min(abs(f - g) for g in order[:k]) <= 3 for k, f in enumerate(order) if k >= 2)
    assert _max_center_pct(out, data, gt) <= 1.1 * _max_center_pct(_run(data), data, gt) + 0.05


def test_a_long_chain_with_noisy_keypoints_keeps_its_scale(flight):
    """The flight without its revisit (50 frames, each seeing the wall 14 m away from 0.65 m
    further on) with 0.5 px keypoint noise, twice the default loss scale: the loss follows the
    measured noise, so the chain does not collapse into a spin on the spot (62 % centre error
    with the loss scale held at 0.25 px)."""
    data, gt = flight
    usable = np.arange(len(data.names)) < 50
    out = _run(replace(data, usable=usable, sequence_reach=3))
    assert out.registered[:50].all()
    assert 0.3 < out.diagnostics["loss_scale_px"] < 0.7  # about the keypoints' 0.5 px noise
    first = {k: v for k, v in gt.items() if int(k[6:9]) < 50}
    assert _max_center_pct(out, data, first) < 3.0


def test_global_adjustments_converge_tightly_only_in_the_last_final_round(flight, monkeypatch):
    """Periodic global runs stop at ``periodic_function_tolerance``, the final refinement's
    rounds before the last at ``global_function_tolerance`` (filtering and re-triangulation
    follow them) and its last round at ``final_function_tolerance``."""
    data, gt = flight
    calls: list[float] = []
    adjust = IncrementalMapper._adjust

    def spy(self, var_images, tracks, max_iterations, refine_intrinsics, function_tolerance=1e-6, **kw):
        if refine_intrinsics:  # the global runs (local ones hold the intrinsics)
            calls.append(function_tolerance)
        return adjust(self, var_images, tracks, max_iterations, refine_intrinsics, function_tolerance, **kw)

    monkeypatch.setattr(IncrementalMapper, "_adjust", spy)
    out = _run(data)
    b = BundleSettings()
    runs = out.diagnostics["global_ba_runs"]
    assert [len(r["round_iterations"]) for r in runs] == [len(r["observations"]) for r in runs]
    assert sum(len(r["round_iterations"]) for r in runs) == len(calls)
    tolerances = iter(calls)
    per_run = [[next(tolerances) for _ in r["round_iterations"]] for r in runs]
    assert set(per_run[0]) == {b.global_function_tolerance}  # the initial pair's
    finals = [k for k, r in enumerate(runs) if r["final"]]
    assert finals and all(r["rounds"] == 1 for r in runs[1 : finals[0]])
    assert all(t == [b.periodic_function_tolerance] for t in per_run[1 : finals[0]])
    for k in finals:
        assert per_run[k][-1] == b.final_function_tolerance
        assert set(per_run[k][:-1]) <= {b.global_function_tolerance}
    assert len(per_run[finals[0]]) >= 2  # the final refinement adjusts, filters, adjusts again
    assert out.registered.all() and _max_center_pct(out, data, gt) < 2.0
