"""COLMAP text models (``cameras.txt``, ``images.txt``, ``points3D.txt``) and nerfstudio export.

COLMAP conventions and how they are converted here:

- **Poses**: ``images.txt`` stores ``QW QX QY QZ TX TY TZ`` = the rotation (Hamilton unit
  quaternion) and translation of **cam_from_world** (world-to-camera, ``p_cam = R p_world + t``),
  camera axes as OpenCV (x right, y down, z forward). skyrecon uses the same, unchanged.
- **Pixels**: COLMAP puts the centre of the top-left pixel at (0.5, 0.5); skyrecon at (0, 0).
  The reader subtracts 0.5 from ``cx``, ``cy`` and from every keypoint; the writer adds it back.
- **Camera models**: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV
  (when ``k4 = k5 = k6 = 0``) map exactly onto :class:`~skyrecon.core.Intrinsics` (OpenCV
  ``k1 k2 p1 p2 k3``). Fisheye, FOV, thin-prism and rational FULL_OPENCV models cannot be
  represented and raise :class:`~skyrecon.errors.InputError`.

Floats are written with Python's shortest round-trip representation, so writing then reading
gives back the same numbers (poses to ~1e-15 after the quaternion round trip).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.reconstruction import Image, Point3D, Reconstruction
from skyrecon.core.rigid import Rigid3, matrix_to_quaternion, quaternion_to_matrix
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.text import parse_numbers

__all__ = [
    "COLMAP_MODELS",
    "read_colmap_text",
    "write_colmap_text",
    "read_colmap_cameras_text",
    "intrinsics_to_colmap",
    "write_nerfstudio_transforms",
]

#: COLMAP camera models skyrecon can read, with their number of parameters.
COLMAP_MODELS: dict[str, int] = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "FULL_OPENCV": 12,
}

#: Models COLMAP knows that have no exact OpenCV k1 k2 p1 p2 k3 equivalent.
_UNSUPPORTED_MODELS = {
    "OPENCV_FISHEYE",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "FOV",
    "SIMPLE_FISHEYE",
    "FISHEYE",
}

_PIXEL_OFFSET = 0.5  # COLMAP pixel coordinate = skyrecon pixel coordinate + 0.5


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _fmt(x: float) -> str:
    """Shortest text that reads back as the same float64."""
    return repr(float(x))


def _data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, stripped line) for every non-empty, non-comment line."""
    for i, ln in enumerate(_read_lines(path), start=1):
        s = ln.strip()
        if s and not s.startswith("#"):
            yield i, s


def _read_lines(path: Path) -> list[str]:
    if not path.exists():
        raise InputError("COLMAP model file not found; a text model needs cameras.txt and images.txt", path)
    if path.is_dir():
        raise InputError("is a directory, expected a COLMAP text file", path)
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError:
        raise InputError(
            "not a text file; this reader needs COLMAP's text format (convert a binary model with "
            "'colmap model_converter --output_type TXT')",
            path,
        ) from None
    except OSError as exc:
        raise InputError(f"cannot read ({exc})", path) from None


def _nums(tokens: list[str], path: Path, line_no: int, what: str, kind: type = float) -> list:
    """:func:`~skyrecon.io.text.parse_numbers` as a list of Python ints or floats."""
    return parse_numbers(tokens, path, line_no, what, kind=kind).tolist()


