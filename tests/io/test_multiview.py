"""Multi-view camera readers: Middlebury *_par.txt, Strecha *.camera, HALCON, auto-detection.

Each format is written here the way its tool writes it (from a synthetic ring of cameras), read
back, and checked two ways: the poses equal the synthetic ``cam_from_world``, and projecting a
world point with the format's own documented formula gives the same pixel as ``PosedView.project``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skyrecon.core import Image, Intrinsics, PosedView, Reconstruction, Rigid3
from skyrecon.errors import InputError
from skyrecon.io.colmap import write_colmap_text
from skyrecon.io.images import write_image
from skyrecon.io.multiview import (
    image_size_from_header,
    read_cameras,
    read_halcon_cameras,
    read_middlebury_par,
    read_strecha_cameras,
)


# ----------------------------------------------------------------------------------------------
# synthetic scene and writers in each file format
# ----------------------------------------------------------------------------------------------
def ring_views(n: int = 5, width: int = 64, height: int = 48, seed: int = 0) -> list[PosedView]:
    """``n`` cameras on a tilted ring of radius ~2 m looking at the origin, with distinct K."""
    rng = np.random.default_rng(seed)
    views = []
    for i in range(n):
        a = 2 * np.pi * i / n + rng.uniform(-0.1, 0.1)
        eye = np.array([2 * np.cos(a), 2 * np.sin(a), 0.7 + rng.uniform(-0.2, 0.2)])
        pose = Rigid3.look_at(eye, rng.uniform(-0.1, 0.1, 3))
        f = 60 + 5 * i
        K = np.array([[f, 0, width / 2 - 0.3 + i], [0, f * 1.01, height / 2 + 0.2], [0, 0, 1]])
        views.append(PosedView(f"img{i:04d}.png", Intrinsics.from_K(K, width, height), pose))
    return views


def _row(values) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(values))


def write_par(path: Path, views: list[PosedView]) -> None:
    """Middlebury: ``name K(9) R(9) t(3)`` with (R, t) world-to-camera."""
    lines = [str(len(views))]
    for v in views:
        lines.append(f"{v.name} {_row(v.intrinsics.K)} {_row(v.cam_from_world.R)} {_row(v.cam_from_world.t)}")
    path.write_text("\n".join(lines) + "\n")


def write_strecha(directory: Path, views: list[PosedView]) -> None:
    """Strecha: K, '0 0 0', R camera-to-world, camera centre, 'w h'."""
    directory.mkdir(parents=True, exist_ok=True)
    for v in views:
        world_from_cam = v.cam_from_world.inverse()
        K = v.intrinsics.K
        text = "\n".join(
            [
                _row(K[0]),
                _row(K[1]),
                _row(K[2]),
                "0 0 0",
                _row(world_from_cam.R[0]),
                _row(world_from_cam.R[1]),
                _row(world_from_cam.R[2]),
                _row(world_from_cam.t),
                f"{v.intrinsics.width} {v.intrinsics.height}",
            ]
        )
        (directory / f"{v.name}.camera").write_text(text + "\n")


HALCON_TEMPLATE = """#
# INTERNAL CAMERA PARAMETERS
#

ParGroup: Camera: Parameter;
\t"Internal camera parameters";

Focus:foc:\t{focus!r};
\tDOUBLE:0.0:;
\t"Focal length of the lens";

Poly1:poly1:\t{poly1};
\tDOUBLE::;
\t"1st polynomial distortion coefficient";

Poly2:poly2:\t0;
\tDOUBLE::;
\t"2nd polynomial distortion coefficient";

Poly3:poly3:\t0;
\tDOUBLE::;
\t"3rd polynomial distortion coefficient";

Poly4:poly4:\t0;
\tDOUBLE::;
\t"4th polynomial distortion coefficient * 1000";

Poly5:poly5:\t0;
\tDOUBLE::;
\t"5th polynomial distortion coefficient * 1000";

