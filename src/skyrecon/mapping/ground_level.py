"""Plain ground from stereo: the ground level learnt over a flight, and the guesses that lie on it.

A stereo matcher measures almost nothing on a plain road or square seen from a drone: only the
kerbs, the feet of walls and poles, and the odd marking. Its smoothed values over the plain
ground are guesses (:class:`~skyrecon.mapping.frame_support.FrameSupport`), too noisy to be
depth (a median error of about 0.4 pixel, a metre at 17 m), and the guesses alone become hits
only next to an occupied voxel, so a plain street stays unknown in the map.

But the ground is one surface the whole flight measures in pieces, and the drone knows which way
is down. :class:`GroundLevel` keeps a histogram of the world height of every trusted depth pixel
whose ray points down (the feet of every wall, kerb and pole it has seen) and takes the ground as
the *lowest* well-supported level (:func:`lowest_level`): roofs and terraces are higher levels,
and stereo noise below the ground is spread thin; the level is then drawn halfway towards that
of the measured pixels alone, as plain ground filled with fitted planes errs low and the measured
ground high (:attr:`GroundSettings.measured_share`). Then, per frame, a guessed pixel is a ground
pixel when its guess agrees with the disparity the ground plane would have there
(``|d_guess - d_plane| <= tolerance``); its depth is the plane's, exact up to the level's
error, not the guess's. The ground pixels go to a :class:`FrameSupport` as hits only (never free
space), once two frames agree on a voxel and not in a voxel trusted rays found free.

Safe by construction: a guess on a plain object standing on the ground (a container, a bus) that
happens to agree with the ground plane adds a hit on the ground behind or under it, never free
space in front; a wrong level (no ground seen yet, sloping terrain) makes guesses disagree, and
nothing is added. The level is a flat-ground model: for terrain that slopes by more than the
tolerance over the flight the guesses disagree with it and the street stays unknown, as before.

Frames and units: world frame z up, metres; depth (H, W) float32 metres along the camera's
optical axis; disparity ``d = f B / Z - doffs`` pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.mapping.inputs import as_world_from_cam
from skyrecon.mapping.rays import camera_rays

_LEVEL_STEP = 4  # every 4th pixel of each row and column counts towards the level
_FARTHEST_FACTOR = 4.0  # depth beyond this many times the range (weight under 1/16) is not counted
_FARTHEST_M = 1000.0  # nor beyond this, metres (keeps the histogram small)
_DOWN = np.array([0.0, 0.0, -1.0])  # world
_MIN_MEASURED_SHARE = 0.01  # measured pixels near the level, of every pixel there, to move it


def lowest_level(
    heights_m: np.ndarray,
    weights: np.ndarray,
    bin_m: float,
    min_share: float,
    window_m: float,
    prominence: float = 1.5,
    prominence_m: float = 0.5,
    prominence_above: float = 1.2,
) -> float | None:
    """The lowest well-supported level of a height histogram, metres, or None.

    Args:
        heights_m: (K,) bin centres, ascending, metres; weights: (K,) counts per bin.
        bin_m: bin width, metres.
        min_share: a level needs at least this share of the strongest level's count (smoothed
            over 5 bins).
        window_m: the level is the weighted mean of the bins within this distance of its peak.
        prominence: ... and at least this many times the (smoothed) count ``prominence_m``
            metres below it: a horizontal surface is a peak, a wall seen from above a plateau
            (its every height is as common as the next), and nothing should lie under the
            ground but noise ...
        prominence_above: ... and this many times the count ``prominence_m`` metres above
            it: walls rising from the ground make a plateau above the ground's peak (on plain
            streets, where the matcher measures little but the feet of walls, the peak stood
            1.39x above it in one flight and no level was found for 30 of 40 frames).
        prominence_m: see ``prominence``, metres.
    """
    if weights.sum() <= 0:
        return None
    smooth = np.convolve(np.pad(weights, 2), np.ones(5) / 5.0, mode="valid")  # len(weights), any length
    prev = np.concatenate([[-1.0], smooth[:-1]])
    nxt = np.concatenate([smooth[1:], [-1.0]])
    k = max(1, int(round(prominence_m / bin_m)))
    padded = np.pad(smooth, k)
    below, above = padded[: len(smooth)], padded[2 * k :]  # the counts k bins below and above
    peaks = np.nonzero(
        (smooth >= prev)
        & (smooth > nxt)
        & (smooth >= min_share * smooth.max())
        & (smooth >= prominence * below)
        & (smooth >= prominence_above * above)
    )[0]
    if len(peaks) == 0:
        return None
    p = int(peaks[0])
    near = np.abs(heights_m - heights_m[p]) <= window_m + 1e-9
    w = weights[near]
    return float(np.sum(heights_m[near] * w) / w.sum()) if w.sum() > 0 else None


@dataclass(frozen=True)
class GroundSettings:
    """How plain ground is found (see the module docstring).

    Attributes:
        min_down_cos: only rays at least this steep downwards count (cosine between the ray and
            straight down): a ray along the horizon meets the ground too far off to tell.
        bin_m: height histogram bin, metres.
        min_share: a level needs this share of the strongest level's support.
        min_points: trusted pixels counted (every second one of each row and column) before
            the level is used.
        tolerance_px: a guess agrees with the ground plane within this disparity, pixels ...
        tolerance_rel: ... plus this fraction of the plane's disparity.
        below_voxels: the hits go this many map voxels below the level, into the ground (see
            :meth:`GroundLevel.ground_depth`).
        beyond_trusted: ground pixels count up to twice the rig's trusted range (within the
            map's range) rather than the trusted range: their depth is the plane's, not the
            matcher's (the guess only has to agree with it), so it does not grow noisy with
            range the way measured depth does. On plain seed 4 of the stereo map benchmark
            this took the street voxels observed within 20 m from 0.56 to 0.89 (most are seen
            within 20 m in only a frame or two, after several frames from farther away), and
            the far ground hits were right 99.8 % of the time.
        measured_share, measured_search_m: the level found on every counted pixel is moved
            this share of the way to the level of the *measured* pixels alone (the peak of
            their own histogram within ``measured_search_m`` metres of it; given which pixels
            took a fitted plane, :meth:`GroundLevel.add`'s ``fitted``). The two populations
            err in opposite directions: plain ground the plane fill covered outnumbers the
            measured ground several times, and its planes come out flatter in disparity than
            the ground (the nearest pixels of a segment too far, the farthest too near; the
            nearest weigh the most), which put the level 0.14-0.27 m low under 1.5-3 grey
            levels of camera noise on plain seeds 1, 3, 7, 11 and 13 of the stereo map
            benchmark (-0.26 m on seed 13: its hits went into the voxel layer under the
            street); the measured pixels include the feet of walls and poles and put it 0.05-
            0.35 m high. Halfway, the flight's last level lay within 0.11 m of the true ground
            on plain seeds 1, 3, 4, 5, 7, 11, 13 and 23 at 0, 1.5 and 3 grey levels, and
            within -0.06 to +0.25 m on seeds 2, 6, 8, 9 and 10, which were not looked at while
            choosing it (+0.25: seed 6 at 3 grey levels, +0.15 before). In the benchmark's map
            (1.5 grey levels) seed 13's precision on the surface went 0.374 -> 0.769 (its
            ground hits back in the street's voxel layer), seed 5's 0.788 -> 0.820, the other
            seeds' figures moved by at most 0.004; noise-free by at most 0.006. The peak itself
            is still found on every pixel: the measured ones alone are too few to tell the
            ground from a roof in the first frames (a 9-10 m "ground" on seeds 1 and 13).
            0: the level of every pixel, as before session 59.
    """

    min_down_cos: float = 0.2
    bin_m: float = 0.1
    min_share: float = 0.15
    min_points: int = 500
    tolerance_px: float = 1.0
    tolerance_rel: float = 0.1
    below_voxels: float = 0.5
    beyond_trusted: bool = True
    measured_share: float = 0.5
    measured_search_m: float = 0.5

    def __post_init__(self) -> None:
        if not (0 < self.min_down_cos < 1 and self.bin_m > 0 and 0 < self.min_share <= 1):
            raise InputError("ground settings: need 0 < min_down_cos < 1, bin_m > 0, 0 < min_share <= 1")
        if self.tolerance_px < 0 or self.tolerance_rel < 0 or self.min_points < 1:
            raise InputError("ground settings: tolerances must be >= 0 and min_points >= 1")
        if not (0 <= self.below_voxels <= 1):
            raise InputError("ground settings: below_voxels must be in [0, 1]")
        if not (0 <= self.measured_share <= 1) or self.measured_search_m < 0:
            raise InputError("ground settings: measured_share must be in [0, 1], measured_search_m >= 0")


class GroundLevel:
    """The world height of the ground, learnt from trusted depth over a flight.

    Args:
        settings: :class:`GroundSettings`.
        max_range_m: depth counts with weight 1 up to this range (from the camera, metres),
            and less beyond it (weight ``(max_range_m / range)^2``: stereo depth error grows
            with the square of the range, and far depth too far would put the ground low).
    Attributes:
        z_m: the ground's world height, metres, or None until enough has been seen.
        levels: ``z_m`` after each frame :meth:`add` counted, in order (None: none yet), so
            that a frame can be judged with the level of the frames before it whatever has been
            added since (:class:`~skyrecon.mapping.StereoMapper` integrates a frame while the
            next one is matched).
    """

    def __init__(self, settings: GroundSettings | None = None, max_range_m: float = np.inf):
        self.settings = settings or GroundSettings()
        self.max_range_m = float(max_range_m)
        self._lo_bin = 0
        self._counts = np.zeros(0, np.float64)
        self._measured: np.ndarray | None = np.zeros(0, np.float64)  # the measured pixels' counts
        self._split = False  # whether any frame said which of its pixels were fitted planes
        self._n = 0
        self.z_m: float | None = None
        self.levels: list[float | None] = []

    def level_after(self, frames: int) -> float | None:
        """The level as it was once the first ``frames`` frames were added, metres (None
        before that many, or while no level was found then). Not the last level found before
        it: the lowest peak of the histogram loses its prominence for a few frames now and
        then, and a stale level taken then put ground hits on far roofs (noisy plain seed 1
        of ``benchmarks/mapping/stereo_map.py``: precision beyond 20 m 0.998 -> 0.849)."""
        return self.levels[frames - 1] if 0 < frames <= len(self.levels) else None

    def __setstate__(self, state: dict) -> None:
        """Unpickle (a checkpoint's level); one pickled before it kept ``levels`` has none."""
        self.__dict__.update(state)
        self.__dict__.setdefault("levels", [])
        self.__dict__.setdefault("_measured", None)  # nor the measured pixels' own counts
        self.__dict__.setdefault("_split", False)

    @staticmethod
    def _rays_down(intrinsics: Intrinsics, pose: Rigid3, step: int) -> tuple[np.ndarray, np.ndarray]:
        """(H', W') lengths of the rays of every ``step``-th pixel (directions with z = 1), and
        (H', W') the metres down (world) per metre of depth along each."""
        dirs, lengths = camera_rays(intrinsics, step)
        return lengths, dirs @ (pose.R.T @ _DOWN)

    def add(
        self,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        fitted: np.ndarray | None = None,
    ) -> None:
        """Count the world heights of one frame's trusted depth (H, W) (metres, NaN none);
        ``fitted``: optional (H, W) bool, its pixels whose depth is a fitted plane's rather
        than measured (:attr:`~skyrecon.perception.DepthFrame.from_plane`; see
        :attr:`GroundSettings.measured_share`)."""
        self._add(depth_m, intrinsics, world_from_cam, fitted)
        self.levels.append(self.z_m)

    def _grow(self, lo: int, hi: int) -> None:
        """Make the histograms hold bins ``lo..hi`` (bin indices)."""
        if len(self._counts) == 0:
            self._lo_bin, self._counts = lo, np.zeros(hi - lo + 1)
            self._measured = np.zeros(hi - lo + 1)
            return
        new_lo = min(lo, self._lo_bin)
        new_hi = max(hi, self._lo_bin + len(self._counts) - 1)
        at = self._lo_bin - new_lo
        grown = np.zeros((2, new_hi - new_lo + 1))
        grown[0, at : at + len(self._counts)] = self._counts
        if self._measured is not None:
            grown[1, at : at + len(self._measured)] = self._measured
        self._lo_bin, self._counts = new_lo, grown[0]
        self._measured = None if self._measured is None else grown[1]

    def _add(
        self,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        fitted: np.ndarray | None,
    ) -> None:
        pose = as_world_from_cam(world_from_cam)
        k = _LEVEL_STEP  # a histogram needs no full resolution
        norm, down = self._rays_down(intrinsics, pose, k)
        depth = np.asarray(depth_m, np.float64)[::k, ::k]
        with np.errstate(invalid="ignore"):
            ok = down >= self.settings.min_down_cos * norm
            ok &= depth * norm <= min(_FARTHEST_FACTOR * self.max_range_m, _FARTHEST_M)
        if not ok.any():
            return
        z = pose.t[2] - depth[ok] * down[ok]
        weight = np.minimum(1.0, (self.max_range_m / (depth[ok] * norm[ok])) ** 2)
        b = np.floor(z / self.settings.bin_m).astype(np.int64)
        self._grow(int(b.min()), int(b.max()))
        self._counts += np.bincount(b - self._lo_bin, weight, minlength=len(self._counts))
        if self._measured is not None:  # (a level pickled before it kept them has none)
            measured = np.ones(len(b), bool) if fitted is None else ~np.asarray(fitted, bool)[::k, ::k][ok]
            self._split |= fitted is not None
            self._measured += np.bincount(
                b[measured] - self._lo_bin, weight[measured], minlength=len(self._counts)
            )
        self._n += int(ok.sum())
        if self._n >= self.settings.min_points:
            s = self.settings
            centres = (np.arange(len(self._counts)) + self._lo_bin + 0.5) * s.bin_m
            self.z_m = lowest_level(centres, self._counts, s.bin_m, s.min_share, 2 * s.bin_m)
            if self.z_m is not None and self._split and self._measured is not None:
                self.z_m = self._balanced(centres, self.z_m)

    def _balanced(self, centres_m: np.ndarray, z_all_m: float) -> float:
        """The level ``z_all_m`` found on every pixel, moved towards the measured pixels' own
        level near it (see :attr:`GroundSettings.measured_share`), metres."""
        s = self.settings
        assert self._measured is not None
        near = np.abs(centres_m - z_all_m) <= s.measured_search_m + 1e-9
        measured = self._measured
        if s.measured_share <= 0 or measured[near].sum() < _MIN_MEASURED_SHARE * self._counts[near].sum():
            return z_all_m
        smooth = np.convolve(measured, np.ones(3) / 3.0, mode="same")
        peak = int(np.argmax(np.where(near, smooth, -1.0)))
        window = np.abs(centres_m - centres_m[peak]) <= 2 * s.bin_m + 1e-9
        z_measured = float(np.sum(centres_m[window] * measured[window]) / measured[window].sum())
        return (1.0 - s.measured_share) * z_all_m + s.measured_share * z_measured

    def ground_depth(
        self,
        guess_depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        focal_baseline_px_m: float,
        below_m: float = 0.0,
        step: int = 1,
    ) -> np.ndarray | None:
        """The ground plane's depth at the guessed pixels that agree with it.

        Args:
            guess_depth_m: (H, W) float32 guessed depth, metres (NaN none).
            intrinsics: the depth camera; world_from_cam: its pose.
            focal_baseline_px_m: ``f B`` of the rig (disparity = f B / depth), pixel metres.
            below_m: the depth returned is that of a plane this far below the level, metres
                (the agreement is judged on the level itself): a flat ground's solid lies under
                its surface, and the voxel holding the level may lie above it (a ground on a
                voxel boundary, or a level estimated a little high, put every hit in the empty
                voxel layer over the street); half a voxel down lands in the voxel under the
                surface for any level error under half a voxel.
            step: judge only every ``step``-th pixel of each row and column (what
                :class:`~skyrecon.mapping.frame_support.FrameSupport` reads).
        Returns:
            (H', W') float32 depth at pixels ``[::step, ::step]`` where the guess agrees with
            the ground plane (NaN elsewhere), metres along the optical axis; None before the
            level is known.
        """
        if self.z_m is None:
            return None
        pose = as_world_from_cam(world_from_cam)
        s = self.settings
        norm, down = self._rays_down(intrinsics, pose, step)
        drop = pose.t[2] - self.z_m  # camera height above the ground, metres
        if drop <= 0:
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            plane = np.where(down >= s.min_down_cos * norm, drop / down, np.nan)
            d_plane = focal_baseline_px_m / plane
            d_guess = focal_baseline_px_m / np.asarray(guess_depth_m, np.float64)[::step, ::step]
            agree = np.abs(d_guess - d_plane) <= s.tolerance_px + s.tolerance_rel * d_plane
        if below_m:
            plane = plane * ((drop + below_m) / drop)
        return np.where(agree, plane, np.nan).astype(np.float32)
