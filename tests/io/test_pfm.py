"""PFM reading and writing: Middlebury conventions, exact round trips, malformed files."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skyrecon.errors import InputError
from skyrecon.io.pfm import encode_pfm, read_pfm, write_pfm


def _raw_pfm(magic: bytes, width: int, height: int, scale: bytes, values: np.ndarray) -> bytes:
    return magic + b"\n" + f"{width} {height}".encode() + b"\n" + scale + b"\n" + values.tobytes()


def test_round_trip_grey_exact_with_nan(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(7, 11)).astype(np.float32) * 100
    a[2, 3] = np.nan
    a[0, :] = np.nan
    write_pfm(tmp_path / "a.pfm", a)
    b = read_pfm(tmp_path / "a.pfm")
    assert b.dtype == np.float32 and b.shape == (7, 11)
    np.testing.assert_array_equal(a, b)


def test_round_trip_colour_exact(tmp_path):
    rng = np.random.default_rng(1)
    a = rng.uniform(-1e6, 1e6, size=(5, 4, 3)).astype(np.float32)
    a[1, 1, 2] = np.nan
    write_pfm(tmp_path / "c.pfm", a)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), a)


def test_file_layout_little_endian_bottom_up_inf(tmp_path):
    a = np.array([[1, 2, 3], [4, 5, np.nan]], dtype=np.float32)
    write_pfm(tmp_path / "a.pfm", a)
    data = (tmp_path / "a.pfm").read_bytes()
    header = b"Pf\n3 2\n-1\n"
    assert data.startswith(header)
    stored = np.frombuffer(data[len(header) :], "<f4").reshape(2, 3)
    np.testing.assert_array_equal(stored[0], [4, 5, np.inf])  # last image row first
    np.testing.assert_array_equal(stored[1], [1, 2, 3])


def test_big_endian_positive_scale_and_inf_to_nan(tmp_path):
    top_down = np.array([[1.5, np.inf], [-np.inf, 2.25]], dtype=np.float32)
    path = tmp_path / "be.pfm"
    path.write_bytes(_raw_pfm(b"Pf", 2, 2, b"1.0", top_down[::-1].astype(">f4")))
    b = read_pfm(path)
    assert b.dtype == np.float32 and b.dtype.byteorder in ("=", "<", "|")
    np.testing.assert_array_equal(b, [[1.5, np.nan], [np.nan, 2.25]])


def test_header_with_odd_whitespace_and_scale_magnitude(tmp_path):
    a = np.arange(6, dtype="<f4").reshape(2, 3)
    path = tmp_path / "w.pfm"
    path.write_bytes(b"Pf\n3  2\n-0.5\n" + a[::-1].tobytes())
    np.testing.assert_array_equal(read_pfm(path), a)


def test_data_starting_with_whitespace_byte(tmp_path):
    # 0x0a as the first data byte must not be mistaken for header whitespace.
    a = np.frombuffer(b"\n\x00\x00\x00" + b"\x20\x00\x00\x00", "<f4").reshape(1, 2).copy()
    path = tmp_path / "ws.pfm"
    path.write_bytes(b"Pf\n2 1\n-1\n" + a.tobytes())
    np.testing.assert_array_equal(read_pfm(path), a)


@settings(max_examples=40, deadline=None)
@given(
    hnp.arrays(
        np.float32,
        st.one_of(
            hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=9),
            st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3)),
        ),
        elements=st.floats(width=32, allow_infinity=False),
    )
)
def test_property_round_trip(tmp_path_factory, a):
    path = tmp_path_factory.mktemp("pfm") / "p.pfm"
    write_pfm(path, a)
    np.testing.assert_array_equal(read_pfm(path), a)


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=64))
def test_property_garbage_never_crashes(tmp_path_factory, junk):
    path = tmp_path_factory.mktemp("pfm") / "g.pfm"
    path.write_bytes(b"Pf\n" + junk)
    try:
        out = read_pfm(path)
    except InputError as exc:
        assert str(path) in str(exc)
    else:
        assert out.dtype == np.float32 and out.ndim == 2


def test_write_accepts_h_w_1_and_integer_arrays(tmp_path):
    write_pfm(tmp_path / "a.pfm", np.ones((2, 3, 1)))
    assert read_pfm(tmp_path / "a.pfm").shape == (2, 3)
    write_pfm(tmp_path / "b.pfm", np.arange(6).reshape(2, 3))
    np.testing.assert_array_equal(read_pfm(tmp_path / "b.pfm"), np.arange(6).reshape(2, 3))


def test_write_is_atomic_no_temp_files(tmp_path):
    write_pfm(tmp_path / "a.pfm", np.zeros((3, 3), np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["a.pfm"]


@pytest.mark.parametrize(
    "content, words",
    [
        (b"", "empty"),
        (b"P5\n3 2\n255\n" + bytes(6), "not a PFM"),
        (b"Pf\n3 2\n-1\n" + bytes(20), "truncated"),
        (b"Pf\n3 2\n", "missing the scale"),
        (b"Pf\n3\n", "missing the height"),
        (b"Pf\n3 2\n-1", "no pixel data"),
        (b"Pf\nthree 2\n-1\n" + bytes(24), "must be numbers"),
        (b"Pf\n0 2\n-1\n", "positive"),
        (b"Pf\n3 2\n0\n" + bytes(24), "non-zero"),
        (b"Pf\n3 2\nnan\n" + bytes(24), "non-zero"),
        (b"PF\n3 2\n-1\n" + bytes(24), "truncated"),
    ],
)
def test_malformed_files_raise_input_error_naming_the_file(tmp_path, content, words):
    path = tmp_path / "bad.pfm"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_pfm(path)
    assert str(path) in str(info.value)
    assert words in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found") as info:
        read_pfm(tmp_path / "nope.pfm")
    assert "nope.pfm" in str(info.value)


@pytest.mark.parametrize("shape", [(3,), (2, 3, 2), (2, 3, 4), (0, 3), (1, 2, 3, 4)])
def test_write_rejects_bad_shapes(tmp_path, shape):
    with pytest.raises(InputError) as info:
        write_pfm(tmp_path / "x.pfm", np.zeros(shape, np.float32))
    assert "x.pfm" in str(info.value)
    assert not (tmp_path / "x.pfm").exists()


def test_encode_rejects_non_numeric():
    with pytest.raises(InputError):
        encode_pfm(np.array([["a", "b"]]))


def test_write_does_not_modify_the_input(tmp_path):
    a = np.array([[np.nan]], dtype="<f4")
    write_pfm(tmp_path / "a.pfm", a)
    assert np.isnan(a[0, 0])
