"""Depth maps stored beside a stereo sequence: ``SEQUENCE/SUBDIR/<frame>.pfm``.

``skyrecon render sequence`` writes the true depth of the left camera as ``depth_2/NNNNNN.pfm``
(one per frame, named like the left image); ``skyrecon map SEQUENCE --depth depth_2`` reads them.
Depth: (H, W) float32 metres along the left optical axis, NaN invalid (inf in the file).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import InputError
from skyrecon.io.pfm import read_pfm
from skyrecon.io.sequence import StereoSequence


def sequence_depth_paths(seq: StereoSequence, subdir: str) -> list[Path]:
    """``seq.root / subdir / <left image stem>.pfm`` for every frame of ``seq``, in frame order."""
    return [seq.root / subdir / f"{p.stem}.pfm" for p in seq.left_paths]


def read_depth_map(path: str | Path, camera: Intrinsics) -> np.ndarray:
    """(H, W) float32 depth (metres) of one PFM file, checked against the camera's size.

    Raises:
        InputError: missing or corrupt file, or a size other than the camera's (names the file).
    """
    depth = read_pfm(path)
    if depth.shape != camera.shape:
        raise InputError(
            f"depth map is {depth.shape[1]}x{depth.shape[0]}, images are {camera.width}x{camera.height}",
            path,
        )
    return depth


def iter_depth_maps(paths: Sequence[str | Path], camera: Intrinsics) -> Iterator[np.ndarray]:
    """The depth maps of ``paths`` one at a time (read lazily, see :func:`read_depth_map`)."""
    for path in paths:
        yield read_depth_map(path, camera)
