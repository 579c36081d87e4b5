"""COLMAP text model read/write and the nerfstudio export."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skyrecon.core import Image, Intrinsics, Point3D, Reconstruction, Rigid3, quaternion_to_matrix
from skyrecon.errors import InputError
from skyrecon.io.colmap import (
    intrinsics_to_colmap,
    read_colmap_cameras_text,
    read_colmap_text,
    write_colmap_text,
    write_nerfstudio_transforms,
)


def synthetic_reconstruction(seed: int = 0, n_images: int = 4, n_points: int = 30) -> Reconstruction:
    """Three cameras (PINHOLE, OPENCV and FULL_OPENCV-like distortion), posed images, points with
    tracks whose keypoints are the exact projections of the points."""
    rng = np.random.default_rng(seed)
    cameras = {
        1: Intrinsics(500.0, 502.0, 319.5, 239.5, 640, 480),
        2: Intrinsics(800.25, 799.75, 400.1, 300.2, 800, 600, np.array([-0.1, 0.02, 1e-3, -2e-3, 0.0])),
        7: Intrinsics(300.0, 300.0, 159.5, 119.5, 320, 240, np.array([0.05, -0.01, 0.0, 0.0, 0.003])),
    }
    cam_ids = [1, 2, 7, 1, 2, 7]
    xyz = rng.uniform(-1, 1, (n_points, 3))
    images = {}
    for k in range(n_images):
        a = 0.4 * k
        pose = Rigid3.look_at([5 * np.sin(a), -5 * np.cos(a), 1.0 + 0.1 * k], [0, 0, 0])
        images[10 + k] = Image(10 + k, f"frame_{k:03d}.jpg", cam_ids[k], pose)
    points = {}
    obs: dict[int, list] = {i: [] for i in images}
    for j in range(n_points):
        track = []
        for iid, im in images.items():
            if (j + iid) % 3 == 0:
                continue
            uv = cameras[im.camera_id].project(im.cam_from_world.apply(xyz[j : j + 1]))[0]
            track.append((iid, len(obs[iid])))
            obs[iid].append((uv, 100 + j))
        points[100 + j] = Point3D(100 + j, xyz[j], rng.integers(0, 256, 3), float(rng.uniform(0, 2)), track)
    for iid, im in images.items():
        extra = [(rng.uniform(0, 100, 2), -1)]  # an untriangulated keypoint
        allobs = obs[iid] + extra
        im.keypoints = np.array([o[0] for o in allobs])
        im.point3d_ids = np.array([o[1] for o in allobs], dtype=np.int64)
    rec = Reconstruction(cameras, images, points)
    rec.validate()
    return rec


def assert_same_reconstruction(a: Reconstruction, b: Reconstruction, atol: float = 1e-9) -> None:
    assert sorted(a.cameras) == sorted(b.cameras)
    for cid in a.cameras:
        ca, cb = a.cameras[cid], b.cameras[cid]
        assert ca.size == cb.size
        np.testing.assert_allclose(ca.K, cb.K, atol=atol, rtol=0)
        np.testing.assert_allclose(ca.dist, cb.dist, atol=atol, rtol=0)
    assert sorted(a.images) == sorted(b.images)
    for iid in a.images:
        ia, ib = a.images[iid], b.images[iid]
        assert (ia.name, ia.camera_id) == (ib.name, ib.camera_id)
        assert ia.cam_from_world.allclose(ib.cam_from_world, atol=atol)
        np.testing.assert_allclose(ia.keypoints, ib.keypoints, atol=atol, rtol=0)
        np.testing.assert_array_equal(ia.point3d_ids, ib.point3d_ids)
    assert sorted(a.points3d) == sorted(b.points3d)
    for pid in a.points3d:
        pa, pb = a.points3d[pid], b.points3d[pid]
        np.testing.assert_allclose(pa.xyz, pb.xyz, atol=atol, rtol=0)
        np.testing.assert_array_equal(pa.color, pb.color)
        assert abs(pa.error - pb.error) < atol
        np.testing.assert_array_equal(pa.track, pb.track)


# ----------------------------------------------------------------------------------------------
# round trips
# ----------------------------------------------------------------------------------------------
def test_round_trip_exact(tmp_path: Path) -> None:
    rec = synthetic_reconstruction()
    write_colmap_text(tmp_path / "new" / "model", rec)  # creates missing directories
    back = read_colmap_text(tmp_path / "new" / "model")
    assert_same_reconstruction(rec, back, atol=1e-9)
    assert np.abs(back.reprojection_errors()).max() < 1e-6
    # Round trips do not drift.
    write_colmap_text(tmp_path / "again", back)
    assert_same_reconstruction(rec, read_colmap_text(tmp_path / "again"), atol=1e-9)
    assert not list((tmp_path / "new" / "model").glob(".*tmp"))  # atomic writes leave no temp files


def test_written_format_is_colmap(tmp_path: Path) -> None:
    rec = synthetic_reconstruction()
    write_colmap_text(tmp_path, rec)
    cams = (tmp_path / "cameras.txt").read_text().splitlines()
    assert cams[0] == "# Camera list with one line of data per camera:"
    assert cams[1] == "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"
    assert cams[2] == "# Number of cameras: 3"
    models = {int(ln.split()[0]): ln.split()[1] for ln in cams[3:]}
    assert models == {1: "PINHOLE", 2: "OPENCV", 7: "FULL_OPENCV"}
    line1 = next(ln for ln in cams[3:] if ln.startswith("1 "))
    assert [float(x) for x in line1.split()[2:]] == [640, 480, 500.0, 502.0, 320.0, 240.0]  # cx, cy + 0.5
    full = next(ln for ln in cams[3:] if ln.startswith("7 ")).split()
    assert len(full) == 4 + 12 and [float(x) for x in full[-3:]] == [0.0, 0.0, 0.0]

    imgs = (tmp_path / "images.txt").read_text().splitlines()
    assert imgs[0] == "# Image list with two lines of data per image:"
    assert imgs[1] == "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"
    assert imgs[2] == "#   POINTS2D[] as (X, Y, POINT3D_ID)"
    assert imgs[3].startswith("# Number of images: 4, mean observations per image: ")
    tok = imgs[4].split()
    assert len(tok) == 10 and tok[0] == "10" and tok[9] == "frame_000.jpg"
    im = rec.images[10]
    np.testing.assert_allclose(
        quaternion_to_matrix(np.array(tok[1:5], float)), im.cam_from_world.R, atol=1e-12
    )
    np.testing.assert_allclose(np.array(tok[5:8], float), im.cam_from_world.t, atol=0)
    pts = np.array(imgs[5].split(), float).reshape(-1, 3)
    np.testing.assert_allclose(pts[:, :2], im.keypoints + 0.5, atol=1e-12)

    p3 = (tmp_path / "points3D.txt").read_text().splitlines()
    assert p3[1] == "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"
    assert p3[2].startswith("# Number of points: 30, mean track length: ")


def test_empty_reconstruction_round_trip(tmp_path: Path) -> None:
    write_colmap_text(tmp_path, Reconstruction())
    back = read_colmap_text(tmp_path)
    assert not back.cameras and not back.images and not back.points3d


# ----------------------------------------------------------------------------------------------
# reading hand-written COLMAP files
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("line", "expect"),
    [
        ("1 SIMPLE_PINHOLE 100 80 90 50.5 40.5", (90, 90, 50, 40, [0, 0, 0, 0, 0])),
        ("1 PINHOLE 100 80 90 91 50.5 40.5", (90, 91, 50, 40, [0, 0, 0, 0, 0])),
        ("1 SIMPLE_RADIAL 100 80 90 50.5 40.5 0.1", (90, 90, 50, 40, [0.1, 0, 0, 0, 0])),
        ("1 RADIAL 100 80 90 50.5 40.5 0.1 -0.02", (90, 90, 50, 40, [0.1, -0.02, 0, 0, 0])),
        (
            "1 OPENCV 100 80 90 91 50.5 40.5 0.1 -0.02 0.001 0.002",
            (90, 91, 50, 40, [0.1, -0.02, 0.001, 0.002, 0]),
        ),
        (
            "1 FULL_OPENCV 100 80 90 91 50.5 40.5 0.1 -0.02 0.001 0.002 0.003 0 0 0",
            (90, 91, 50, 40, [0.1, -0.02, 0.001, 0.002, 0.003]),
        ),
    ],
)
def test_camera_models(tmp_path: Path, line: str, expect) -> None:
    (tmp_path / "cameras.txt").write_text("# comment\n\n" + line + "\n")
    cam = read_colmap_cameras_text(tmp_path / "cameras.txt")[1]
    fx, fy, cx, cy, dist = expect
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (fx, fy, cx, cy, 100, 80)
    np.testing.assert_allclose(cam.dist, dist)


def test_writer_model_choice() -> None:
    assert intrinsics_to_colmap(Intrinsics(1, 1, 0, 0, 2, 2))[0] == "PINHOLE"
    assert intrinsics_to_colmap(Intrinsics(1, 1, 0, 0, 2, 2, np.array([0.1, 0, 0, 0, 0])))[0] == "OPENCV"
    model, params = intrinsics_to_colmap(Intrinsics(1, 1, 0, 0, 2, 2, np.array([0, 0, 0, 0, 0.1])))
    assert model == "FULL_OPENCV" and params[-4:] == [0.1, 0.0, 0.0, 0.0]
    with pytest.raises(InputError, match="skew"):
        intrinsics_to_colmap(Intrinsics(1, 1, 0, 0, 2, 2, skew=0.5))


@pytest.mark.parametrize(
    ("line", "match"),
    [
        (
            "1 FULL_OPENCV 100 80 90 91 50 40 0.1 0 0 0 0 0.2 0 0",
            "line 1: FULL_OPENCV .* k4..k6 .* undistort",
        ),
        ("1 OPENCV_FISHEYE 100 80 90 91 50 40 0.1 0 0 0", "OPENCV_FISHEYE cannot be represented"),
        ("1 SIMPLE_RADIAL_FISHEYE 100 80 90 50 40 0.1", "cannot be represented"),
        ("1 WEIRD 100 80 90 50 40", "unknown COLMAP camera model 'WEIRD'"),
        ("1 PINHOLE 100 80 90 91 50", "PINHOLE takes 4 parameters, got 3"),
        ("1 PINHOLE 100 80 90 nan 50 40", "NaN"),
        ("1 PINHOLE 100 80 90 -1 50 40", "focal lengths must be positive"),
        ("1 PINHOLE 100.5 80 90 91 50 40", "'100.5' is not a valid int"),
        ("1 PINHOLE", "expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS"),
        ("1 PINHOLE 100 80 90 91 50 40\n1 PINHOLE 100 80 90 91 50 40", "line 2: camera id 1 appears twice"),
    ],
)
def test_bad_cameras(tmp_path: Path, line: str, match: str) -> None:
    (tmp_path / "cameras.txt").write_text(line + "\n")
    (tmp_path / "images.txt").write_text("")
    with pytest.raises(InputError, match=match) as info:
        read_colmap_text(tmp_path)
    assert "cameras.txt" in str(info.value)


CAMERAS = "1 PINHOLE 100 80 90 90 50.5 40.5\n"


def test_pixel_convention_and_empty_points_lines(tmp_path: Path) -> None:
    """COLMAP (0.5, 0.5) is skyrecon (0, 0); empty POINTS2D lines; a file ending after an image line."""
    (tmp_path / "cameras.txt").write_text(CAMERAS)
    (tmp_path / "images.txt").write_text(
        "# header\n"
        "1 1 0 0 0 0 0 0 1 a.png\n"
        "0.5 0.5 -1 50.5 40.5 7\n"
        "2 1 0 0 0 0 0 1 1 b with space.png\n"
        "\n"
        "3 0.5 0.5 0.5 0.5 1 2 3 1 c.png"
    )
    (tmp_path / "points3D.txt").write_text("7 0 0 5 255 0 10 0.25 1 1\n")
    rec = read_colmap_text(tmp_path)
    np.testing.assert_allclose(rec.images[1].keypoints, [[0, 0], [50, 40]])
    np.testing.assert_array_equal(rec.images[1].point3d_ids, [-1, 7])
    assert rec.images[2].name == "b with space.png" and len(rec.images[2].keypoints) == 0
    assert rec.images[3].name == "c.png" and len(rec.images[3].keypoints) == 0
    assert rec.cameras[1].cx == 50.0 and rec.cameras[1].cy == 40.0
    # The point on the optical axis lands on the principal point, where its keypoint is.
    assert rec.reprojection_errors().max() < 1e-12
    np.testing.assert_allclose(rec.images[3].cam_from_world.R, quaternion_to_matrix([0.5, 0.5, 0.5, 0.5]))
    np.testing.assert_array_equal(rec.points3d[7].color, [255, 0, 10])


def test_points3d_optional(tmp_path: Path) -> None:
    (tmp_path / "cameras.txt").write_text(CAMERAS)
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    rec = read_colmap_text(tmp_path)
    assert len(rec.images) == 1 and not rec.points3d


@pytest.mark.parametrize(
    ("images", "points", "match"),
    [
        ("1 1 0 0 0 0 0 0 1\n\n", "", "images.txt: line 1: expected 'IMAGE_ID QW"),
        (
            "1 1 0 0 0 0 0 0 1 a.png\n1 2 -1 3\n",
            "",
            "images.txt: line 2: POINTS2D of image a.png must be triples",
        ),
        ("1 1 0 0 0 0 0 0 1 a.png\n1 2 x\n", "", "images.txt: line 2: POINT3D_IDs of a.png: 'x'"),
        ("1 1 0 0 0 0 0 0 1 a.png\n1 nan -1\n", "", "images.txt: line 2: keypoints of a.png contains NaN"),
        ("1 0 0 0 0 0 0 0 1 a.png\n\n", "", "images.txt: line 1: the quaternion of image a.png is zero"),
        ("1 1 0 0 0 0 inf 0 1 a.png\n\n", "", "images.txt: line 1: translation contains NaN"),
        ("1 1 0 0 0 0 0 0 1 a.png\n\n1 1 0 0 0 0 0 0 1 b.png\n\n", "", "line 3: image id 1 appears twice"),
        ("1 1 0 0 0 0 0 0 2 a.png\n\n", "", "inconsistent model: image a.png refers to missing camera 2"),
        (
            "1 1 0 0 0 0 0 0 1 a.png\n\n",
            "5 0 0 1 1 2 3 0.5 9 0\n",
            "inconsistent model: point 5 .* missing image 9",
        ),
        ("1 1 0 0 0 0 0 0 1 a.png\n\n", "5 0 0 1 1 2 3 0.5 1 0\n", "point 5 refers to keypoint 0 of a.png"),
        (
            "1 1 0 0 0 0 0 0 1 a.png\n\n",
            "5 0 0 1 1 2 3 0.5 1\n",
            "points3D.txt: line 1: expected 'POINT3D_ID",
        ),
        ("1 1 0 0 0 0 0 0 1 a.png\n\n", "5 0 0 1 1 2 300 0.5\n", "points3D.txt: line 1: colour"),
        ("1 1 0 0 0 0 0 0 1 a.png\n\n", "5 0 nan 1 1 2 3 0.5\n", "points3D.txt: line 1: X Y Z contains NaN"),
        (
            "1 1 0 0 0 0 0 0 1 a.png\n\n",
            "5 0 0 1 1 2 3 0.5\n5 0 0 1 1 2 3 0.5\n",
            "line 2: point id 5 appears twice",
        ),
    ],
)
def test_malformed_models(tmp_path: Path, images: str, points: str, match: str) -> None:
    (tmp_path / "cameras.txt").write_text(CAMERAS)
    (tmp_path / "images.txt").write_text(images)
    if points:
        (tmp_path / "points3D.txt").write_text(points)
    with pytest.raises(InputError, match=match) as info:
        read_colmap_text(tmp_path)
    assert str(tmp_path) in str(info.value)


def test_missing_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="directory not found"):
        read_colmap_text(tmp_path / "nope")
    with pytest.raises(InputError, match="no cameras.txt here"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.txt").write_text(CAMERAS)
    (tmp_path / "images.bin").write_bytes(b"\x00\x01")
    with pytest.raises(InputError, match="no images.txt here.*binary model.*model_converter"):
        read_colmap_text(tmp_path)
    (tmp_path / "images.txt").write_bytes(b"\xff\xfe\x00\x01binary")
    with pytest.raises(InputError, match="not a text file"):
        read_colmap_text(tmp_path)


def test_writer_rejects_bad_input(tmp_path: Path) -> None:
    rec = synthetic_reconstruction()
    rec.images[10].name = "bad\nname.png"
    with pytest.raises(InputError, match="cannot be written"):
        write_colmap_text(tmp_path / "a", rec)
    rec = synthetic_reconstruction()
    rec.cameras[1] = Intrinsics(500, 500, 320, 240, 640, 480, skew=1.0)
    with pytest.raises(InputError, match="skew"):
        write_colmap_text(tmp_path / "b", rec)
    rec = synthetic_reconstruction()
    rec.images[10].camera_id = 99
    with pytest.raises(InputError, match="missing camera 99"):
        write_colmap_text(tmp_path / "c", rec)
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())


# ----------------------------------------------------------------------------------------------
# nerfstudio
# ----------------------------------------------------------------------------------------------
def test_nerfstudio_transforms_shared_camera(tmp_path: Path) -> None:
    rec = synthetic_reconstruction()
    for im in rec.images.values():
        im.camera_id = 2
    write_nerfstudio_transforms(tmp_path / "out" / "transforms.json", rec)
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())
    cam = rec.cameras[2]
    assert meta["camera_model"] == "OPENCV"
    assert (meta["fl_x"], meta["fl_y"], meta["w"], meta["h"]) == (cam.fx, cam.fy, 800, 600)
    assert meta["cx"] == pytest.approx(cam.cx + 0.5) and meta["cy"] == pytest.approx(cam.cy + 0.5)
    assert [meta[k] for k in ("k1", "k2", "p1", "p2")] == list(cam.dist[:4]) and "k3" not in meta
    assert [f["file_path"] for f in meta["frames"]] == [f"images/frame_{k:03d}.jpg" for k in range(4)]
    for frame, (iid, im) in zip(meta["frames"], sorted(rec.images.items())):
        M = np.array(frame["transform_matrix"])
        assert frame["colmap_im_id"] == iid and "fl_x" not in frame
        np.testing.assert_allclose(M[3], [0, 0, 0, 1])
        np.testing.assert_allclose(M[:3, 3], im.center_world, atol=1e-12)  # camera centre
        world_from_cam = im.cam_from_world.inverse()
        np.testing.assert_allclose(M[:3, 0], world_from_cam.R[:, 0], atol=1e-12)  # x right: same
        np.testing.assert_allclose(M[:3, 1:3], -world_from_cam.R[:, 1:3], atol=1e-12)  # y up, z back
        # A point in front of the (OpenCV) camera has negative z in the OpenGL camera frame.
        xyz = next(iter(rec.points3d.values())).xyz
        p_gl = np.linalg.inv(M) @ np.append(xyz, 1.0)
        assert p_gl[2] < 0 and im.cam_from_world.apply(xyz)[2] > 0
        assert p_gl[2] == pytest.approx(-im.cam_from_world.apply(xyz)[2])


def test_nerfstudio_transforms_per_frame_cameras(tmp_path: Path) -> None:
    rec = synthetic_reconstruction()
    write_nerfstudio_transforms(tmp_path / "t.json", rec, image_prefix="rgb/")
    meta = json.loads((tmp_path / "t.json").read_text())
    assert "fl_x" not in meta
    f2 = meta["frames"][2]  # image 12 uses camera 7 (k3 != 0)
    assert f2["file_path"] == "rgb/frame_002.jpg" and f2["w"] == 320 and f2["k3"] == 0.003
    assert f2["cx"] == pytest.approx(160.0)
    with pytest.raises(InputError, match="no registered images"):
        write_nerfstudio_transforms(tmp_path / "e.json", Reconstruction())
