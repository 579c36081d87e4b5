"""Stereo sequences in the KITTI odometry layout.

::

    root/
      image_2/000000.png ...   left images (RGB or grey PNG)
      image_3/000000.png ...   right images, the same file names
      calib.txt                ``P0:`` .. ``P3:`` lines; P2/P3 are the rectified left/right
                               3x4 projections (P3's fourth column is ``-fx * baseline``)
      poses.txt                optional; one line per frame: 12 numbers, the row-major 3x4
                               ``world_from_left_camera`` matrix ``[R | t]``, metres
                               (``p_world = R p_left + t``)

Frames are ordered by file name. The image size is not in ``calib.txt``; it is taken
from the first left image.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image as PILImage
from tqdm import tqdm

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.io.atomic import write_text_atomic
from skyrecon.io.calib import format_kitti_calib, read_kitti_calib
from skyrecon.io.images import read_image, write_image
from skyrecon.io.text import parse_numbers

LEFT_DIR, RIGHT_DIR, CALIB_FILE, POSES_FILE = "image_2", "image_3", "calib.txt", "poses.txt"
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
_FRAME_NAME = re.compile(r"^\d{6}\.png$")


@dataclass
class StereoSequence:
    """A rectified stereo sequence on disk.

    Attributes:
        root: the sequence directory.
        rig: the rectified rig (left = camera 2, right = camera 3), metres.
        left_paths, right_paths: image files of each frame, in frame order.
        world_from_left: per-frame pose of the left camera in the world (frames
            ``("world", "left")``), metres; None when there is no ``poses.txt``.
    """

    root: Path
    rig: StereoRig
    left_paths: list[Path]
    right_paths: list[Path]
    world_from_left: list[Rigid3] | None = None

    def __len__(self) -> int:
        return len(self.left_paths)

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) images of frame ``i``: (H, W, 3) uint8 RGB each, checked against the rig's size."""
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame sequence")
        images = []
        for path, camera in ((self.left_paths[i], self.rig.left), (self.right_paths[i], self.rig.right)):
            image = read_image(path, "rgb")
            if image.shape[:2] != camera.shape:
                raise InputError(
                    f"image is {image.shape[1]}x{image.shape[0]} but the sequence's calibration is for "
                    f"{camera.width}x{camera.height}; all frames must have the same size",
                    path,
                )
            images.append(image)
        return images[0], images[1]


def is_sequence_dir(path: str | Path) -> bool:
    """True when ``path`` looks like a sequence: ``image_2/``, ``image_3/`` and ``calib.txt``."""
    p = Path(path)
    return (p / LEFT_DIR).is_dir() and (p / RIGHT_DIR).is_dir() and (p / CALIB_FILE).is_file()


def _image_files(directory: Path) -> dict[str, Path]:
    if not directory.is_dir():
        raise InputError(
            "missing image directory: a sequence needs image_2/ (left) and image_3/ (right)", directory
        )
    return {p.stem: p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES}


def _frame_paths(root: Path) -> tuple[list[Path], list[Path]]:
    left, right = _image_files(root / LEFT_DIR), _image_files(root / RIGHT_DIR)
    if not left:
        raise InputError("no images (.png/.jpg) in the left image directory", root / LEFT_DIR)
    only_left, only_right = sorted(left.keys() - right.keys()), sorted(right.keys() - left.keys())
    if only_left or only_right:
        names = [f"{n} only in image_2" for n in only_left[:3]] + [
            f"{n} only in image_3" for n in only_right[:3]
        ]
        raise InputError(
            f"left and right frames differ ({', '.join(names)}); every frame needs both images", root
        )
    names = sorted(left)
    return [left[n] for n in names], [right[n] for n in names]


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image, reading only its header."""
    try:
        with PILImage.open(path) as im:
            return im.size
    except (OSError, ValueError, SyntaxError) as exc:
        raise InputError(f"cannot read image ({exc}); the file is corrupt", path) from None


def parse_poses(text: str, path: Path) -> list[Rigid3]:
    """``poses.txt`` text -> ``world_from_left`` per line (12 numbers, row-major 3x4, metres)."""
    poses = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words:
            continue
        if len(words) != 12:
            raise InputError(
                f"line {lineno}: a pose needs 12 numbers (row-major 3x4), found {len(words)}", path
            )
        values = parse_numbers(words, path, lineno, "the pose")
        try:
            poses.append(Rigid3.from_matrix(values.reshape(3, 4), "world", "left"))
        except InputError as exc:
            raise InputError(f"line {lineno}: {exc.reason}", path) from None
    return poses


def read_sequence(root: str | Path) -> StereoSequence:
    """Open a stereo sequence directory (layout in the module docstring).

    Checks that both image directories exist with the same frame names, that ``calib.txt``
    holds a rectified P2/P3 pair, and that ``poses.txt`` (when present) has one valid
    pose per frame. Images are read lazily by :meth:`StereoSequence.frame`.

    Raises:
        InputError: naming the file (and line) at fault.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError("sequence directory not found; check the path", root)
    left_paths, right_paths = _frame_paths(root)
    calib_path = root / CALIB_FILE
    if not calib_path.is_file():
        raise InputError("missing calib.txt with the P2:/P3: projections of the stereo pair", calib_path)
    width, height = _image_size(left_paths[0])
    rig = read_kitti_calib(calib_path, width, height).rig
    poses = None
    poses_path = root / POSES_FILE
    if poses_path.exists():
        try:
            text = poses_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read poses ({exc})", poses_path) from None
        poses = parse_poses(text, poses_path)
        if len(poses) != len(left_paths):
            raise InputError(
                f"{len(poses)} poses for {len(left_paths)} frames; poses.txt needs one line per frame",
                poses_path,
            )
    return StereoSequence(root, rig, left_paths, right_paths, poses)


