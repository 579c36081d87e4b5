"""Readers for multi-view camera sets with known intrinsics and poses.

Every reader returns ``list[PosedView]`` in skyrecon conventions: intrinsics in pixels with the
centre of the top-left pixel at (0, 0), OpenCV camera axes (x right, y down, z forward), and the
pose as ``cam_from_world`` (``p_cam = R @ p_world + t``, metres). Each reader's docstring says
how its file stores the pose and how it is converted.

Supported layouts (see :func:`read_cameras` for auto-detection):

- Middlebury multi-view ``*_par.txt`` (:func:`read_middlebury_par`): K, R, t world-to-camera.
- Strecha ``*.camera`` files (:func:`read_strecha_cameras`): R camera-to-world, t = camera centre.
- HALCON ``intrinsics_cameraNN.txt`` + ``extrinsics_cameraNN.txt`` (:func:`read_halcon_cameras`):
  [R | T] camera-to-world.
- COLMAP text models (``cameras.txt`` + ``images.txt``), through :mod:`skyrecon.io.colmap`.

Rotations read from text are checked (orthogonality error at most ``ROTATION_TOL``, det = +1) and
then projected onto the nearest exact rotation, since files print them to a few digits.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from PIL import Image as PILImage

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Reconstruction
from skyrecon.core.rigid import Rigid3, orthonormalize
from skyrecon.core.view import PosedView
from skyrecon.errors import InputError
from skyrecon.io.colmap import read_colmap_text
from skyrecon.io.text import parse_numbers

__all__ = [
    "ROTATION_TOL",
    "read_middlebury_par",
    "read_strecha_cameras",
    "read_halcon_cameras",
    "read_cameras",
    "views_from_reconstruction",
    "image_size_from_header",
]

#: Largest accepted ``max |R R^T - I|`` for a rotation read from a text file (6 printed decimals
#: give about 1e-6). Larger errors mean the file does not hold a rotation (or is mis-parsed).
ROTATION_TOL = 1e-4

_DEFAULT_MIDDLEBURY_SIZE = (640, 480)


# ----------------------------------------------------------------------------------------------
# small parsing helpers
# ----------------------------------------------------------------------------------------------
def _where(line_no: int | None) -> str:
    return f"line {line_no}: " if line_no is not None else ""


def _rotation(R: np.ndarray, path: Path, line_no: int | None, what: str) -> np.ndarray:
    """Check that ``R`` (3, 3) is a rotation within ``ROTATION_TOL``; return the nearest exact one."""
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > ROTATION_TOL or det <= 0:
        raise InputError(
            f"{_where(line_no)}{what} is not a rotation matrix (orthogonality error {err:.2e}, "
            f"det {det:.4f}); check the file format and the column order",
            path,
        )
    return orthonormalize(R)


def _read_text(path: Path, what: str) -> str:
    if not path.exists():
        raise InputError(f"{what} not found; check the path", path)
    if path.is_dir():
        raise InputError(f"is a directory, expected a {what}", path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise InputError(f"not a text file; expected a {what}", path) from None
    except OSError as exc:
        raise InputError(f"cannot read {what} ({exc})", path) from None
    if not text.strip():
        raise InputError(f"{what} is empty", path)
    return text


def _intrinsics(K: np.ndarray, width: int, height: int, path: Path, line_no: int | None) -> Intrinsics:
    try:
        return Intrinsics.from_K(K, width, height)
    except InputError as exc:
        raise InputError(f"{_where(line_no)}bad calibration matrix: {exc.reason}", path) from None


def image_size_from_header(path: str | Path) -> tuple[int, int] | None:
    """``(width, height)`` of an image file, read from its header without decoding the pixels.

    Returns None when the file is missing or not a readable image.
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with PILImage.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except Exception:  # noqa: BLE001 - any decoder failure means "size unknown"
        return None


def _image_path(image_dir: Path | None, name: str) -> Path | None:
    if image_dir is None:
        return None
    p = image_dir / name
    return p if p.is_file() else None


