"""PLY point clouds: the real PMVS cloud, every encoding, elements around the vertices, bad files."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skyrecon.core.depth import PointCloud
from skyrecon.errors import InputError
from skyrecon.io.ply import encode_ply, read_ply, write_ply
from tests.conftest import require

ROCK = "robovision-rock/2016_10_25__12_11_32/reference.ply"


def _header(fmt: str, *elements: tuple[str, int, list[str]]) -> bytes:
    lines = ["ply", f"format {fmt} 1.0", "comment test file"]
    for name, count, props in elements:
        lines.append(f"element {name} {count}")
        lines += [f"property {p}" for p in props]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode()


def _cloud(n: int, colors: bool = True, normals: bool = True, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(
        rng.normal(size=(n, 3)) * 10,
        rng.integers(0, 256, (n, 3)) if colors else None,
        rng.normal(size=(n, 3)) if normals else None,
    )


def _assert_same(a: PointCloud, b: PointCloud) -> None:
    np.testing.assert_array_equal(a.points, b.points)
    for x, y in ((a.colors, b.colors), (a.normals, b.normals)):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)


# ----- the real file -------------------------------------------------------------------
@pytest.mark.realdata
def test_real_rock_reference_ply(real_data):
    path = require(real_data, ROCK)
    cloud = read_ply(path)
    assert len(cloud) == 18741
    assert cloud.points.dtype == np.float32 and cloud.colors.dtype == np.uint8
    np.testing.assert_allclose(cloud.points[0], [0.00673005, 0.0261546, 0.00957147], rtol=1e-6)
    np.testing.assert_allclose(cloud.normals[0], [-0.355283, -0.628787, -0.691665], rtol=1e-6)
    np.testing.assert_array_equal(cloud.colors[0], [12, 12, 12])
    extent = cloud.points.max(axis=0) - cloud.points.min(axis=0)
    assert 0.02 < extent.max() < 0.08  # the object is about 4 cm across
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-3)


@pytest.mark.realdata
def test_real_rock_round_trip_binary_and_ascii(real_data, tmp_path):
    cloud = read_ply(require(real_data, ROCK))
    for binary in (True, False):
        write_ply(tmp_path / "r.ply", cloud, binary=binary)
        _assert_same(read_ply(tmp_path / "r.ply"), cloud)


# ----- writing ------------------------------------------------------------------------------
def test_binary_header_layout(tmp_path):
    write_ply(tmp_path / "c.ply", _cloud(3))
    data = (tmp_path / "c.ply").read_bytes()
    header = data[: data.index(b"end_header\n") + len(b"end_header\n")].decode()
    assert "format binary_little_endian 1.0" in header
    props = [line.split()[1:] for line in header.splitlines() if line.startswith("property")]
    assert props == [
        ["float", "x"],
        ["float", "y"],
        ["float", "z"],
        ["uchar", "red"],
        ["uchar", "green"],
        ["uchar", "blue"],
        ["float", "nx"],
        ["float", "ny"],
        ["float", "nz"],
    ]
    assert len(data) - len(header) == 3 * (12 + 3 + 12)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("colors, normals", [(True, True), (True, False), (False, True), (False, False)])
def test_round_trip_exact(tmp_path, binary, colors, normals):
    cloud = _cloud(50, colors, normals)
    write_ply(tmp_path / "c.ply", cloud, binary=binary)
    _assert_same(read_ply(tmp_path / "c.ply"), cloud)


@pytest.mark.parametrize("binary", [True, False])
def test_empty_cloud(tmp_path, binary):
    write_ply(tmp_path / "e.ply", PointCloud(np.zeros((0, 3))), binary=binary)
    assert len(read_ply(tmp_path / "e.ply")) == 0


def test_write_refuses_nan_points_and_is_atomic(tmp_path):
    cloud = _cloud(4)
    cloud.points[1, 2] = np.nan
    with pytest.raises(InputError, match="NaN") as info:
        write_ply(tmp_path / "bad.ply", cloud)
    assert "bad.ply" in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_one_million_points_binary_is_fast(tmp_path):
    cloud = _cloud(1_000_000, seed=3)
    t0 = time.perf_counter()
    write_ply(tmp_path / "big.ply", cloud)
    t1 = time.perf_counter()
    back = read_ply(tmp_path / "big.ply")
    t2 = time.perf_counter()
    _assert_same(back, cloud)
    assert t1 - t0 < 1.0, f"write took {t1 - t0:.2f} s"
    assert t2 - t1 < 1.0, f"read took {t2 - t1:.2f} s"


@settings(max_examples=30, deadline=None)
@given(
    hnp.arrays(
        np.float32,
        st.tuples(st.integers(0, 20), st.just(3)),
        elements=st.floats(width=32, allow_nan=False, allow_infinity=False),
    ),
    st.booleans(),
)
def test_property_round_trip(tmp_path_factory, points, binary):
    n = len(points)
    cloud = PointCloud(points, np.arange(3 * n).reshape(n, 3) % 256, points[::-1] * 0.5)
    path = tmp_path_factory.mktemp("ply") / "p.ply"
    write_ply(path, cloud, binary=binary)
    _assert_same(read_ply(path), cloud)


# ----- reading other writers' files ---------------------------------------------------------------
def test_big_endian_doubles_any_order_extra_props_float_colours(tmp_path):
    header = _header(
        "binary_big_endian",
        (
            "vertex",
            2,
            [
                "float confidence",
                "double z",
                "float red",
                "float green",
                "float blue",
                "double x",
                "uchar alpha",
                "double y",
            ],
        ),
    )
    rows = np.array(
        [(0.9, 3.0, 1.0, 0.5, 0.0, 1.0, 255, 2.0), (0.1, -3.0, 0.0, 0.2, 1.0, -1.0, 7, -2.0)],
        dtype=[
            ("c", ">f4"),
            ("z", ">f8"),
            ("r", ">f4"),
            ("g", ">f4"),
            ("b", ">f4"),
            ("x", ">f8"),
            ("a", "u1"),
            ("y", ">f8"),
        ],
    )
    (tmp_path / "be.ply").write_bytes(header + rows.tobytes())
    cloud = read_ply(tmp_path / "be.ply")
    np.testing.assert_array_equal(cloud.points, [[1, 2, 3], [-1, -2, -3]])
    np.testing.assert_array_equal(cloud.colors, [[255, 128, 0], [0, 51, 255]])
    assert cloud.normals is None


def test_integer_coordinates_and_ushort_colours(tmp_path):
    header = _header(
        "binary_little_endian",
        ("vertex", 1, ["int x", "short y", "char z", "ushort red", "ushort green", "ushort blue"]),
    )
    rows = np.array(
        [(5, -6, -7, 65535, 0, 257 * 10)],
        dtype=[("x", "<i4"), ("y", "<i2"), ("z", "i1"), ("r", "<u2"), ("g", "<u2"), ("b", "<u2")],
    )
    (tmp_path / "i.ply").write_bytes(header + rows.tobytes())
    cloud = read_ply(tmp_path / "i.ply")
    np.testing.assert_array_equal(cloud.points, [[5, -6, -7]])
    np.testing.assert_array_equal(cloud.colors, [[255, 0, 10]])


def test_binary_faces_before_and_after_vertices(tmp_path):
    verts = np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], dtype="<f4")
    tri = np.array(
        [(3, (0, 1, 2), 9), (3, (0, 2, 3), 8)], dtype=[("n", "u1"), ("i", "<i4", (3,)), ("flag", "u1")]
    )
    face_props = ["list uchar int vertex_indices", "uchar flag"]
    # Uniform triangles before the vertices (vectorised skip).
    data = _header(
        "binary_little_endian", ("face", 2, face_props), ("vertex", 4, ["float x", "float y", "float z"])
    )
    (tmp_path / "a.ply").write_bytes(data + tri.tobytes() + verts.tobytes())
    np.testing.assert_array_equal(read_ply(tmp_path / "a.ply").points, verts)
    # Ragged lists before the vertices (row-by-row skip).
    ragged = (
        np.array([3], "u1").tobytes()
        + np.array([0, 1, 2], "<i4").tobytes()
        + b"\x01"
        + np.array([4], "u1").tobytes()
        + np.array([0, 1, 2, 3], "<i4").tobytes()
        + b"\x02"
    )
    (tmp_path / "b.ply").write_bytes(data + ragged + verts.tobytes())
    np.testing.assert_array_equal(read_ply(tmp_path / "b.ply").points, verts)
    # Faces after the vertices, including a zero-count face element.
    data = _header(
        "binary_little_endian",
        ("vertex", 4, ["float x", "float y", "float z"]),
        ("face", 2, face_props),
        ("edge", 0, ["int vertex1"]),
    )
    (tmp_path / "c.ply").write_bytes(data + verts.tobytes() + tri.tobytes())
    np.testing.assert_array_equal(read_ply(tmp_path / "c.ply").points, verts)


def test_truncated_ragged_list_before_vertices(tmp_path):
    data = _header(
        "binary_little_endian",
        ("face", 2, ["list uchar int vertex_indices"]),
        ("vertex", 1, ["float x", "float y", "float z"]),
    )
    body = (
        np.array([3], "u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes() + np.array([200], "u1").tobytes()
    )
    (tmp_path / "t.ply").write_bytes(data + body)
    with pytest.raises(InputError, match="truncated"):
        read_ply(tmp_path / "t.ply")


def test_ascii_faces_around_vertices_crlf_and_blank_lines(tmp_path):
    text = (
        "ply\r\nformat ascii 1.0\r\nobj_info made by hand\r\n"
        "element face 2\r\nproperty list uchar int vertex_indices\r\n"
        "element vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nproperty uchar alpha\r\n"
        "element face2 1\r\nproperty list uchar int vertex_indices\r\n"
        "end_header\r\n"
        "3 0 1 2\r\n4 0 1 2 0\r\n"
        "1 2 3 255\r\n\r\n4 5 6 255\r\n-7e-3 nan_is_not_here 9 255\r\n"
    ).replace("nan_is_not_here", "8.5")
    (tmp_path / "a.ply").write_bytes((text + "3 0 1 2\r\n").encode())
    cloud = read_ply(tmp_path / "a.ply")
    np.testing.assert_allclose(cloud.points, [[1, 2, 3], [4, 5, 6], [-7e-3, 8.5, 9]])
    assert cloud.colors is None and cloud.normals is None


def test_diffuse_colour_names(tmp_path):
    text = _header(
        "ascii",
        (
            "vertex",
            1,
            [
                "float x",
                "float y",
                "float z",
                "uchar diffuse_red",
                "uchar diffuse_green",
                "uchar diffuse_blue",
            ],
        ),
    )
    (tmp_path / "d.ply").write_bytes(text + b"0 0 0 1 2 3\n")
    np.testing.assert_array_equal(read_ply(tmp_path / "d.ply").colors, [[1, 2, 3]])


# ----- malformed files --------------------------------------------------------------------------
XYZ = ["float x", "float y", "float z"]


@pytest.mark.parametrize(
    "content, words",
    [
        (b"", "empty"),
        (b"PLY?\n", "not a PLY"),
        (b"solid cube\nfacet\n", "not a PLY"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "end_header"),
        (
            b"ply\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
            "format",
        ),
        (b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown PLY format"),
        (_header("ascii", ("face", 0, ["list uchar int vertex_indices"])), "no 'vertex'"),
        (_header("ascii", ("vertex", 1, ["float x", "float y"])) + b"1 2\n", "z"),
        (
            _header("ascii", ("vertex", 1, ["float x", "float y", "float z", "quad w"])),
            "unknown PLY property type",
        ),
        (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "property before any element"),
        (b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n", "non-negative integer"),
        (b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n", "non-negative integer"),
        (b"ply\nformat ascii 1.0\nbanana\nend_header\n", "unexpected"),
        (_header("ascii", ("vertex", 1, XYZ + ["float x"])) + b"1 2 3 4\n", "repeats"),
        (_header("ascii", ("vertex", 1, XYZ + ["list uchar int idx"])) + b"1 2 3 0\n", "list properties"),
        (_header("binary_little_endian", ("vertex", 3, XYZ)) + bytes(30), "truncated"),
        (_header("ascii", ("vertex", 3, XYZ)) + b"1 2 3\n4 5 6\n", "truncated"),
        (
            _header("ascii", ("vertex", 2, XYZ)) + b"1 2 3\n4 5\n",
            "line 10: expected 3 vertex values, found 2",
        ),
        (_header("ascii", ("vertex", 2, XYZ)) + b"1 2 3\n4 5 6 7\n", "line 10"),
        (
            _header("ascii", ("vertex", 2, XYZ)) + b"1 2 3\n4 five 6\n",
            "line 10: vertex values must be numbers",
        ),
        (_header("ascii", ("vertex", 2, XYZ)) + b"1 2 3\n4 nan 6\n", "NaN"),
        (
            _header("binary_little_endian", ("vertex", 1, XYZ)) + np.array([1, np.inf, 2], "<f4").tobytes(),
            "NaN or infinite",
        ),
    ],
)
def test_malformed_files_raise_input_error_naming_the_file(tmp_path, content, words):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_ply(path)
    assert str(path) in str(info.value)
    assert words in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_ply(tmp_path / "none.ply")


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=80))
def test_property_garbage_after_header_never_crashes(tmp_path_factory, junk):
    path = tmp_path_factory.mktemp("ply") / "g.ply"
    path.write_bytes(
        _header("binary_little_endian", ("face", 1, ["list uchar int vertex_indices"]), ("vertex", 2, XYZ))
        + junk
    )
    try:
        cloud = read_ply(path)
    except InputError as exc:
        assert str(path) in str(exc)
    else:
        assert len(cloud) == 2


@settings(max_examples=40, deadline=None)
@given(st.text(alphabet="0123456789.-e \n", max_size=60))
def test_property_ascii_garbage_never_crashes(tmp_path_factory, body):
    path = tmp_path_factory.mktemp("ply") / "g.ply"
    path.write_bytes(_header("ascii", ("vertex", 2, XYZ)) + body.encode())
    try:
        cloud = read_ply(path)
    except InputError as exc:
        assert str(path) in str(exc)
    else:
        assert len(cloud) == 2 and np.isfinite(cloud.points).all()


def test_encode_ply_is_bytes():
    data = encode_ply(_cloud(2, colors=False, normals=False), binary=False)
    assert data.startswith(b"ply\nformat ascii 1.0\n") and data.count(b"\n") == 8 + 2