# ----------------------------------------------------------------------------------------------
# cameras
# ----------------------------------------------------------------------------------------------
def _intrinsics_from_colmap(
    model: str, width: int, height: int, params: list[float], path: Path, line_no: int
) -> Intrinsics:
    o = _PIXEL_OFFSET
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = params
        fx = fy = f
        dist = [0.0] * 5
    elif model == "PINHOLE":
        fx, fy, cx, cy = params
        dist = [0.0] * 5
    elif model == "SIMPLE_RADIAL":
        f, cx, cy, k = params
        fx = fy = f
        dist = [k, 0.0, 0.0, 0.0, 0.0]
    elif model == "RADIAL":
        f, cx, cy, k1, k2 = params
        fx = fy = f
        dist = [k1, k2, 0.0, 0.0, 0.0]
    elif model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = params
        dist = [k1, k2, p1, p2, 0.0]
    elif model == "FULL_OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 = params
        if k4 != 0 or k5 != 0 or k6 != 0:
            raise InputError(
                f"line {line_no}: FULL_OPENCV camera with rational coefficients k4..k6 = {k4:g}, {k5:g}, {k6:g} "
                "cannot be represented (skyrecon supports k1 k2 p1 p2 k3); undistort the images with "
                "'colmap image_undistorter' and use the undistorted model",
                path,
            )
        dist = [k1, k2, p1, p2, k3]
    else:  # pragma: no cover - callers check the model first
        raise AssertionError(model)
    try:
        return Intrinsics(fx, fy, cx - o, cy - o, width, height, np.asarray(dist, dtype=np.float64))
    except InputError as exc:
        raise InputError(f"line {line_no}: invalid camera: {exc.reason}", path) from None


def read_colmap_cameras_text(path: str | Path) -> dict[int, Intrinsics]:
    """Read a COLMAP ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line.

    Returns:
        camera id -> Intrinsics (principal point moved to skyrecon's pixel-centre convention).
    Raises:
        InputError: unknown or unsupported model, wrong parameter count, NaN, duplicate id.
    """
    path = Path(path)
    cameras: dict[int, Intrinsics] = {}
    for line_no, ln in _data_lines(path):
        tok = ln.split()
        if len(tok) < 4:
            raise InputError(
                f"line {line_no}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got {ln[:80]!r}", path
            )
        cam_id, w, h = _nums([tok[0], tok[2], tok[3]], path, line_no, "camera id / size", int)
        model = tok[1].upper()
        if model in _UNSUPPORTED_MODELS:
            raise InputError(
                f"line {line_no}: COLMAP camera model {model} cannot be represented by skyrecon's "
                "pinhole + OpenCV (k1 k2 p1 p2 k3) intrinsics; undistort the images with "
                "'colmap image_undistorter' and use the undistorted model",
                path,
            )
        if model not in COLMAP_MODELS:
            raise InputError(
                f"line {line_no}: unknown COLMAP camera model {tok[1]!r}; supported: {', '.join(COLMAP_MODELS)}",
                path,
            )
        params = _nums(tok[4:], path, line_no, f"{model} parameters")
        if len(params) != COLMAP_MODELS[model]:
            raise InputError(
                f"line {line_no}: camera model {model} takes {COLMAP_MODELS[model]} parameters, got {len(params)}",
                path,
            )
        if cam_id in cameras:
            raise InputError(f"line {line_no}: camera id {cam_id} appears twice", path)
        cameras[cam_id] = _intrinsics_from_colmap(model, w, h, params, path, line_no)
    return cameras


def intrinsics_to_colmap(cam: Intrinsics) -> tuple[str, list[float]]:
    """COLMAP model name and parameters (COLMAP pixel convention) for a skyrecon camera.

    PINHOLE when there is no distortion, OPENCV when ``k3 == 0``, FULL_OPENCV otherwise
    (with ``k4 = k5 = k6 = 0``). Raises ``InputError`` for a camera with skew, which no COLMAP
    model represents.
    """
    if cam.skew != 0:
        raise InputError(
            f"camera has skew {cam.skew:g}; COLMAP camera models have no skew parameter, so it cannot be written"
        )
    o = _PIXEL_OFFSET
    k1, k2, p1, p2, k3 = (float(x) for x in cam.dist)
    base = [cam.fx, cam.fy, cam.cx + o, cam.cy + o]
    if not cam.has_distortion:
        return "PINHOLE", base
    if k3 == 0:
        return "OPENCV", base + [k1, k2, p1, p2]
    return "FULL_OPENCV", base + [k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]