Sx:sx:\t{sx!r};
\tDOUBLE:0.0:;
\t"Width of a cell on the sensor";

Sy:sy:\t{sy!r};
\tDOUBLE:0.0:;
\t"Height of a cell on the sensor";

Cx:cx:\t{cx!r};
\tDOUBLE::;
\t"X-coordinate of the image center";

Cy:cy:\t{cy!r};
\tDOUBLE::;
\t"Y-coordinate of the image center";

ImageWidth:imgw:\t{w};
\tINT:1:32768;
\t"Width of the images";

ImageHeight:imgh:\t{h};
\tINT:1:32768;
\t"Height of the images";
"""


def write_halcon(directory: Path, views: list[PosedView], poly1: float = 0.0) -> None:
    """HALCON: intrinsics (Focus, Sx, Sy, Cx, Cy, ...) + extrinsics [R | T] camera-to-world."""
    directory.mkdir(parents=True, exist_ok=True)
    focus = 0.016
    for i, v in enumerate(views, start=1):
        k = v.intrinsics
        (directory / f"intrinsics_camera{i:02d}.txt").write_text(
            HALCON_TEMPLATE.format(
                focus=focus,
                poly1=poly1,
                sx=focus / k.fx,
                sy=focus / k.fy,
                cx=k.cx,
                cy=k.cy,
                w=k.width,
                h=k.height,
            )
        )
        world_from_cam = v.cam_from_world.inverse()
        (directory / f"extrinsics_camera{i:02d}.txt").write_text(_row(world_from_cam.matrix3x4) + " \n")


def assert_same_views(got: list[PosedView], want: list[PosedView], names: list[str] | None = None) -> None:
    assert [v.name for v in got] == (names or [v.name for v in want])
    for g, w in zip(got, want):
        assert g.cam_from_world.allclose(w.cam_from_world, atol=1e-9)
        np.testing.assert_allclose(g.intrinsics.K, w.intrinsics.K, atol=1e-9)
        assert g.intrinsics.size == w.intrinsics.size
        assert (g.cam_from_world.dst, g.cam_from_world.src) == ("cam", "world")


WORLD_POINTS = np.array([[0.0, 0.0, 0.0], [0.1, -0.05, 0.2], [-0.2, 0.1, -0.1]])


# ----------------------------------------------------------------------------------------------
# Middlebury
# ----------------------------------------------------------------------------------------------
def test_middlebury_round_trip_and_projection(tmp_path: Path) -> None:
    views = ring_views()
    write_par(tmp_path / "scene_par.txt", views)
    for v in views:
        write_image(tmp_path / v.name, np.zeros((48, 64, 3), np.uint8))
    got = read_middlebury_par(tmp_path / "scene_par.txt")
    assert_same_views(got, views)
    assert all(g.image_path == tmp_path / g.name for g in got)
    # The file's own formula: x ~ K (R X + t), with (K, R, t) as written on the line.
    line = (tmp_path / "scene_par.txt").read_text().splitlines()[2].split()
    vals = np.array(line[1:], float)
    K, R, t = vals[:9].reshape(3, 3), vals[9:18].reshape(3, 3), vals[18:]
    x = (K @ (R @ WORLD_POINTS.T + t[:, None])).T
    np.testing.assert_allclose(got[1].project(WORLD_POINTS)[0], x[:, :2] / x[:, 2:], atol=1e-9)


def test_middlebury_image_size_from_header_and_default(tmp_path: Path) -> None:
    views = ring_views(2)
    write_par(tmp_path / "a_par.txt", views)
    write_image(tmp_path / views[1].name, np.zeros((30, 40), np.uint8))  # only the second image exists
    got = read_middlebury_par(tmp_path / "a_par.txt")
    assert got[0].intrinsics.size == (40, 30) and got[0].image_path is None and got[1].image_path is not None
    write_image(tmp_path / views[0].name, np.zeros((20, 24), np.uint8))  # each view reads its own header
    assert [g.intrinsics.size for g in read_middlebury_par(tmp_path / "a_par.txt")] == [(24, 20), (40, 30)]
    (tmp_path / views[0].name).unlink()
    (tmp_path / views[1].name).unlink()
    with pytest.warns(UserWarning, match="640x480"):
        got = read_middlebury_par(tmp_path / "a_par.txt")
    assert got[0].intrinsics.size == (640, 480)
    got = read_middlebury_par(tmp_path / "a_par.txt", width=320, height=240)
    assert got[1].intrinsics.size == (320, 240)
    assert image_size_from_header(tmp_path / "missing.png") is None


def test_middlebury_image_dir(tmp_path: Path) -> None:
    views = ring_views(2)
    write_par(tmp_path / "a_par.txt", views)
    (tmp_path / "imgs").mkdir()
    write_image(tmp_path / "imgs" / views[0].name, np.zeros((48, 64, 3), np.uint8))
    got = read_middlebury_par(tmp_path / "a_par.txt", image_dir=tmp_path / "imgs")
    assert got[0].image_path == tmp_path / "imgs" / views[0].name
    assert got[0].intrinsics.size == (64, 48)


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda ls: ["3"] + ls[1:], "announces 3 images but 2"),
        (lambda ls: ls[:2], "announces 2 images but 1"),
        (lambda ls: ["two"] + ls[1:], "line 1: expected the number of images"),
        (lambda ls: [ls[0], ls[1], ls[2].rsplit(" ", 1)[0]], "line 3: expected an image name and 21 numbers"),
        (lambda ls: [ls[0], ls[1].replace(ls[1].split()[5], "nan", 1), ls[2]], "line 2: .*NaN"),
        (
            lambda ls: [ls[0], ls[1], ls[2].replace(ls[2].split()[12], "abc", 1)],
            "line 3: .*'abc' is not a number",
        ),
        (lambda ls: [ls[0], _scale_R(ls[1], 2.0), ls[2]], "line 2: R of .* is not a rotation"),
        (lambda ls: [ls[0], _scale_R(ls[1], -1.0), ls[2]], "line 2: R of .* is not a rotation"),
        (lambda ls: [ls[0], ls[1], ls[1]], "listed twice"),
        (lambda ls: ["0"], "lists no cameras"),
    ],
)
def test_middlebury_malformed(tmp_path: Path, mutate, match: str) -> None:
    views = ring_views(2)
    path = tmp_path / "bad_par.txt"
    write_par(path, views)
    path.write_text("\n".join(mutate(path.read_text().splitlines())) + "\n")
    with pytest.raises(InputError, match=match) as info:
        read_middlebury_par(path, width=64, height=48)
    assert str(path) in str(info.value)


def _scale_R(line: str, s: float) -> str:
    tok = line.split()
    R = np.array(tok[10:19], float) * s
    return " ".join(tok[:10] + [repr(float(x)) for x in R] + tok[19:])


def test_middlebury_missing_and_empty(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_middlebury_par(tmp_path / "none_par.txt")
    (tmp_path / "e_par.txt").write_text("\n")
    with pytest.raises(InputError, match="empty"):
        read_middlebury_par(tmp_path / "e_par.txt")
    (tmp_path / "b_par.txt").write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(InputError, match="not a text file"):
        read_middlebury_par(tmp_path / "b_par.txt")


# ----------------------------------------------------------------------------------------------
# Strecha
# ----------------------------------------------------------------------------------------------
def strecha_layout(root: Path, views: list[PosedView]) -> Path:
    """root/gt_dense_cameras/<name>.camera and root/images/<name>."""
    write_strecha(root / "gt_dense_cameras", views)
    (root / "images").mkdir(parents=True)
    for v in views:
        write_image(root / "images" / v.name, np.zeros((48, 64, 3), np.uint8))
    return root


def test_strecha_round_trip_and_projection(tmp_path: Path) -> None:
    views = [PosedView(f"{i:04d}.jpg", v.intrinsics, v.cam_from_world) for i, v in enumerate(ring_views())]
    root = strecha_layout(tmp_path, views)
    for spec in (root, root / "gt_dense_cameras"):
        got = read_strecha_cameras(spec)
        assert_same_views(got, views)
        assert all(g.image_path == root / "images" / g.name for g in got)
    # The file's own formula: x ~ K R^T (X - t), R camera-to-world, t = camera centre.
    text = (root / "gt_dense_cameras" / "0002.jpg.camera").read_text()
    rows = [np.array(ln.split(), float) for ln in text.splitlines()]
    K, R, c = np.stack(rows[0:3]), np.stack(rows[4:7]), rows[7]
    x = (K @ R.T @ (WORLD_POINTS - c).T).T
    np.testing.assert_allclose(got[2].project(WORLD_POINTS)[0], x[:, :2] / x[:, 2:], atol=1e-9)
    np.testing.assert_allclose(got[2].center_world, c, atol=1e-12)


def test_strecha_files_list_single_file_and_image_dir(tmp_path: Path) -> None:
    views = ring_views(3)
    write_strecha(tmp_path / "cams", views)
    files = sorted((tmp_path / "cams").glob("*.camera"))
    got = read_strecha_cameras(files[::-1])
    assert_same_views(got, views)
    assert all(g.image_path is None for g in got)  # no images anywhere
    got = read_strecha_cameras(files[1])
    assert_same_views(got, views[1:2])
    write_image(tmp_path / "cams" / views[0].name, np.zeros((48, 64, 3), np.uint8))
    assert read_strecha_cameras(tmp_path / "cams")[0].image_path == tmp_path / "cams" / views[0].name
    (tmp_path / "elsewhere").mkdir()
    write_image(tmp_path / "elsewhere" / views[2].name, np.zeros((48, 64, 3), np.uint8))
    got = read_strecha_cameras(tmp_path / "cams", image_dir=tmp_path / "elsewhere")
    assert [g.image_path is not None for g in got] == [False, False, True]


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda ls: ls[:8], "expected 9 non-empty lines"),
        (lambda ls: ls[:2] + ["0 0"] + ls[3:], "line 3: expected 3 numbers, got 2"),
        (lambda ls: ls[:3] + ["0.1 0 0"] + ls[4:], "line 4: non-zero distortion"),
        (lambda ls: ls[:4] + ["1 0 0", "1 0 0"] + ls[6:], "line 5: R .* is not a rotation"),
        (lambda ls: ls[:7] + ["1 nan 2"] + ls[8:], "line 8: .*NaN"),
        (lambda ls: ls[:8] + ["64.5 48"], "line 9: image size"),
        (lambda ls: ls[:8] + ["64 48 1"], "line 9: expected 2 numbers"),
        (lambda ls: ["0 0 1", "0 1 0", "0 0 0"] + ls[3:], "bad calibration matrix"),
    ],
)
def test_strecha_malformed(tmp_path: Path, mutate, match: str) -> None:
    write_strecha(tmp_path, ring_views(1))
    path = next(tmp_path.glob("*.camera"))
    path.write_text("\n".join(mutate(path.read_text().splitlines())) + "\n")
    with pytest.raises(InputError, match=match) as info:
        read_strecha_cameras(tmp_path)
    assert str(path) in str(info.value)


def test_strecha_missing(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        read_strecha_cameras(tmp_path / "nope")
    with pytest.raises(InputError, match=r"no \*\.camera files"):
        read_strecha_cameras(tmp_path)
    with pytest.raises(InputError, match="not found"):
        read_strecha_cameras([tmp_path / "a.jpg.camera"])


@settings(max_examples=40, deadline=None)
@given(
    rotvec=st.tuples(*[st.floats(-3.0, 3.0)] * 3),
    center=st.tuples(*[st.floats(-100.0, 100.0)] * 3),
    f=st.floats(50.0, 5000.0),
)
def test_strecha_property_round_trip(tmp_path_factory, rotvec, center, f) -> None:
    directory = tmp_path_factory.mktemp("strecha")
    world_from_cam = Rigid3.from_rotvec(np.array(rotvec), np.array(center))
    view = PosedView("x.png", Intrinsics(f, f, 31.5, 23.5, 64, 48), world_from_cam.inverse())
    write_strecha(directory, [view])
    (got,) = read_strecha_cameras(directory)
    assert got.cam_from_world.allclose(view.cam_from_world, atol=1e-9 * max(1.0, float(np.abs(center).max())))
    np.testing.assert_allclose(got.center_world, center, atol=1e-9)


# ----------------------------------------------------------------------------------------------
# HALCON
# ----------------------------------------------------------------------------------------------
def test_halcon_round_trip_and_projection(tmp_path: Path) -> None:
    views = ring_views(4)
    write_halcon(tmp_path, views)
    write_image(tmp_path / "image_camera02.png", np.zeros((48, 64), np.uint8))
    got = read_halcon_cameras(tmp_path)
    assert_same_views(got, views, names=[f"image_camera{i:02d}.png" for i in range(1, 5)])
    assert [g.image_path is not None for g in got] == [False, True, False, False]
    # The file's own formula: x_world = R x_cam + T, so x_cam = R^T (X - T); K = Focus/Sx ...
    M = np.array((tmp_path / "extrinsics_camera03.txt").read_text().split(), float).reshape(3, 4)
    p_cam = (M[:, :3].T @ (WORLD_POINTS - M[:, 3]).T).T
    k = views[2].intrinsics
    uv = np.stack([k.fx * p_cam[:, 0] / p_cam[:, 2] + k.cx, k.fy * p_cam[:, 1] / p_cam[:, 2] + k.cy], axis=1)
    np.testing.assert_allclose(got[2].project(WORLD_POINTS)[0], uv, atol=1e-9)


def test_halcon_rejects_distortion(tmp_path: Path) -> None:
    write_halcon(tmp_path, ring_views(2), poly1=-120.5)
    with pytest.raises(InputError, match="polynomial distortion is not supported.*undistort") as info:
        read_halcon_cameras(tmp_path)
    assert "intrinsics_camera01.txt" in str(info.value)


@pytest.mark.parametrize(
    ("which", "mutate", "match"),
    [
        ("extrinsics_camera02.txt", lambda s: " ".join(s.split()[:11]), "expected 12 numbers .* got 11"),
        ("extrinsics_camera02.txt", lambda s: s.replace(s.split()[0], "nan", 1), "NaN"),
        ("extrinsics_camera02.txt", lambda s: "1 0 0 0 0 1 0 0 0 1 0 0", "R .* is not a rotation"),
        (
            "intrinsics_camera02.txt",
            lambda s: s.replace("Cy:cy:", "Cyy:cyy:"),
            "missing HALCON camera parameters Cy",
        ),
        ("intrinsics_camera02.txt", lambda s: s[: s.index("Sx:sx:")], "missing .*Sx, Sy, Cx, Cy"),
        (
            "intrinsics_camera02.txt",
            lambda s: s.replace("Focus:foc:\t0.016", "Focus:foc:\tabc"),
            "'abc' is not a number",
        ),
        (
            "intrinsics_camera02.txt",
            lambda s: s.replace("Focus:foc:\t0.016", "Focus:foc:\t0.0"),
            "telecentric",
        ),
    ],
)
def test_halcon_malformed(tmp_path: Path, which: str, mutate, match: str) -> None:
    write_halcon(tmp_path, ring_views(2))
    path = tmp_path / which
    path.write_text(mutate(path.read_text()))
    with pytest.raises(InputError, match=match) as info:
        read_halcon_cameras(tmp_path)
    assert str(path) in str(info.value)


def test_halcon_missing_pair(tmp_path: Path) -> None:
    write_halcon(tmp_path, ring_views(2))
    (tmp_path / "extrinsics_camera02.txt").unlink()
    with pytest.raises(
        InputError, match="camera 02 has intrinsics_camera02.txt but no extrinsics_camera02.txt"
    ):
        read_halcon_cameras(tmp_path)
    with pytest.raises(InputError, match="no HALCON"):
        read_halcon_cameras(tmp_path / "..")
    with pytest.raises(InputError, match="not found"):
        read_halcon_cameras(tmp_path / "nope")


# ----------------------------------------------------------------------------------------------
# auto-detection
# ----------------------------------------------------------------------------------------------
def test_read_cameras_detects_every_layout(tmp_path: Path) -> None:
    views = ring_views(3)
    (tmp_path / "mb").mkdir()
    write_par(tmp_path / "mb" / "x_par.txt", views)
    write_image(tmp_path / "mb" / views[0].name, np.zeros((48, 64, 3), np.uint8))
    got = read_cameras(tmp_path / "mb" / "x_par.txt", image_dir=None)
    assert_same_views(got, views)
    assert_same_views(read_cameras(tmp_path / "mb"), views)  # a directory with exactly one *_par.txt

    strecha_layout(tmp_path / "st", views)
    assert_same_views(read_cameras(tmp_path / "st"), views)
    assert_same_views(read_cameras(tmp_path / "st" / "gt_dense_cameras"), views)
    assert read_cameras(tmp_path / "st")[0].image_path == tmp_path / "st" / "images" / views[0].name
    assert_same_views(
        read_cameras(tmp_path / "st" / "gt_dense_cameras" / f"{views[1].name}.camera"), views[1:2]
    )

    write_halcon(tmp_path / "ha", views)
    assert_same_views(
        read_cameras(tmp_path / "ha"), views, names=[f"image_camera{i:02d}.png" for i in (1, 2, 3)]
    )
    assert len(read_cameras(tmp_path / "ha" / "intrinsics_camera01.txt")) == 3

    rec = Reconstruction(
        cameras={i + 1: v.intrinsics for i, v in enumerate(views)},
        images={i + 1: Image(i + 1, v.name, i + 1, v.cam_from_world) for i, v in enumerate(views)},
    )
    write_colmap_text(tmp_path / "proj" / "sparse", rec)
    (tmp_path / "proj" / "images").mkdir()
    write_image(tmp_path / "proj" / "images" / views[0].name, np.zeros((48, 64, 3), np.uint8))
    got = read_cameras(tmp_path / "proj" / "sparse")
    assert_same_views(got, views)
    assert got[0].image_path == tmp_path / "proj" / "images" / views[0].name
    assert_same_views(read_cameras(tmp_path / "proj" / "sparse" / "images.txt"), views)


def test_read_cameras_rejects_unknown(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found.*_par.txt.*camera.*HALCON.*COLMAP"):
        read_cameras(tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("hello\n")
    with pytest.raises(InputError, match="no camera files recognised.*_par.txt.*HALCON.*COLMAP"):
        read_cameras(tmp_path)
    with pytest.raises(InputError, match="unrecognised camera file"):
        read_cameras(tmp_path / "notes.txt")
    write_par(tmp_path / "a_par.txt", ring_views(1))
    write_par(tmp_path / "b_par.txt", ring_views(1))
    with pytest.raises(InputError, match="several Middlebury camera files"):
        read_cameras(tmp_path)


def test_rotation_tolerance_accepts_printed_rotations(tmp_path: Path) -> None:
    """Rotations printed to 6 decimals (as in real HALCON files) are accepted and made exact."""
    views = ring_views(2)
    write_halcon(tmp_path, views)
    for p in tmp_path.glob("extrinsics_*.txt"):
        p.write_text(" ".join(f"{float(x):.6f}" for x in p.read_text().split()) + "\n")
    got = read_halcon_cameras(tmp_path)
    for g, v in zip(got, views):
        R = g.cam_from_world.R
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12
        assert math.degrees(np.arccos(np.clip((np.trace(R.T @ v.cam_from_world.R) - 1) / 2, -1, 1))) < 1e-3
