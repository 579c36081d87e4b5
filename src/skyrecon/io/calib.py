"""Camera and stereo calibration files: ``K.txt``, Middlebury 2014 ``calib.txt``, KITTI.

- ``K.txt``: three lines of three numbers, the 3x3 calibration matrix (pixels). It holds no
  image size, so the caller gives it.
- Middlebury 2014 ``calib.txt``: ``key=value`` lines; ``cam0``/``cam1`` are the two 3x3
  matrices in Matlab syntax ``[f 0 cx; 0 f cy; 0 0 1]``; ``baseline`` is in MILLIMETRES;
  ``doffs = cx1 - cx0``, pixels; ``width``, ``height``, ``ndisp`` and optional ``isint``,
  ``vmin``, ``vmax``, ``dyavg``, ``dymax``.
- KITTI: ``key: numbers`` lines. The odometry/object files have ``P0:`` .. ``P3:``
  (rectified 3x4 projections ``K [I | t]`` of points in the rectified cam0 frame) and
  optionally ``Tr:`` (odometry: cam0_from_velodyne, 3x4) or ``R0_rect``/``Tr_velo_to_cam``
  (object). The raw ``calib_cam_to_cam.txt`` has ``P_rect_0N``, ``S_rect_0N`` (rectified
  image size), ``K_0N``, ``D_0N``, ``R_0N``, ``T_0N``, ``R_rect_0N``, ``S_0N`` and a text
  ``calib_time`` line. The stereo pair is camera 2 (left) and camera 3 (right).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.text import parse_numbers


def _read_text(path: Path, what: str) -> str:
    if not path.is_file():
        raise InputError(f"{what} file not found; check the path", path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise InputError(f"{what} file is not text", path) from None
    if not text.strip():
        raise InputError(f"{what} file is empty", path)
    return text


def _intrinsics(K: np.ndarray, width: int, height: int, path: Path) -> Intrinsics:
    try:
        return Intrinsics.from_K(K, width, height)
    except InputError as exc:
        raise InputError(exc.reason, path) from None


def _fmt(x: float) -> str:
    """Shortest text that reads back as the same float64."""
    return repr(float(x))


# ----- K.txt ---------------------------------------------------------------------
def read_K_txt(path: str | Path, width: int, height: int) -> Intrinsics:
    """Read a 3x3 calibration matrix from ``K.txt`` (3 lines of 3 numbers, pixels).

    Args:
        path: the file (e.g. Strecha's ``images/K.txt``).
        width, height: the size of the images it describes, pixels.
    Returns:
        Intrinsics without distortion.
    """
    path = Path(path)
    text = _read_text(path, "K.txt")
    rows = [(i, line.split()) for i, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if len(rows) != 3:
        raise InputError(f"K.txt must have 3 lines of 3 numbers, found {len(rows)} non-empty lines", path)
    K = np.stack([parse_numbers(words, path, lineno, count=3) for lineno, words in rows])
    return _intrinsics(K, width, height, path)


def write_K_txt(path: str | Path, intrinsics: Intrinsics) -> None:
    """Write the intrinsics' 3x3 K as ``K.txt`` (3 lines of 3 numbers), atomically; exact round trip."""
    K = intrinsics.K
    write_text_atomic(path, "".join(" ".join(_fmt(v) for v in row) + "\n" for row in K))


# ----- Middlebury 2014 -------------------------------------------------------------
@dataclass(frozen=True)
class MiddleburyCalib:
    """A Middlebury 2014 stereo calibration.

    Attributes:
        rig: rectified rig, baseline in metres, ``doffs_px = cx1 - cx0``.
        K0, K1: (3, 3) calibration matrices of the left (cam0) and right (cam1) images.
        width, height: image size, pixels.
        ndisp: a conservative bound on the disparity range, pixels (None if absent).
        isint: 1 when the GT disparities are integers (None if absent).
        vmin, vmax: tight bounds on the valid disparities, pixels (None if absent).
        dyavg, dymax: average and maximum absolute vertical disparity, pixels (None if absent).
    """

    rig: StereoRig
    K0: np.ndarray
    K1: np.ndarray
    width: int
    height: int
    ndisp: int | None = None
    isint: int | None = None
    vmin: float | None = None
    vmax: float | None = None
    dyavg: float | None = None
    dymax: float | None = None

    @property
    def baseline_mm(self) -> float:
        return self.rig.baseline_m * 1000.0

    @property
    def doffs_px(self) -> float:
        return self.rig.doffs_px


def _matlab_matrix(value: str, path: Path, lineno: int) -> np.ndarray:
    """``[a b c; d e f; g h i]`` -> (3, 3)."""
    m = re.fullmatch(r"\[(.*)\]", value.strip())
    rows = m.group(1).split(";") if m else []
    if len(rows) != 3 or any(len(r.split()) != 3 for r in rows):
        raise InputError(f"line {lineno}: expected a 3x3 matrix '[a b c; d e f; g h i]', got {value!r}", path)
    return np.stack([parse_numbers(r.split(), path, lineno) for r in rows])


def _middlebury_entries(text: str, path: Path) -> dict[str, tuple[str, int]]:
    entries: dict[str, tuple[str, int]] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise InputError(f"line {lineno}: expected 'key=value', got {line.strip()!r}", path)
        entries[key.strip()] = (value.strip(), lineno)
    return entries


_MiddleburyEntries = dict[str, tuple[str, int]]


def _scalar(entries: _MiddleburyEntries, key: str, path: Path) -> float:
    """The single number of a required ``key=value`` line."""
    if key not in entries:
        raise InputError(f"missing '{key}=' line in the Middlebury calibration", path)
    value, lineno = entries[key]
    words = value.split()
    if len(words) != 1:
        raise InputError(f"line {lineno}: '{key}' needs one number, got {value!r}", path)
    return float(parse_numbers(words, path, lineno)[0])


def _integer(entries: _MiddleburyEntries, key: str, path: Path) -> int:
    """The single integer of a required ``key=value`` line."""
    v = _scalar(entries, key, path)
    if v != int(v):
        raise InputError(f"line {entries[key][1]}: '{key}' must be an integer, got {v}", path)
    return int(v)


def _optional_scalar(entries: _MiddleburyEntries, key: str, path: Path) -> float | None:
    return _scalar(entries, key, path) if key in entries else None


def _optional_integer(entries: _MiddleburyEntries, key: str, path: Path) -> int | None:
    return _integer(entries, key, path) if key in entries else None


def read_middlebury_calib(path: str | Path) -> MiddleburyCalib:
    """Read a Middlebury 2014 ``calib.txt``.

    The baseline in the file is in millimetres; the returned rig's is in metres.
    ``doffs`` must agree with ``cx1 - cx0`` and the two cameras must share f and cy
    (the pairs are rectified).
    """
    path = Path(path)
    entries = _middlebury_entries(_read_text(path, "Middlebury calibration"), path)
    for key in ("cam0", "cam1"):
        if key not in entries:
            raise InputError(f"missing '{key}=' line in the Middlebury calibration", path)
    K0, K1 = (_matlab_matrix(entries[k][0], path, entries[k][1]) for k in ("cam0", "cam1"))
    width, height = _integer(entries, "width", path), _integer(entries, "height", path)
    baseline_mm, doffs = _scalar(entries, "baseline", path), _scalar(entries, "doffs", path)
    left, right = _intrinsics(K0, width, height, path), _intrinsics(K1, width, height, path)
    if abs(left.fx - right.fx) > 1e-6 or abs(left.fy - right.fy) > 1e-6 or abs(left.cy - right.cy) > 1e-6:
        raise InputError("cam0 and cam1 must share f and cy in a rectified Middlebury pair", path)
    if abs(doffs - (right.cx - left.cx)) > 0.01:
        raise InputError(f"doffs={doffs} disagrees with cx1 - cx0 = {right.cx - left.cx:.6g}", path)
    if not baseline_mm > 0:
        raise InputError(f"the baseline must be positive (millimetres), got {baseline_mm}", path)
    rig = StereoRig.rectified(left, baseline_mm / 1000.0, right.cx - left.cx)
    return MiddleburyCalib(
        rig,
        K0,
        K1,
        width,
        height,
        ndisp=_optional_integer(entries, "ndisp", path),
        isint=_optional_integer(entries, "isint", path),
        vmin=_optional_scalar(entries, "vmin", path),
        vmax=_optional_scalar(entries, "vmax", path),
        dyavg=_optional_scalar(entries, "dyavg", path),
        dymax=_optional_scalar(entries, "dymax", path),
    )


# ----- KITTI ---------------------------------------------------------------------------
@dataclass(frozen=True)
class KittiCalib:
    """A KITTI calibration.

    Attributes:
        projections: rectified 3x4 projection matrices keyed ``"P0"`` .. ``"P3"`` (from
            ``P0:`` .. ``P3:`` lines, or from ``P_rect_00`` .. ``P_rect_03``); each maps
            points in the rectified cam0 frame (metres) to pixels.
        rig: the rectified stereo rig of cameras 2 (left) and 3 (right).
        width, height: the rectified image size, pixels.
        entries: every numeric line of the file by its key, as a flat float64 array.
        cam0_from_velo: the odometry ``Tr:`` (or object ``Tr_velo_to_cam:``) transform,
            velodyne -> rectified cam0, metres; None when absent.
    """

    projections: dict[str, np.ndarray]
    rig: StereoRig
    width: int
    height: int
    entries: dict[str, np.ndarray]
    cam0_from_velo: Rigid3 | None = None


def _kitti_entries(text: str, path: Path) -> dict[str, tuple[np.ndarray, int]]:
    """``key: numbers`` lines; lines whose values are not numbers (``calib_time``) are skipped."""
    entries: dict[str, tuple[np.ndarray, int]] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        if not sep or not key.strip() or " " in key.strip():
            raise InputError(f"line {lineno}: expected 'KEY: numbers', got {line.strip()!r}", path)
        words = value.split()
        if key.strip() == "calib_time":
            continue
        entries[key.strip()] = (parse_numbers(words, path, lineno), lineno)
    return entries


def _projection(entries: dict, key: str, path: Path) -> np.ndarray:
    values, lineno = entries[key]
    if values.size != 12:
        raise InputError(f"line {lineno}: '{key}' needs 12 numbers (a 3x4 matrix), found {values.size}", path)
    return values.reshape(3, 4)


def _image_size(entries: dict, width: int | None, height: int | None, path: Path) -> tuple[int, int]:
    if "S_rect_02" in entries:
        values, lineno = entries["S_rect_02"]
        if values.size != 2 or np.any(values != np.round(values)) or np.any(values <= 0):
            raise InputError(f"line {lineno}: 'S_rect_02' needs 2 positive integers (width height)", path)
        w, h = int(values[0]), int(values[1])
        if (width is not None and width != w) or (height is not None and height != h):
            raise InputError(
                f"the calibration is for {w}x{h} images (S_rect_02) but the images are "
                f"{width}x{height}; use the calibration of these images",
                path,
            )
        return w, h
    if width is None or height is None:
        raise InputError("the calibration has no image size: pass width and height", path)
    return int(width), int(height)


def rectified_rig_from_projections(
    P_left: np.ndarray, P_right: np.ndarray, width: int, height: int
) -> StereoRig:
    """A rectified rig from two rectified 3x4 projections ``K [I | t]`` (KITTI P2/P3).

    The baseline is the x offset between the optical centres, ``(K_r^-1 P_r - K_l^-1 P_l)[0]``,
    metres. Real KITTI projections also hold tiny y/z offsets (about 3 mm and 0.02 mm for
    2011_09_26) that the rectified images ignore; they are dropped here so that the rig
    is exactly row-aligned (``StereoRig.from_projections`` keeps them and is then not
    ``is_rectified``). ``doffs_px = cx_right - cx_left``.
    """
    P_left = np.asarray(P_left, dtype=np.float64).reshape(3, 4)
    P_right = np.asarray(P_right, dtype=np.float64).reshape(3, 4)
    left = Intrinsics.from_K(P_left[:, :3], width, height)
    right = Intrinsics.from_K(P_right[:, :3], width, height)
    if abs(left.fx - right.fx) > 1e-6 or abs(left.fy - right.fy) > 1e-6 or abs(left.cy - right.cy) > 1e-6:
        raise InputError("the two projections are not a rectified pair: fx, fy and cy must be equal")
    offset = np.linalg.solve(right.K, P_right[:, 3]) - np.linalg.solve(left.K, P_left[:, 3])
    if offset[0] >= 0:
        raise InputError(
            "the right camera is not to the right of the left one (P_right[0,3] must be smaller)"
        )
    if np.hypot(offset[1], offset[2]) > 0.05 * abs(offset[0]):
        raise InputError(f"the cameras are offset off the x axis by {offset[1:]} m: not a rectified pair")
    return StereoRig.rectified(left, float(-offset[0]), right.cx - left.cx)


def read_kitti_calib(path: str | Path, width: int | None = None, height: int | None = None) -> KittiCalib:
    """Read a KITTI calibration: odometry/object ``P0:``..``P3:`` files or raw ``calib_cam_to_cam.txt``.

    Args:
        path: the calibration file.
        width, height: image size, pixels. Taken from ``S_rect_02`` when the file has it
            (they must then agree); required otherwise.
    Returns:
        KittiCalib whose ``rig`` is cameras 2/3 as a rectified rig (see
        :func:`rectified_rig_from_projections`).
    """
    path = Path(path)
    entries = _kitti_entries(_read_text(path, "KITTI calibration"), path)
    keys = {f"P{i}": k for i in range(4) for k in (f"P{i}", f"P_rect_0{i}") if k in entries}
    if "P2" not in keys or "P3" not in keys:
        raise InputError("no 'P2:'/'P3:' (or 'P_rect_02:'/'P_rect_03:') lines: not a KITTI calibration", path)
    projections = {name: _projection(entries, key, path) for name, key in keys.items()}
    w, h = _image_size(entries, width, height, path)
    try:
        rig = rectified_rig_from_projections(projections["P2"], projections["P3"], w, h)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    return KittiCalib(
        projections, rig, w, h, {k: v for k, (v, _) in entries.items()}, _velo_pose(entries, path)
    )


def _velo_pose(entries: dict, path: Path) -> Rigid3 | None:
    key = "Tr" if "Tr" in entries else "Tr_velo_to_cam" if "Tr_velo_to_cam" in entries else None
    if key is None:
        return None
    values, lineno = entries[key]
    if values.size != 12:
        raise InputError(f"line {lineno}: '{key}' needs 12 numbers (a 3x4 matrix), found {values.size}", path)
    try:
        return Rigid3.from_matrix(values.reshape(3, 4), "cam0", "velo")
    except InputError as exc:
        raise InputError(f"line {lineno}: '{key}': {exc.reason}", path) from None


def kitti_projections(rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """(P_left, P_right), each (3, 4), of a rectified rig with the left camera as reference.

    ``P_left = K_l [I | 0]`` and ``P_right = [K_r | (-fx * B, 0, 0)]`` (B = baseline, metres).
    """
    if not rig.is_rectified:
        raise InputError("KITTI calibration files describe rectified rigs; rectify this rig first")
    P_left = np.hstack([rig.left.K, np.zeros((3, 1))])
    P_right = np.hstack([rig.right.K, np.array([[-rig.right.fx * rig.baseline_m], [0.0], [0.0]])])
    return P_left, P_right


def format_kitti_calib(rig: StereoRig) -> str:
    """Text of a KITTI odometry ``calib.txt`` for a rectified rig (see :func:`write_kitti_calib`)."""
    P_left, P_right = kitti_projections(rig)
    lines = [
        f"{name}: " + " ".join(_fmt(v) for v in P.reshape(-1))
        for name, P in (("P0", P_left), ("P1", P_right), ("P2", P_left), ("P3", P_right))
    ]
    return "\n".join(lines) + "\n"


def write_kitti_calib(path: str | Path, rig: StereoRig) -> None:
    """Write a rectified rig as a KITTI odometry ``calib.txt`` (``P0:`` .. ``P3:`` lines), atomically.

    ``P2`` is the left camera, ``K [I | 0]``, and ``P3`` the right one,
    ``[K_r | (-fx * B, 0, 0)]``; the reference frame is the left camera. There is no
    grey pair, so ``P0`` repeats ``P2`` and ``P1`` repeats ``P3``. The file holds no
    image size. Numbers are written with full float64 precision.
    """
    path = Path(path)
    try:
        text = format_kitti_calib(rig)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    write_text_atomic(path, text)


# ----- any stereo calibration ------------------------------------------------------------
@dataclass(frozen=True)
class StereoCalibration:
    """A stereo calibration of any supported format.

    Attributes:
        rig: the two cameras and ``right_from_left`` (metres); rectified for Middlebury and
            KITTI files, possibly unrectified (with distortion) for OpenCV files.
        max_disparity: the file's disparity bound (Middlebury ``ndisp``), pixels, or None.
        kind: ``"middlebury"``, ``"kitti"`` or ``"opencv"``.
    """

    rig: StereoRig
    max_disparity: int | None
    kind: str


_OPENCV_KEYS = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_left", "KL"),
    "D1": ("D1", "distCoeffs1", "dist_coeffs_left", "DL"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_right", "KR"),
    "D2": ("D2", "distCoeffs2", "dist_coeffs_right", "DR"),
    "R": ("R",),
    "T": ("T",),
}


def read_opencv_stereo_calib(path: str | Path, width: int, height: int) -> StereoRig:
    """Read an OpenCV ``FileStorage`` stereo calibration (YAML, XML or JSON).

    The file holds what ``cv2.stereoCalibrate`` returns: ``K1``/``M1``, ``D1``, ``K2``/``M2``,
    ``D2``, ``R`` and ``T`` with ``x_right = R x_left + T`` (T in metres: calibrate with the
    pattern's square size in metres). Optional ``width``/``height`` or ``imageSize`` must agree
    with the images. Distortion may have at most 5 coefficients (k1 k2 p1 p2 k3).

    Returns:
        StereoRig, generally not rectified (rectify with ``skyrecon.stereo.rectify_rig``).
    """
    path = Path(path)
    _read_text(path, "OpenCV stereo calibration")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise InputError(
            f"cannot parse the OpenCV calibration ({' '.join(str(exc).split())[:120]})", path
        ) from None
    try:
        values: dict[str, np.ndarray] = {}
        for name, keys in _OPENCV_KEYS.items():
            for key in keys:
                node = fs.getNode(key)
                if not node.empty():
                    m = node.mat()
                    values[name] = np.asarray(m if m is not None else node.real(), dtype=np.float64)
                    break
        size_node = fs.getNode("imageSize")
        file_size = None
        if not size_node.empty():
            m = size_node.mat()
            file_size = tuple(int(v) for v in (np.asarray(m).ravel() if m is not None else []))
        elif not fs.getNode("width").empty() and not fs.getNode("height").empty():
            file_size = (int(fs.getNode("width").real()), int(fs.getNode("height").real()))
    finally:
        fs.release()
    missing = [n for n in ("K1", "K2", "R", "T") if n not in values]
    if missing:
        raise InputError(
            f"missing {', '.join(missing)} in the OpenCV stereo calibration (need K1 D1 K2 D2 R T)", path
        )
    if file_size and tuple(file_size[:2]) != (width, height):
        raise InputError(
            f"the calibration is for {file_size[0]}x{file_size[1]} images but the images are {width}x{height}",
            path,
        )
    for name, arr in values.items():
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name} contains NaN or infinite values", path)
    try:
        left = Intrinsics.from_K(
            values["K1"].reshape(3, 3), width, height, values.get("D1", np.zeros(5)).ravel()
        )
        right = Intrinsics.from_K(
            values["K2"].reshape(3, 3), width, height, values.get("D2", np.zeros(5)).ravel()
        )
        right_from_left = Rigid3(values["R"].reshape(3, 3), values["T"].ravel())
    except (InputError, ValueError) as exc:
        raise InputError(getattr(exc, "reason", str(exc)), path) from None
    return StereoRig(left, right, right_from_left)


def read_stereo_calib(path: str | Path, width: int, height: int) -> StereoCalibration:
    """Read a stereo calibration, recognising the format from the file's content.

    Accepts a Middlebury 2014 ``calib.txt`` (``cam0=`` lines), a KITTI file (``P2:``/``P3:`` or
    ``P_rect_02``/``P_rect_03``), or an OpenCV FileStorage file (``.yml``/``.yaml``/``.xml``/
    ``.json`` with K1 D1 K2 D2 R T).

    Args:
        path: the calibration file.
        width, height: size of the images it must describe, pixels.
    Raises:
        InputError: unknown format, or a calibration for another image size.
    """
    path = Path(path)
    text = _read_text(path, "stereo calibration")
    if path.suffix.lower() in (".yml", ".yaml", ".xml", ".json") or text.lstrip().startswith(
        ("%YAML", "<?xml")
    ):
        return StereoCalibration(read_opencv_stereo_calib(path, width, height), None, "opencv")
    if re.search(r"^\s*cam0\s*=", text, re.M):
        calib = read_middlebury_calib(path)
        if (calib.width, calib.height) != (width, height):
            raise InputError(
                f"the calibration is for {calib.width}x{calib.height} images but the images are {width}x{height}; "
                "use the calib.txt of the same resolution",
                path,
            )
        return StereoCalibration(calib.rig, calib.ndisp, "middlebury")
    if re.search(r"^\s*(P2|P_rect_02)\s*:", text, re.M):
        kitti = read_kitti_calib(path, width, height)
        return StereoCalibration(kitti.rig, None, "kitti")
    raise InputError(
        "unknown stereo calibration format: expected a Middlebury calib.txt (cam0=...), a KITTI file "
        "(P2:/P3: lines) or an OpenCV YAML/XML/JSON file with K1 D1 K2 D2 R T",
        path,
    )
