"""Incremental mapper: initial pair, next-best-view registration by robust PnP, multi-view
triangulation, local and global bundle adjustment, outlier filtering and re-triangulation.

One 3D point per feature track (tracks come from union-find over verified matches); a point's
*active* observations are those consistent with it. Poses are ``cam_from_world``; the gauge is
the first image of the initial pair (identity pose) and the unit baseline of that pair, fixed in
every adjustment by holding that image and one translation coordinate of the second image.

All thresholds of :class:`~skyrecon.sfm.settings.MapperSettings` are working pixels; the mapper
converts them with ``scale`` (working / input resolution) because keypoints are input pixels.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.errors import EstimationError
from skyrecon.geometry.homography import estimate_homography
from skyrecon.geometry.sampling import RansacOptions
from skyrecon.sfm.bundle import BundleProblem, BundleReport, BundleSolverOptions, bundle_adjust
from skyrecon.sfm.matching import PairGeometry
from skyrecon.sfm.pnp import estimate_absolute_pose
from skyrecon.sfm.settings import BundleSettings, MapperSettings
from skyrecon.sfm.tracks import Tracks
from skyrecon.sfm.triangulation import max_triangulation_angles_deg, triangulate_tracks

__all__ = ["MapperInput", "MapperOutput", "IncrementalMapper"]

#: The fewest verified matches an initial pair may have when no pair has
#: ``MapperSettings.init_min_inliers`` (then half of that, at least this). Small images (a 12-photo
#: survey at 320x240) can fall just short of 100 (99) while the model they make is sound; the
#: initialisation still needs ``init_min_points`` triangulated points after its adjustment.
INIT_MIN_INLIERS_FLOOR = 30


@dataclass
class MapperInput:
    """What the mapper works on.

    Attributes:
        names: image names.
        keypoints: per image, (M_i, 2) float64 keypoints, input pixels (as detected, distorted).
        keypoint_sizes: per image, (M_i,) keypoint diameters, input pixels.
        colors: per image, (M_i, 3) uint8 RGB under each keypoint.
        cameras: the cameras (input resolution).
        camera_of_image: (n,) int index into ``cameras`` of each image.
        tracks: feature tracks over all images.
        pairs: verified pairs (for the initial pair and for diagnostics).
        usable: (n,) bool: images that may be registered (others were left out earlier).
        scale: feature (working) resolution / input resolution.
        sequence_reach: for the frames of one flight (sequential pairing), in flight order: the
            farthest frame offset paired along the sequence; the mapper then grows the model
            along the flight and registers a frame through loop pairs alone (no registered frame
            within this reach) only when no frame along the flight can be registered. 0 for
            unordered photos.
    """

    names: list[str]
    keypoints: list[np.ndarray]
    keypoint_sizes: list[np.ndarray]
    colors: list[np.ndarray]
    cameras: list[Intrinsics]
    camera_of_image: np.ndarray
    tracks: Tracks
    pairs: list[PairGeometry]
    usable: np.ndarray
    scale: float = 1.0
    sequence_reach: int = 0


@dataclass
class MapperOutput:
    """The mapper's result.

    Attributes:
        registered: (n,) bool.
        R, t: (n, 3, 3), (n, 3) ``cam_from_world`` of the registered images.
        cameras: refined cameras (same order as the input).
        points: (n_tracks, 3) float64 world points (valid where ``has_point``).
        has_point: (n_tracks,) bool.
        active: (n_obs,) bool: observation (of ``tracks``) used by its point.
        colors: (n_tracks, 3) uint8 mean colour of the active observations.
        errors_px: (n_obs,) reprojection error of the active observations (NaN elsewhere).
        failures: image index -> why it was not registered.
        init_pair: the initial pair (image indices).
        diagnostics: counters and timings; ``loops`` (one record per loop: its image, points,
            RMS errors, whether it was adjusted and kept) and ``global_ba_runs`` (one record per
            global adjustment: registered images, rounds, final or not, LM iterations in all and
            in each round, observations adjusted in each round, seconds in the solver and in all).
        warnings: human-readable warnings.
        registration_order: image indices in the order they were registered.
    """

    registered: np.ndarray
    R: np.ndarray
    t: np.ndarray
    cameras: list[Intrinsics]
    points: np.ndarray
    has_point: np.ndarray
    active: np.ndarray
    colors: np.ndarray
    errors_px: np.ndarray
    failures: dict[int, str]
    init_pair: tuple[int, int] | None
    diagnostics: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    registration_order: list[int] = field(default_factory=list)


def _ranges(ptr: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Concatenated ``arange(ptr[k], ptr[k+1])`` for every k in ids."""
    ids = np.asarray(ids, np.int64)
    if len(ids) == 0:
        return np.zeros(0, np.int64)
    lens = ptr[ids + 1] - ptr[ids]
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    starts = np.repeat(ptr[ids] - np.concatenate([[0], np.cumsum(lens)[:-1]]), lens)
    return starts + np.arange(total)


