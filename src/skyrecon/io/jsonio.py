"""JSON output: one conversion of NumPy values, paths and dataclasses to plain JSON, and an atomic writer.

Every ``*.json`` file skyrecon writes goes through :func:`to_jsonable`, so the files are strict JSON
(no ``NaN``/``Infinity`` tokens): a non-finite number becomes ``null``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from skyrecon.io.atomic import write_text_atomic

__all__ = ["dumps_json", "to_jsonable", "write_json"]


def to_jsonable(obj: Any) -> Any:
    """A copy of ``obj`` made only of dict, list, str, int, float (finite), bool and None.

    Converts, recursively: NumPy arrays (to nested lists) and scalars (to int, float or bool),
    non-finite floats (NaN, +-inf) to None, paths to str, dataclass instances to dicts of their
    fields, mappings to dicts with str keys, tuples, lists and sets to lists. Anything else is
    returned unchanged (``json.dumps`` then says what it cannot write).
    """
    if obj is None or isinstance(obj, (str, bool)):
        return obj
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, PurePath):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    return obj


def dumps_json(obj: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` (see :func:`to_jsonable`), ending with a newline.

    Raises:
        TypeError: ``obj`` holds a value JSON cannot represent (after conversion).
    """
    return json.dumps(to_jsonable(obj), indent=indent, allow_nan=False) + "\n"


def write_json(path: str | Path, obj: Any, indent: int | None = 2) -> None:
    """Write ``obj`` as strict JSON (see :func:`to_jsonable`) to ``path``, atomically.

    Missing parent directories are created; an interrupted write leaves the old file or none.
    """
    write_text_atomic(path, dumps_json(obj, indent))
