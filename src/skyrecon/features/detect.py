"""Keypoint detection and description: SIFT (default, with RootSIFT), ORB and AKAZE.

Images are downscaled to a configurable longer side before detection; keypoints are mapped back
to full-resolution pixels with the pixel-centre convention (centre of the top-left pixel = (0, 0)):
``u_full = (u_small + 0.5) / s - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from skyrecon.errors import InputError

__all__ = [
    "FeatureMethod",
    "FeatureSettings",
    "Features",
    "to_gray_uint8",
    "resize_longer_side",
    "detect_features",
]

FeatureMethod = Literal["sift", "rootsift", "orb", "akaze"]
FEATURE_METHODS: tuple[str, ...] = ("sift", "rootsift", "orb", "akaze")


@dataclass(frozen=True)
class FeatureSettings:
    """How to detect and describe features.

    Attributes:
        method: ``"rootsift"`` (SIFT with Hellinger-normalised descriptors, default), ``"sift"``,
            ``"orb"`` or ``"akaze"`` (binary descriptors; AKAZE only where OpenCV provides it).
        max_image_size: longer image side used for detection, pixels (None or 0: full resolution;
            images are never upscaled).
        max_features: keep at most this many strongest keypoints (0: no limit; ORB needs a limit
            and uses 8000 when 0). Default 8000: enough for accurate poses, bounded matching cost.
        sift_contrast_threshold: OpenCV SIFT contrast threshold (lower: more features). The
            default 0.01 (OpenCV: 0.04) detects many weak but well-localised keypoints; the
            strongest ``max_features`` are kept.
        sift_edge_threshold: OpenCV SIFT edge threshold.
        akaze_threshold: AKAZE detector response threshold.
        sift_precise_upscale: OpenCV's exact 2x upsampling of the first octave (``x -> 2x``);
            without it OpenCV's upsampled octave is shifted by a quarter pixel.
    """

    method: FeatureMethod = "rootsift"
    max_image_size: int | None = 1536
    max_features: int = 8000
    sift_contrast_threshold: float = 0.01
    sift_edge_threshold: float = 10.0
    akaze_threshold: float = 0.0008
    sift_precise_upscale: bool = True

    def __post_init__(self) -> None:
        if self.method not in FEATURE_METHODS:
            raise InputError(
                f"unknown feature method {self.method!r}; use one of {', '.join(FEATURE_METHODS)}"
            )
        if self.max_image_size is not None and self.max_image_size < 0:
            raise InputError(
                f"max_image_size must be positive (or 0/None for full size), got {self.max_image_size}"
            )
        if self.max_features < 0:
            raise InputError(f"max_features must be >= 0, got {self.max_features}")

    @property
    def binary(self) -> bool:
        """Whether descriptors are binary strings (Hamming distance)."""
        return self.method in ("orb", "akaze")


@dataclass
class Features:
    """Keypoints and descriptors of one image.

    Attributes:
        keypoints: (N, 2) float64 pixel positions (u, v) in the *full-resolution* image.
        scales: (N,) float32 keypoint diameter in full-resolution pixels.
        angles: (N,) float32 orientation, degrees (OpenCV convention; -1 if none).
        responses: (N,) float32 detector response.
        descriptors: (N, D) float32 (SIFT/RootSIFT, unit L2 norm) or uint8 (ORB, AKAZE).
        image_size: (width, height) of the full-resolution image.
        scale: detection-image size / full size (<= 1).
        method: the feature method.
    """

    keypoints: np.ndarray
    scales: np.ndarray
    angles: np.ndarray
    responses: np.ndarray
    descriptors: np.ndarray
    image_size: tuple[int, int]
    scale: float
    method: str

    def __len__(self) -> int:
        return len(self.keypoints)

    @property
    def binary(self) -> bool:
        return self.descriptors.dtype == np.uint8


def to_gray_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey from (H, W) or (H, W, 3|4) RGB(A) uint8/uint16/float images.

    Raises:
        InputError: not an image array, empty, or containing NaN.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise InputError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    if img.shape[0] < 16 or img.shape[1] < 16:
        raise InputError(f"image is too small ({img.shape[1]}x{img.shape[0]}); need at least 16x16 pixels")
    if img.dtype == np.uint16:
        img = (img / 257.0).round().astype(np.uint8)
    elif img.dtype.kind == "f":
        if not np.all(np.isfinite(img)):
            raise InputError("image contains NaN or infinite values")
        mx = float(img.max()) if img.size else 0.0
        img = np.clip(img * (255.0 if mx <= 1.0 else 1.0), 0, 255).round().astype(np.uint8)
    elif img.dtype == np.bool_:
        img = img.astype(np.uint8) * 255
    elif img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[..., 0]
        else:
            img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img)


def resize_longer_side(image: np.ndarray, max_size: int | None) -> tuple[np.ndarray, float, float]:
    """Downscale so that the longer side is at most ``max_size`` (area interpolation).

    Returns:
        ``(resized, sx, sy)`` with ``sx = new_width / width`` and ``sy = new_height / height``
        (both 1 when no resizing happened).
    """
    h, w = image.shape[:2]
    if not max_size or max(h, w) <= max_size:
        return image, 1.0, 1.0
    s = max_size / max(h, w)
    nw, nh = max(1, int(round(w * s))), max(1, int(round(h * s)))
    return cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA), nw / w, nh / h


def _detector(settings: FeatureSettings):
    if settings.method in ("sift", "rootsift"):
        return cv2.SIFT.create(
            nfeatures=settings.max_features,
            contrastThreshold=settings.sift_contrast_threshold,
            edgeThreshold=settings.sift_edge_threshold,
            enable_precise_upscale=settings.sift_precise_upscale,
        )
    if settings.method == "orb":
        return cv2.ORB.create(
            nfeatures=settings.max_features or 8000, scaleFactor=1.2, nlevels=8, fastThreshold=10
        )
    create = getattr(cv2, "AKAZE_create", None)
    if create is None:
        raise InputError(
            f"AKAZE is not available in this OpenCV build ({cv2.__version__}; OpenCV 5 moved it out of "
            "the main modules); use the sift, rootsift or orb feature method"
        )
    return create(threshold=settings.akaze_threshold)


def detect_features(image: np.ndarray, settings: FeatureSettings = FeatureSettings()) -> Features:
    """Detect and describe keypoints of one image.

    Args:
        image: (H, W) grey or (H, W, 3) RGB image (uint8 preferred).
        settings: detector, descriptor and working resolution.
    Returns:
        Features with keypoints in full-resolution pixels.
    Raises:
        InputError: not a valid image.
    """
    gray = to_gray_uint8(image)
    H, W = gray.shape
    small, sx, sy = resize_longer_side(gray, settings.max_image_size)
    det = _detector(settings)
    kps, desc = det.detectAndCompute(small, None)
    n = len(kps)
    if n == 0 or desc is None:
        dim, dt = (
            (128, np.float32) if not settings.binary else (61 if settings.method == "akaze" else 32, np.uint8)
        )
        return Features(
            np.zeros((0, 2)),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
            np.zeros((0, dim), dt),
            (W, H),
            float(sx),
            settings.method,
        )
    pts = np.array([k.pt for k in kps], dtype=np.float64)
    size = np.array([k.size for k in kps], dtype=np.float32)
    ang = np.array([k.angle for k in kps], dtype=np.float32)
    resp = np.array([k.response for k in kps], dtype=np.float32)
    if settings.max_features and n > settings.max_features:
        keep = np.argsort(-resp, kind="stable")[: settings.max_features]
        keep.sort()
        pts, size, ang, resp, desc = pts[keep], size[keep], ang[keep], resp[keep], desc[keep]
    full = np.empty_like(pts)
    full[:, 0] = (pts[:, 0] + 0.5) / sx - 0.5
    full[:, 1] = (pts[:, 1] + 0.5) / sy - 0.5
    if settings.binary:
        descriptors = np.ascontiguousarray(desc, dtype=np.uint8)
    else:
        d = desc.astype(np.float32)
        if settings.method == "rootsift":
            d /= np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
            d = np.sqrt(d)
        else:
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        descriptors = np.ascontiguousarray(d)
    return Features(full, size / np.float32(sx), ang, resp, descriptors, (W, H), float(sx), settings.method)