# ----------------------------------------------------------------------------------------------
# Middlebury multi-view
# ----------------------------------------------------------------------------------------------
def read_middlebury_par(
    path: str | Path,
    image_dir: str | Path | None = None,
    width: int | None = None,
    height: int | None = None,
) -> list[PosedView]:
    """Read a Middlebury multi-view ``*_par.txt`` camera file.

    File layout: the first line is the number of images; then one line per image::

        imgname.png k11 k12 k13 k21 k22 k23 k31 k32 k33 r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3

    Pose convention in the file: **world-to-camera**, ``P = K [R | t]``, i.e. ``x ~ K (R X + t)``;
    the camera centre is ``-R^T t``. This is already ``cam_from_world``, so (R, t) are used as
    they are. Units: metres; the image origin is the top-left pixel, x right, y down (K is used
    unchanged, with pixel centres at integer coordinates).

    Args:
        path: the ``*_par.txt`` file.
        image_dir: directory holding the images; defaults to the file's directory.
        width, height: image size in pixels, for every view. When not given, each view's size is
            read from its image file's header (without decoding the pixels); views whose image is
            missing take the size of the first image found; if no image is found, 640x480 (the
            Middlebury multi-view size) is assumed and a ``UserWarning`` says so.
    Returns:
        One ``PosedView`` per line, in file order; ``name`` is the image file name and
        ``image_path`` is set when that file exists in ``image_dir``.
    Raises:
        InputError: missing or empty file, wrong count, wrong number of values on a line,
            non-numbers, NaN, a matrix that is not a rotation, a bad K.
    """
    path = Path(path)
    text = _read_text(path, "Middlebury camera file (*_par.txt)")
    image_dir = path.parent if image_dir is None else Path(image_dir)
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln and not ln.startswith("#")]
    first_no, first = lines[0]
    try:
        count = int(first.split()[0])
        if len(first.split()) != 1 or count < 0:
            raise ValueError
    except ValueError:
        raise InputError(
            f"line {first_no}: expected the number of images on the first line, got {first[:60]!r}", path
        ) from None
    rows = lines[1:]
    if len(rows) != count:
        raise InputError(
            f"the first line announces {count} images but {len(rows)} camera lines follow; "
            "the file is truncated or the count is wrong",
            path,
        )
    if count == 0:
        raise InputError("the file lists no cameras", path)

    if (width is None) != (height is None):
        raise InputError("give both width and height, or neither", path)
    sizes: dict[str, tuple[int, int] | None] = {}
    if width is None or height is None:
        sizes = {ln.split()[0]: image_size_from_header(image_dir / ln.split()[0]) for _, ln in rows}
        found = [sz for sz in sizes.values() if sz is not None]
        if found:
            default_size = found[0]
        else:
            default_size = _DEFAULT_MIDDLEBURY_SIZE
            warnings.warn(
                f"{path}: no image found in {image_dir} to read the image size from; assuming "
                f"{default_size[0]}x{default_size[1]} (pass width/height to override)",
                UserWarning,
                stacklevel=2,
            )
    else:
        default_size = (int(width), int(height))

    views: list[PosedView] = []
    for line_no, ln in rows:
        tok = ln.split()
        if len(tok) != 22:
            raise InputError(
                f"line {line_no}: expected an image name and 21 numbers (K 3x3, R 3x3, t 3), "
                f"got {len(tok) - 1} numbers",
                path,
            )
        name = tok[0]
        vals = parse_numbers(tok[1:], path, line_no, f"camera of {name}")
        K = vals[0:9].reshape(3, 3)
        R = _rotation(vals[9:18].reshape(3, 3), path, line_no, f"R of {name}")
        t = vals[18:21]
        w, h = sizes.get(name) or default_size
        views.append(
            PosedView(
                name,
                _intrinsics(K, w, h, path, line_no),
                Rigid3(R, t, "cam", "world"),
                _image_path(image_dir, name),
            )
        )
    _check_unique_names(views, path)
    return views