# ----------------------------------------------------------------------------------------------
# images and points
# ----------------------------------------------------------------------------------------------
def _read_images(path: Path) -> dict[int, Image]:
    lines = _read_lines(path)
    images: dict[int, Image] = {}
    i = 0
    n = len(lines)
    while i < n:
        s = lines[i].strip()
        line_no = i + 1
        i += 1
        if not s or s.startswith("#"):
            continue
        tok = s.split(maxsplit=9)
        if len(tok) < 10:
            raise InputError(
                f"line {line_no}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {s[:80]!r}",
                path,
            )
        image_id = _nums([tok[0]], path, line_no, "IMAGE_ID", int)[0]
        q = np.array(_nums(tok[1:5], path, line_no, "quaternion"))
        t = np.array(_nums(tok[5:8], path, line_no, "translation"))
        camera_id = _nums([tok[8]], path, line_no, "CAMERA_ID", int)[0]
        name = tok[9].strip()
        if not np.linalg.norm(q) > 1e-12:
            raise InputError(f"line {line_no}: the quaternion of image {name} is zero", path)
        # The POINTS2D line follows directly (it may be empty). A file ending right after the
        # last image line is read as that image having no keypoints.
        pts_line = lines[i] if i < n else ""
        pts_no = i + 1
        i += 1
        ptok = pts_line.split()
        if len(ptok) % 3:
            raise InputError(
                f"line {pts_no}: POINTS2D of image {name} must be triples 'X Y POINT3D_ID', got {len(ptok)} values "
                "(the line is truncated, or the POINTS2D line is missing)",
                path,
            )
        triples = np.asarray(ptok, dtype=str).reshape(-1, 3)
        xy = parse_numbers(triples[:, :2].ravel().tolist(), path, pts_no, f"keypoints of {name}").reshape(
            -1, 2
        )
        xy -= _PIXEL_OFFSET
        ids = parse_numbers(triples[:, 2].tolist(), path, pts_no, f"POINT3D_IDs of {name}", kind=int)
        if image_id in images:
            raise InputError(f"line {line_no}: image id {image_id} appears twice", path)
        pose = Rigid3(quaternion_to_matrix(q), t, "cam", "world")
        images[image_id] = Image(image_id, name, camera_id, pose, xy, np.where(ids < 0, -1, ids))
    return images


def _read_points(path: Path) -> dict[int, Point3D]:
    points: dict[int, Point3D] = {}
    for line_no, s in _data_lines(path):
        tok = s.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise InputError(
                f"line {line_no}: expected 'POINT3D_ID X Y Z R G B ERROR' followed by (IMAGE_ID, POINT2D_IDX) "
                f"pairs, got {len(tok)} values",
                path,
            )
        pid = _nums([tok[0]], path, line_no, "POINT3D_ID", int)[0]
        xyz = _nums(tok[1:4], path, line_no, "X Y Z")
        rgb = _nums(tok[4:7], path, line_no, "R G B", int)
        if not all(0 <= c <= 255 for c in rgb):
            raise InputError(f"line {line_no}: colour {rgb} is outside 0..255", path)
        err = _nums([tok[7]], path, line_no, "ERROR")[0]
        track = parse_numbers(tok[8:], path, line_no, "track", kind=int).reshape(-1, 2)
        if pid in points:
            raise InputError(f"line {line_no}: point id {pid} appears twice", path)
        points[pid] = Point3D(pid, np.array(xyz), np.array(rgb, dtype=np.uint8), err, track)
    return points


