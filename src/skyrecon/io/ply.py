"""PLY point clouds: read ascii and binary (either byte order), write binary little-endian or ascii.

Only the ``vertex`` element is read: ``x y z`` (required, any numeric type), ``red green
blue`` (optional; integer types as 0..255, float types as 0..1) and ``nx ny nz``
(optional). Other vertex properties (``alpha``, ``confidence``, ...) are ignored, and so
are other elements (``face`` with its list properties, ``edge``, ...), before or after
the vertices. Points keep the frame and units of the file (skyrecon writes metres, in
the frame its caller states: the left camera for ``stereo``, the world for ``mvs``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skyrecon.core.depth import PointCloud
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_bytes_atomic

_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_MAX_HEADER_BYTES = 1 << 20
_COLOR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"), ("r", "g", "b"))


@dataclass
class _Property:
    name: str
    code: str  # numpy type code without byte order, e.g. "f4"
    count_code: str | None = None  # list properties: the type of the length prefix


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property] = field(default_factory=list)

    @property
    def has_lists(self) -> bool:
        return any(p.count_code is not None for p in self.properties)

    def dtype(self, order: str) -> np.dtype:
        return np.dtype([(p.name, order + p.code) for p in self.properties])


@dataclass
class _Header:
    format: str
    elements: list[_Element]
    data_offset: int
    num_lines: int  # lines up to and including end_header


def _names(dtype: np.dtype) -> tuple[str, ...]:
    """Field names of a structured dtype (empty for a plain one)."""
    return dtype.names or ()


# ----- header ---------------------------------------------------------------
def _type_code(name: str, path: Path, lineno: int) -> str:
    try:
        return _TYPES[name]
    except KeyError:
        raise InputError(f"line {lineno}: unknown PLY property type {name!r}", path) from None


def _parse_property(words: list[str], path: Path, lineno: int) -> _Property:
    if len(words) == 5 and words[1] == "list":
        return _Property(words[4], _type_code(words[3], path, lineno), _type_code(words[2], path, lineno))
    if len(words) == 3:
        return _Property(words[2], _type_code(words[1], path, lineno))
    raise InputError(f"line {lineno}: bad property line {' '.join(words)!r}", path)


def _parse_element(words: list[str], path: Path, lineno: int) -> _Element:
    if len(words) != 3:
        raise InputError(f"line {lineno}: bad element line {' '.join(words)!r}", path)
    try:
        count = int(words[2])
    except ValueError:
        count = -1
    if count < 0:
        raise InputError(f"line {lineno}: element count {words[2]!r} must be a non-negative integer", path)
    return _Element(words[1], count)


def _header_lines(data: bytes, path: Path) -> tuple[list[str], int]:
    """The header's lines (without 'end_header') and the offset of the first data byte."""
    if not data.startswith(b"ply") or data[3:4] not in (b"\n", b"\r"):
        raise InputError("not a PLY file: it does not start with 'ply'", path)
    lines: list[str] = []
    pos = 0
    while True:
        nl = data.find(b"\n", pos, _MAX_HEADER_BYTES)
        if nl < 0:
            raise InputError("truncated PLY header: no 'end_header' line", path)
        line = data[pos:nl].decode("latin-1").strip()
        pos = nl + 1
        if line == "end_header":
            return lines, pos
        lines.append(line)


def _parse_header(data: bytes, path: Path) -> _Header:
    lines, offset = _header_lines(data, path)
    fmt, elements = None, []
    for lineno, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise InputError(f"line {lineno}: unknown PLY format {line!r}", path)
            fmt = words[1]
        elif words[0] == "element":
            elements.append(_parse_element(words, path, lineno))
        elif words[0] == "property":
            if not elements:
                raise InputError(f"line {lineno}: property before any element", path)
            elements[-1].properties.append(_parse_property(words, path, lineno))
        else:
            raise InputError(f"line {lineno}: unexpected PLY header line {line!r}", path)
    if fmt is None:
        raise InputError("PLY header has no 'format' line", path)
    return _Header(fmt, elements, offset, len(lines) + 1)


def _vertex_index(header: _Header, path: Path) -> int:
    names = [e.name for e in header.elements]
    if "vertex" not in names:
        raise InputError("PLY file has no 'vertex' element", path)
    i = names.index("vertex")
    vertex = header.elements[i]
    props = [p.name for p in vertex.properties]
    missing = [n for n in ("x", "y", "z") if n not in props]
    if missing:
        raise InputError(f"PLY vertices lack the {'/'.join(missing)} properties", path)
    if len(set(props)) != len(props):
        raise InputError("PLY vertex element repeats a property name", path)
    if vertex.has_lists:
        raise InputError("list properties in the vertex element are not supported", path)
    return i


