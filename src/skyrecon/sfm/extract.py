"""Per-image feature extraction, fanned out on the executor and cached in the run's workspace.

Each image's features are stored once as ``<workspace>/features/<stem>-<key>.npz`` where the key
hashes the file's bytes and the feature settings, so a rerun (or a run with more images) reuses
them. The cache holds keypoints in input-image pixels (float64), keypoint sizes (float32),
detector responses (float32), RootSIFT/SIFT descriptors (float16) and the RGB colour under each
keypoint (uint8).
"""

from __future__ import annotations

import hashlib
import re
from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from skyrecon.errors import SkyreconError
from skyrecon.features.detect import FeatureSettings, detect_features
from skyrecon.io.atomic import atomic_write
from skyrecon.io.images import read_image
from skyrecon.threads import limited_threads

__all__ = ["ExtractedImage", "ExtractTask", "extract_one", "load_features", "feature_cache_key"]

_CACHE_VERSION = "sfm-features-3"


@dataclass(frozen=True)
class ExtractTask:
    """One image to extract (picklable work item)."""

    index: int
    path: str
    name: str
    settings: FeatureSettings
    cache_dir: str
    target_features: int = 0


@dataclass
class ExtractedImage:
    """What extraction found out about one image.

    Attributes:
        index, name, path: the image.
        ok: features are available in ``cache_path``.
        reason: why not (unreadable file), else "".
        width, height: image size in pixels (0 when unreadable).
        num_features: keypoints detected.
        file_hash: SHA-1 of the file's bytes (duplicates share it).
        cache_path: the feature file.
        scale: detection resolution / input resolution (<= 1).
        cached: the features came from the cache.
    """

    index: int
    name: str
    path: str
    ok: bool
    reason: str
    width: int
    height: int
    num_features: int
    file_hash: str
    cache_path: str
    scale: float
    cached: bool


def feature_cache_key(file_hash: str, settings: FeatureSettings, target_features: int = 0) -> str:
    """Cache key of an image's features: file content + feature settings + format version."""
    return hashlib.sha1(f"{_CACHE_VERSION}|{file_hash}|{settings!r}|{target_features}".encode()).hexdigest()[
        :20
    ]


def detect_adaptive(image: np.ndarray, settings: FeatureSettings, target: int):
    """Detect features; when a SIFT detection finds fewer than ``target`` keypoints, detect again
    with half the contrast threshold (at most twice): small or soft images get enough features
    while large sharp ones keep the cheaper, more selective threshold."""
    f = detect_features(image, settings)
    tries = 0
    while target > 0 and len(f) < target and settings.method in ("sift", "rootsift") and tries < 2:
        settings = replace(settings, sift_contrast_threshold=settings.sift_contrast_threshold / 2)
        f = detect_features(image, settings)
        tries += 1
    return f


def _safe_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", Path(name).stem)[:60] or "image"


def _colors_at(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    ij = np.clip(np.round(xy).astype(np.int64), 0, [w - 1, h - 1]) if len(xy) else np.zeros((0, 2), np.int64)
    c = image[ij[:, 1], ij[:, 0]]
    if c.ndim == 1:
        c = np.repeat(c[:, None], 3, axis=1)
    return np.ascontiguousarray(c[:, :3], dtype=np.uint8)


def extract_one(task: ExtractTask) -> ExtractedImage:
    """Extract (or load from the cache) the features of one image. Never raises for a bad file:
    the result says why it is unusable. Runs single-threaded (the executor parallelises)."""
    with limited_threads(1):
        return _extract_one(task)


def _extract_one(task: ExtractTask) -> ExtractedImage:
    path = Path(task.path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        return ExtractedImage(
            task.index,
            task.name,
            task.path,
            False,
            f"cannot read the file ({exc.strerror})",
            0,
            0,
            0,
            "",
            "",
            1.0,
            False,
        )
    file_hash = hashlib.sha1(data).hexdigest()
    key = feature_cache_key(file_hash, task.settings, task.target_features)
    cache = Path(task.cache_dir) / f"{_safe_stem(task.name)}-{key}.npz"
    if cache.is_file():
        try:
            with np.load(cache) as z:
                w, h = (int(v) for v in z["size"])
                n = int(len(z["scales"]))
                scale = float(z["scale"])
            return ExtractedImage(
                task.index, task.name, task.path, True, "", w, h, n, file_hash, str(cache), scale, True
            )
        except Exception:  # a corrupt cache file: extract again
            pass
    try:
        image = read_image(path)
    except SkyreconError as exc:
        return ExtractedImage(
            task.index,
            task.name,
            task.path,
            False,
            f"cannot decode the image ({exc})",
            0,
            0,
            0,
            file_hash,
            "",
            1.0,
            False,
        )
    h, w = image.shape[:2]
    try:
        f = detect_adaptive(image, task.settings, task.target_features)
    except SkyreconError as exc:
        return ExtractedImage(
            task.index, task.name, task.path, False, str(exc), w, h, 0, file_hash, "", 1.0, False
        )
    colors = _colors_at(image, f.keypoints)
    with atomic_write(cache, "wb") as fh:
        np.savez(
            fh,
            keypoints=f.keypoints.astype(np.float64),
            scales=f.scales.astype(np.float32),
            responses=f.responses.astype(np.float32),
            descriptors=f.descriptors.astype(np.float16 if f.descriptors.dtype != np.uint8 else np.uint8),
            colors=colors,
            size=np.array([w, h]),
            scale=np.array(f.scale),
        )
    return ExtractedImage(
        task.index, task.name, task.path, True, "", w, h, len(f), file_hash, str(cache), f.scale, False
    )


_LOADED: OrderedDict[tuple[str, tuple[str, ...]], dict[str, np.ndarray]] = OrderedDict()
_LOADED_MAX = 32


def load_features(
    cache_path: str, keys: tuple[str, ...] = ("keypoints", "scales", "colors")
) -> dict[str, np.ndarray]:
    """Arrays of one cached feature file (descriptors come back as float32 or uint8).

    A small per-process LRU cache keeps recently used files, so work items that reuse an
    image (neighbouring pairs of a sequence) read it once.
    """
    k = (cache_path, keys)
    hit = _LOADED.get(k)
    if hit is not None:
        _LOADED.move_to_end(k)
        return hit
    with np.load(cache_path) as z:
        out = {}
        for name in keys:
            a = z[name]
            if name == "descriptors" and a.dtype == np.float16:
                a = a.astype(np.float32)
            out[name] = a
    _LOADED[k] = out
    while len(_LOADED) > _LOADED_MAX:
        _LOADED.popitem(last=False)
    return out
