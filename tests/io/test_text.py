"""One parser for the numbers on a line of a text file, with errors naming file, line and word."""

from pathlib import Path

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.io.text import parse_numbers


def test_parses_floats_and_ints():
    got = parse_numbers("1 2.5 -3e2", Path("f.txt"), 4)
    assert got.dtype == np.float64 and got.tolist() == [1.0, 2.5, -300.0]
    ints = parse_numbers(["1", "-2", "30"], "f.txt", 1, "ids", kind=int)
    assert ints.dtype == np.int64 and ints.tolist() == [1, -2, 30]
    assert parse_numbers("", None, None).shape == (0,)


def test_long_lines_take_the_vectorised_path_with_the_same_results():
    words = [str(v) for v in np.arange(100) * 0.5]
    np.testing.assert_array_equal(parse_numbers(words, "f", 1), np.arange(100) * 0.5)
    with pytest.raises(InputError, match=r"f: line 1: track: 'x' is not a valid int; expected integers"):
        parse_numbers([*map(str, range(50)), "x"], "f", 1, "track", kind=int)
    with pytest.raises(InputError, match="line 1: keypoints contains NaN"):
        parse_numbers([*words, "nan"], "f", 1, "keypoints")


@pytest.mark.parametrize(
    ("words", "what", "kwargs", "match"),
    [
        ("1 two 3", None, {}, r"f.txt: line 7: expected numbers, 'two' is not a number"),
        ("1 two 3", "the pose", {}, r"line 7: the pose: 'two' is not a number; expected numbers"),
        ("1 nan 3", None, {}, r"line 7: NaN or infinite value in '1 nan 3'"),
        ("1 inf 3", "X Y Z", {}, r"line 7: X Y Z contains NaN or infinite values"),
        ("1 2.5", "size", {"kind": int}, r"line 7: size: '2.5' is not a valid int"),
        ("1 2", None, {"count": 3}, r"line 7: expected 3 numbers, found 2"),
        ("1 2", "'P2'", {"count": 1}, r"line 7: 'P2' needs 1 number, found 2"),
    ],
)
def test_errors_name_file_line_and_word(words, what, kwargs, match):
    with pytest.raises(InputError, match=match):
        parse_numbers(words, Path("f.txt"), 7, what, **kwargs)


def test_no_line_number():
    with pytest.raises(InputError, match=r"^\S*f.txt: \[R \| T\]: 'a' is not a number"):
        parse_numbers("a", Path("f.txt"), None, "[R | T]")