# ----- binary body ------------------------------------------------------------
def _uniform_row_dtype(element: _Element, order: str, data: bytes, offset: int) -> np.dtype | None:
    """Row dtype if every list of the element's first row has the same length, else None."""
    fields: list[tuple[Any, ...]] = []
    pos = offset
    for j, p in enumerate(element.properties):
        if p.count_code is None:
            fields.append((f"f{j}", order + p.code))
            pos += np.dtype(p.code).itemsize
            continue
        csize = np.dtype(p.count_code).itemsize
        if pos + csize > len(data):
            return None
        n = int(np.frombuffer(data, order + p.count_code, 1, pos)[0])
        if n < 0:
            return None
        fields.append((f"n{j}", order + p.count_code))
        fields.append((f"v{j}", order + p.code, (n,)))
        pos += csize + n * np.dtype(p.code).itemsize
    return np.dtype(fields)


def _skip_binary_rows(element: _Element, order: str, data: bytes, offset: int, path: Path) -> int:
    """Offset just after ``element``'s rows. Vectorised when all list lengths are equal."""
    if element.count == 0:
        return offset
    if not element.has_lists:
        return offset + element.count * element.dtype(order).itemsize
    row = _uniform_row_dtype(element, order, data, offset)
    if row is not None and offset + element.count * row.itemsize <= len(data):
        rows = np.frombuffer(data, row, element.count, offset)
        if all(np.all(rows[f] == rows[f][0]) for f in _names(row) if f.startswith("n")):
            return offset + element.count * row.itemsize
    for _ in range(element.count):  # ragged lists: walk row by row
        for p in element.properties:
            if p.count_code is None:
                offset += np.dtype(p.code).itemsize
                continue
            if offset + np.dtype(p.count_code).itemsize > len(data):
                raise InputError(f"truncated PLY file inside element '{element.name}'", path)
            n = np.frombuffer(data, order + p.count_code, 1, offset)[0]
            offset += np.dtype(p.count_code).itemsize + int(n) * np.dtype(p.code).itemsize
    return offset


def _read_binary_vertices(data: bytes, header: _Header, vi: int, path: Path) -> np.ndarray:
    order = _FORMATS[header.format]
    offset = header.data_offset
    for element in header.elements[:vi]:
        offset = _skip_binary_rows(element, order, data, offset, path)
    vertex = header.elements[vi]
    dtype = vertex.dtype(order)
    available = max(0, len(data) - offset) // dtype.itemsize
    if available < vertex.count:
        raise InputError(f"truncated PLY file: {vertex.count} vertices declared, data for {available}", path)
    return np.frombuffer(data, dtype, vertex.count, offset)


# ----- ascii body -------------------------------------------------------------
def _bad_ascii_line(lines: list[bytes], numbers: list[int], nprops: int, path: Path) -> InputError:
    """The error for the first vertex line that does not hold ``nprops`` numbers."""
    for line, lineno in zip(lines, numbers):
        words = line.split()
        if len(words) != nprops:
            return InputError(f"line {lineno}: expected {nprops} vertex values, found {len(words)}", path)
        try:
            [float(w) for w in words]
        except ValueError:
            return InputError(
                f"line {lineno}: vertex values must be numbers, got {line.decode('latin-1')!r}", path
            )
    return InputError("malformed vertex data", path)


def _read_ascii_vertices(data: bytes, header: _Header, vi: int, path: Path) -> np.ndarray:
    raw = data[header.data_offset :].split(b"\n")
    numbers = [i for i, line in enumerate(raw) if line.strip()]
    start = sum(e.count for e in header.elements[:vi])  # ascii: one line per element row
    vertex = header.elements[vi]
    rows = numbers[start : start + vertex.count]
    if len(rows) < vertex.count:
        raise InputError(
            f"truncated PLY file: {vertex.count} vertices declared, found {len(rows)} vertex lines", path
        )
    lines = [raw[i] for i in rows]
    nprops = len(vertex.properties)
    tokens = b" ".join(lines).split()
    linenos = [header.num_lines + 1 + i for i in rows]
    if len(tokens) != vertex.count * nprops:
        raise _bad_ascii_line(lines, linenos, nprops, path)
    try:
        values = np.array(tokens, dtype=np.float64).reshape(vertex.count, nprops)
    except ValueError:
        raise _bad_ascii_line(lines, linenos, nprops, path) from None
    out = np.empty(vertex.count, vertex.dtype("="))
    for j, p in enumerate(vertex.properties):
        out[p.name] = values[:, j]
    return out


