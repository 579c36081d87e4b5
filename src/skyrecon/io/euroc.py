"""Stereo sequences in the EuRoC / ASL layout, rectified on the fly.

::

    root/                       (or root/mav0/)
      cam0/ data.csv            ``#timestamp [ns],filename`` per frame
            data/<ns>.png       left images (grey or colour)
            sensor.yaml         ``T_BS`` (4x4 ``body_from_sensor``, row-major ``data: [...]``),
                                ``resolution: [w, h]``, ``intrinsics: [fu, fv, cu, cv]``,
                                ``distortion_model: radial-tangential``,
                                ``distortion_coefficients: [k1, k2, p1, p2]``
      cam1/ ...                 right camera, the same files
      state_groundtruth_estimate0/data.csv   optional ground truth (``world_from_body``, see
                                :mod:`skyrecon.io.trajectory`)

The two cameras are rectified with ``cv2.stereoRectify`` (zero disparity at infinity, no black
border: ``alpha=0``); :meth:`EurocSequence.frame` returns rectified images of the same size as the
raw ones and :attr:`EurocSequence.rig` is the rectified rig. The rectified left camera is rotated
from the raw cam0 by ``R1``: ``body_from_left = body_from_cam0 @ cam0_from_left``.

Frames are the timestamps present in both ``cam0/data.csv`` and ``cam1/data.csv``, in time order.
PyYAML is not a dependency: ``sensor.yaml`` is read by :func:`parse_sensor_yaml`, a small reader
for the subset EuRoC uses (nested maps by indentation, scalars, ``[...]`` lists over several lines,
``#`` comments, a ``%YAML`` directive).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3, orthonormalize
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.images import read_image
from skyrecon.io.trajectory import TimedTrajectory, read_euroc_groundtruth

__all__ = [
    "EurocCamera",
    "EurocSequence",
    "is_euroc_dir",
    "euroc_root",
    "parse_sensor_yaml",
    "read_euroc_camera",
    "read_euroc",
]

GROUNDTRUTH = "state_groundtruth_estimate0/data.csv"


# ----- sensor.yaml ----------------------------------------------------------------------------
def _scalar(text: str) -> Any:
    t = text.strip()
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "'\"":
        return t[1:-1]
    for kind in (int, float):
        try:
            return kind(t)
        except ValueError:
            pass
    return t


def _strip_comment(line: str) -> str:
    out, quote = [], None
    for ch in line:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#":
            break
        out.append(ch)
    return "".join(out).rstrip()


def parse_sensor_yaml(text: str, path: Path | None = None) -> dict[str, Any]:
    """The mapping of an EuRoC ``sensor.yaml`` (a YAML subset: see the module docstring).

    Raises:
        InputError: naming the line that is not ``key: value``.
    """
    root: dict[str, Any] = {}
    stack: list[tuple[int, dict[str, Any]]] = [(-1, root)]
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        raw = _strip_comment(lines[i])
        lineno = i + 1
        i += 1
        if not raw.strip() or raw.lstrip().startswith("%") or raw.strip() == "---":
            continue
        indent = len(raw) - len(raw.lstrip(" "))
        m = re.match(r"^\s*([A-Za-z_][\w\-. ]*?)\s*:(?:\s+(.*)|\s*)$", raw)
        if m is None:
            raise InputError(f"line {lineno}: expected 'key: value', got {raw.strip()!r}", path)
        key, value = m.group(1), (m.group(2) or "").strip()
        while stack and indent <= stack[-1][0]:
            stack.pop()
        parent = stack[-1][1]
        if value == "":
            child: dict[str, Any] = {}
            parent[key] = child
            stack.append((indent, child))
            continue
        if value.startswith("["):
            while "]" not in value and i < len(lines):
                value += " " + _strip_comment(lines[i]).strip()
                i += 1
            if "]" not in value:
                raise InputError(f"line {lineno}: the list of {key!r} is not closed with ']'", path)
            inner = value[1 : value.index("]")]
            parent[key] = [_scalar(w) for w in inner.split(",") if w.strip()]
            continue
        parent[key] = _scalar(value)
    return root


# ----- cameras ------------------------------------------------------------------------------
@dataclass(frozen=True)
class EurocCamera:
    """One camera of the rig as ``sensor.yaml`` and ``data.csv`` describe it.

    Attributes:
        intrinsics: the raw (distorted) camera: pinhole + radial-tangential ``k1 k2 p1 p2``.
        body_from_cam: ``T_BS``, metres.
        timestamps_ns: (N,) int64 frame times.
        paths: the image file of each frame.
    """

    intrinsics: Intrinsics
    body_from_cam: Rigid3
    timestamps_ns: np.ndarray
    paths: list[Path] = field(default_factory=list)


def _number_list(cfg: dict[str, Any], key: str, n: int | tuple[int, ...], path: Path) -> np.ndarray:
    if key not in cfg:
        raise InputError(f"missing '{key}'", path)
    v = cfg[key]
    if isinstance(v, dict):
        v = v.get("data")
    sizes = (n,) if isinstance(n, int) else n
    if not isinstance(v, list) or len(v) not in sizes or not all(isinstance(x, (int, float)) for x in v):
        raise InputError(f"'{key}' must be a list of {' or '.join(map(str, sizes))} numbers, got {v!r}", path)
    return np.asarray(v, dtype=np.float64)


def read_euroc_camera(cam_dir: str | Path) -> EurocCamera:
    """Read ``cam_dir/sensor.yaml`` and ``cam_dir/data.csv``.

    Raises:
        InputError: naming the file at fault.
    """
    cam_dir = Path(cam_dir)
    yaml_path = cam_dir / "sensor.yaml"
    if not yaml_path.is_file():
        raise InputError("missing sensor.yaml (the camera's calibration)", yaml_path)
    try:
        cfg = parse_sensor_yaml(yaml_path.read_text(encoding="utf-8"), yaml_path)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read ({exc})", yaml_path) from None
    model = str(cfg.get("distortion_model", "radial-tangential"))
    if model not in ("radial-tangential", "radtan", "none"):
        raise InputError(
            f"distortion_model {model!r} is not supported (only radial-tangential); rectify the images first",
            yaml_path,
        )
    camera_model = str(cfg.get("camera_model", "pinhole"))
    if camera_model != "pinhole":
        raise InputError(f"camera_model {camera_model!r} is not supported (only pinhole)", yaml_path)
    fu, fv, cu, cv = _number_list(cfg, "intrinsics", 4, yaml_path)
    w, h = _number_list(cfg, "resolution", 2, yaml_path).astype(int)
    dist = (
        _number_list(cfg, "distortion_coefficients", (4, 5), yaml_path)
        if "distortion_coefficients" in cfg
        else np.zeros(4)
    )
    T = _number_list(cfg, "T_BS", 16, yaml_path).reshape(4, 4)
    try:
        intr = Intrinsics(fu, fv, cu, cv, int(w), int(h), dist)
        R = T[:3, :3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise InputError("T_BS's rotation is not orthonormal")
        body_from_cam = Rigid3(orthonormalize(R), T[:3, 3], "body", "cam")
    except InputError as exc:
        raise InputError(exc.reason, yaml_path) from None
    ts, paths = _read_data_csv(cam_dir)
    return EurocCamera(intr, body_from_cam, ts, paths)


def _read_data_csv(cam_dir: Path) -> tuple[np.ndarray, list[Path]]:
    csv = cam_dir / "data.csv"
    if not csv.is_file():
        raise InputError("missing data.csv (frame timestamps and file names)", csv)
    ts, paths = [], []
    for lineno, line in enumerate(csv.read_text(encoding="utf-8").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        words = [w.strip() for w in line.split(",")]
        if len(words) < 2:
            raise InputError(f"line {lineno}: expected 'timestamp [ns],filename'", csv)
        try:
            ts.append(int(words[0]))
        except ValueError:
            raise InputError(
                f"line {lineno}: the timestamp {words[0]!r} is not an integer of nanoseconds", csv
            ) from None
        paths.append(cam_dir / "data" / words[1])
    if not ts:
        raise InputError("no frames listed", csv)
    t = np.array(ts, dtype=np.int64)
    if np.any(np.diff(t) <= 0):
        raise InputError("timestamps must increase down the file", csv)
    return t, paths


# ----- the sequence --------------------------------------------------------------------------
def euroc_root(path: str | Path) -> Path | None:
    """The directory holding ``cam0/`` and ``cam1/`` (``path`` or ``path/mav0``), or None."""
    p = Path(path)
    for cand in (p, p / "mav0"):
        if (cand / "cam0" / "data.csv").is_file() and (cand / "cam1").is_dir():
            return cand
    return None


def is_euroc_dir(path: str | Path) -> bool:
    """True when ``path`` (or ``path/mav0``) has ``cam0/data.csv`` and ``cam1/``."""
    return euroc_root(path) is not None


@dataclass
class EurocSequence:
    """A EuRoC stereo sequence, rectified.

    Attributes:
        root: the directory holding ``cam0/`` and ``cam1/``.
        rig: the rectified rig, metres.
        timestamps_s: (N,) frame times, seconds (the nanosecond stamps / 1e9).
        left_paths, right_paths: raw image files of each frame.
        body_from_left: the rectified left camera in the body (IMU) frame.
        groundtruth: the body ground truth when the sequence has one, else None.
        world_from_left: ground-truth ``world_from_left`` per frame (None where no ground truth
            covers the frame's time; None as a whole without ground truth).
        cam0, cam1: the raw cameras.
    """

    root: Path
    rig: StereoRig
    timestamps_s: np.ndarray
    left_paths: list[Path]
    right_paths: list[Path]
    body_from_left: Rigid3
    cam0: EurocCamera
    cam1: EurocCamera
    maps: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    groundtruth: TimedTrajectory | None = None
    world_from_left: list[Rigid3 | None] | None = None

    def __len__(self) -> int:
        return len(self.left_paths)

    def raw_frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) raw images of frame ``i``, (H, W, 3) uint8 RGB."""
        out = []
        for path, cam in ((self.left_paths[i], self.cam0), (self.right_paths[i], self.cam1)):
            image = read_image(path, "rgb")
            if image.shape[:2] != cam.intrinsics.shape:
                raise InputError(
                    f"image is {image.shape[1]}x{image.shape[0]} but sensor.yaml says "
                    f"{cam.intrinsics.width}x{cam.intrinsics.height}",
                    path,
                )
            out.append(image)
        return out[0], out[1]

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) rectified images of frame ``i``, (H, W, 3) uint8 RGB, the rig's size."""
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame sequence")
        raw = self.raw_frame(i)
        return tuple(  # type: ignore[return-value]
            cv2.remap(im, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            for im, (mx, my) in zip(raw, self.maps)
        )


def _rectify(cam0: EurocCamera, cam1: EurocCamera):
    k0, k1 = cam0.intrinsics, cam1.intrinsics
    if k0.shape != k1.shape:
        raise InputError(
            f"the two cameras have different resolutions ({k0.width}x{k0.height} and {k1.width}x{k1.height})"
        )
    size = (k0.width, k0.height)
    cam1_from_cam0 = cam1.body_from_cam.inverse() @ cam0.body_from_cam
    if np.linalg.norm(cam1_from_cam0.t) < 1e-6:
        raise InputError("cam0 and cam1 are at the same place (T_BS): not a stereo pair")
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        k0.K,
        k0.dist[:5],
        k1.K,
        k1.dist[:5],
        size,
        cam1_from_cam0.R,
        cam1_from_cam0.t.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    if abs(P2[1, 3]) > 1e-6 * abs(P2[0, 3]):
        raise InputError("cam1 is above or below cam0, not beside it: vertical stereo is not supported")
    maps = tuple(
        cv2.initUndistortRectifyMap(k.K, k.dist[:5], R, P[:, :3], size, cv2.CV_32FC1)
        for k, R, P in ((k0, R1, P1), (k1, R2, P2))
    )
    rig = StereoRig.from_projections(P1, P2, size[0], size[1])
    if rig.right_from_left.t[0] > 0:
        raise InputError("cam1 is to the LEFT of cam0; swap cam0 and cam1")
    cam0_from_left = Rigid3(R1.T, np.zeros(3), "cam", "left")
    return rig, cam0.body_from_cam @ cam0_from_left, maps


def read_euroc(path: str | Path, groundtruth: str | Path | None = None) -> EurocSequence:
    """Open a EuRoC/ASL stereo sequence (layout in the module docstring) and set up rectification.

    Args:
        path: the sequence directory (with ``mav0/``) or ``mav0`` itself.
        groundtruth: a EuRoC ground-truth csv; default ``state_groundtruth_estimate0/data.csv`` when
            present.
    Raises:
        InputError: naming the file at fault.
    """
    root = euroc_root(path)
    if root is None:
        raise InputError("not a EuRoC sequence: expected mav0/cam0/data.csv and mav0/cam1/", path)
    cam0 = read_euroc_camera(root / "cam0")
    cam1 = read_euroc_camera(root / "cam1")
    common, i0, i1 = np.intersect1d(cam0.timestamps_ns, cam1.timestamps_ns, return_indices=True)
    if len(common) == 0:
        raise InputError(
            "cam0 and cam1 share no timestamp: the stereo frames cannot be paired", root / "cam1" / "data.csv"
        )
    rig, body_from_left, maps = _rectify(cam0, cam1)
    seq = EurocSequence(
        root=root,
        rig=rig,
        timestamps_s=common.astype(np.float64) * 1e-9,
        left_paths=[cam0.paths[k] for k in i0],
        right_paths=[cam1.paths[k] for k in i1],
        body_from_left=body_from_left.with_frames("body", "left"),
        cam0=cam0,
        cam1=cam1,
        maps=maps,
    )
    gt_path = Path(groundtruth) if groundtruth is not None else root / GROUNDTRUTH
    if groundtruth is not None or gt_path.is_file():
        gt = read_euroc_groundtruth(gt_path)
        seq.groundtruth = gt
        idx, poses = gt.transformed(seq.body_from_left, "left").at_times(seq.timestamps_s, max_gap_s=0.05)
        wfl: list[Rigid3 | None] = [None] * len(seq)
        for k, p in zip(idx, poses):
            wfl[int(k)] = p
        seq.world_from_left = wfl
    return seq