def read_colmap_text(directory: str | Path) -> Reconstruction:
    """Read a COLMAP text model directory.

    Files: ``cameras.txt`` and ``images.txt`` (required) and ``points3D.txt`` (optional; no
    points when absent). Poses in ``images.txt`` are ``cam_from_world`` (world-to-camera)
    quaternion + translation and are kept as they are; keypoints and principal points are
    shifted by -0.5 px into skyrecon's pixel convention.

    Args:
        directory: the model directory (e.g. ``sparse/0`` after ``colmap model_converter``).
    Returns:
        The reconstruction; ``Image.keypoints`` (M, 2) pixels, ``point3d_ids`` (M,) with -1 for
        untriangulated keypoints; ``Point3D.xyz`` world frame, metres (or the model's gauge).
    Raises:
        InputError: missing files, malformed lines (naming file and line), unsupported camera
            models, ids that do not refer to each other.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError("COLMAP model directory not found; check the path", directory)
    for req in ("cameras.txt", "images.txt"):
        if not (directory / req).is_file():
            bin_hint = (
                " (found a binary model: convert it with 'colmap model_converter --output_type TXT')"
                if (directory / req.replace(".txt", ".bin")).is_file()
                else ""
            )
            raise InputError(
                f"no {req} here; a COLMAP text model needs cameras.txt and images.txt{bin_hint}", directory
            )
    cameras = read_colmap_cameras_text(directory / "cameras.txt")
    images = _read_images(directory / "images.txt")
    points_path = directory / "points3D.txt"
    points = _read_points(points_path) if points_path.exists() else {}
    rec = Reconstruction(cameras, images, points)
    try:
        rec.validate()
    except InputError as exc:
        raise InputError(f"inconsistent model: {exc.reason}", directory) from None
    return rec


# ----------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------
def _check_name(name: str) -> None:
    if not name or name != name.strip() or "\n" in name or "\r" in name:
        raise InputError(
            f"image name {name!r} cannot be written to images.txt (empty, or leading/trailing whitespace or newlines)"
        )


def write_colmap_text(directory: str | Path, reconstruction: Reconstruction) -> None:
    """Write a reconstruction as a COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``).

    Each file is written atomically; ``directory`` is created if missing. Poses are written as
    ``cam_from_world`` quaternion (w >= 0) + translation; keypoints and principal points are
    shifted by +0.5 px into COLMAP's pixel convention. Camera models: PINHOLE (no distortion),
    OPENCV (``k3 == 0``), FULL_OPENCV otherwise. Ids are written in increasing order.

    Raises:
        InputError: the reconstruction is inconsistent (see ``Reconstruction.validate``), a
            camera has skew, or an image name cannot be stored in the text format.
    """
    directory = Path(directory)
    reconstruction.validate()
    cams, imgs, pts = reconstruction.cameras, reconstruction.images, reconstruction.points3d

    out = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
        f"# Number of cameras: {len(cams)}",
    ]
    for cid in sorted(cams):
        cam = cams[cid]
        model, params = intrinsics_to_colmap(cam)
        out.append(" ".join([str(cid), model, str(cam.width), str(cam.height), *map(_fmt, params)]))
    cameras_text = "\n".join(out) + "\n"

    n_obs = sum(int(np.count_nonzero(im.point3d_ids >= 0)) for im in imgs.values())
    out = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(imgs)}, mean observations per image: {n_obs / len(imgs) if imgs else 0:.6f}",
    ]
    for iid in sorted(imgs):
        im = imgs[iid]
        _check_name(im.name)
        q = matrix_to_quaternion(im.cam_from_world.R)
        t = im.cam_from_world.t
        out.append(" ".join([str(iid), *map(_fmt, q), *map(_fmt, t), str(im.camera_id), im.name]))
        kp = im.keypoints + _PIXEL_OFFSET
        out.append(" ".join(f"{_fmt(x)} {_fmt(y)} {int(pid)}" for (x, y), pid in zip(kp, im.point3d_ids)))
    images_text = "\n".join(out) + "\n"

    track_len = sum(len(p.track) for p in pts.values())
    out = [
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
        f"# Number of points: {len(pts)}, mean track length: {track_len / len(pts) if pts else 0:.6f}",
    ]
    for pid in sorted(pts):
        p = pts[pid]
        if not np.all(np.isfinite(p.xyz)):
            raise InputError(f"point {pid} has a NaN or infinite position; remove it before writing")
        out.append(
            " ".join(
                [
                    str(pid),
                    *map(_fmt, p.xyz),
                    *(str(int(c)) for c in p.color),
                    _fmt(p.error),
                    *(str(int(v)) for v in p.track.ravel()),
                ]
            )
        )
    points_text = "\n".join(out) + "\n"

    write_text_atomic(directory / "cameras.txt", cameras_text)
    write_text_atomic(directory / "images.txt", images_text)
    write_text_atomic(directory / "points3D.txt", points_text)


# ----------------------------------------------------------------------------------------------
# nerfstudio
# ----------------------------------------------------------------------------------------------
#: OpenCV camera axes (x right, y down, z forward) -> OpenGL/nerfstudio (x right, y up, z back).
_OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])


def _nerfstudio_intrinsics(cam: Intrinsics) -> dict[str, float | int]:
    if cam.skew != 0:
        raise InputError(f"camera has skew {cam.skew:g}; nerfstudio cameras have no skew parameter")
    k1, k2, p1, p2, k3 = (float(x) for x in cam.dist)
    d: dict[str, float | int] = {
        "fl_x": cam.fx,
        "fl_y": cam.fy,
        "cx": cam.cx + _PIXEL_OFFSET,
        "cy": cam.cy + _PIXEL_OFFSET,
        "w": cam.width,
        "h": cam.height,
        "k1": k1,
        "k2": k2,
        "p1": p1,
        "p2": p2,
    }
    if k3 != 0:
        d["k3"] = k3
    return d


def write_nerfstudio_transforms(
    path: str | Path, reconstruction: Reconstruction, image_prefix: str = "images/"
) -> None:
    """Write a nerfstudio ``transforms.json`` for the registered images of a reconstruction.

    Layout::

        {"camera_model": "OPENCV",
         "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2"[, "k3"]   # when all images share one camera
         "frames": [{"file_path": "images/<name>", "transform_matrix": 4x4, "colmap_im_id": id,
                     [per-frame intrinsics when cameras differ]}, ...]}

    ``transform_matrix`` is **camera-to-world** (``world_from_cam``) in nerfstudio's OpenGL camera
    axes (x right, y up, z backward): ``world_from_cam`` with its y and z columns negated. The
    world frame is the reconstruction's, unchanged (no axis swap, no ``applied_transform``).
    ``cx``, ``cy`` use nerfstudio's (and COLMAP's) convention, with the top-left pixel centre at
    (0.5, 0.5): skyrecon's values + 0.5. Frames are in image-id order.

    Args:
        path: the ``transforms.json`` file to write (atomically).
        reconstruction: cameras and posed images (3D points are not written).
        image_prefix: prefix of ``file_path`` (relative to the json's directory).
    Raises:
        InputError: no images, or a camera with skew.
    """
    reconstruction.validate()
    imgs = reconstruction.images
    if not imgs:
        raise InputError("the reconstruction has no registered images; nothing to export", path)
    used = {im.camera_id for im in imgs.values()}
    intr = {cid: _nerfstudio_intrinsics(reconstruction.cameras[cid]) for cid in used}
    shared = len({json.dumps(v, sort_keys=True) for v in intr.values()}) == 1
    meta: dict = {"camera_model": "OPENCV"}
    if shared:
        meta.update(next(iter(intr.values())))
    frames = []
    for iid in sorted(imgs):
        im = imgs[iid]
        M = im.cam_from_world.inverse().matrix
        M[:3, :3] = M[:3, :3] @ _OPENCV_TO_OPENGL
        frame: dict = {
            "file_path": f"{image_prefix}{im.name}",
            "transform_matrix": M.tolist(),
            "colmap_im_id": int(iid),
        }
        if not shared:
            frame.update(intr[im.camera_id])
        frames.append(frame)
    meta["frames"] = frames
    write_text_atomic(path, json.dumps(meta, indent=2) + "\n")
