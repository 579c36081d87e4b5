"""Pinhole camera intrinsics with optional OpenCV-model lens distortion.

Pixel ``(u, v) = (column, row)``; the centre of the top-left pixel is (0, 0).
Camera frame: x right, y down, z forward (OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyrecon.errors import InputError


@dataclass(frozen=True)
class Intrinsics:
    """Intrinsics of one camera.

    Attributes:
        fx, fy: focal lengths, pixels.
        cx, cy: principal point, pixels (top-left pixel centre at (0, 0)).
        width, height: image size, pixels.
        dist: (5,) OpenCV distortion ``k1, k2, p1, p2, k3`` (zeros for none).
        skew: K[0, 1], pixels (almost always 0).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    skew: float = 0.0

    def __post_init__(self) -> None:
        vals = [self.fx, self.fy, self.cx, self.cy, self.skew]
        if not all(np.isfinite(v) for v in vals):
            raise InputError(f"intrinsics contain NaN or infinite values: {vals}")
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        d = np.zeros(5)
        dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if dist.size > 5:
            raise InputError(f"at most 5 distortion coefficients (k1 k2 p1 p2 k3), got {dist.size}")
        if not np.all(np.isfinite(dist)):
            raise InputError("distortion coefficients contain NaN or infinite values")
        d[: dist.size] = dist
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy", "skew"):
            object.__setattr__(self, name, float(getattr(self, name)))

    # ----- construction -------------------------------------------------
    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int, dist: np.ndarray | None = None) -> Intrinsics:
        """From a (3, 3) calibration matrix and the image size in pixels."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise InputError(f"K must be 3x3, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise InputError("K contains NaN or infinite values")
        if abs(K[2, 2]) < 1e-12:
            raise InputError("K[2,2] is zero: not a calibration matrix")
        K = K / K[2, 2]
        if abs(K[1, 0]) > 1e-9 or abs(K[2, 0]) > 1e-9 or abs(K[2, 1]) > 1e-9:
            raise InputError("K must be upper triangular [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        return cls(
            K[0, 0],
            K[1, 1],
            K[0, 2],
            K[1, 2],
            width,
            height,
            np.zeros(5) if dist is None else dist,
            K[0, 1],
        )

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, principal point at the image centre, horizontal field of view in degrees."""
        f = (width / 2) / np.tan(np.radians(hfov_deg) / 2)
        return cls(f, f, (width - 1) / 2, (height - 1) / 2, width, height)

    # ----- views ---------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        """(3, 3) calibration matrix."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (self.width, self.height)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width): the shape of an image from this camera."""
        return (self.height, self.width)

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    def without_distortion(self) -> Intrinsics:
        return Intrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height, np.zeros(5), self.skew)

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics for the image resized by ``factor`` (keeps the pixel-centre convention)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        sx, sy = w / self.width, h / self.height
        return Intrinsics(
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            w,
            h,
            self.dist,
            self.skew * sx,
        )

    def check_image(self, image: np.ndarray, what: str = "image") -> None:
        """Raise ``InputError`` unless ``image`` (H, W[, C]) has this camera's size."""
        h, w = image.shape[:2]
        if (w, h) != (self.width, self.height):
            raise InputError(
                f"{what} is {w}x{h} but the calibration is for {self.width}x{self.height}; "
                "resize the image or use the matching calibration"
            )

    # ----- distortion -----------------------------------------------------
    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens distortion to normalised coordinates (N, 2) (z = 1 plane)."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def undistort_normalized(self, xy_d: np.ndarray, iterations: int = 200) -> np.ndarray:
        """Invert :meth:`distort_normalized` by fixed-point iteration, (N, 2) -> (N, 2).

        Stops early once no point moves by more than 1e-15; strong barrel distortion near the
        image corners needs many iterations.
        """
        if not self.has_distortion:
            return xy_d.copy()
        k1, k2, p1, p2, k3 = self.dist
        xy = xy_d.copy()
        for _ in range(iterations):
            x, y = xy[:, 0], xy[:, 1]
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            new = np.stack([(xy_d[:, 0] - dx) / radial, (xy_d[:, 1] - dy) / radial], axis=1)
            done = not np.nanmax(np.abs(new - xy), initial=0.0) > 1e-15
            xy = new
            if done:
                break
        return xy

    # ----- projection -----------------------------------------------------
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points to pixels.

        Args:
            points_cam: (N, 3) points in this camera's frame, metres.
        Returns:
            (N, 2) float64 pixels (u, v). Points with z <= 0 give NaN.
        """
        p = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        if self.has_distortion:
            xy = self.distort_normalized(xy)
        u = self.fx * xy[:, 0] + self.skew * xy[:, 1] + self.cx
        v = self.fy * xy[:, 1] + self.cy
        return np.stack([u, v], axis=1)

    def normalized(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) to undistorted normalised coordinates (N, 2) on the z = 1 plane."""
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        y = (uv[:, 1] - self.cy) / self.fy
        x = (uv[:, 0] - self.cx - self.skew * y) / self.fx
        return self.undistort_normalized(np.stack([x, y], axis=1))

    def unproject(self, pixels: np.ndarray, depth_m: np.ndarray | float = 1.0) -> np.ndarray:
        """Back-project pixels with depth along the optical axis to camera-frame points.

        Args:
            pixels: (N, 2) pixels (u, v).
            depth_m: (N,) or scalar depth along z, metres.
        Returns:
            (N, 3) float64 points in the camera frame.
        """
        xy = self.normalized(pixels)
        z = np.broadcast_to(np.asarray(depth_m, dtype=np.float64), (xy.shape[0],))
        return np.stack([xy[:, 0] * z, xy[:, 1] * z, z], axis=1)

    def pixel_grid(self) -> np.ndarray:
        """(H, W, 2) float64 pixel coordinates (u, v) of every pixel centre."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return np.stack([u, v], axis=-1)

    def ray_directions(self) -> np.ndarray:
        """(H, W, 3) float64 camera-frame directions with z = 1 for every pixel centre."""
        xy = self.normalized(self.pixel_grid().reshape(-1, 2))
        d = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        return d.reshape(self.height, self.width, 3)

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel (N, 2) lies inside the image (pixel-centre convention), NaN -> False."""
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin)
                & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin)
                & (uv[:, 1] <= self.height - 0.5 - margin)
            )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Intrinsics):
            return NotImplemented
        return (
            (self.width, self.height) == (other.width, other.height)
            and np.allclose(self.K, other.K)
            and np.allclose(self.dist, other.dist)
        )

    def __hash__(self) -> int:
        return hash((self.width, self.height, round(self.fx, 6), round(self.fy, 6)))
