"""One NumPy-to-JSON conversion and an atomic JSON writer."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from skyrecon.io.jsonio import dumps_json, to_jsonable, write_json


@dataclasses.dataclass
class _Record:
    name: str
    values: np.ndarray
    where: Path


def test_numpy_values_become_plain_json():
    obj = {
        "int": np.int64(3),
        "float": np.float32(0.5),
        "bool": np.bool_(True),
        "array": np.array([[1.0, np.nan], [np.inf, -2.0]]),
        "ints": np.arange(3, dtype=np.uint16),
        "tuple": (1, np.float64(-np.inf)),
        "set": {7},
        "path": Path("out") / "a.ply",
        7: "key made text",
        "nested": [{"x": np.float64(1.25)}],
        "none": None,
    }
    got = to_jsonable(obj)
    assert got == {
        "int": 3,
        "float": 0.5,
        "bool": True,
        "array": [[1.0, None], [None, -2.0]],
        "ints": [0, 1, 2],
        "tuple": [1, None],
        "set": [7],
        "path": "out/a.ply",
        "7": "key made text",
        "nested": [{"x": 1.25}],
        "none": None,
    }
    assert type(got["int"]) is int and type(got["bool"]) is bool and type(got["ints"][0]) is int
    assert to_jsonable(float("nan")) is None and to_jsonable(True) is True


def test_dataclasses_become_dicts():
    rec = _Record("a", np.array([1, 2]), Path("x"))
    assert to_jsonable(rec) == {"name": "a", "values": [1, 2], "where": "x"}
    assert to_jsonable(_Record) is _Record  # a class is not an instance


def test_dumps_is_strict_json():
    text = dumps_json({"a": np.nan, "b": np.arange(2)})
    assert text.endswith("\n")
    assert json.loads(text) == {"a": None, "b": [0, 1]}
    assert "NaN" not in text
    with pytest.raises(TypeError):
        dumps_json({"x": object()})


def test_write_json_atomic(tmp_path):
    path = tmp_path / "sub" / "s.json"
    write_json(path, {"v": np.float64(2.0)})
    assert json.loads(path.read_text()) == {"v": 2.0}
    with pytest.raises(TypeError):
        write_json(path, {"x": object()})
    assert json.loads(path.read_text()) == {"v": 2.0}  # a failed write leaves the old file
    assert [p.name for p in path.parent.iterdir()] == ["s.json"]