# ----- conversion to a PointCloud ----------------------------------------------
def _colors(vertices: np.ndarray) -> np.ndarray | None:
    names = _names(vertices.dtype)
    for triple in _COLOR_NAMES:
        if all(n in names for n in triple):
            c = np.stack([vertices[n] for n in triple], axis=1)
            kind = vertices.dtype[triple[0]]
            if kind.kind == "f":
                c = c.astype(np.float64) * 255.0
            elif kind.itemsize == 2:
                c = c.astype(np.float64) / 257.0
            return np.clip(np.rint(c), 0, 255).astype(np.uint8)
    return None


def _to_cloud(vertices: np.ndarray, path: Path) -> PointCloud:
    points = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1).astype(np.float32)
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise InputError(
            f"{int(bad.sum())} of {len(points)} vertices have NaN or infinite coordinates "
            f"(first: vertex {int(np.argmax(bad))}); remove them before loading",
            path,
        )
    normals = None
    if all(n in _names(vertices.dtype) for n in ("nx", "ny", "nz")):
        normals = np.stack([vertices["nx"], vertices["ny"], vertices["nz"]], axis=1).astype(np.float32)
    return PointCloud(points, _colors(vertices), normals)


def read_ply(path: str | Path) -> PointCloud:
    """Read the vertices of a PLY file (ascii, binary_little_endian or binary_big_endian).

    Args:
        path: the ``.ply`` file.
    Returns:
        PointCloud: points (N, 3) float32 in the file's units and frame; colours (N, 3)
        uint8 RGB when the file has red/green/blue; normals (N, 3) float32 when it has
        nx/ny/nz.
    Raises:
        InputError: missing, empty, truncated or malformed file; no x/y/z; NaN or
            infinite coordinates.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("PLY file not found; check the path", path)
    data = path.read_bytes()
    if not data:
        raise InputError("PLY file is empty", path)
    header = _parse_header(data, path)
    vi = _vertex_index(header, path)
    if header.format == "ascii":
        vertices = _read_ascii_vertices(data, header, vi, path)
    else:
        vertices = _read_binary_vertices(data, header, vi, path)
    return _to_cloud(vertices, path)


# ----- writing -------------------------------------------------------------------
def _vertex_table(cloud: PointCloud) -> np.ndarray:
    """Structured little-endian array: x y z float, [red green blue uchar], [nx ny nz float]."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if cloud.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if cloud.normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    table = np.empty(len(cloud), np.dtype(fields))
    for j, n in enumerate("xyz"):
        table[n] = cloud.points[:, j]
    if cloud.colors is not None:
        for j, n in enumerate(("red", "green", "blue")):
            table[n] = cloud.colors[:, j]
    if cloud.normals is not None:
        for j, n in enumerate(("nx", "ny", "nz")):
            table[n] = cloud.normals[:, j]
    return table


def _header_text(table: np.ndarray, fmt: str) -> bytes:
    names = {"<f4": "float", "|u1": "uchar", "u1": "uchar"}
    lines = ["ply", f"format {fmt} 1.0", "comment written by skyrecon", f"element vertex {len(table)}"]
    for name in _names(table.dtype):
        lines.append(f"property {names[table.dtype[name].str]} {name}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def _ascii_body(table: np.ndarray) -> bytes:
    """One line per vertex; floats with 9 significant digits (exact for float32)."""
    if len(table) == 0:
        return b""
    names = _names(table.dtype)
    fmt = " ".join("%d" if table.dtype[n].kind == "u" else "%.9g" for n in names)
    columns = np.stack([table[n].astype(np.float64) for n in names], axis=1)
    return ("\n".join(fmt % tuple(row) for row in columns.tolist()) + "\n").encode("ascii")


def encode_ply(cloud: PointCloud, binary: bool = True) -> bytes:
    """The bytes of a PLY file holding ``cloud`` (see :func:`write_ply`)."""
    if not np.isfinite(cloud.points).all():
        raise InputError("the point cloud has NaN or infinite coordinates; drop them before writing")
    table = _vertex_table(cloud)
    if binary:
        return _header_text(table, "binary_little_endian") + table.tobytes()
    return _header_text(table, "ascii") + _ascii_body(table)


def write_ply(path: str | Path, cloud: PointCloud, binary: bool = True) -> None:
    """Write a point cloud as PLY, atomically.

    Binary little-endian by default (``binary=False`` for ascii): ``x y z`` float32,
    ``red green blue`` uchar when the cloud has colours, ``nx ny nz`` float32 when it
    has normals. Points are written in the cloud's own frame and units (metres).
    Reading the file back with :func:`read_ply` gives exactly the same arrays.
    """
    path = Path(path)
    try:
        data = encode_ply(cloud, binary)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    write_bytes_atomic(path, data)