def format_poses(world_from_left: Sequence[Rigid3]) -> str:
    """``poses.txt`` text: one row-major 3x4 ``world_from_left`` per line, full float64 precision."""
    return "".join(" ".join(repr(float(v)) for v in p.matrix3x4.reshape(-1)) + "\n" for p in world_from_left)


def _check_pose_frames(world_from_left: Sequence[Rigid3]) -> None:
    for i, pose in enumerate(world_from_left):
        if pose.dst not in (None, "world") or pose.src == "world":
            raise InputError(
                f"pose {i} is {pose.name}, but a sequence stores world_from_left poses; invert it"
            )


def _check_frame(i: int, left: np.ndarray, right: np.ndarray, rig: StereoRig) -> None:
    for image, camera, side in ((left, rig.left, "left"), (right, rig.right, "right")):
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim not in (2, 3):
            raise InputError(
                f"frame {i}: the {side} image must be (H, W) or (H, W, 3) uint8, got {image.dtype} {image.shape}"
            )
        if image.shape[:2] != camera.shape:
            raise InputError(
                f"frame {i}: the {side} image is {image.shape[1]}x{image.shape[0]}, "
                f"the rig is {camera.width}x{camera.height}"
            )


def _remove_stale_frames(directory: Path, count: int) -> None:
    """Delete ``NNNNNN.png`` frames numbered ``count`` or more left by an earlier, longer sequence."""
    for p in directory.iterdir():
        if _FRAME_NAME.match(p.name) and int(p.stem) >= count:
            p.unlink()


def write_sequence(
    root: str | Path,
    rig: StereoRig,
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    world_from_left: Sequence[Rigid3] | None = None,
    progress: bool = False,
) -> StereoSequence:
    """Write a stereo sequence in the KITTI odometry layout; every file is written atomically.

    Args:
        root: the sequence directory (created if missing). Frames ``NNNNNN.png`` of an
            earlier, longer sequence in the same place are removed.
        rig: a rectified rig; its image size is the size of every frame.
        frames: (left, right) pairs, each (H, W, 3) uint8 RGB or (H, W) uint8 grey.
        world_from_left: one ``world_from_left`` pose per frame, metres, or None.
        progress: show a progress bar.
    Returns:
        The sequence as :func:`read_sequence` would read it.
    """
    root = Path(root)
    if world_from_left is not None:
        world_from_left = list(world_from_left)
        _check_pose_frames(world_from_left)
        if hasattr(frames, "__len__") and len(frames) != len(world_from_left):  # type: ignore[arg-type]
            raise InputError(f"{len(world_from_left)} poses for {len(frames)} frames")  # type: ignore[arg-type]
    calib_text = format_kitti_calib(rig)
    if progress:
        frames = tqdm(frames, desc="writing frames", unit="frame")
    count = 0
    for i, (left, right) in enumerate(frames):
        _check_frame(i, left, right, rig)
        write_image(root / LEFT_DIR / f"{i:06d}.png", np.asarray(left))
        write_image(root / RIGHT_DIR / f"{i:06d}.png", np.asarray(right))
        count = i + 1
    if count == 0:
        raise InputError("no frames to write")
    if world_from_left is not None and len(world_from_left) != count:
        raise InputError(f"{len(world_from_left)} poses for {count} frames")
    for d in (LEFT_DIR, RIGHT_DIR):
        _remove_stale_frames(root / d, count)
    write_text_atomic(root / CALIB_FILE, calib_text)
    poses_path = root / POSES_FILE
    if world_from_left is not None:
        write_text_atomic(poses_path, format_poses(world_from_left))
    elif poses_path.exists():
        poses_path.unlink()
    return read_sequence(root)
