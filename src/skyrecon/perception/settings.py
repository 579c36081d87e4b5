"""The rules by which stereo becomes depth for the map, as one settings object with two presets.

:meth:`PerceptionSettings.mapping` is what ``skyrecon map`` uses (accuracy first: full
resolution, uniqueness test, discontinuity filter, obstacles only within the rig's trusted
range); :meth:`PerceptionSettings.flight` is what the delivery loop uses (speed first: the fast
half-resolution matcher, depth subsampled, matches at infinity carve free space).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from skyrecon.core.stereo_rig import StereoRig
from skyrecon.errors import InputError
from skyrecon.stereo import trusted_range_m

_SKYRECON_MATCHERS = ("skyrecon", "skyrecon-fast")


@dataclass(frozen=True)
class PerceptionSettings:
    """How a rectified stereo pair becomes a depth image for the occupancy map.

    Attributes:
        method: stereo matcher name (see :func:`skyrecon.stereo.available_matchers`).
        max_disparity: disparity search range, pixels.
        matcher_settings: settings of the matcher (see :func:`skyrecon.stereo.create_matcher`);
            None: ``{"uniqueness": 0.05, "paths": 4, "horizontal_paths": True, "guided_fill":
            False}`` for the skyrecon matchers (a drone's camera looks down at plain streets, see
            :class:`skyrecon.stereo.SkyreconSettings`; the colour-guided fill only refines
            filled pixels, which the map takes as guesses: on the stereo map benchmark's
            flights the maps were the same without it, 2-3 ms a frame sooner; the matcher's
            third pair of diagonal paths, its default for single pairs since session 42, is
            left off here: on the stereo map benchmark's plain cities it changed recall within
            20 m by -0.023 to +0.034 of OpenCV + OctoMap's (seeds 4, 3, 11; seed 4, the worst,
            1.041 -> 1.018x) and precision at the surface by -0.09 to -0.01, for 5-7 % more
            time), nothing for the others.
        use_filled: also keep pixels the matcher filled by interpolation (off: they are
            guesses, not measurements, and could carve free space through a textureless wall).
        max_disparity_step_px: drop pixels whose 3x3 neighbourhood spans more disparity than
            this, pixels (depth discontinuities, where smoothing puts points in the air between
            foreground and background); None keeps them.
        depth_stride: the depth image is ``depth[::stride, ::stride]`` of the full-resolution
            one (with the matching camera, see :func:`strided_intrinsics`).
        sky_is_free: matches at ``d + doffs <= 0`` (beyond any range: open sky) become +inf
            depth, so the map carves free space along them up to its range; off: NaN (no evidence).
        max_depth_error_m: obstacles are marked only within the trusted range where a
            ``disparity_error_px`` disparity error moves depth by less than this, metres;
            None: ``max_depth_error_voxels`` voxels of the map.
        max_depth_error_voxels: the same bound in voxels of the map (used when
            ``max_depth_error_m`` is None); None with ``max_depth_error_m`` None: no trusted-range limit.
        disparity_error_px: the disparity error assumed for the trusted range, pixels.
        min_texture: a measured pixel counts as measured only where the left image's mean
            absolute horizontal grey-level gradient over its ``texture_window_px`` window is at
            least this, raised above the image's noise with ``noise_aware_texture`` (0: only
            more texture than noise, every pixel of a noise-free image) (grey levels per pixel,
            0-255 scale; see
            :func:`~skyrecon.perception.stereo_depth.texture_masks`); elsewhere (plain walls,
            roads, sky, horizontal edges) the matcher's value comes from smoothing along its
            paths, not from the image, and the pixel is treated as unmeasured. None: every
            measured pixel counts.
        texture_window_px: side of that window, pixels (odd).
        texture_scale: the texture test (and its noise estimate) runs on the left image reduced
            by this factor: the resolution the matcher works at (2 for ``skyrecon-fast``, whose
            half-resolution images carry half the noise and twice the gradient per pixel).
        noise_aware_texture: ``min_texture`` is for a noise-free image: raise it above the
            left image's own noise, measured on the image (a real camera's 1-2 grey levels on
            a plain wall pass a fixed threshold; see :mod:`skyrecon.core.image_noise`). Off:
            the threshold as given, whatever the noise.
        plane_fill: give an unmeasured segment the disparity of the plane that the measured
            pixels all around it lie on (see :func:`skyrecon.stereo.plane_supported_fill`):
            a plain wall or road bounded by measured edges gets depth, an occluded strip
            (bounded by foreground and background) or the sky above a roof line does not.
        plane_tolerance_px: inlier band of the plane fit, pixels of disparity.
        plane_min_inlier_fraction: share of the bordering measured pixels that must be inliers.
        plane_max_guess_gap_px: a segment whose plane differs from the matcher's own values
            inside it by more than this on most of its pixels is not filled (the plain road
            between two poles at one depth is not a sheet hung between them); None: no check.
        plane_open_borders: a plain segment running into the left, right or bottom image border
            needs no support on that side (``open_borders`` of
            :func:`~skyrecon.stereo.plane_supported_fill`).
        plane_prior_guess_check: with a ground plane given (``ground`` of
            :meth:`~skyrecon.perception.StereoDepth.compute`), whether a plain segment that takes
            the ground's plane must also agree with the matcher's own values inside it
            (``plane_max_guess_gap_px``; ``prior_guess_check`` of
            :func:`~skyrecon.stereo.plane_supported_fill`). On in the flight loop (the segments
            become open air there); off for ``skyrecon map``, which takes them for hits on the
            ground only (:class:`~skyrecon.mapping.StereoMapper`).
        plane_min_support_px: measured blobs of fewer full-resolution pixels support no plane
            (``min_support_area_px`` of :func:`~skyrecon.stereo.plane_supported_fill`): a noisy
            camera's specks on a plain wall match at random disparities; 0: every blob.
        guesses: also return the depth of the matcher's values that are not kept (see
            :attr:`DepthFrame.guess_depth_m`), for evidence that needs several frames.
        fine_max_disparity: 0 (default): off; else also match the pair at full resolution with
            OpenCV's block matcher over disparities ``0 .. fine_max_disparity - 1`` (a multiple
            of 16) and return it as :attr:`DepthFrame.fine`. A half-resolution matcher
            loses small objects against the background behind them (a drone of 1 x 0.4 m
            15-20 m away is 10 x 4 of its pixels, and it reads the background 30 m away); the
            block matcher at full resolution finds them (median depth within 0.3 m at 13-20 m
            on recorded frames). 16 disparities reach down to 6.4 m with the default rig,
            where the half-resolution matcher already sees such objects. For the mover tracker
            (:mod:`skyrecon.perception.movers`), not for the map.
        fine_block_px: block size of that matcher, pixels (odd, at least 5).
        horizon_far_m: with ``sky_is_free`` and a horizon row given, the unmeasured band
            between open sky and ground at least this far, metres, counts as sky too (see
            :func:`~skyrecon.perception.stereo_depth.horizon_band`; the map's range: nothing
            in the band lies within it); None: off.
        ground_range_m: with a ground plane given to :meth:`StereoDepth.compute` and the plane
            fill, a plain segment that takes the ground's plane (see ``ground`` there) is open
            air up to this range, metres (+inf depth: the map carves free space along it and
            marks no obstacle), on the pixels whose ray is still ``ground_clearance_m`` above
            the ground at this range; its other pixels stay unmeasured. The map's range: a
            plain roof, car or platform no taller than the clearance that the noisy border
            cannot tell from the ground is never carved into, and neither is the ground. None:
            off (the segments keep the ground's depth).
        ground_clearance_m: see ``ground_range_m``, metres; at least
            :data:`~skyrecon.perception.stereo_depth.GROUND_CLEARANCE_SHARE` of the camera's
            height above the ground (what the border's disparity cannot tell apart grows with
            it).
        near_speck_area_m2: when the texture test takes pixels out (a noisy camera), drop
            blobs of depth within a few metres smaller than this, square metres
            (:func:`~skyrecon.perception.stereo_depth.near_specks`); None: off.
    """

    method: str = "skyrecon"
    max_disparity: int = 128
    matcher_settings: Mapping[str, Any] | None = None
    use_filled: bool = False
    max_disparity_step_px: float | None = 1.0
    depth_stride: int = 1
    sky_is_free: bool = False
    max_depth_error_m: float | None = None
    max_depth_error_voxels: float | None = 2.0
    disparity_error_px: float = 0.25
    min_texture: float | None = None
    texture_window_px: int = 7
    texture_scale: int = 1
    noise_aware_texture: bool = True
    plane_fill: bool = False
    plane_tolerance_px: float = 0.3
    plane_min_inlier_fraction: float = 0.7
    plane_max_guess_gap_px: float | None = 1.5
    plane_open_borders: bool = True
    plane_prior_guess_check: bool = True
    plane_min_support_px: int = 0
    guesses: bool = False
    fine_max_disparity: int = 0
    fine_block_px: int = 9
    horizon_far_m: float | None = None
    ground_range_m: float | None = None
    ground_clearance_m: float = 3.0
    near_speck_area_m2: float | None = None

    def __post_init__(self) -> None:
        if not int(self.max_disparity) > 0:
            raise InputError(f"max disparity must be positive, got {self.max_disparity} px")
        if not (int(self.depth_stride) == self.depth_stride and self.depth_stride >= 1):
            raise InputError(f"depth stride must be a positive integer, got {self.depth_stride}")
        if self.max_depth_error_m is not None and not self.max_depth_error_m > 0:
            raise InputError(f"max depth error must be positive, got {self.max_depth_error_m} m")
        if self.max_depth_error_voxels is not None and not self.max_depth_error_voxels > 0:
            raise InputError(f"max depth error must be positive, got {self.max_depth_error_voxels} voxels")
        if not self.disparity_error_px > 0:
            raise InputError(f"disparity error must be positive, got {self.disparity_error_px} px")
        if self.max_disparity_step_px is not None and not self.max_disparity_step_px > 0:
            raise InputError(f"max disparity step must be positive, got {self.max_disparity_step_px} px")
        if self.min_texture is not None and not self.min_texture >= 0:
            raise InputError(
                f"min texture must be a non-negative grey-level deviation, got {self.min_texture}"
            )
        if self.texture_scale not in (1, 2, 4):
            raise InputError(f"texture scale must be 1, 2 or 4, got {self.texture_scale}")
        if not (int(self.texture_window_px) == self.texture_window_px and self.texture_window_px % 2 == 1):
            raise InputError(f"texture window must be an odd number of pixels, got {self.texture_window_px}")
        if not (
            int(self.fine_max_disparity) == self.fine_max_disparity and self.fine_max_disparity % 16 == 0
        ):
            raise InputError(
                f"fine max disparity must be 0 (off) or a multiple of 16, got {self.fine_max_disparity}"
            )
        if not (
            int(self.fine_block_px) == self.fine_block_px
            and self.fine_block_px % 2 == 1
            and self.fine_block_px >= 5
        ):
            raise InputError(
                f"fine block size must be an odd number of pixels >= 5, got {self.fine_block_px}"
            )
        if not self.plane_tolerance_px > 0:
            raise InputError(f"plane tolerance must be positive, got {self.plane_tolerance_px} px")
        if not 0 < self.plane_min_inlier_fraction <= 1:
            raise InputError(
                f"plane inlier fraction must lie in (0, 1], got {self.plane_min_inlier_fraction}"
            )
        if self.horizon_far_m is not None and not self.horizon_far_m > 0:
            raise InputError(f"horizon far range must be positive or None, got {self.horizon_far_m} m")
        if self.ground_range_m is not None and not self.ground_range_m > 0:
            raise InputError(f"ground range must be positive or None, got {self.ground_range_m} m")
        if self.near_speck_area_m2 is not None and not self.near_speck_area_m2 > 0:
            raise InputError(f"near speck area must be positive or None, got {self.near_speck_area_m2} m^2")
        if not self.ground_clearance_m >= 0:
            raise InputError(f"ground clearance must be >= 0, got {self.ground_clearance_m} m")
        if not (
            int(self.plane_min_support_px) == self.plane_min_support_px and self.plane_min_support_px >= 0
        ):
            raise InputError(
                f"plane min support must be a whole number of pixels >= 0, got {self.plane_min_support_px}"
            )
        gap = self.plane_max_guess_gap_px
        if gap is not None and not gap > 0:
            raise InputError(f"plane guess gap must be positive or None, got {gap} px")

    @classmethod
    def mapping(cls, **overrides: Any) -> PerceptionSettings:
        """What ``skyrecon map`` uses: full-resolution ``skyrecon`` matcher with a uniqueness
        test and the horizontal paths (no colour-guided fill), measured pixels away from
        discontinuities and on texture (mean horizontal gradient >= 0.5 grey levels per pixel
        over 7x7, raised above the image's noise), plain segments bounded by one measured plane
        filled with it (``plane_fill``), sky dropped, obstacles within the trusted range of 2 voxels of depth
        error; a plain segment that takes the ground's plane (when one is given) need not agree
        with the matcher's values inside (``plane_prior_guess_check`` off: the map takes it for
        hits on the ground only). Keyword overrides on top."""
        return replace(
            cls(min_texture=0.5, plane_fill=True, guesses=True, plane_prior_guess_check=False), **overrides
        )

    @classmethod
    def flight(cls, **overrides: Any) -> PerceptionSettings:
        """What the delivery loop uses: ``skyrecon-fast`` (half resolution) without extra
        matcher settings, 64 px disparity, measured pixels, no discontinuity filter, depth
        subsampled by 2, sky carves free space, obstacles within the trusted range of 3 voxels
        of depth error for a disparity error of 0.5 px (a quarter pixel at the matcher's half
        resolution): about 17 m for the 0.3 m rig at 640 px and 0.5 m voxels. Farther depth
        still carves free space up to the map's range. A measured pixel counts only where the
        half-resolution image the matcher sees has more texture than noise (``min_texture`` 0,
        ``texture_scale`` 2: every pixel of a noise-free image; with a real camera's noise the
        matcher's values over a plain wall are noise, and in the delivery demo they were
        phantom obstacles on every wall); near blobs under 10 x 10 cm are specks of that noise
        (``near_speck_area_m2``), and blobs under 100 pixels (10 x 10) support no plane of the
        plane fill (``plane_min_support_px``). A plain segment cut by the image's border must be
        supported on every side all the same (``plane_open_borders`` off): a near plain wall
        filling the view, bounded only by the far building along its one edge, took that
        building's plane (plain delivery seeds 4 and 19; the ground, a road running out of the
        image, has its own prior). Keyword overrides on top."""
        base = cls(
            method="skyrecon-fast",
            min_texture=0.0,
            texture_scale=2,
            plane_fill=True,
            max_disparity=64,
            matcher_settings={},
            max_disparity_step_px=None,
            depth_stride=2,
            sky_is_free=True,
            max_depth_error_voxels=3.0,
            disparity_error_px=0.5,
            near_speck_area_m2=0.01,
            plane_min_support_px=100,
            plane_open_borders=False,
        )
        return replace(base, **overrides)

    def matcher_kwargs(self) -> dict[str, Any]:
        """The settings passed to :func:`skyrecon.stereo.create_matcher`: ``matcher_settings``,
        or for the skyrecon matchers by default a uniqueness test and the horizontal paths; for
        the skyrecon matchers always, unless set there, the census tolerance measured on each
        image (``census_tolerance`` None: a camera's noise does not scramble the census of a
        plain surface; see :class:`skyrecon.stereo.SkyreconSettings`)."""
        if self.matcher_settings is not None:
            kw = dict(self.matcher_settings)
        elif self.method in _SKYRECON_MATCHERS:
            kw = {"uniqueness": 0.05, "paths": 4, "horizontal_paths": True, "guided_fill": False}
        else:
            kw = {}
        if self.method in _SKYRECON_MATCHERS:
            kw.setdefault("census_tolerance", None)
        return kw

    def hit_range_m(self, rig: StereoRig, voxel_size_m: float, max_range_m: float) -> float:
        """Range up to which measurements may mark obstacles, metres: ``max_range_m`` limited
        to the rig's trusted range (see :func:`skyrecon.stereo.trusted_range_m`), if any."""
        err = self.max_depth_error_m
        if err is None and self.max_depth_error_voxels is not None:
            err = self.max_depth_error_voxels * voxel_size_m
        if err is None:
            return float(max_range_m)
        return float(min(max_range_m, trusted_range_m(rig, err, self.disparity_error_px)))


def stereo_hit_range_m(
    rig: StereoRig,
    voxel_size_m: float,
    max_range_m: float,
    max_depth_error_m: float | None = None,
    disparity_error_px: float = 0.25,
) -> float:
    """Range up to which stereo measurements may mark obstacles, metres.

    ``min(max_range_m, trusted_range_m(rig, max_depth_error_m or 2 * voxel_size_m, disparity_error_px))``.
    """
    s = PerceptionSettings(max_depth_error_m=max_depth_error_m, disparity_error_px=disparity_error_px)
    return s.hit_range_m(rig, voxel_size_m, max_range_m)
