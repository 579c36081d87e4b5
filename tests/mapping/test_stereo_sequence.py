"""Occupancy map from a stereo sequence (what ``skyrecon map`` runs): accuracy against the true
city, no obstacles beyond the trusted range, only measured pixels, the command uses the same code."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.cli.main import main
from skyrecon.errors import InputError
from skyrecon.io.sequence import write_sequence
from skyrecon.mapping import (
    StereoMapper,
    StereoMapSettings,
    load_map,
    map_stereo_sequence,
    stereo_hit_range_m,
)
from skyrecon.perception import PerceptionSettings, disparity_discontinuities
from skyrecon.sim import default_rig, flight_poses, generate_city, render_stereo

VOXEL = 0.5
HALF_DIAGONAL = 0.5 * np.sqrt(3) * VOXEL


@pytest.fixture(scope="module")
def flight():
    """(city, rig, poses, frames): 5 stereo frames 320x240 (0.6 m baseline: trusted range ~19.6 m
    at 0.5 m voxels) of a flight down a street with buildings 5 to 40 m away."""
    city = generate_city(7, 200.0)
    rig = default_rig(320, 240, 90.0, 0.6)
    poses = flight_poses(city, 5, seed=7, fps=2.0)
    return city, rig, poses, [render_stereo(city, rig, p.inverse()) for p in poses]


def _map(flight, **overrides) -> StereoMapper:
    _, rig, poses, frames = flight
    return map_stereo_sequence(
        ((f.left, f.right) for f in frames), rig, poses, voxel_size_m=VOXEL, **overrides
    )


def _nearest_camera_m(centres: np.ndarray, poses) -> np.ndarray:
    cams = np.array([p.t for p in poses])
    return np.min(np.linalg.norm(centres[:, None, :] - cams[None], axis=2), axis=1)


def test_stereo_map_is_accurate_and_stops_at_the_trusted_range(flight):
    city, rig, poses, _ = flight
    mapper = _map(flight)
    assert mapper.hit_range_m == pytest.approx(stereo_hit_range_m(rig, VOXEL, 40.0), rel=1e-9)
    assert 18.0 < mapper.hit_range_m < 21.0 and mapper.map.config.max_range_m == mapper.hit_range_m
    centres = mapper.map.occupied_centers()
    assert len(centres) > 1000
    # precision: occupied voxels overlap the true geometry (ground included)
    precision = np.mean(city.distance(centres, include_ground=True) <= HALF_DIAGONAL)
    assert precision > 0.85, precision
    # no obstacle beyond the trusted range (plus the band of voxels a surface point may mark
    # behind it) but the ground's hits, under the ground level (GroundSettings.beyond_trusted)
    band = mapper.map.config.grazing_cap_voxels * VOXEL + HALF_DIAGONAL
    above = centres[:, 2] > 0.0
    assert _nearest_camera_m(centres[above], poses).max() <= mapper.hit_range_m + band
    ground = centres[~above]
    assert len(ground) > 100 and np.all(ground[:, 2] == -0.25)
    # without the range limit the same frames put thousands of (noisier) obstacles farther away
    loose = _map(flight, max_depth_error_m=100.0)
    far = loose.map.occupied_centers()
    far = far[(_nearest_camera_m(far, poses) > mapper.hit_range_m + band) & (far[:, 2] > 0.0)]
    assert len(far) > 1000
    assert np.mean(city.distance(far, include_ground=True) <= HALF_DIAGONAL) < precision - 0.1
    summary = mapper.timings.summary()
    assert summary["frames"] == len(poses) and len(mapper.timings.integrate_s) == len(poses)


def test_only_measured_pixels_away_from_discontinuities_are_used(flight):
    _, rig, _, frames = flight
    mapper = StereoMapper(rig, voxel_size_m=VOXEL, plane_fill=False)
    f = frames[0]
    depth = mapper.depth(f.left, f.right)
    result = mapper.matcher.compute(f.left, f.right)
    assert result.filled.any()  # the matcher did fill some pixels...
    ok = np.isfinite(depth)
    assert not np.any(ok & ~result.measured)  # ...that never reach the map
    assert not np.any(ok & disparity_discontinuities(result.disparity, 1.0))
    assert ok.mean() > 0.5
    # measured depth agrees with the truth where the map may use it
    near = ok & (depth < mapper.hit_range_m)
    err = np.abs(depth[near] - f.depth_left_m[near])
    assert np.median(err) < 0.3 and np.mean(err < 1.0) > 0.9, (np.median(err), np.mean(err < 1.0))


def test_disparity_discontinuities():
    d = np.full((10, 12), 20.0, np.float32)
    d[:, 6:] = 30.0
    d[0, 0] = np.nan
    edge = disparity_discontinuities(d, 1.0)
    assert edge[:, 5:7].all() and not edge[5:, :5].any() and not edge[:, 8:].any()
    assert edge[0, 1] and edge[1, 1]  # next to an invalid pixel


def test_bad_input(flight):
    _, rig, poses, frames = flight
    pairs = [(f.left, f.right) for f in frames]
    with pytest.raises(InputError, match="poses"):
        map_stereo_sequence(pairs, rig, poses[:2], voxel_size_m=VOXEL)
    with pytest.raises(InputError, match="no stereo frames"):
        map_stereo_sequence([], rig, poses, voxel_size_m=VOXEL)
    with pytest.raises(InputError):
        StereoMapSettings(voxel_size_m=-1.0)
    with pytest.raises(InputError, match="frame 0"):
        map_stereo_sequence([(frames[0].left[:100], frames[0].right[:100])], rig, poses, voxel_size_m=VOXEL)


def test_command_line_runs_the_same_stereo_mapper(flight, tmp_path):
    _, rig, poses, frames = flight
    seq = tmp_path / "seq"
    write_sequence(seq, rig, ((f.left, f.right) for f in frames), poses)
    out = tmp_path / "map"
    assert main(["map", str(seq), "--out", str(out), "--voxel-size", str(VOXEL), "--quiet"]) == 0
    cli = load_map(out)
    lib = _map(flight).map
    assert cli.config.max_range_m == pytest.approx(lib.config.max_range_m)
    assert cli.config.prob_hit == lib.config.prob_hit and cli.config.prob_miss == lib.config.prob_miss
    a = {tuple(v) for v in cli.occupied_voxels().tolist()}
    b = {tuple(v) for v in lib.occupied_voxels().tolist()}
    assert len(a ^ b) <= 0.01 * len(b)


def test_settings_overrides_reach_the_perception_rules():
    s = StereoMapSettings(voxel_size_m=0.5).with_overrides(
        max_disparity=64, max_depth_error_m=1.0, prob_hit=0.7
    )
    assert s.perception == PerceptionSettings.mapping(max_disparity=64, max_depth_error_m=1.0)
    assert (s.voxel_size_m, s.prob_hit) == (0.5, 0.7)
    flying = s.with_overrides(perception=PerceptionSettings.flight(), depth_stride=1)
    assert flying.perception == PerceptionSettings.flight(depth_stride=1)
    with pytest.raises(InputError, match="unknown"):
        s.with_overrides(voxels=3)


def test_command_line_flat_ground_learns_the_ground_level(flight, tmp_path):
    """``skyrecon map`` learns the ground level by default (``--no-flat-ground`` turns it
    off): the level is the city's ground (z = 0), and the ground adds no free space (its hits
    are tested in test_ground_level)."""
    _, rig, poses, frames = flight
    seq = tmp_path / "seq"
    write_sequence(seq, rig, ((f.left, f.right) for f in frames), poses)
    out = tmp_path / "map"
    args = ["map", str(seq), "--out", str(out), "--voxel-size", str(VOXEL), "--quiet"]
    assert main(args) == 0
    cli = load_map(out)
    lib = _map(flight)
    assert lib.ground is not None and lib.ground.z_m == pytest.approx(0.0, abs=0.3)
    plain = _map(flight, ground=None).map
    assert main([*args[:3], str(tmp_path / "off"), *args[4:], "--no-flat-ground"]) == 0
    off = {tuple(v) for v in load_map(tmp_path / "off").occupied_voxels().tolist()}
    assert len(off ^ {tuple(v) for v in plain.occupied_voxels().tolist()}) <= 0.01 * len(off)
    a = {tuple(v) for v in cli.occupied_voxels().tolist()}
    b = {tuple(v) for v in lib.map.occupied_voxels().tolist()}
    assert len(a ^ b) <= 0.01 * len(b)
    assert lib.map.counts()["free"] == plain.counts()["free"]  # no free space carved by the ground


def test_command_line_says_how_far_stereo_is_trusted(flight, tmp_path, capsys):
    """The stereo map marks obstacles only within the trusted range (2 voxels of depth error);
    the command says how far that is, and when nothing lies within it, what reaches farther
    (one line, exit status 2) rather than blaming the depth or the poses."""
    _, rig, poses, frames = flight
    seq = tmp_path / "seq"
    write_sequence(seq, rig, ((f.left, f.right) for f in frames), poses)
    trusted = stereo_hit_range_m(rig, VOXEL, 40.0)
    assert main(["map", str(seq), "--out", str(tmp_path / "ok"), "--voxel-size", str(VOXEL)]) == 0
    assert f"stereo depth is trusted to {trusted:.1f} m at {VOXEL:g} m voxels" in capsys.readouterr().err
    tiny = stereo_hit_range_m(rig, VOXEL, 40.0, max_depth_error_m=0.02)
    args = ["map", str(seq), "--out", str(tmp_path / "near"), "--voxel-size", str(VOXEL), "--quiet"]
    assert main([*args, "--max-depth-error", "0.02"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"within {tiny:.1f} m" in err[0] and "larger --max-depth-error" in err[0]
    assert not (tmp_path / "near").exists()


def test_the_range_hint_scales_with_the_voxel(flight):
    from skyrecon.cli.map import _range_hint

    rig = flight[1]  # trusted to 19.6 m at 0.5 m voxels, 12.4 m at 0.2 m
    fine = StereoMapSettings(voxel_size_m=0.2, max_range_m=40.0)
    assert StereoMapper(rig, fine).hit_range_m == pytest.approx(12.4, abs=0.05)
    assert "--voxel-size 0.5 trusts depth to 19.6 m" in _range_hint(fine, rig)  # range ~ sqrt(voxel)
    assert "fly closer" in _range_hint(StereoMapSettings(voxel_size_m=0.5, max_range_m=40.0), rig)
    assert "larger --max-depth-error" in _range_hint(fine.with_overrides(max_depth_error_m=0.2), rig)


def _same_map(a, b) -> bool:
    return np.array_equal(a.grid.block_coords, b.grid.block_coords) and np.array_equal(
        a.grid.blocks, b.grid.blocks, equal_nan=True
    )


def test_overlapped_integration_builds_the_same_map_and_times_every_frame(flight):
    _, rig, poses, frames = flight
    overlapped = StereoMapper(rig, voxel_size_m=VOXEL, overlap=True)
    inline = StereoMapper(rig, voxel_size_m=VOXEL, matcher=overlapped.matcher, overlap=False)
    for f, p in zip(frames, poses):
        late = overlapped.add_frame(f.left, f.right, p)
        now = inline.add_frame(f.left, f.right, p)
        assert late.stats is None and now.stats is not None
        np.testing.assert_array_equal(late.depth_m, now.depth_m)
    # the last frame is still waiting: reading the map integrates it
    assert overlapped._pending is not None
    assert _same_map(overlapped.map, inline.map) and overlapped._pending is None
    assert overlapped.ground is not None and overlapped.ground.z_m == inline.ground.z_m
    assert len(overlapped.timings.depth_s) == len(overlapped.timings.integrate_s) == len(frames)
    # a checkpoint's state holds every frame added, and a restored mapper carries on from it
    state = overlapped.resume_state()
    assert state[0] is overlapped.map


def test_overlapped_integration_hands_its_errors_to_the_caller(flight, monkeypatch):
    _, rig, poses, frames = flight
    mapper = StereoMapper(rig, voxel_size_m=VOXEL, overlap=True)
    f = frames[0]
    with pytest.raises(InputError, match="world_from_cam"):  # a bad pose is refused at once
        mapper.add_frame(f.left, f.right, poses[0].inverse())
    mapper.add_frame(f.left, f.right, poses[0])  # waits to be integrated

    def broken(*args, **kwargs):
        raise RuntimeError("update failed")

    monkeypatch.setattr(mapper._map, "integrate_depth", broken)
    with pytest.raises(RuntimeError, match="update failed"):  # the background update's error
        mapper.add_frame(frames[1].left, frames[1].right, poses[1])
    # a frame whose images are refused still has the waiting frame integrated
    monkeypatch.undo()
    mapper = StereoMapper(rig, voxel_size_m=VOXEL, overlap=True)
    mapper.add_frame(f.left, f.right, poses[0])
    with pytest.raises(InputError):
        mapper.add_frame(f.left[:10], f.right, poses[1])
    assert mapper._pending is None and len(mapper.map.occupied_centers()) > 100
