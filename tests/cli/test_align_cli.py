"""End to end: ``skyrecon align`` on models and clouds of a rendered scene with exactly known transforms.

The "world" is a synthetic monument: true cameras on an orbit, true surface points from the
renderer's depth. A "model" is that world seen through a known similarity (as SfM would give it,
in its own gauge); aligning it back must recover the inverse."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrecon.cli.align import match_names, read_init, read_positions
from skyrecon.cli.main import main
from skyrecon.core import DepthMap, Image, Intrinsics, Point3D, PointCloud, Reconstruction, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.io import read_colmap_text, read_ply, write_colmap_text, write_ply
from skyrecon.sfm.align import Sim3
from skyrecon.sim import generate_object_scene, orbit_views, render_views

CAM = Intrinsics.from_fov(160, 120, 70)
#: model_from_world of the test model: a turn, an offset and SfM's arbitrary scale.
MODEL_FROM_WORLD = Sim3(rotvec_to_matrix([0.3, -1.2, 0.5]), [1.0, 2.0, -3.0], 0.37)


def _reconstruction(
    views, xyz: np.ndarray, rgb: np.ndarray, names=None, noise_m: float = 0.0
) -> Reconstruction:
    """A COLMAP-like model of the true cameras and points: keypoints are the exact projections;
    ``noise_m`` jitters the stored points like triangulation noise (seeded)."""
    rec = Reconstruction({1: CAM})
    tracks: list[list[tuple[int, int]]] = [[] for _ in range(len(xyz))]
    for k, v in enumerate(views, start=1):
        pc = v.cam_from_world.apply(xyz)
        uv = CAM.project(pc)
        vis = np.nonzero((pc[:, 2] > 0.1) & CAM.in_image(uv))[0]
        ids = np.arange(1, len(xyz) + 1)[vis]
        rec.images[k] = Image(k, names[k - 1] if names else v.name, 1, v.cam_from_world, uv[vis], ids)
        for j, p in enumerate(vis):
            tracks[p].append((k, j))
    stored = xyz + np.random.default_rng(7).normal(0.0, noise_m, xyz.shape) if noise_m else xyz
    for p in range(len(xyz)):
        rec.points3d[p + 1] = Point3D(
            p + 1, stored[p], rgb[p], 0.0, np.array(tracks[p], np.int64).reshape(-1, 2)
        )
    return rec


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """True views, true sparse points (a random subset of the surfaces) and a dense cloud PLY."""
    d = tmp_path_factory.mktemp("world")
    scene = generate_object_scene(2)
    views = orbit_views(scene, 8, CAM, seed=1, arc_deg=150)
    clouds = [
        DepthMap(r.depth_m, CAM, v.cam_from_world).to_points_world(r.image)
        for v, r in zip(views, render_views(scene, views))
    ]
    dense = PointCloud.concatenate(clouds)
    rng = np.random.default_rng(0)
    near = np.linalg.norm(dense.points - scene.center, axis=1) < 12.0  # the monument and the plaza around it
    idx = rng.permutation(np.nonzero(near)[0])
    sparse = dense.select(idx[:1500])
    cloud = dense.select(np.sort(idx[1500:31500]))
    write_ply(d / "cloud.ply", cloud)
    xyz = sparse.points.astype(np.float64)
    return {
        "dir": d,
        "views": views,
        "xyz": xyz,
        "rgb": sparse.colors,
        "cloud": d / "cloud.ply",
        "extent": float(np.ptp(np.stack([v.cam_from_world.center for v in views]), axis=0).max()),
    }


@pytest.fixture(scope="module")
def model(world):
    """The world in an arbitrary gauge, written as a run directory holding sparse/."""
    d = world["dir"] / "run"
    rec = MODEL_FROM_WORLD.transform_reconstruction(
        _reconstruction(world["views"], world["xyz"], world["rgb"])
    )
    write_colmap_text(d / "sparse", rec)
    return d


def _positions_file(path, views, glitch: dict | None = None, extra: bool = True):
    lines = ["# name  x y z (metres)"]
    for v in views:
        c = v.cam_from_world.center + (glitch or {}).get(v.name, 0.0)
        lines.append(f"{v.name} {c[0]:.9f} {c[1]:.9f} {c[2]:.9f}")
    if extra:
        lines.append("not_in_model.png 1 2 3  # a photo the model does not have")
    path.write_text("\n".join(lines) + "\n")
    return path


def _run(capsys, *args: str) -> tuple[int, list[str]]:
    code = main(["align", *map(str, args)])
    return code, capsys.readouterr().err.strip().splitlines()


def _centres(rec: Reconstruction) -> dict[str, np.ndarray]:
    return {im.name: im.center_world for im in rec.images.values()}


def test_positions_give_the_true_similarity(world, model, tmp_path, capsys):
    pos = _positions_file(tmp_path / "gps.txt", world["views"])
    code, err = _run(capsys, model, "--positions", pos, "--out", tmp_path / "out")
    assert code == 0, err
    assert err[-2].startswith("aligned 8 images and 1500 points to 8 camera positions (8 inliers)")
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    truth = MODEL_FROM_WORLD.inverse()
    assert abs(result["scale"] - truth.scale) < 1e-6 * truth.scale
    assert np.allclose(result["R"], truth.R, atol=1e-7) and np.allclose(result["t"], truth.t, atol=1e-6)
    assert np.allclose(result["world_from_model"]["matrix"], truth.matrix, atol=1e-6)
    assert result["residual_rms_m"] < 1e-6 and result["residual_median_m"] < 1e-6
    assert result["num_correspondences"] == 8 and result["outliers"] == []
    assert result["positions_without_image"] == ["not_in_model.png"]
    aligned = read_colmap_text(tmp_path / "out" / "sparse")
    gt = {v.name: v.cam_from_world for v in world["views"]}
    for name, c in _centres(aligned).items():
        assert np.linalg.norm(c - gt[name].center) < 1e-6
        assert np.allclose(aligned.image_by_name(name).cam_from_world.R, gt[name].R, atol=1e-7)
    xyz, _ = aligned.points_array()
    assert np.abs(xyz - world["xyz"]).max() < 1e-5
    assert len(read_ply(tmp_path / "out" / "sparse.ply")) == 1500
    # the result can start another alignment
    assert read_init(tmp_path / "out" / "align.json").matrix == pytest.approx(truth.matrix, abs=1e-6)


def test_a_gps_glitch_is_ignored_and_named(world, model, tmp_path, capsys):
    bad = world["views"][5].name
    pos = _positions_file(tmp_path / "gps.txt", world["views"], glitch={bad: np.array([4.0, -3.0, 2.0])})
    code, err = _run(capsys, model / "sparse", "--positions", pos, "--out", tmp_path / "out")
    assert code == 0
    assert any(line.startswith("warning:") and bad in line for line in err)
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    assert result["outliers"] == [bad] and result["num_inliers"] == 7
    assert result["residual_rms_m"] < 1e-6
    assert result["residuals_m"][bad] == pytest.approx(np.sqrt(16 + 9 + 4), rel=1e-3)


def test_rigid_alignment_keeps_the_scale(world, tmp_path, capsys):
    turn = Sim3(MODEL_FROM_WORLD.R, MODEL_FROM_WORLD.t, 1.0)
    write_colmap_text(
        tmp_path / "m",
        turn.transform_reconstruction(_reconstruction(world["views"], world["xyz"][:50], world["rgb"][:50])),
    )
    pos = _positions_file(tmp_path / "gps.txt", world["views"])
    code, _ = _run(capsys, tmp_path / "m", "--positions", pos, "--no-scale", "--out", tmp_path / "out")
    assert code == 0
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    assert result["scale"] == 1.0 and result["residual_rms_m"] < 1e-6 and result["with_scale"] is False


def test_to_model_merges_two_overlapping_models(world, tmp_path, capsys):
    views = world["views"]
    ref_from_world = Sim3(
        rotvec_to_matrix([0.0, 0.0, 0.7]), [100.0, 50.0, 3.0], 1.0
    )  # e.g. a local metric frame
    ref = ref_from_world.transform_reconstruction(
        _reconstruction(views[:6], world["xyz"][:900], world["rgb"][:900])
    )
    src = MODEL_FROM_WORLD.transform_reconstruction(
        _reconstruction(views[2:], world["xyz"][600:], world["rgb"][600:])
    )
    write_colmap_text(tmp_path / "ref", ref)
    write_colmap_text(tmp_path / "src", src)
    code, err = _run(
        capsys, tmp_path / "src", "--to-model", tmp_path / "ref", "--merge", "--out", tmp_path / "out"
    )
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    assert result["num_correspondences"] == 4 and result["init"] == "camera centres"
    assert result["icp"]["converged"] and result["icp"]["fitness"] > 0.5
    truth = ref_from_world @ MODEL_FROM_WORLD.inverse()
    assert np.allclose(result["world_from_model"]["matrix"], truth.matrix, atol=1e-4)
    aligned = read_colmap_text(tmp_path / "out" / "sparse")
    for v in views[2:]:
        assert (
            np.linalg.norm(
                aligned.image_by_name(v.name).center_world - ref_from_world.apply(v.cam_from_world.center)
            )
            < 1e-4 * world["extent"]
        )
    assert len(read_ply(tmp_path / "out" / "merged.ply")) == 900 + 900


def test_to_model_without_common_names_needs_an_initial_alignment(world, tmp_path, capsys):
    views = world["views"]
    ref = _reconstruction(
        views, world["xyz"], world["rgb"], names=[f"flight1_{k}.jpg" for k in range(len(views))]
    )
    write_colmap_text(tmp_path / "ref", ref)
    src = MODEL_FROM_WORLD.transform_reconstruction(
        _reconstruction(views, world["xyz"][::2], world["rgb"][::2], noise_m=0.005)
    )
    write_colmap_text(tmp_path / "src", src)
    code, err = _run(capsys, tmp_path / "src", "--to-model", tmp_path / "ref", "--out", tmp_path / "o1")
    assert code == 2 and len(err) == 1 and err[0].startswith("error:") and "--init" in err[0]
    # a rough initial alignment (a few degrees, 2 % in scale, 0.3 m off) is refined by ICP
    truth = MODEL_FROM_WORLD.inverse()
    rough = Sim3(rotvec_to_matrix([0.03, -0.02, 0.04]), [0.3, -0.2, 0.1], 1.02) @ truth
    (tmp_path / "init.txt").write_text(
        "\n".join(" ".join(f"{x:.12g}" for x in row) for row in rough.matrix) + "\n"
    )
    code, err = _run(
        capsys,
        tmp_path / "src",
        "--to-model",
        tmp_path / "ref",
        "--init",
        tmp_path / "init.txt",
        "--out",
        tmp_path / "o2",
    )
    assert code == 0, err
    result = json.loads((tmp_path / "o2" / "align.json").read_text())
    assert result["init"] == "file" and result["icp"]["converged"]
    aligned = read_colmap_text(tmp_path / "o2" / "sparse")
    err_m = max(
        np.linalg.norm(aligned.image_by_name(v.name).center_world - v.cam_from_world.center) for v in views
    )
    assert err_m < 0.01 * world["extent"]


def test_to_cloud_refines_a_nearly_aligned_model(world, tmp_path, capsys):
    off = Sim3(rotvec_to_matrix([0.02, -0.015, 0.03]), [0.15, -0.1, 0.05], 1.03)  # model_from_world
    write_colmap_text(
        tmp_path / "m",
        off.transform_reconstruction(
            _reconstruction(world["views"], world["xyz"], world["rgb"], noise_m=0.005)
        ),
    )
    code, err = _run(capsys, tmp_path / "m", "--to-cloud", world["cloud"], "--out", tmp_path / "out")
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    assert result["init"].startswith("identity") and result["icp"]["converged"]
    assert abs(result["scale"] * 1.03 - 1) < 1e-3
    assert result["residual_median_m"] < 0.01  # point-to-plane, with 5 mm noise on the points
    aligned = read_colmap_text(tmp_path / "out" / "sparse")
    err_m = max(
        np.linalg.norm(aligned.image_by_name(v.name).center_world - v.cam_from_world.center)
        for v in world["views"]
    )
    assert err_m < 0.005 * world["extent"]


def test_to_cloud_from_centroids_and_a_far_scale(world, tmp_path, capsys):
    off = Sim3(np.eye(3), [30.0, -20.0, 5.0], 0.5)
    write_colmap_text(
        tmp_path / "m",
        off.transform_reconstruction(
            _reconstruction(world["views"], world["xyz"], world["rgb"], noise_m=0.005)
        ),
    )
    code, err = _run(capsys, tmp_path / "m", "--to-cloud", world["cloud"], "--out", tmp_path / "out")
    assert code == 0, err
    assert any("centroids" in line for line in err)
    result = json.loads((tmp_path / "out" / "align.json").read_text())
    assert result["init"].startswith("centroids") and abs(result["scale"] - 2.0) < 0.01
    aligned = read_colmap_text(tmp_path / "out" / "sparse")
    err_m = max(
        np.linalg.norm(aligned.image_by_name(v.name).center_world - v.cam_from_world.center)
        for v in world["views"]
    )
    assert err_m < 0.01 * world["extent"]


def test_icp_that_does_not_converge_says_so(world, tmp_path, capsys):
    off = Sim3(rotvec_to_matrix([0.05, 0.0, 0.05]), [0.4, 0.0, 0.0], 1.0)
    write_colmap_text(
        tmp_path / "m",
        off.transform_reconstruction(
            _reconstruction(world["views"], world["xyz"], world["rgb"], noise_m=0.005)
        ),
    )
    code, err = _run(
        capsys,
        tmp_path / "m",
        "--to-cloud",
        world["cloud"],
        "--no-scale",
        "--max-iterations",
        "1",
        "--quiet",
        "--out",
        tmp_path / "out",
    )
    assert code == 0
    assert len(err) == 1 and err[0].startswith("warning: ICP did not converge")
    assert json.loads((tmp_path / "out" / "align.json").read_text())["icp"]["converged"] is False


@pytest.mark.parametrize(
    "case",
    [
        "no_match",
        "two_match",
        "collinear",
        "nan",
        "no_positions_file",
        "missing_model",
        "not_a_model",
        "missing_cloud",
        "merge_positions",
        "bad_init",
    ],
)
def test_bad_input_is_one_line_and_exit_2(world, model, tmp_path, capsys, case):
    names = [v.name for v in world["views"]]
    pos = tmp_path / "pos.txt"
    args = [model, "--positions", pos]
    if case == "no_match":
        pos.write_text("".join(f"DSC_{k:04d}.JPG {k} {k * k} 1\n" for k in range(8)))
        expect = "none of the 8 names"
    elif case == "two_match":
        pos.write_text(f"{names[0]} 0 0 0\n{names[1]} 1 0 0\nother.png 0 1 0\n")
        expect = "only 2 model images"
    elif case == "collinear":
        pos.write_text("".join(f"{n} {2.0 * k} {1.0 * k} 10\n" for k, n in enumerate(names)))
        expect = "lie on a line"
    elif case == "nan":
        pos.write_text(f"{names[0]} 0 0 0\n{names[1]} nan 0 0\n")
        expect = "line 2: NaN"
    elif case == "no_positions_file":
        expect = "positions file not found"
    elif case == "missing_model":
        args = [tmp_path / "nope", "--positions", pos]
        expect = "model directory not found"
    elif case == "not_a_model":
        (tmp_path / "empty").mkdir()
        args = [tmp_path / "empty", "--positions", pos]
        expect = "no COLMAP text model"
    elif case == "missing_cloud":
        args = [model, "--to-cloud", tmp_path / "nope.ply"]
        expect = "PLY file not found"
    elif case == "merge_positions":
        args = [model, "--positions", pos, "--merge"]
        expect = "--merge needs"
    else:
        (tmp_path / "init.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 -1 0\n")
        args = [model, "--to-cloud", world["cloud"], "--init", tmp_path / "init.txt"]
        expect = "not a scaled rotation"
    code, err = _run(capsys, *args, "--out", tmp_path / "out")
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error:") and expect in err[0], err


def test_positions_parser_and_name_matching(tmp_path):
    f = tmp_path / "p.txt"
    f.write_text("\ufeff# header\nimg 1.png, 1, 2, 3\n\nb.jpg 4 5 6 # comment\n")
    pos = read_positions(f)
    assert list(pos) == ["img 1.png", "b.jpg"] and np.allclose(pos["b.jpg"], [4, 5, 6])
    f.write_text("a.png 1 2\n")
    with pytest.raises(InputError, match="line 1"):
        read_positions(f)
    f.write_text("a.png 1 2 3\na.png 1 2 3\n")
    with pytest.raises(InputError, match="twice"):
        read_positions(f)
    m = match_names(["images/a.png", "images/b.png", "c.png"], ["a.png", "b", "c.png", "z.png"])
    assert m == {"images/a.png": "a.png", "images/b.png": "b", "c.png": "c.png"}
