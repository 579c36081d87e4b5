"""Place recognition over the odometry's keyframes, and the geometric check of a loop candidate.

Each keyframe stores (:class:`Place`): a thumbnail signature (the grey image shrunk to 32x24,
blurred, zero-mean, unit norm), upright ORB descriptors computed at the odometry's own corners
(``cv2.ORB.compute`` at angle 0: the camera does not roll, so steering would only add noise) and
the stereo 3D point of each of those corners in the keyframe's left camera frame.

A search (:meth:`PlaceDatabase.candidates`) considers only keyframes that are old enough (at least
``min_keyframe_gap`` keyframes and ``min_path_m`` metres of flight back) and, to bound the work,
near the current estimate: within ``gate_m + gate_fraction * path`` metres and looking the same way
within ``max_view_angle_deg`` (the gate grows with the distance flown since, as the drift does).
Appearance decides among them: the ``top_k`` best thumbnails are matched with their ORB
descriptors (Hamming, ratio test) and ranked by the number of matches.

The geometric check (:func:`verify_loop`) solves PnP in RANSAC both ways: the candidate's 3D points
against the current corners, and the current 3D points against the candidate's corners. Two
independent stereo depth sets must agree on the relative pose ``candidate_from_current``; both need
enough inliers spread over the image.

Frames: ``left`` camera (OpenCV axes) of each keyframe. Units: metres, pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.core.rigid import rotation_angle
from skyrecon.errors import EstimationError
from skyrecon.odometry.frontend import grid_coverage
from skyrecon.sfm.pnp import estimate_absolute_pose

__all__ = ["Place", "PlaceDatabase", "LoopMatch", "verify_loop", "thumbnail"]

THUMB_SIZE = (32, 24)


def thumbnail(grey: np.ndarray) -> np.ndarray:
    """(768,) float32 signature of an (H, W) uint8 image: 32x24, blurred, zero-mean, unit norm."""
    small = cv2.resize(grey, THUMB_SIZE, interpolation=cv2.INTER_AREA).astype(np.float32)
    sig = cv2.GaussianBlur(small, (3, 3), 0.8).ravel()
    sig = sig - np.float32(sig.mean())
    n = float(np.linalg.norm(sig))
    return (sig / np.float32(n) if n > 1e-6 else sig).astype(np.float32)


@dataclass
class Place:
    """What a keyframe keeps for place recognition.

    Attributes:
        keyframe: index of the keyframe in the odometry's keyframe list.
        frame: its frame index.
        signature: (768,) thumbnail signature.
        uv: (M, 2) float64 pixels of the described corners (left image).
        descriptors: (M, 32) uint8 ORB descriptors.
        points_cam: (M, 3) float64 stereo 3D points in the keyframe's left camera frame, metres.
        path_m: distance flown from the first keyframe to this one (odometry estimate), metres.
    """

    keyframe: int
    frame: int
    signature: np.ndarray
    uv: np.ndarray
    descriptors: np.ndarray
    points_cam: np.ndarray
    path_m: float


@dataclass
class LoopMatch:
    """A verified loop.

    Attributes:
        candidate_from_current: (4, 4) relative pose of the current keyframe's left camera in the
            candidate's, metres.
        inliers: inliers of the weaker of the two PnP solutions.
        matches: descriptor matches tried.
        coverage: fraction of a 4x4 image grid covered by the inliers (the weaker direction).
        disagreement_m, disagreement_deg: how far apart the two directions' poses are.
    """

    candidate_from_current: np.ndarray
    inliers: int
    matches: int
    coverage: float
    disagreement_m: float
    disagreement_deg: float


class PlaceDatabase:
    """The keyframes' places and the candidate search (see the module docstring).

    Args:
        image_size: (width, height) of the images, pixels.
        min_keyframe_gap: candidates are at least this many keyframes old.
        min_path_m: ... and at least this many metres of flight back.
        gate_m, gate_fraction: candidates lie within ``gate_m + gate_fraction * path`` metres of the
            current estimate (``path``: metres flown since the candidate).
        max_view_angle_deg: ... and look the same way within this angle.
        top_k: thumbnails matched with their descriptors per search (bounds the work).
        ratio: Lowe ratio of the descriptor matching.
    """

    def __init__(
        self,
        image_size: tuple[int, int],
        min_keyframe_gap: int = 20,
        min_path_m: float = 40.0,
        gate_m: float = 3.0,
        gate_fraction: float = 0.03,
        max_view_angle_deg: float = 45.0,
        top_k: int = 4,
        ratio: float = 0.8,
    ) -> None:
        self.image_size = image_size
        self.min_keyframe_gap = min_keyframe_gap
        self.min_path_m = min_path_m
        self.gate_m = gate_m
        self.gate_fraction = gate_fraction
        self.max_view_angle_deg = max_view_angle_deg
        self.top_k = top_k
        self.ratio = ratio
        self.places: list[Place] = []
        self._orb = cv2.ORB.create(edgeThreshold=19, patchSize=31)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def describe(
        self,
        keyframe: int,
        frame: int,
        grey: np.ndarray,
        uv: np.ndarray,
        points_cam: np.ndarray,
        path_m: float,
    ) -> Place:
        """The place of a keyframe: ORB descriptors at its corners ``uv`` (N, 2) pixels with their
        3D points ``points_cam`` (N, 3), left camera frame, metres (rows with NaN are dropped)."""
        good = np.isfinite(points_cam).all(axis=1) & np.isfinite(uv).all(axis=1)
        idx = np.flatnonzero(good)
        kps = [cv2.KeyPoint(float(uv[k, 0]), float(uv[k, 1]), 31.0, 0.0, 0.0, 0, int(k)) for k in idx]
        kept, desc = self._orb.compute(grey, kps) if kps else ((), None)
        if desc is None or not len(kept):
            sel = np.zeros(0, np.int64)
            desc = np.zeros((0, 32), np.uint8)
        else:
            sel = np.array([k.class_id for k in kept], np.int64)
        return Place(
            keyframe,
            frame,
            thumbnail(grey),
            uv[sel].astype(np.float64),
            np.asarray(desc, np.uint8),
            points_cam[sel].astype(np.float64),
            float(path_m),
        )

    def add(self, place: Place) -> None:
        self.places.append(place)

    def match(self, a: Place, b: Place) -> np.ndarray:
        """(K, 2) index pairs (into ``a``, into ``b``) of ratio-test descriptor matches."""
        if len(a.descriptors) < 2 or len(b.descriptors) < 2:
            return np.zeros((0, 2), np.int64)
        pairs = []
        for m in self._matcher.knnMatch(a.descriptors, b.descriptors, k=2):
            if len(m) == 2 and m[0].distance < self.ratio * m[1].distance:
                pairs.append((m[0].queryIdx, m[0].trainIdx))
        return np.array(pairs, np.int64).reshape(-1, 2)

    def candidates(
        self, query: Place, world_from_kf: list[np.ndarray], min_matches: int
    ) -> list[tuple[Place, np.ndarray]]:
        """Old places near the current estimate that look like ``query``, best first, with their
        matches (see :meth:`match`); only those with at least ``min_matches`` matches.

        Args:
            query: the current keyframe's place (``query.keyframe`` indexes ``world_from_kf``).
            world_from_kf: current ``world_from_left`` estimate of every keyframe (4x4).
            min_matches: fewer descriptor matches drop a candidate.
        """
        old = [
            p
            for p in self.places
            if p.keyframe <= query.keyframe - self.min_keyframe_gap
            and query.path_m - p.path_m >= self.min_path_m
        ]
        if not old:
            return []
        T = world_from_kf[query.keyframe]
        pos = np.stack([world_from_kf[p.keyframe][:3, 3] for p in old])
        axes = np.stack([world_from_kf[p.keyframe][:3, 2] for p in old])
        path = np.array([query.path_m - p.path_m for p in old])
        near = np.linalg.norm(pos - T[:3, 3], axis=1) <= self.gate_m + self.gate_fraction * path
        near &= axes @ T[:3, 2] >= math.cos(math.radians(self.max_view_angle_deg))
        if not np.any(near):
            return []
        pool = [p for p, n in zip(old, near) if n]
        score = np.stack([p.signature for p in pool]) @ query.signature
        best = np.argsort(-score)[: self.top_k]
        out = []
        for k in best.tolist():
            pairs = self.match(query, pool[k])
            if len(pairs) >= min_matches:
                out.append((pool[k], pairs))
        out.sort(key=lambda c: -len(c[1]))
        return out


def _pnp(
    uv: np.ndarray,
    X: np.ndarray,
    f: np.ndarray,
    c: np.ndarray,
    size: tuple[int, int],
    threshold_px: float,
    min_inliers: int,
    seed: int,
) -> tuple[np.ndarray, int, float]:
    """``b_from_a`` (4x4) of the camera seeing pixels ``uv`` of points ``X`` given in frame ``a``;
    its inlier count and inlier coverage. Raises EstimationError."""
    pose = estimate_absolute_pose(
        (uv - c) / f,
        X,
        float(f[0]),
        threshold_px=threshold_px,
        seed=seed,
        max_iterations=500,
        confidence=0.999,
        min_inliers=min_inliers,
    )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = pose.R, pose.t
    return T, pose.num_inliers, grid_coverage(uv[pose.inliers], *size)


def verify_loop(
    current: Place,
    candidate: Place,
    pairs: np.ndarray,
    focal_px: tuple[float, float],
    principal_px: tuple[float, float],
    image_size: tuple[int, int],
    threshold_px: float = 2.0,
    min_inliers: int = 40,
    min_coverage: float = 0.25,
    max_disagreement_m: float = 0.3,
    max_disagreement_deg: float = 1.0,
    seed: int = 0,
) -> LoopMatch | str:
    """The geometric check of a loop candidate: PnP in RANSAC both ways (see the module docstring).

    Args:
        current, candidate: the two places.
        pairs: (K, 2) matches (index into ``current``, index into ``candidate``).
        focal_px, principal_px: the left camera's (fx, fy) and (cx, cy), pixels.
        image_size: (width, height), pixels (for the inlier coverage).
        threshold_px: RANSAC inlier threshold, pixels.
        min_inliers: fewer inliers in either direction fail the check.
        min_coverage: inliers covering less of a 4x4 image grid fail the check.
        max_disagreement_m, max_disagreement_deg: the two directions' poses must agree this well.
        seed: seeds the RANSAC.
    Returns:
        :class:`LoopMatch`, or a one-line reason why the candidate failed.
    """
    if len(pairs) < min_inliers:
        return f"{len(pairs)} descriptor matches (< {min_inliers})"
    f, c = np.asarray(focal_px, np.float64), np.asarray(principal_px, np.float64)
    size = image_size
    a, b = pairs[:, 0], pairs[:, 1]
    try:
        cur_from_cand, n1, cov1 = _pnp(
            current.uv[a], candidate.points_cam[b], f, c, size, threshold_px, min_inliers, seed
        )
        cand_from_cur, n2, cov2 = _pnp(
            candidate.uv[b], current.points_cam[a], f, c, size, threshold_px, min_inliers, seed + 1
        )
    except EstimationError as exc:
        return f"geometric check failed: {exc}"
    n, cov = min(n1, n2), min(cov1, cov2)
    if cov < min_coverage:
        return f"loop inliers cover {cov:.0%} of the image grid (< {min_coverage:.0%})"
    # the two directions must agree: cand_from_cur @ cur_from_cand = identity
    D = cand_from_cur @ cur_from_cand
    dm = float(np.linalg.norm(D[:3, 3]))
    dd = math.degrees(rotation_angle(D[:3, :3]))
    if dm > max_disagreement_m or dd > max_disagreement_deg:
        return (
            f"the two PnP directions disagree by {dm:.2f} m, {dd:.2f} deg "
            f"(> {max_disagreement_m:g} m, {max_disagreement_deg:g} deg)"
        )
    # the current-from-candidate solution (the candidate's stored points) is the measurement
    out = np.eye(4)
    out[:3, :3] = cur_from_cand[:3, :3].T
    out[:3, 3] = -cur_from_cand[:3, :3].T @ cur_from_cand[:3, 3]
    return LoopMatch(out, n, len(pairs), cov, dm, dd)