# ----------------------------------------------------------------------------------------------
# Strecha
# ----------------------------------------------------------------------------------------------
def _strecha_files(directory_or_files: str | Path | Iterable[str | Path]) -> tuple[list[Path], Path]:
    """The ``*.camera`` files to read and the directory they live in."""
    if isinstance(directory_or_files, (str, Path)):
        p = Path(directory_or_files)
        if not p.exists():
            raise InputError("Strecha camera directory or file not found; check the path", p)
        if p.is_file():
            return [p], p.parent
        if not any(p.glob("*.camera")) and (p / "gt_dense_cameras").is_dir():
            p = p / "gt_dense_cameras"
        files = sorted(p.glob("*.camera"))
        if not files:
            raise InputError("no *.camera files in this directory (Strecha layout expected)", p)
        return files, p
    files = sorted(Path(f) for f in directory_or_files)
    if not files:
        raise InputError("no Strecha *.camera files given")
    return files, files[0].parent


def _read_one_strecha(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    text = _read_text(path, "Strecha camera file (*.camera)")
    lines = [(i + 1, ln.split()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, tok) for i, tok in lines if tok]
    if len(lines) != 9:
        raise InputError(
            f"expected 9 non-empty lines (K: 3, distortion: 1, R: 3, camera centre: 1, 'width height': 1), "
            f"got {len(lines)}; the file is truncated or not a Strecha camera",
            path,
        )
    rows = []
    for k, (line_no, tok) in enumerate(lines):
        want = 2 if k == 8 else 3
        if len(tok) != want:
            raise InputError(f"line {line_no}: expected {want} numbers, got {len(tok)}", path)
        rows.append(parse_numbers(tok, path, line_no, "camera values"))
    K = np.stack(rows[0:3])
    dist = rows[3]
    if np.any(dist != 0):
        raise InputError(
            f"line {lines[3][0]}: non-zero distortion {dist.tolist()} is not supported for Strecha cameras; "
            "undistort the images first and set the line to 0 0 0",
            path,
        )
    R_world_from_cam = _rotation(np.stack(rows[4:7]), path, lines[4][0], "R (camera-to-world)")
    center = rows[7]
    wh = rows[8]
    if np.any(wh != np.round(wh)) or np.any(wh <= 0):
        raise InputError(
            f"line {lines[8][0]}: image size must be two positive integers, got {wh.tolist()}", path
        )
    return K, R_world_from_cam, center, int(wh[0]), int(wh[1])


def read_strecha_cameras(
    directory_or_files: str | Path | Iterable[str | Path], image_dir: str | Path | None = None
) -> list[PosedView]:
    """Read Strecha-style ``*.camera`` files (EPFL dense MVS benchmark, e.g. fountain-P11).

    Each file has 9 lines::

        K             3 lines of 3 numbers (pixels)
        distortion    1 line, must be 0 0 0 (the benchmark images are undistorted)
        R             3 lines: the camera-to-world rotation (columns = camera axes in the world)
        t             1 line: the camera centre in the world, metres
        width height  1 line

    Pose convention in the file: **camera-to-world** rotation and the **camera centre**, so that
    ``x ~ K R^T (X - t)``. Converted to ``cam_from_world = (R^T, -R^T t)``.

    Args:
        directory_or_files: a directory of ``*.camera`` files, a directory containing
            ``gt_dense_cameras/``, one ``*.camera`` file, or an iterable of files.
        image_dir: where the images are. Default: a sibling ``images/`` directory of the camera
            directory if it exists, else the camera directory itself.
    Returns:
        Views sorted by name; the name is the camera file name without ``.camera``
        (``0000.jpg.camera`` -> ``0000.jpg``); ``image_path`` is set when the image exists.
    Raises:
        InputError: no files, a truncated file, a wrong number of values, NaN, a non-rotation,
            non-zero distortion.
    """
    files, cam_dir = _strecha_files(directory_or_files)
    if image_dir is None:
        image_dir = cam_dir.parent / "images" if (cam_dir.parent / "images").is_dir() else cam_dir
    image_dir = Path(image_dir)
    views = []
    for f in files:
        K, R_wc, center, w, h = _read_one_strecha(f)
        name = f.name[: -len(".camera")] if f.name.endswith(".camera") else f.name
        R_cw = R_wc.T
        cam_from_world = Rigid3(R_cw, -R_cw @ center, "cam", "world")
        views.append(
            PosedView(name, _intrinsics(K, w, h, f, None), cam_from_world, _image_path(image_dir, name))
        )
    views.sort(key=lambda v: v.name)
    _check_unique_names(views, cam_dir)
    return views


# ----------------------------------------------------------------------------------------------
# HALCON
# ----------------------------------------------------------------------------------------------
_HALCON_LINE = re.compile(r"^\s*([A-Za-z][A-Za-z0-9]*)\s*:\s*([A-Za-z][A-Za-z0-9]*)\s*:\s*([^;]*);")
_HALCON_REQUIRED = ("Focus", "Sx", "Sy", "Cx", "Cy", "ImageWidth", "ImageHeight")
_HALCON_DISTORTION = ("Poly1", "Poly2", "Poly3", "Poly4", "Poly5", "Kappa", "K1", "K2", "K3", "P1", "P2")
_HALCON_KNOWN = _HALCON_REQUIRED + _HALCON_DISTORTION
_HALCON_NUM = re.compile(r"(?:intrinsics|extrinsics)_camera(\d+)\.txt$")


def _read_halcon_intrinsics(path: Path) -> Intrinsics:
    text = _read_text(path, "HALCON intrinsics file")
    values: dict[str, float] = {}
    for line_no, ln in enumerate(text.splitlines(), start=1):
        m = _HALCON_LINE.match(ln)
        if not m or m.group(1) not in _HALCON_KNOWN:
            continue
        key, raw = m.group(1), m.group(3).strip()
        values[key] = float(parse_numbers([raw] if raw else ["<empty>"], path, line_no, key)[0])
    missing = [k for k in _HALCON_REQUIRED if k not in values]
    if missing:
        raise InputError(
            f"missing HALCON camera parameters {', '.join(missing)} (expected 'Name:short: value;' lines "
            "for Focus, Sx, Sy, Cx, Cy, ImageWidth, ImageHeight); the file is truncated or not a HALCON "
            "camera parameter file",
            path,
        )
    nonzero = {k: v for k, v in values.items() if k in _HALCON_DISTORTION and v != 0}
    if nonzero:
        kind = "polynomial" if any(k.startswith("Poly") for k in nonzero) else "lens"
        raise InputError(
            f"HALCON {kind} distortion is not supported ({', '.join(f'{k}={v:g}' for k, v in nonzero.items())}); "
            "undistort the images first (e.g. HALCON change_radial_distortion_image) and use the "
            "distortion-free camera parameters",
            path,
        )
    if values["Focus"] <= 0:
        raise InputError(
            f"Focus = {values['Focus']:g}: telecentric or invalid cameras are not supported (need Focus > 0)",
            path,
        )
    if values["Sx"] <= 0 or values["Sy"] <= 0:
        raise InputError(f"pixel pitch Sx, Sy must be positive, got {values['Sx']:g}, {values['Sy']:g}", path)
    w, h = values["ImageWidth"], values["ImageHeight"]
    if w != round(w) or h != round(h) or w <= 0 or h <= 0:
        raise InputError(f"ImageWidth/ImageHeight must be positive integers, got {w:g}, {h:g}", path)
    fx = values["Focus"] / values["Sx"]
    fy = values["Focus"] / values["Sy"]
    return Intrinsics(fx, fy, values["Cx"], values["Cy"], int(w), int(h))


def _read_halcon_extrinsics(path: Path) -> Rigid3:
    text = _read_text(path, "HALCON extrinsics file")
    tok = text.split()
    if len(tok) != 12:
        raise InputError(
            f"expected 12 numbers (row-major 3x4 [R | T], camera-to-world), got {len(tok)}", path
        )
    M = parse_numbers(tok, path, None, "[R | T]").reshape(3, 4)
    R_wc = _rotation(M[:, :3], path, None, "R (camera-to-world)")
    T = M[:, 3]
    return Rigid3(R_wc.T, -R_wc.T @ T, "cam", "world")


def read_halcon_cameras(directory: str | Path, image_dir: str | Path | None = None) -> list[PosedView]:
    """Read a HALCON camera set: ``intrinsics_cameraNN.txt`` + ``extrinsics_cameraNN.txt`` per camera.

    Intrinsics: the HALCON ``ParGroup: Camera: Parameter`` text; the ``Name:short: value;`` lines
    give ``Focus`` (metres), ``Poly1..5`` (polynomial distortion; must be 0), ``Sx``, ``Sy``
    (pixel pitch, metres), ``Cx``, ``Cy`` (principal point, pixels), ``ImageWidth``,
    ``ImageHeight``. ``K = [[Focus/Sx, 0, Cx], [0, Focus/Sy, Cy], [0, 0, 1]]``. HALCON's pixel
    coordinates put the centre of the top-left pixel at (0, 0), as skyrecon does.

    Extrinsics: one line of 12 numbers, the row-major 3x4 ``[R | T]``. Pose convention in the
    file: **camera-to-world**, ``x_world = R x_cam + T`` (T is the camera centre), metres.
    Converted to ``cam_from_world = (R^T, -R^T T)``.

    Args:
        directory: the folder with the camera files (and usually the images).
        image_dir: where the images are; defaults to ``directory``.
    Returns:
        Views sorted by camera number; name ``image_cameraNN.png``, ``image_path`` set when that
        image exists in ``image_dir``.
    Raises:
        InputError: no camera files, an intrinsics file without its extrinsics (or the reverse),
            missing parameters, non-zero distortion, wrong number of values, NaN, a non-rotation.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError("HALCON camera directory not found; check the path", directory)
    intr = {
        m.group(1): p for p in directory.glob("intrinsics_camera*.txt") if (m := _HALCON_NUM.search(p.name))
    }
    extr = {
        m.group(1): p for p in directory.glob("extrinsics_camera*.txt") if (m := _HALCON_NUM.search(p.name))
    }
    if not intr and not extr:
        raise InputError("no HALCON intrinsics_cameraNN.txt / extrinsics_cameraNN.txt files here", directory)
    for nn in sorted(set(intr) ^ set(extr)):
        have, lack = ("intrinsics", "extrinsics") if nn in intr else ("extrinsics", "intrinsics")
        raise InputError(f"camera {nn} has {have}_camera{nn}.txt but no {lack}_camera{nn}.txt", directory)
    image_dir = directory if image_dir is None else Path(image_dir)
    views = []
    for nn in sorted(intr, key=lambda s: (int(s), s)):
        name = f"image_camera{nn}.png"
        views.append(
            PosedView(
                name,
                _read_halcon_intrinsics(intr[nn]),
                _read_halcon_extrinsics(extr[nn]),
                _image_path(image_dir, name),
            )
        )
    return views


# ----------------------------------------------------------------------------------------------
# COLMAP and auto-detection
# ----------------------------------------------------------------------------------------------
def views_from_reconstruction(
    reconstruction: Reconstruction, image_dir: str | Path | None = None
) -> list[PosedView]:
    """One ``PosedView`` per registered image of a reconstruction, sorted by image id.

    ``image_path`` is ``image_dir / name`` when that file exists.
    """
    image_dir = None if image_dir is None else Path(image_dir)
    return [
        PosedView(
            im.name, reconstruction.cameras[im.camera_id], im.cam_from_world, _image_path(image_dir, im.name)
        )
        for _, im in sorted(reconstruction.images.items())
    ]


def _colmap_image_dir(model_dir: Path, reconstruction: Reconstruction) -> Path | None:
    """Guess where a COLMAP model's images are: beside it, or in ``images/`` one or two levels up."""
    names = [im.name for im in reconstruction.images.values()]
    if not names:
        return None
    for cand in (
        model_dir,
        model_dir / "images",
        model_dir.parent / "images",
        model_dir.parent.parent / "images",
    ):
        if (cand / names[0]).is_file():
            return cand
    return None


_ACCEPTED = (
    "a Middlebury *_par.txt file; a directory of Strecha *.camera files (or one containing "
    "gt_dense_cameras/); a directory of HALCON intrinsics_cameraNN.txt + extrinsics_cameraNN.txt "
    "files; or a COLMAP text model directory (cameras.txt + images.txt)"
)


def read_cameras(spec: str | Path, image_dir: str | Path | None = None) -> list[PosedView]:
    """Read a multi-view camera set, detecting its format.

    Accepted ``spec``:

    - a Middlebury ``*_par.txt`` file (or a directory with exactly one) -> :func:`read_middlebury_par`;
    - a COLMAP text model directory with ``cameras.txt`` and ``images.txt`` (or one of those
      files) -> :func:`skyrecon.io.colmap.read_colmap_text`, then one view per image;
    - a directory of Strecha ``*.camera`` files, a directory containing ``gt_dense_cameras/``,
      or one ``*.camera`` file -> :func:`read_strecha_cameras`;
    - a directory with HALCON ``intrinsics_cameraNN.txt`` / ``extrinsics_cameraNN.txt`` files
      -> :func:`read_halcon_cameras`.

    Args:
        spec: the file or directory.
        image_dir: where the images are (overrides each reader's default).
    Returns:
        ``list[PosedView]`` with ``cam_from_world`` poses.
    Raises:
        InputError: ``spec`` does not exist or matches none of the layouts (the message lists them),
            or the files are malformed.
    """
    p = Path(spec)
    if not p.exists():
        raise InputError(f"camera specification not found; expected {_ACCEPTED}", p)
    if p.is_file():
        if p.name.endswith("_par.txt"):
            return read_middlebury_par(p, image_dir)
        if p.name.endswith(".camera"):
            return read_strecha_cameras(p, image_dir)
        if p.name in ("cameras.txt", "images.txt", "points3D.txt"):
            p = p.parent
        elif _HALCON_NUM.search(p.name):
            return read_halcon_cameras(p.parent, image_dir)
        else:
            raise InputError(f"unrecognised camera file; expected {_ACCEPTED}", p)
    # p is a directory
    if (p / "cameras.txt").is_file() and (p / "images.txt").is_file():
        rec = read_colmap_text(p)
        return views_from_reconstruction(
            rec, image_dir if image_dir is not None else _colmap_image_dir(p, rec)
        )
    if any(p.glob("*.camera")) or (p / "gt_dense_cameras").is_dir():
        return read_strecha_cameras(p, image_dir)
    if any(p.glob("intrinsics_camera*.txt")) or any(p.glob("extrinsics_camera*.txt")):
        return read_halcon_cameras(p, image_dir)
    pars = sorted(p.glob("*_par.txt"))
    if len(pars) == 1:
        return read_middlebury_par(pars[0], image_dir)
    if len(pars) > 1:
        raise InputError(
            f"several Middlebury camera files here ({', '.join(x.name for x in pars)}); name one of them", p
        )
    raise InputError(f"no camera files recognised in this directory; expected {_ACCEPTED}", p)


def _check_unique_names(views: list[PosedView], path: Path) -> None:
    seen: set[str] = set()
    for v in views:
        if v.name in seen:
            raise InputError(f"image {v.name!r} is listed twice", path)
        seen.add(v.name)
