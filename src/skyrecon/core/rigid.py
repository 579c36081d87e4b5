"""Rigid transforms named ``b_from_a``.

A ``Rigid3`` maps points from frame ``a`` to frame ``b``: ``p_b = R @ p_a + t``.
Compose right to left: ``c_from_a = c_from_b @ b_from_a``. Frames are optional
labels; when both sides of a composition carry them they must agree, which
catches the classic inverted-pose bug at the point where it happens.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyrecon.errors import InputError, SkyreconError


class FrameMismatchError(SkyreconError):
    """Two transforms were composed whose frames do not chain."""


def _as_rotation(R: np.ndarray, tol: float = 1e-5) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise InputError(f"a rotation must be 3x3, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise InputError("the rotation contains NaN or infinite values")
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > tol or abs(np.linalg.det(R) - 1.0) > tol * 10:
        raise InputError(f"not a rotation matrix (orthogonality error {err:.2e}, det {np.linalg.det(R):.6f})")
    return R


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm) to a 3x3 matrix, via SVD."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: axis-angle vector (3,) in radians to a 3x3 rotation."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        Kx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        return np.eye(3) + Kx
    k = w / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * Kx + (1 - np.cos(theta)) * (Kx @ Kx)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotvec_to_matrix`: (3,) axis-angle in radians."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    theta = np.arccos(cos)
    if theta < 1e-8:
        return np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2
    if np.pi - theta < 1e-5:
        # Near 180 degrees: axis from the symmetric part.
        M = (R + np.eye(3)) / 2
        i = int(np.argmax(np.diag(M)))
        axis = M[:, i] / np.sqrt(max(M[i, i], 1e-300))
        return axis / np.linalg.norm(axis) * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w * theta / (2 * np.sin(theta))


def quaternion_to_matrix(q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) (Hamilton, as COLMAP) to a 3x3 rotation."""
    q = np.asarray(q_wxyz, dtype=np.float64).reshape(4)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise InputError(f"invalid quaternion {q.tolist()}")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """3x3 rotation to a unit quaternion (w, x, y, z) with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s])
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s])
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_angle(R: np.ndarray) -> float:
    """Angle in radians, in [0, pi], of a (3, 3) rotation matrix (geodesic distance to identity).

    Computed as ``atan2(|sin|, cos)`` from the skew and trace parts, which stays accurate for tiny
    angles (where ``arccos`` of the trace loses half the digits). The angle between two rotations
    ``A`` and ``B`` is ``rotation_angle(A.T @ B)``.
    """
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    sin = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arctan2(sin, cos))


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle in degrees, in [0, 180], of a (3, 3) rotation matrix (see :func:`rotation_angle`)."""
    return float(np.degrees(rotation_angle(R)))


