"""The stereo visual odometry a user would assemble from OpenCV alone: the baseline of the benchmark.

Frame to frame: the previous frame's left image gets ``cv2.goodFeaturesToTrack`` corners and an
``cv2.StereoSGBM`` disparity (the project's reference SGBM configuration: 3-way, block 5,
P1 = 8*3*5^2, P2 = 32*3*5^2, uniqueness 10, speckle 100/2) that lifts them to 3D; they are tracked
into the current left image with pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``, 21x21 window,
4 levels, forward-backward check at 1 px), and ``cv2.solvePnPRansac`` (EPnP minimal solver, 1.5 px
threshold, 300 iterations, then ``cv2.solvePnPRefineLM`` on the inliers) gives the motion. Features are
re-detected every frame (no map, no keyframes, no bundle adjustment). Fewer than 12 inliers, or a
motion over 5 m between frames: the frame is lost and the pose follows the constant-velocity
prediction.

Same shape as the engine: ``track(left, right, timestamp_s) -> FrameEstimate``; ``trajectory()``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from skyrecon.core.rigid import Rigid3
from skyrecon.core.stereo_rig import StereoRig
from skyrecon.odometry.types import FrameEstimate, TrackingState


class OpenCVStereoVO:
    """Frame-to-frame stereo VO with OpenCV building blocks (see the module docstring)."""

    def __init__(
        self,
        rig: StereoRig,
        max_disparity: int = 128,
        max_corners: int = 1500,
        min_inliers: int = 12,
        init_world_from_left: Rigid3 | None = None,
    ):
        if not rig.is_rectified:
            raise ValueError("the OpenCV baseline needs a rectified rig")
        self.rig = rig
        self.K = rig.left.K
        self.min_inliers = min_inliers
        self.max_corners = max_corners
        nd = int(-(-max_disparity // 16) * 16)
        bs = 5
        self.sgbm = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=nd,
            blockSize=bs,
            P1=8 * 3 * bs**2,
            P2=32 * 3 * bs**2,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=100,
            speckleRange=2,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )
        self.estimates: list[FrameEstimate] = []
        self._pose = (init_world_from_left or Rigid3.identity()).with_frames("world", "left")
        self._velocity = Rigid3.identity()  # prev_from_cur of the last motion
        self._prev_gray: np.ndarray | None = None
        self._prev_pts: np.ndarray | None = None  # (N, 2) float32 pixels in the previous left image
        self._prev_xyz: np.ndarray | None = None  # (N, 3) previous left-camera points, metres

    @staticmethod
    def _gray(image: np.ndarray) -> np.ndarray:
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)

    def _features_3d(
        self, left: np.ndarray, right: np.ndarray, gray: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        disp = self.sgbm.compute(left, right).astype(np.float32) / 16.0
        pts = cv2.goodFeaturesToTrack(gray, self.max_corners, 0.01, 7, blockSize=7)
        if pts is None:
            return np.zeros((0, 2), np.float32), np.zeros((0, 3))
        pts = pts.reshape(-1, 2)
        u = np.clip(np.round(pts[:, 0]).astype(int), 0, gray.shape[1] - 1)
        v = np.clip(np.round(pts[:, 1]).astype(int), 0, gray.shape[0] - 1)
        d = disp[v, u]
        ok = d > 1.0
        z = self.rig.left.fx * self.rig.baseline_m / d[ok]
        x = (pts[ok, 0] - self.rig.left.cx) * z / self.rig.left.fx
        y = (pts[ok, 1] - self.rig.left.cy) * z / self.rig.left.fy
        return pts[ok].astype(np.float32), np.stack([x, y, z], axis=1)

    def track(
        self, left: np.ndarray, right: np.ndarray, timestamp_s: float, disparity_px=None
    ) -> FrameEstimate:
        t0 = time.perf_counter()
        gray = self._gray(left)
        index = len(self.estimates)
        state, reason, n_tracked, n_inliers, rms = TrackingState.OK, "", 0, 0, float("nan")
        if self._prev_gray is not None and self._prev_pts is not None and len(self._prev_pts) >= 6:
            p1, st, _ = cv2.calcOpticalFlowPyrLK(
                self._prev_gray, gray, self._prev_pts.reshape(-1, 1, 2), None, winSize=(21, 21), maxLevel=4
            )
            p0b, st_b, _ = cv2.calcOpticalFlowPyrLK(
                gray, self._prev_gray, p1, None, winSize=(21, 21), maxLevel=4
            )
            fb = np.linalg.norm(p0b.reshape(-1, 2) - self._prev_pts, axis=1)
            good = (st.ravel() == 1) & (st_b.ravel() == 1) & (fb < 1.0)
            n_tracked = int(good.sum())
            motion = None
            if n_tracked >= 6:
                obj = self._prev_xyz[good].astype(np.float64)
                img = p1.reshape(-1, 2)[good].astype(np.float64)
                ok, rvec, tvec, inl = cv2.solvePnPRansac(
                    obj,
                    img,
                    self.K,
                    None,
                    iterationsCount=300,
                    reprojectionError=1.5,
                    confidence=0.999,
                    flags=cv2.SOLVEPNP_EPNP,
                )
                if ok and inl is not None and len(inl) >= self.min_inliers:
                    inl = inl.ravel()
                    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], self.K, None, rvec, tvec)
                    proj, _ = cv2.projectPoints(obj[inl], rvec, tvec, self.K, None)
                    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img[inl]) ** 2, axis=1))))
                    cur_from_prev = Rigid3(cv2.Rodrigues(rvec)[0], tvec.ravel())
                    n_inliers = len(inl)
                    if np.linalg.norm(cur_from_prev.t) < 5.0:
                        motion = cur_from_prev.inverse()
                    else:
                        reason = f"implausible motion {np.linalg.norm(cur_from_prev.t):.1f} m"
                else:
                    reason = f"{0 if inl is None else len(inl)} inliers (< {self.min_inliers})"
            else:
                reason = f"{n_tracked} features tracked"
            if motion is None:
                state, motion = TrackingState.LOST, self._velocity
            self._velocity = motion
            self._pose = (self._pose.with_frames(None, None) @ motion).with_frames("world", "left")
        elif self._prev_gray is not None:
            state, reason = TrackingState.LOST, "no 3D features in the previous frame"
            self._pose = (self._pose.with_frames(None, None) @ self._velocity).with_frames("world", "left")
        pts, xyz = self._features_3d(left, right, gray)
        self._prev_gray, self._prev_pts, self._prev_xyz = gray, pts, xyz
        est = FrameEstimate(
            index=index,
            timestamp_s=float(timestamp_s),
            world_from_left=self._pose,
            state=state,
            reason=reason,
            keyframe=True,
            n_features=len(pts),
            n_stereo=len(xyz),
            n_tracked=n_tracked,
            n_inliers=n_inliers,
            reprojection_rms_px=rms,
            timings_ms={"total": 1000.0 * (time.perf_counter() - t0)},
        )
        self.estimates.append(est)
        return est

    def trajectory(self) -> list[Rigid3]:
        return [e.world_from_left for e in self.estimates]