class IncrementalMapper:
    """Grows one reconstruction image by image. See the module docstring.

    Args:
        data: images, keypoints, tracks, pairs.
        settings: mapper thresholds (working pixels).
        bundle: adjustment settings.
        seed: seeds every random choice (RANSAC of the absolute poses).
    """

    def __init__(
        self, data: MapperInput, settings: MapperSettings, bundle: BundleSettings, seed: int = 0
    ) -> None:
        self.d = data
        self.s = settings
        self.b = bundle
        self.seed = int(seed)
        n = len(data.names)
        self.n = n
        tr = data.tracks
        self.ptr = tr.ptr
        self.obs_img = tr.obs_image
        self.obs_kp = tr.obs_kp
        self.obs_track = tr.obs_track
        self.n_tracks = tr.num_tracks
        self.reg = np.zeros(n, bool)
        self.R = np.tile(np.eye(3), (n, 1, 1))
        self.t = np.zeros((n, 3))
        self.X = np.full((self.n_tracks, 3), np.nan)
        self.has_pt = np.zeros(self.n_tracks, bool)
        self.active = np.zeros(len(self.obs_img), bool)
        self.blocked = np.zeros(len(self.obs_img), bool)  # observations a failed loop step dropped
        self.rank = np.full(n, -1, np.int64)  # position of each image in the registration order
        self.tri_failed_at = np.zeros(self.n_tracks, np.int64)  # registered observations at the last failure
        self.trials = np.zeros(n, np.int64)
        self.tried_at = np.full(n, -1, np.int64)
        self.failures: dict[int, str] = {}
        self.order: list[int] = []
        self.ref: tuple[int, int] | None = None
        self.warnings: list[str] = []
        sc = max(float(data.scale), 1e-9)
        self.px = 1.0 / sc  # input pixels per working pixel
        self.cam_of_img = np.asarray(data.camera_of_image, np.int64)
        self.cameras = list(data.cameras)
        self.kp_offset = np.concatenate([[0], np.cumsum([len(k) for k in data.keypoints])]).astype(np.int64)
        self.obs_flat = self.kp_offset[self.obs_img] + self.obs_kp
        self.raw_kp = np.concatenate(data.keypoints) if n else np.zeros((0, 2))
        sizes = np.concatenate(data.keypoint_sizes).astype(np.float64) if n else np.zeros(0)
        if bundle.scale_weighting and len(sizes):
            med = float(np.median(sizes[sizes > 0])) if np.any(sizes > 0) else 1.0
            w = np.clip(sizes / med, 0.5, 4.0)
        else:
            w = np.ones(len(sizes))
        self.sigma_flat = w * self.px  # input pixels
        self.colors_flat = np.concatenate(data.colors) if n else np.zeros((0, 3), np.uint8)
        self.radial = [bool(bundle.refine_distortion and not np.any(c.dist[2:] != 0)) for c in self.cameras]
        if bundle.refine_distortion and not all(self.radial):
            self.warnings.append(
                "distortion refinement skipped for cameras with tangential or k3 coefficients (only k1, k2 are refined)"
            )
        self._update_normalized()
        self.stats: dict[str, Any] = {
            "pnp_attempts": 0,
            "pnp_failures": 0,
            "local_ba": 0,
            "global_ba": 0,
            "local_ba_s": 0.0,
            "global_ba_s": 0.0,
            "triangulation_s": 0.0,
            "pnp_s": 0.0,
            "filtered_observations": 0,
            "init_trials": 0,
            "loops_detected": 0,
            "loop_global_ba": 0,
            "loop_fallbacks": 0,
            "loops": [],
            "global_ba_runs": [],
        }
        self.last_global_images = 0
        self.last_global_points = 0
        self.loss_scale_px = float(bundle.loss_scale_px)  # see _follow_noise
        self.last_loop_rank = -(1 << 30)  # registration rank of the last loop handled

    # ------------------------------------------------------------------ camera model
    def _update_normalized(self) -> None:
        """Normalised undistorted coordinates of all keypoints and the pixels the adjustment uses."""
        n_all = len(self.raw_kp)
        self.xn_flat = np.zeros((n_all, 2))
        self.uv_flat = np.zeros((n_all, 2))
        img_of_kp = np.repeat(np.arange(self.n), np.diff(self.kp_offset))
        for c, cam in enumerate(self.cameras):
            sel = np.nonzero(self.cam_of_img[img_of_kp] == c)[0]
            if len(sel) == 0:
                continue
            xn = cam.normalized(self.raw_kp[sel])
            self.xn_flat[sel] = xn
            if self.radial[c]:
                self.uv_flat[sel] = self.raw_kp[sel]
            else:
                self.uv_flat[sel] = xn * [cam.fx, cam.fy] + [cam.cx, cam.cy]
        self.focal = np.array([0.5 * (self.cameras[c].fx + self.cameras[c].fy) for c in self.cam_of_img])

    def _camera_rows(self) -> np.ndarray:
        rows = []
        for c, cam in enumerate(self.cameras):
            k1, k2 = (cam.dist[0], cam.dist[1]) if self.radial[c] else (0.0, 0.0)
            rows.append([cam.fx, cam.fy, cam.cx, cam.cy, k1, k2])
        return np.array(rows, np.float64)

    def _set_camera_rows(self, rows: np.ndarray) -> bool:
        changed = False
        for c, cam in enumerate(self.cameras):
            fx, fy, _, _, k1, k2 = rows[c]
            dist = cam.dist.copy()
            if self.radial[c]:
                dist[0], dist[1] = k1, k2
            if fx != cam.fx or fy != cam.fy or np.any(dist != cam.dist):
                self.cameras[c] = Intrinsics(fx, fy, cam.cx, cam.cy, cam.width, cam.height, dist, cam.skew)
                changed = True
        if changed:
            self._update_normalized()
        return changed

    # ------------------------------------------------------------------ helpers
    def _centers(self) -> np.ndarray:
        return -np.einsum("kji,kj->ki", self.R, self.t)

    def _obs_errors(self, obs: np.ndarray) -> np.ndarray:
        """Reprojection error (input pixels, on the undistorted normalised plane x focal)."""
        if len(obs) == 0:
            return np.zeros(0)
        img = self.obs_img[obs]
        X = self.X[self.obs_track[obs]]
        P = np.einsum("kij,kj->ki", self.R[img], X) + self.t[img]
        xn = self.xn_flat[self.obs_flat[obs]]
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.hypot(P[:, 0] / P[:, 2] - xn[:, 0], P[:, 1] / P[:, 2] - xn[:, 1]) * self.focal[img]
        e[~(P[:, 2] > 0) | ~np.isfinite(e)] = np.inf
        return e

    def _remove_points(self, tracks: np.ndarray) -> None:
        if len(tracks) == 0:
            return
        self.has_pt[tracks] = False
        self.X[tracks] = np.nan
        self.active[_ranges(self.ptr, tracks)] = False
        self.tri_failed_at[tracks] = 0

    def _point_obs_counts(self, tracks: np.ndarray) -> np.ndarray:
        obs = _ranges(self.ptr, tracks)
        lens = self.ptr[tracks + 1] - self.ptr[tracks]
        seg = np.repeat(np.arange(len(tracks)), lens)
        return np.bincount(seg, weights=self.active[obs].astype(np.float64), minlength=len(tracks)).astype(
            np.int64
        )

    # ------------------------------------------------------------------ triangulation
    def _triangulate(self, tracks: np.ndarray) -> int:
        """Triangulate tracks that have no point yet from their observations in registered images."""
        t0 = time.perf_counter()
        tracks = tracks[~self.has_pt[tracks]]
        if len(tracks) == 0:
            return 0
        obs = _ranges(self.ptr, tracks)
        seg = np.repeat(np.arange(len(tracks)), self.ptr[tracks + 1] - self.ptr[tracks])
        keep = self.reg[self.obs_img[obs]] & ~self.blocked[obs]
        obs, seg = obs[keep], seg[keep]
        counts = np.bincount(seg, minlength=len(tracks))
        # skip tracks that failed before with the same registered observations, or (long
        # tracks) with less than 1/8 fewer: a far facade seen by 100+ frames of a flight would
        # otherwise be re-triangulated, and fail again, at every registration
        failed = self.tri_failed_at[tracks]
        cand = (counts >= 2) & ((counts < failed) | (counts >= failed + np.maximum(1, failed // 8)))
        if not np.any(cand):
            return 0
        sel = cand[seg]
        obs, seg = obs[sel], seg[sel]
        tracks = tracks[cand]
        counts = counts[cand]
        ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        res = triangulate_tracks(
            ptr,
            self.xn_flat[self.obs_flat[obs]],
            self.obs_img[obs],
            self.R,
            self.t,
            self.focal,
            self.s.triangulation_max_error_px * self.px,
            self.s.triangulation_min_angle_deg,
        )
        ok = res.ok
        self.tri_failed_at[tracks[~ok]] = counts[~ok]
        self.X[tracks[ok]] = res.points[ok]
        self.has_pt[tracks[ok]] = True
        self.active[obs[res.inliers]] = True
        self.stats["triangulation_s"] += time.perf_counter() - t0
        return int(ok.sum())

    def _complete(self, tracks: np.ndarray) -> int:
        """Add inactive observations in registered images that agree with existing points."""
        tracks = tracks[self.has_pt[tracks]]
        if len(tracks) == 0:
            return 0
        obs = _ranges(self.ptr, tracks)
        obs = obs[~self.active[obs] & ~self.blocked[obs] & self.reg[self.obs_img[obs]]]
        if len(obs) == 0:
            return 0
        e = self._obs_errors(obs)
        thr = min(self.s.triangulation_max_error_px, self.s.filter_max_error_px) * self.px
        good = obs[e < thr]
        self.active[good] = True
        return len(good)

    def _tracks_of_images(self, images: Sequence[int] | np.ndarray) -> np.ndarray:
        per_image = [self.d.tracks.kp_track[i] for i in images]
        t = np.concatenate(per_image) if per_image else np.zeros(0, np.int64)
        return np.unique(t[t >= 0])

    # ------------------------------------------------------------------ adjustment
    def _gauge(
        self, var_images: np.ndarray, const_images: np.ndarray, prob: BundleProblem, local_index: dict
    ) -> None:
        """Fix the similarity gauge of a problem (see the module docstring)."""
        assert self.ref is not None
        constant_images, constant_pose_coords = prob.constant_images, prob.constant_pose_coords
        assert constant_images is not None and constant_pose_coords is not None  # BundleProblem fills them
        r0, r1 = self.ref
        var_set = set(int(v) for v in var_images)
        anchor = None
        if r0 in var_set:
            constant_images[local_index[r0]] = True
            anchor = r0
        elif len(const_images) == 0:
            anchor = int(var_images[0])
            constant_images[local_index[anchor]] = True
        elif len(const_images) >= 2:
            return
        else:
            anchor = int(const_images[0])
        # scale: one translation coordinate of a second image
        second = r1 if (r1 in var_set and r1 != anchor) else None
        if second is None:
            C = self._centers()
            cand = [v for v in var_images if int(v) != anchor]
            if not cand:
                return
            second = int(max(cand, key=lambda v: np.linalg.norm(C[v] - C[anchor])))
        C = self._centers()
        d = self.R[second] @ (C[second] - C[anchor])
        k = int(np.argmax(np.abs(d)))
        constant_pose_coords[local_index[second], 3 + k] = True

    def _adjust(
        self,
        var_images: np.ndarray,
        tracks: np.ndarray,
        max_iterations: int,
        refine_intrinsics: bool,
        function_tolerance: float = 1e-6,
        write_back: bool = True,
        force_focal: bool = False,
        only_var_images: bool = False,
    ) -> tuple[BundleReport, BundleProblem]:
        """Bundle-adjust the poses of ``var_images`` and the points of ``tracks`` (observations in
        other registered images enter as constants, or are left out with ``only_var_images``).
        With ``write_back`` off the mapper's state is left as it was (a trial, e.g. the
        focal-length check)."""
        obs = _ranges(self.ptr, tracks)
        obs = obs[self.active[obs]]
        if only_var_images:
            obs = obs[np.isin(self.obs_img[obs], var_images)]
        images = np.unique(np.concatenate([self.obs_img[obs], var_images]))
        local_index = {int(im): k for k, im in enumerate(images)}
        img_local = np.searchsorted(images, self.obs_img[obs])
        pt_local = np.searchsorted(tracks, self.obs_track[obs])
        var_mask = np.isin(images, var_images)
        const_images = images[~var_mask]
        cams = self._camera_rows()
        prob = BundleProblem(
            self.R[images].copy(),
            self.t[images].copy(),
            self.X[tracks].copy(),
            cams,
            self.cam_of_img[images],
            img_local,
            pt_local,
            self.uv_flat[self.obs_flat[obs]],
            self.sigma_flat[self.obs_flat[obs]],
            constant_images=~var_mask,
        )
        self._gauge(images[var_mask], const_images, prob, local_index)
        opts = BundleSolverOptions(
            loss=self.b.loss,
            loss_scale=self.loss_scale_px,
            max_iterations=max_iterations,
            function_tolerance=function_tolerance,
            refine_focal_length=force_focal or (refine_intrinsics and self.b.refine_focal_length),
            refine_distortion=refine_intrinsics and self.b.refine_distortion and any(self.radial),
        )
        rep = bundle_adjust(prob, opts)
        if not write_back:
            return rep, prob
        self.R[images] = prob.R
        self.t[images] = prob.t
        self.X[tracks] = prob.points
        if opts.refine_focal_length or opts.refine_distortion:
            self._set_camera_rows(prob.cameras)
        return rep, prob

    def _filter(self, tracks: np.ndarray, check_angle: bool) -> int:
        """Deactivate observations with large errors; drop points left with < 2 observations or
        (``check_angle``) too small a triangulation angle."""
        tracks = tracks[self.has_pt[tracks]]
        if len(tracks) == 0:
            return 0
        obs = _ranges(self.ptr, tracks)
        obs = obs[self.active[obs]]
        e = self._obs_errors(obs)
        bad = obs[~(e <= self.s.filter_max_error_px * self.px)]
        self.active[bad] = False
        n_removed = len(bad)
        cnt = self._point_obs_counts(tracks)
        drop = tracks[cnt < 2]
        if check_angle:
            keep = tracks[cnt >= 2]
            ang = self._angles(keep, self.s.filter_min_angle_deg)
            drop = np.concatenate([drop, keep[ang < self.s.filter_min_angle_deg]])
        self._remove_points(drop)
        self.stats["filtered_observations"] += n_removed
        return n_removed

    def _angles(self, tracks: np.ndarray, enough_deg: float = np.inf) -> np.ndarray:
        """Largest triangulation angle of each track's point (a bound on the same side of a
        finite ``enough_deg``, see ``max_triangulation_angles_deg``)."""
        obs = _ranges(self.ptr, tracks)
        lens = self.ptr[tracks + 1] - self.ptr[tracks]
        ptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        return max_triangulation_angles_deg(
            ptr, self.X[tracks], self.obs_img[obs], self._centers(), self.active[obs], enough_deg
        )

    def _local_ba(self, image: int) -> None:
        t0 = time.perf_counter()
        my_tracks = self.d.tracks.kp_track[image]
        my_tracks = np.unique(my_tracks[my_tracks >= 0])
        my_tracks = my_tracks[self.has_pt[my_tracks]]
        obs = _ranges(self.ptr, my_tracks)
        obs = obs[self.active[obs]]
        shared = np.bincount(self.obs_img[obs], minlength=self.n)
        shared[image] = 0
        shared[~self.reg] = 0
        nb = np.argsort(-shared, kind="stable")[: self.s.local_ba_images - 1]
        nb = nb[shared[nb] > 0]
        var_images = np.unique(np.concatenate([[image], nb])).astype(np.int64)
        tracks = self._tracks_of_images(var_images)
        tracks = tracks[self.has_pt[tracks]]
        if len(tracks) == 0:
            return
        for _ in range(2):
            tracks = tracks[self.has_pt[tracks]]
            if len(tracks) == 0:
                break
            _ = self._adjust(
                var_images, tracks, self.b.local_max_iterations, False, self.b.local_function_tolerance
            )
            n_bad = self._filter(tracks, check_angle=False)
            n_new = self._complete(tracks)
            if n_bad + n_new == 0:
                break
        self.stats["local_ba"] += 1
        self.stats["local_ba_s"] += time.perf_counter() - t0

    def _noise_px(self) -> float:
        """Robust per-axis noise of the active observations (working pixels, each residual
        divided by its observation's sigma), from the median residual and corrected for the
        degrees of freedom the poses and points take; 0 with too few observations."""
        obs = np.nonzero(self.active)[0]
        dof = 2 * len(obs) - 3 * int(self.has_pt.sum()) - 6 * int(self.reg.sum())
        if len(obs) < 100 or dof <= 0:
            return 0.0
        r = self._obs_errors(obs) / self.sigma_flat[self.obs_flat[obs]]
        r = r[np.isfinite(r)]
        if len(r) == 0:
            return 0.0
        # the median norm of a 2D Gaussian residual is 1.1774 sigma
        return float(np.median(r) / 1.1774 * np.sqrt(2 * len(obs) / dof))

    def _follow_noise(self) -> None:
        """The robust loss's scale: ``BundleSettings.loss_scale_px``, or the model's measured
        keypoint noise when that is larger. A scale far below the noise treats most good
        observations as outliers, and a long chain of weakly constrained views can then
        collapse (its baselines shrink towards zero) instead of fitting them."""
        self.loss_scale_px = max(float(self.b.loss_scale_px), self._noise_px())
        self.stats["loss_scale_px"] = self.loss_scale_px

    def _global_ba(
        self,
        rounds: int = 1,
        max_iterations: int | None = None,
        final: bool = False,
        function_tolerance: float | None = None,
    ) -> BundleReport | None:
        """Global adjustment of every registered image and point, ``rounds`` times with
        filtering, track completion and re-triangulation in between. Rounds stop at
        ``function_tolerance`` (default ``BundleSettings.global_function_tolerance``); the last
        round of the ``final`` refinement at ``final_function_tolerance``."""
        t0 = time.perf_counter()
        rep = None
        self._follow_noise()
        round_iterations: list[int] = []
        solve_s, n_obs_adjusted = 0.0, []
        settled = False  # a final round changed too little: the next one is the last
        if function_tolerance is None:
            function_tolerance = self.b.global_function_tolerance
        for r in range(rounds):
            tracks = np.nonzero(self.has_pt)[0]
            if len(tracks) == 0:
                break
            var_images = np.nonzero(self.reg)[0]
            n_obs_before = int(self.active.sum())
            last = final and (r == rounds - 1 or settled)
            # rounds before the last are followed by filtering and re-triangulation: only the
            # last one converges to the final tolerance
            rep, prob = self._adjust(
                var_images,
                tracks,
                max_iterations or self.b.global_max_iterations,
                True,
                self.b.final_function_tolerance if last else function_tolerance,
            )
            n_obs_adjusted.append(len(prob.obs_image))
            round_iterations.append(rep.iterations)
            solve_s += rep.seconds
            self._filter(tracks, check_angle=True)
            all_tracks = np.arange(self.n_tracks)
            self._complete(all_tracks)
            self._triangulate(all_tracks)
            change = abs(int(self.active.sum()) - n_obs_before) / max(1, n_obs_before)
            if r > 0 and change < 5e-4:
                if last or not final:
                    break
                settled = True
        self.stats["global_ba"] += 1
        self.stats["global_ba_s"] += time.perf_counter() - t0
        self.stats["global_ba_runs"].append(
            {
                "images": int(self.reg.sum()),
                "rounds": rounds,
                "final": final,
                "iterations": sum(round_iterations),
                "round_iterations": round_iterations,
                "observations": n_obs_adjusted,
                "solver_s": round(solve_s, 3),
                "seconds": round(time.perf_counter() - t0, 3),
            }
        )
        self.last_global_images = int(self.reg.sum())
        self.last_global_points = int(self.has_pt.sum())
        return rep

    # ------------------------------------------------------------------ initialisation
    def _init_candidates(self) -> list[PairGeometry]:
        posed = [p for p in self.d.pairs if p.status == "ok" and self.d.usable[p.i] and self.d.usable[p.j]]
        ok = [p for p in posed if p.num_inliers >= self.s.init_min_inliers]
        if not ok:  # small or weak images: try the best pairs down to half the matches, and say so
            floor = self._init_inliers_floor
            ok = [p for p in posed if p.num_inliers >= floor]
            if ok:
                best = max(p.num_inliers for p in ok)
                self.warnings.append(
                    f"no image pair has the {self.s.init_min_inliers} verified matches an initial pair "
                    f"needs (the best has {best}): started from a weaker pair (at least {floor}); "
                    "check the model, or give larger images"
                )
        seen: set[tuple[int, int]] = set()
        out: list[PairGeometry] = []
        stages = [
            (self.s.init_min_parallax_deg, self.s.init_max_homography_ratio),
            (self.s.init_min_parallax_deg / 2, 0.95),
            (self.s.init_min_parallax_deg / 4, 1.01),
            (0.0, 1.01),
        ]
        ok.sort(key=lambda p: (-p.num_inliers, p.i, p.j))
        for par, hr in stages:
            for p in ok:
                if len(out) >= self.s.init_max_trials:
                    return out
                if (p.i, p.j) in seen or p.median_parallax_deg < par or self._homography_ratio(p) > hr:
                    continue
                seen.add((p.i, p.j))
                out.append(p)
        return out

    @property
    def _init_inliers_floor(self) -> int:
        """Verified matches an initial pair needs when no pair has ``init_min_inliers``."""
        return max(INIT_MIN_INLIERS_FLOOR, self.s.init_min_inliers // 2)

    def _homography_ratio(self, p: PairGeometry) -> float:
        """Share of a pair's inliers a homography explains (computed once, on demand)."""
        if np.isfinite(p.homography_ratio):
            return p.homography_ratio
        x1 = self.d.keypoints[p.i][p.matches[:, 0]]
        x2 = self.d.keypoints[p.j][p.matches[:, 1]]
        try:
            he = estimate_homography(
                x1,
                x2,
                RansacOptions(
                    threshold=3.0 * self.px,
                    confidence=0.99,
                    max_iterations=300,
                    min_iterations=16,
                    local_optimization=False,
                ),
                self.seed + 17 * p.i + p.j,
            )
            p.homography_ratio = he.num_inliers / max(1, p.num_inliers)
        except EstimationError:
            p.homography_ratio = 0.0
        return p.homography_ratio

    def _try_init(self, p: PairGeometry) -> str:
        """Initialise from a pair; returns "" on success, else why not (state is reset)."""
        if p.R is None or p.t is None:
            return "the pair has no relative pose"
        a, b = p.i, p.j
        self.R[a], self.t[a] = np.eye(3), np.zeros(3)
        self.R[b], self.t[b] = p.R, p.t / np.linalg.norm(p.t)
        self.reg[[a, b]] = True
        self.rank[[a, b]] = [0, 1]
        self.ref = (a, b)
        tracks = self._tracks_of_images([a, b])
        n_tri = self._triangulate(tracks)
        if n_tri < self.s.init_min_points:
            self._reset()
            return f"only {n_tri} points could be triangulated"
        self._global_ba(rounds=2)
        n_pts = int(self.has_pt.sum())
        if n_pts < self.s.init_min_points:
            self._reset()
            return f"only {n_pts} points survived the adjustment"
        return ""

    def _reset(self) -> None:
        self.tri_failed_at[:] = 0
        self.reg[:] = False
        self.has_pt[:] = False
        self.active[:] = False
        self.X[:] = np.nan
        self.ref = None

    def initialize(self) -> tuple[int, int]:
        """Choose and reconstruct the initial pair.

        Raises:
            EstimationError: no pair can start the reconstruction (the message lists why).
        """
        cands = self._init_candidates()
        reasons = []
        for p in cands[: self.s.init_max_trials]:
            self.stats["init_trials"] += 1
            why = self._try_init(p)
            if not why:
                self.order = [p.i, p.j]
                self.stats["init_pair_inliers"] = p.num_inliers
                self.stats["init_pair_parallax_deg"] = p.median_parallax_deg
                return p.i, p.j
            reasons.append(f"{self.d.names[p.i]} + {self.d.names[p.j]}: {why}")
        n_ok = sum(1 for p in self.d.pairs if p.status == "ok")
        best = max((p.num_inliers for p in self.d.pairs if p.status == "ok"), default=0)
        msg = (
            f"cannot start the reconstruction: {n_ok} image pairs have a relative pose"
            f" (the best with {best} inlier matches; an initial pair needs {self.s.init_min_inliers}, or"
            f" {self._init_inliers_floor} when no pair has that)"
        )
        if reasons:
            msg += "; tried " + "; ".join(reasons[:5])
        n_rot = sum(1 for p in self.d.pairs if p.status == "no_translation")
        if n_rot:
            msg += f"; {n_rot} pairs show no parallax (camera only rotated, or identical images)"
        raise EstimationError(
            msg + ". Check that the images overlap, show a textured 3D scene and that K is right"
        )

    # ------------------------------------------------------------------ registration
    def _visible_counts(self) -> np.ndarray:
        sel = self.has_pt[self.obs_track]
        return np.bincount(self.obs_img[sel], minlength=self.n)

    def _register(self, image: int) -> bool:
        t0 = time.perf_counter()
        self.stats["pnp_attempts"] += 1
        kt = self.d.tracks.kp_track[image]
        kps = np.nonzero(kt >= 0)[0]
        kps = kps[self.has_pt[kt[kps]]]
        obs = self.d.tracks.kp_obs[image][kps]
        n_corr = len(kps)
        self.trials[image] += 1
        self.tried_at[image] = int(self.has_pt.sum())
        flat = self.kp_offset[image] + kps
        try:
            pose = estimate_absolute_pose(
                self.xn_flat[flat],
                self.X[kt[kps]],
                float(self.focal[image]),
                self.s.pnp_threshold_px * self.px,
                seed=self.seed * 7919 + image * 31 + int(self.trials[image]),
                min_inliers=self.s.pnp_min_inliers,
                refine_loss_scale_px=self.loss_scale_px * self.px,
                sigmas_px=self.sigma_flat[flat],
            )
        except EstimationError as exc:
            self.failures[image] = f"could not be registered: {exc}"
            self.stats["pnp_failures"] += 1
            self.stats["pnp_s"] += time.perf_counter() - t0
            return False
        if pose.inlier_ratio < self.s.pnp_min_inlier_ratio:
            self.failures[image] = (
                f"could not be registered: only {pose.num_inliers} of {n_corr} 2D-3D correspondences "
                f"({100 * pose.inlier_ratio:.0f}%) agree on a pose"
            )
            self.stats["pnp_failures"] += 1
            self.stats["pnp_s"] += time.perf_counter() - t0
            return False
        self.R[image], self.t[image] = pose.R, pose.t
        self.reg[image] = True
        self.active[obs[pose.inliers]] = True
        self.failures.pop(image, None)
        self.rank[image] = len(self.order)
        self.order.append(image)
        self.stats["pnp_s"] += time.perf_counter() - t0
        return True

    def _along_flight(self) -> np.ndarray:
        """(n,) bool: frames with a registered frame within ``sequence_reach`` of them in the
        flight (all True for unordered photos)."""
        reach = int(self.d.sequence_reach)
        if reach <= 0:
            return np.ones(self.n, bool)
        c = np.concatenate([[0], np.cumsum(self.reg)])
        idx = np.arange(self.n)
        lo, hi = np.maximum(idx - reach, 0), np.minimum(idx + reach + 1, self.n)
        return c[hi] - c[lo] > 0

    def _next_candidates(self) -> list[int]:
        """Unregistered images to try next: most visible points first; for a flight, frames near
        registered frames before those only loop pairs reach (a loop pair between look-alike
        streets would otherwise place a frame, and the flight after it, in the wrong street)."""
        cnt = self._visible_counts()
        n_pts = int(self.has_pt.sum())
        cand = []
        for i in np.lexsort((-cnt, ~self._along_flight())):
            i = int(i)
            if self.reg[i] or not self.d.usable[i] or cnt[i] < self.s.pnp_min_inliers:
                continue
            if (
                self.trials[i] >= self.s.max_registration_trials
                and self.tried_at[i] >= 0
                and n_pts <= 1.05 * self.tried_at[i]
            ):
                continue
            if self.tried_at[i] == n_pts:  # nothing changed since the last attempt
                continue
            cand.append(i)
        return cand

    def _after_registration(self, image: int) -> None:
        tracks = self._tracks_of_images([image])
        self._complete(tracks)
        self._triangulate(tracks)
        self._local_ba(image)
        loop_tracks = self._loop_tracks(image)
        if len(loop_tracks) >= self.s.loop_min_points:
            self._close_loop(image, loop_tracks)
            return
        n_reg = int(self.reg.sum())
        n_pts = int(self.has_pt.sum())
        if (
            n_reg >= self.s.global_ba_ratio * self.last_global_images
            or n_pts >= self.s.global_ba_ratio** 2 * max(1, self.last_global_points)
        ):
            self._global_ba(
                rounds=1,
                max_iterations=min(self.b.global_max_iterations, 30),
                function_tolerance=self.b.periodic_function_tolerance,
            )

    # ------------------------------------------------------------------ loops
    def _loop_tracks(self, image: int) -> np.ndarray:
        """Points ``image`` sees that had not been seen for at least ``loop_min_gap`` registrations
        before (a revisit: the track's registration ranks jump by the gap or more). At most one
        loop is handled per ``loop_min_gap`` registrations."""
        gap = self.s.loop_min_gap
        if gap <= 0 or len(self.order) <= gap or self.rank[image] - self.last_loop_rank < gap:
            return np.zeros(0, np.int64)  # too early, or a loop was handled less than a gap ago
        kt = self.d.tracks.kp_track[image]
        obs_mine = self.d.tracks.kp_obs[image][kt >= 0]
        tracks = self.obs_track[obs_mine[self.active[obs_mine]]]
        tracks = np.unique(tracks[self.has_pt[tracks]])
        if len(tracks) < self.s.loop_min_points:
            return np.zeros(0, np.int64)
        obs = _ranges(self.ptr, tracks)
        obs = obs[self.active[obs]]
        rank = self.rank[self.obs_img[obs]]
        seg = np.searchsorted(tracks, self.obs_track[obs])
        order = np.lexsort((rank, seg))
        r, sg = rank[order], seg[order]
        jump = (sg[1:] == sg[:-1]) & (np.diff(r) >= gap)
        return tracks[np.unique(sg[1:][jump])]

    def _robust_rms(self, obs: np.ndarray) -> float:
        """RMS reprojection error of ``obs`` (input pixels), each clipped at the triangulation
        threshold (observations of removed points count as clipped)."""
        if len(obs) == 0:
            return 0.0
        e = np.minimum(self._obs_errors(obs), self.s.triangulation_max_error_px * self.px)
        return float(np.sqrt(np.mean(e * e)))

    def _close_loop(self, image: int, loop_tracks: np.ndarray) -> None:
        """A loop closed at ``image``: unless its points already fit all their views
        (``loop_consistent_error_ratio``), adjust the whole model at once (so the correction spreads
        over the loop) and keep the result only if the observations the model had before the
        loop do not fit much worse; otherwise restore the model, drop the loop's observations in
        ``image`` and say so (``stats["loops"]``, a warning)."""
        self.stats["loops_detected"] += 1
        self.last_loop_rank = int(self.rank[image])
        cameras = list(self.cameras)
        old = np.nonzero(self.active & (self.obs_img != image))[0]
        rms_before = self._robust_rms(old)
        loop_obs = _ranges(self.ptr, loop_tracks)
        rms_loop = self._robust_rms(loop_obs[self.active[loop_obs]])
        record = {
            "image": self.d.names[image],
            "points": int(len(loop_tracks)),
            "loop_rms_px": rms_loop,
            "rms_before_px": rms_before,
            "rms_after_px": rms_before,
            "adjusted": False,
            "accepted": True,
            "seconds": 0.0,
        }
        self.stats["loops"].append(record)
        ratio = self.s.loop_consistent_error_ratio
        if ratio > 0 and rms_loop <= ratio * rms_before:
            return  # the loop's points already fit every view of them: no drift to spread
        snapshot = (
            self.R.copy(),
            self.t.copy(),
            self.X.copy(),
            self.has_pt.copy(),
            self.active.copy(),
            self.tri_failed_at.copy(),
        )
        t0 = time.perf_counter()
        self._global_ba(rounds=1, max_iterations=self.b.global_max_iterations)
        self.stats["loop_global_ba"] += 1
        rms_after = self._robust_rms(old)
        accepted = rms_after <= self.s.loop_max_error_ratio * rms_before + 1e-9
        record.update(
            rms_after_px=rms_after, adjusted=True, accepted=bool(accepted), seconds=time.perf_counter() - t0
        )
        if accepted:
            return
        self.R, self.t, self.X, self.has_pt, self.active, self.tri_failed_at = snapshot
        if cameras != self.cameras:
            self.cameras = cameras
            self._update_normalized()
        obs = _ranges(self.ptr, loop_tracks)
        drop = obs[self.obs_img[obs] == image]
        self.active[drop] = False
        self.blocked[drop] = True
        self.stats["loop_fallbacks"] += 1
        self.warnings.append(
            f"loop closure at {self.d.names[image]} undone: the adjustment raised the reprojection error "
            f"from {rms_before:.2f} to {rms_after:.2f} px; its {len(loop_tracks)} loop points were dropped"
        )

    def register_all(self) -> None:
        """Register images until none more can be."""
        while True:
            progressed = False
            for i in self._next_candidates()[:8]:
                if self._register(i):
                    self._after_registration(i)
                    progressed = True
                    break
            if not progressed:
                break

    # ------------------------------------------------------------------ run
    def run(self) -> MapperOutput:
        """Initialise, register everything possible, refine; see :class:`MapperOutput`."""
        t0 = time.perf_counter()
        init = self.initialize()
        self.register_all()
        for _ in range(2):
            self._global_ba(rounds=self.s.final_refinements, final=True)
            before = int(self.reg.sum())
            self.trials[:] = 0
            self.register_all()
            if int(self.reg.sum()) == before:
                break
        self._focal_check()
        self.stats["mapper_s"] = time.perf_counter() - t0
        return self._output(init)

    def _focal_check(self) -> None:
        """With the focal length held fixed, find the focal length the model fits best (a trial
        adjustment that changes nothing) and warn when it differs from K's noticeably."""
        tol = self.s.focal_check_tolerance
        if tol <= 0 or self.b.refine_focal_length or self.reg.sum() < 3:
            return
        images = np.nonzero(self.reg)[0]
        step = -(-len(images) // max(3, self.s.focal_check_images))
        if step > 1:  # a thinned model (every step-th image, points it sees at least 3 times)
            images = images[::step]
            obs = np.nonzero(self.active & np.isin(self.obs_img, images))[0]
            cnt = np.bincount(self.obs_track[obs], minlength=self.n_tracks)
            tracks = np.nonzero(self.has_pt & (cnt >= 3))[0]
        else:
            tracks = np.nonzero(self.has_pt)[0]
        if len(tracks) < 20:
            return
        rep, prob = self._adjust(
            images, tracks, 20, False, 1e-5, write_back=False, force_focal=True, only_var_images=True
        )
        self.stats["focal_check_images"] = int(len(images))
        for c, cam in enumerate(self.cameras):
            f_fit = float(prob.cameras[c, 0])
            ratio = f_fit / cam.fx
            self.stats.setdefault("focal_fit_ratio", {})[c] = ratio
            if abs(ratio - 1.0) > tol:
                self.warnings.append(
                    f"the focal length in K seems off: the reconstruction fits best with fx = {f_fit:.1f} px instead "
                    f"of {cam.fx:.1f} px ({100 * (ratio - 1):+.1f}%); check K (image size, lens, zoom) or refine "
                    "the focal length (BundleSettings.refine_focal_length)"
                )

    def _output(self, init: tuple[int, int] | None) -> MapperOutput:
        obs = np.nonzero(self.active)[0]
        err = np.full(len(self.active), np.nan)
        err[obs] = self._obs_errors(obs)
        cnt = np.bincount(self.obs_track[obs], minlength=self.n_tracks)
        col = np.zeros((self.n_tracks, 3))
        np.add.at(col, self.obs_track[obs], self.colors_flat[self.obs_flat[obs]].astype(np.float64))
        colors = np.clip(np.round(col / np.maximum(cnt, 1)[:, None]), 0, 255).astype(np.uint8)
        failures = {}
        counts = self._visible_counts()
        partners: dict[int, set[int]] = {}
        for p in self.d.pairs:
            if p.status != "failed":
                partners.setdefault(p.i, set()).add(p.j)
                partners.setdefault(p.j, set()).add(p.i)
        for i in range(self.n):
            if self.reg[i] or not self.d.usable[i]:
                continue
            if i in self.failures:
                failures[i] = self.failures[i]
            elif not partners.get(i):
                failures[i] = "no verified matches with any other image (no overlap, or too little texture)"
            elif not any(self.reg[j] for j in partners[i]):
                names = ", ".join(self.d.names[j] for j in sorted(partners[i])[:5])
                failures[i] = f"matched only to images that are not in the model ({names})"
            else:
                failures[i] = (
                    f"only {int(counts[i])} of its features see reconstructed 3D points "
                    f"(at least {self.s.pnp_min_inliers} needed)"
                )
        diag = dict(self.stats)
        diag.update(
            num_registered=int(self.reg.sum()),
            num_points=int(self.has_pt.sum()),
            num_observations=int(len(obs)),
            mean_track_length=float(len(obs) / max(1, int(self.has_pt.sum()))),
            mean_reprojection_error_px=float(np.mean(err[obs])) if len(obs) else float("nan"),
        )
        return MapperOutput(
            self.reg.copy(),
            self.R.copy(),
            self.t.copy(),
            list(self.cameras),
            self.X.copy(),
            self.has_pt.copy(),
            self.active.copy(),
            colors,
            err,
            failures,
            init,
            diag,
            list(self.warnings),
            list(self.order),
        )