def rotation_angles_deg(R: np.ndarray) -> np.ndarray:
    """(N,) angles in degrees, in [0, 180], of (N, 3, 3) rotation matrices: :func:`rotation_angle`
    for many at once (same formula)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    skew = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    return np.degrees(np.arctan2(0.5 * np.linalg.norm(skew, axis=1), cos))


@dataclass(frozen=True)
class Rigid3:
    """A rigid transform ``b_from_a``: ``p_b = R @ p_a + t``.

    Attributes:
        R: (3, 3) float64 rotation.
        t: (3,) float64 translation, metres (or the reconstruction's gauge units).
        dst: name of frame b (optional label, e.g. ``"cam"``).
        src: name of frame a (optional label, e.g. ``"world"``).
    """

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    dst: str | None = None
    src: str | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        if t.shape != (3,):
            raise InputError(f"a translation must have 3 values, got {t.size}")
        if not np.all(np.isfinite(t)):
            raise InputError("the translation contains NaN or infinite values")
        object.__setattr__(self, "R", _as_rotation(self.R))
        object.__setattr__(self, "t", t)

    # ----- construction -------------------------------------------------
    @classmethod
    def identity(cls, dst: str | None = None, src: str | None = None) -> Rigid3:
        return cls(np.eye(3), np.zeros(3), dst, src)

    @classmethod
    def from_matrix(cls, M: np.ndarray, dst: str | None = None, src: str | None = None) -> Rigid3:
        """From a (4, 4) or (3, 4) matrix ``[R | t]``."""
        M = np.asarray(M, dtype=np.float64)
        if M.shape not in ((4, 4), (3, 4)):
            raise InputError(f"a pose matrix must be 3x4 or 4x4, got shape {M.shape}")
        return cls(M[:3, :3], M[:3, 3], dst, src)

    @classmethod
    def from_rotvec(
        cls, rotvec: np.ndarray, t: np.ndarray, dst: str | None = None, src: str | None = None
    ) -> Rigid3:
        return cls(rotvec_to_matrix(rotvec), t, dst, src)

    @classmethod
    def look_at(
        cls,
        eye_world: np.ndarray,
        target_world: np.ndarray,
        up_world: np.ndarray | Sequence[float] = (0.0, 0.0, 1.0),
    ) -> Rigid3:
        """``cam_from_world`` for an OpenCV camera at ``eye`` looking at ``target``.

        The camera's z axis points at the target, its y axis (image down) is
        as close as possible to ``-up``. All inputs are (3,) world points, metres.
        """
        eye = np.asarray(eye_world, dtype=np.float64)
        z = np.asarray(target_world, dtype=np.float64) - eye
        nz = np.linalg.norm(z)
        if nz < 1e-12:
            raise InputError("look_at: eye and target coincide")
        z /= nz
        up = np.asarray(up_world, dtype=np.float64)
        x = np.cross(z, up)
        if np.linalg.norm(x) < 1e-9:  # looking straight along up: pick any x
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R_world_from_cam = np.stack([x, y, z], axis=1)
        return cls(R_world_from_cam.T, -R_world_from_cam.T @ eye, "cam", "world")

    # ----- algebra -------------------------------------------------------
    def __matmul__(self, other: Rigid3) -> Rigid3:
        """``c_from_b @ b_from_a -> c_from_a``; checks that the frames chain."""
        if not isinstance(other, Rigid3):
            return NotImplemented
        if self.src is not None and other.dst is not None and self.src != other.dst:
            raise FrameMismatchError(
                f"cannot compose {self.name} @ {other.name}: frame '{self.src}' != '{other.dst}'"
            )
        return Rigid3(self.R @ other.R, self.R @ other.t + self.t, self.dst, other.src)

    def inverse(self) -> Rigid3:
        """``a_from_b`` from ``b_from_a``."""
        Rt = self.R.T
        return Rigid3(Rt, -Rt @ self.t, self.src, self.dst)

    def apply(self, points_a: np.ndarray) -> np.ndarray:
        """Map points from frame a to frame b.

        Args:
            points_a: (N, 3) or (3,) points in frame a.
        Returns:
            Points in frame b, same shape; float64 unless the input was float32.
        """
        p = np.asarray(points_a)
        dtype = np.float32 if p.dtype == np.float32 else np.float64
        out = p.astype(np.float64) @ self.R.T + self.t
        return out.astype(dtype, copy=False)

    def rotate(self, vectors_a: np.ndarray) -> np.ndarray:
        """Rotate direction vectors (N, 3) from frame a to frame b (no translation)."""
        return np.asarray(vectors_a, dtype=np.float64) @ self.R.T

    # ----- views ---------------------------------------------------------
    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix."""
        M = np.eye(4)
        M[:3, :3] = self.R
        M[:3, 3] = self.t
        return M

    @property
    def matrix3x4(self) -> np.ndarray:
        """(3, 4) matrix ``[R | t]``."""
        return self.matrix[:3]

    @property
    def origin_of_src_in_dst(self) -> np.ndarray:
        """Where the origin of frame a lies in frame b: simply ``t``."""
        return self.t.copy()

    @property
    def center(self) -> np.ndarray:
        """Origin of frame b expressed in frame a, (3,).

        For ``cam_from_world`` this is the camera centre in the world: ``-R^T t``.
        """
        return -self.R.T @ self.t

    @property
    def rotvec(self) -> np.ndarray:
        return matrix_to_rotvec(self.R)

    @property
    def name(self) -> str:
        return f"{self.dst or '?'}_from_{self.src or '?'}"

    def with_frames(self, dst: str | None, src: str | None) -> Rigid3:
        return Rigid3(self.R, self.t, dst, src)

    def allclose(self, other: Rigid3, atol: float = 1e-9) -> bool:
        return bool(np.allclose(self.R, other.R, atol=atol) and np.allclose(self.t, other.t, atol=atol))

    def __repr__(self) -> str:
        ang = rotation_angle_deg(self.R)
        return f"Rigid3({self.name}, angle={ang:.3f} deg, t={np.array2string(self.t, precision=4)})"
