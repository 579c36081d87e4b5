"""Movers: what moves in the depth images, told apart from what stands, and tracked.

A delivery drone shares the city with other drones, vehicles and cranes. Integrated into the
static occupancy map they would leave phantom trails, and the planner would not know they move.
:class:`MoverTracker` looks at every depth frame against the static map:

1. **Detection** (:func:`detect_movers`): valid depth pixels (finite, within ``max_range_m``,
   or ``far_range_m`` for the see-through test) are back-projected to world points. A point is a
   *motion candidate* when earlier frames (with ``history_s``, e.g. 0.3 s and 1 s ago,
   :class:`SeenDepth`) saw through its space (the see-through test: something moved in since), or
   when the static map has
   observed the space there as free (its voxel is FREE, and so is the voxel ``behind_m`` farther
   along the viewing ray, so that a point of a static surface pushed forward by depth noise is not
   a candidate, and so are the voxels a little away from it along the axes, so that the silhouette
   of a static object is not one), or when it lies in the gate (predicted box, inflated) of a confirmed moving track
   and does not look like a static surface (its voxel OCCUPIED with no free space behind it).
   With ``motion_ratio`` set (off by default), also a point whose patch the previous frame,
   carried to this one as a still world, does not show (:mod:`skyrecon.perception.motion_test`).
   Candidates are voxelised at ``cluster_voxel_m`` and grouped into 26-connected components;
   each component with enough points, on enough texture for stereo to have measured it (when
   the left image is given), is a :class:`MoverDetection`.
2. **Tracking**: one constant-velocity Kalman filter per track (world frame, state position and
   velocity), association by :func:`scipy.optimize.linear_sum_assignment` on the centre
   distance with a gate; tracks are confirmed after ``confirm_hits`` detections, coast (predicted
   forward) for up to ``coast_s`` when unseen (with ``refute_frames`` set, off by default,
   a coasting track is dropped sooner where the camera sees through the place it predicts), and a
   cluster that stays still is released as a *new static obstacle* (its pixels go back into
   the static map).
3. **Outputs** (:class:`MoverFrame`): the detections, copies of the tracks, and the
   ``dynamic_mask`` of pixels to keep out of the static map (``depth[mask] = NaN`` before
   :meth:`~skyrecon.mapping.OccupancyMap.integrate_depth`). For the planner,
   :meth:`MoverTracker.predict` (predicted paths) and :meth:`MoverTracker.keep_out` (capsules).

Frames and units: world frame z up, metres, seconds; camera frame x right, y down, z forward
(OpenCV); poses are ``world_from_cam`` (``p_world = R @ p_cam + t``).

Known limits: the visible part of a mover is what is measured, so a detection's centre is biased
towards the camera by up to the mover's half depth (the tracker pushes it back by the size the
track remembers, see ``MoverSettings.max_push_m``), and under camera noise stereo smears its
outline backwards (the centre leaves out what lies deeper along the ray than the cluster is
wide, see ``MoverSettings.ray_extent_per_width``); the parts of a mover that share a voxel
with a static surface (the lowest ~0.5 m of a vehicle on the road) are not candidates and stay
out of the mask. With the flight map's hit range (17 m for the default rig) movers are seldom
found beyond 14 m: beyond the hit range the map holds no free space, and inside it an
undetected mover's points are integrated and make its own voxels, and those behind it, occupied
before it can be found (``benchmarks/dynamic/probe_free_space.py`` shows the test's parts at
the movers' points per band of distance).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from skyrecon.core.intrinsics import Intrinsics
from skyrecon.core.rigid import Rigid3
from skyrecon.errors import InputError
from skyrecon.perception.motion_test import MotionView, grid_scale, moved

if TYPE_CHECKING:  # skyrecon.mapping imports skyrecon.perception: import it late, in the functions
    from skyrecon.mapping.occupancy import OccupancyMap
    from skyrecon.perception.stereo_depth import FineDepth, PairMatches

#: earlier-frame ages for the see-through test (MoverSettings.history_s), seconds
SEE_THROUGH_AGES_S = (0.3, 1.0)
#: far clusters with at least this many points get a quantile box (MoverSettings.box_quantile)
_MIN_ROBUST_POINTS = 20
# the 13 "forward" neighbours of a voxel: with their opposites, its 26 neighbours
_HALF_NEIGHBOURS = np.array(
    [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1) if (dx, dy, dz) > (0, 0, 0)],
    dtype=np.int64,
)
_AXIS_STEPS = np.concatenate([np.eye(3), -np.eye(3)])
_CUBE_STEPS = np.concatenate([_HALF_NEIGHBOURS, -_HALF_NEIGHBOURS]).astype(np.float64)  # the 26 around


@dataclass(frozen=True)
class MoverSettings:
    """How movers are detected and tracked (defaults for 320x240 depth at 10 Hz, 0.5 m map voxels).

    Attributes:
        stride: use every ``stride``-th pixel of the depth image (rows and columns) for detection;
            the dynamic mask is still filled at full resolution (1: every pixel).
        cluster_voxel_m: voxel edge of the clustering grid, metres (26-connected components).
        min_points: clusters with fewer candidate points (at the detection stride) are dropped.
        min_range_m, max_range_m: only pixels whose Euclidean range is in this interval are
            considered, metres (beyond ``max_range_m`` stereo depth is too noisy).
        inside_m: the state of a point is read this far behind it along the viewing ray,
            metres, so that a surface lying on a voxel boundary reads as its occupied voxel and
            not as the free voxel in front of it; the states this far along +-x, +-y, +-z must
            be free too (so that the silhouette of a static object, whose rays graze past it
            into free space, is not a candidate).
        free_evidence: a voxel counts as free for the test only when its log-odds is at most
            ``-free_evidence`` (0.6: seen free at least twice; a weak prior from an earlier
            flight, or one glance, is not enough, so a new static obstacle standing where the
            prior had nothing is mapped at once rather than taken for a mover).
        edge_jump_frac: pixels whose 3x3 neighbourhood spans a depth jump of more than this
            fraction of their depth are not candidates (stereo puts points in the air between
            a near edge and the far background there) ...
        edge_hole_min_valid: how unmeasured (NaN) neighbours count in that test: 0, as far
            (the border of a hole is an edge); k > 0, they are left out, and a pixel with fewer
            than k measured neighbours of its 8 is an edge (a speck among holes). The sky's
            ``inf`` counts as far either way. Under camera noise stereo leaves holes inside a
            textured drone (the flight depth's texture test, and the left-right check on its
            panels): counted as far they made 74-81 % of a near drone's points depth edges
            (``benchmarks/dynamic/probe_free_space.py``, noisy seeds 106 and 108: 0-10 m), too
            few were left for a cluster, and movers within 10 m were found in 31 % of the
            frames. With 3 (the default since session 56, with ``min_alias_ratio``), on the
            dynamic benchmark with 1.5 grey levels of camera noise (seeds 100-109): recall
            within 10 m 0.31 -> 0.62, within 20 m 0.15 -> 0.24, the planner's phantom
            track-frames 681 -> 260, median position error 0.45 -> 0.56 m, 10/10 delivered, 0
            collisions both. Without the alias test it let in patches of windows and zebra
            crossings matched a period off (phantom track-frames 681 -> 2127). Held out (seeds
            150-159, flown with both): within 10 m 18 of 44 frames -> 8 of 12, 10-15 m 0.26 ->
            0.31, 15-20 m 0.01 -> 0, phantom track-frames 606 -> 407, median position error
            0.56 -> 0.76 m (why is not yet looked into).
        min_alias_ratio: with the pair's matches given (``matches`` of :func:`detect_movers`),
            a cluster is dropped when, shifted as a whole, it matches at a farther disparity
            nearly as well as at its own:
            :meth:`~skyrecon.perception.stereo_depth.PairMatches.region_alias_ratio` below
            this (0: no such test). A periodic texture (rows of windows, the stripes of a
            crossing, a drone's own panels seen pixel by pixel) has near-equal matches a period
            apart; a region matched a period off matches as well at the true disparity as a
            whole, while an object in front of a background does not (its outline moves
            against what lies behind it). On the detections of four noisy dynamic missions
            (seeds 103, 106, 108, 109, with ``edge_hole_min_valid`` 3): 1.0 kept 85 % of those
            on a mover and 21 % of those in free air on nothing (0.8: 93 / 33 %; 1.2: 74 / 19
            %); the per-pixel test of the fine depth (share of unambiguous pixels at least 0.5)
            kept 55 / 23 %.
        edge_near_frac, edge_near_min_range_m: ... unless they lie on the near side of the
            jump (within ``edge_near_frac`` of their depth of the nearest depth around them: the
            foreground object's own surface) at a range of at least ``edge_near_min_range_m``,
            metres, and no voxel within ``fine_clear_m`` of them (26 steps) is occupied (so that
            a near edge of a static surface, widened onto the background by the matcher, is not
            a mover). A drone 10 m away spans a few half-resolution pixels and nearly all of
            them lie at a depth edge: without this, the crossing drone of held-out mission 165
            was found only 4 m away and hit; with 0.03 and 8 m it was found 10 m away. Off by
            default (0): flown with 0.03 and 8 m on the 50 dynamic missions (seeds 100-149) and
            50 held-out ones (150-199), it gave recall within 20 m 0.22 / 0.21 against 0.17 /
            0.23 without, median position error 0.79 / 0.84 m against 0.52 / 0.59 m, a new
            scaffold up to 1.3 s to be mapped (its near edges passed for movers; target 0.5 s)
            against 0.3 s, and 1 + 1 collisions (seeds 139, 155) against 0 + 2 (155, 165).
            Nearer than 8 m it confirmed chains of stereo outliers in free air as movers.
        behind_m: the free-space test also looks this far behind the point along the viewing
            ray, metres (one map voxel of 0.5 m) ...
        depth_noise_frac, noise_sigmas: ... plus ``noise_sigmas * depth_noise_frac * range``, so
            that depth noise (standard deviation ``depth_noise_frac`` of the range) does not
            make points of static surfaces look like they float in free space.
        gate_m: association gate on the centre distance, metres (grows with the track's
            position uncertainty, up to ``3 * gate_m``, plus the track's largest half size).
        gate_inflate_m: a confirmed moving track's predicted box, inflated by this, metres, is
            the region where its points are candidates even over non-free map space.
        confirm_hits: detections before a track is confirmed.
        reacquire_s, reacquire_gap_m: a track found again after more than ``reacquire_s``
            seconds unseen, more than ``reacquire_gap_m`` from its coasted prediction, starts
            afresh at the detection (velocity unknown: zero with ``init_speed_sigma_mps``),
            keeping its id and staying a mover meanwhile (so the detector's gate keeps finding
            it). Its velocity is stale by then, and the detection may be another object that
            the coasting prediction passed by: in held-out dynamic mission 202 (with the push
            below on) a track coasting for 3 s picked up another drone, kept the first one's
            velocity (5.5 m/s the wrong way; a Kalman correction moves the velocity by only
            about half the innovation per second of coasting), its keep-out swept away from the
            drone it really was, which then hit ours; with (1 s, 1 m) that flight delivered.
            Where the prediction held (within the gap), the velocity did too and is kept. None:
            never. Default (1 s, 1 m) since session 31: with the push below and
            ``MissionConfig.evade_movers`` / ``reach_aware_verify``, seeds 100-149 and the
            held-out 200-249 flew 49/50 (one safe hover) and 50/50 delivered without a
            collision (``benchmarks/dynamic/results.json``, ``results_seeds200-249.json``); without
            ``evade_movers``, seed 115 hovered in a crane boom's sweep and was hit.
        coast_s: a track not seen is predicted forward for up to this long, seconds, then
            dropped (tentative, not yet confirmed tracks are dropped at their first miss).
        refute_frames, refute_range_m: ... unless the camera saw through its predicted centre
            (in view, nearer than ``refute_range_m`` metres, the 3x3-nearest depth there farther
            than the centre by the see-through margin, see ``see_through_frac``) in this many
            consecutive frames: then nothing is where the track says, and it is dropped at
            once (0, the default: never). Out of view, or where something nearer hides the
            centre, a track coasts as before; nearer than 12 m the coarse matcher keeps a
            drone's own depth (farther it may lose a small drone against the background behind
            it, which would refute a real track). Why it was tried: on dynamic missions 100,
            102 and 103 (session 43) 54-78 % of the planner's track-frames were more than 3 m
            from every mover, nearly all of them coasting tracks confirmed on three chance
            clusters of stereo outliers, their keep-outs sweeping free air along a chance
            velocity. Why it is off: it seldom fires, as those tracks coast out of view or
            behind a nearer surface within a few frames: on seeds 100-105 the phantom share was
            0.608 with it (2) against 0.604 without, recall within 20 m 0.233 against 0.257
            (one flight, seed 105, went otherwise); over seeds 100-149 with it, 50/50 delivered,
            0 collisions, phantom share 0.69 (``benchmarks/dynamic/results_refute_session43.json``;
            ``probe_phantoms.py`` sorts phantoms by cause).
        moving_speed_mps: a confirmed track faster than this is moving, m/s.
        static_speed_mps, static_frames: a track with at least ``static_frames`` detections
            that never moved and whose speed (filter estimate and mean displacement since its
            first detection) is below ``static_speed_mps`` is released as a new static obstacle.
        accel_noise_mps2: process noise, white acceleration standard deviation, m/s^2.
        meas_noise_m: measurement noise of a detection centre, standard deviation, metres.
        init_speed_sigma_mps: velocity standard deviation of a new track, m/s.
        size_memory: a track's half size is ``max(detection, size_memory * old + (1 -
            size_memory) * detection)`` per axis (a decaying maximum).
        keep_out_sigmas: keep-out radius margin, in standard deviations of the predicted position.
        max_keep_out_margin_m: cap of that margin, metres (a long-coasting track's uncertainty
            would otherwise close whole streets).
        max_speed_mps, max_climb_mps: a track faster than this (3-D speed), or climbing or sinking
            faster than this, once it has ``confirm_hits`` detections is not a real object (stereo
            outliers at depth edges chained by chance) and is dropped, m/s.
        history_s: ages of the earlier frames for the *see-through test*, seconds (empty: no
            such test). For each age, the latest remembered frame at least that old is taken; a
            point is a candidate when every one of them saw through its space (the depth there
            lay farther by a margin): something has moved in since. This needs no map, so it
            finds movers in space the map has not seen free and beyond the map's range. Asking
            every view (not any) makes one old frame's stereo outlier on a static surface not
            enough; a mover coming straight at the camera is found by it once it closes in by
            more than the margin within the shortest age. Points in front of a surface the map
            holds (within ``behind``) and depth-edge pixels are not candidates by it. Off by
            default: :data:`SEE_THROUGH_AGES_S` turns it on (replayed on four recorded missions it
            raised recall within 20 m from 26 to 41 %; flown in 50 dynamic missions, recall 17 ->
            30 %, but two missions met a mover the drone could not see (from the side; a crane
            boom too close for stereo) that the flights without it had passed by).
        far_range_m: points between ``max_range_m`` and this range are candidates by the
            see-through test only, metres (beyond the map's range the map knows nothing).
        fine_min_range_m, fine_range_m: points of the fine depth (``fine`` of
            :func:`detect_movers`) are considered from ``fine_min_range_m`` up to
            ``fine_range_m``, metres. Nearer, the coarse matcher sees a drone well (at 12 m it is
            13 x 5 of its half-resolution pixels) and the block matcher adds little but
            mistakes: on three recorded missions, 8 of its 269 detections nearer than 12 m were
            movers, against 40 of 77 farther. Full-resolution block matching keeps a quarter
            pixel of disparity within about 0.4 m at 20 m with the default rig.
        fine_unknown: a fine point may also lie in space the map has not seen (not occupied)
            where the coarse depth saw the background behind it in this very frame. The map
            holds space free only up to its hit range (17 m with the default rig), so without
            this, movers 15-20 m away are seldom candidates (three recorded missions: recall
            15-20 m 0 % without, 0-60 % with; recall within 20 m 0.37 -> 0.57 on average, while
            confirmed moving tracks away from every mover went from 72 to 131 track-frames
            per mission). Off by default: the edges of a new static structure (a scaffold tower
            the prior map lacks) then pass for movers and are kept out of the map until their
            track is found static; in one of 13 dynamic missions the tower took 1.7 s to be
            mapped (0.1 s without; the target is 0.5 s).
        fine_clear_m: a fine point is a candidate only when none of the 26 points this far
            from it along the axes and diagonals (steps of -1, 0, 1 times it per axis) is in an
            occupied voxel of the map, metres (block matching widens a near edge
            onto the background beside it by about half its block: those points lie within
            this distance of the mapped surface they belong to).
        see_through_frac: the margin of the see-through test is ``behind_m`` plus
            ``(noise_sigmas * depth_noise_frac + see_through_frac) * range``, range the farther
            of the point's ranges in the two views (stereo depth error grows with the square of
            the range), metres.
        min_texture, min_textured_share, texture_window_px: with the left image given (``image``
            of :func:`detect_movers`), a cluster is dropped when less than ``min_textured_share``
            of its pixels (40 spread over it) lie on texture: a grey-level standard deviation of
            at least ``min_texture`` (0-255 grey levels) over the ``texture_window_px`` square
            window around them. Stereo measures nothing on a plain surface (a wall, a road, the
            sky): the matcher's values there, propagated from the edges, can put a patch of it
            metres off the surface, in space the map holds free, and its centre moves on as the
            camera does: a confirmed "mover" on nothing. A plain object's outline is texture
            (against what lies behind it), so a plain drone keeps its rim. On eight recorded
            dynamic missions (seeds 300-314, session 44) this dropped 50 % of the detections
            more than 1.5 m from every mover (their median share 0.24; 35 of the 78 that fed a
            track the planner avoided) and 4 % of those on a mover (median share 0.80; none that
            fed an avoided track). ``min_texture`` 0: no such test.
        box_quantile, robust_box_range_m: the box of a detection whose points lie at a median
            range of ``robust_box_range_m`` metres or more spans these quantiles of its points per
            axis (``q`` to ``1 - q``; clusters of fewer than 20 points: all of them), so that the
            stereo smear of a small far object (depth error grows with the square of the range)
            does not stretch its box and centre; nearer ones span all their points (0, the
            default: every box spans all its points). Replayed on the noisy recordings below
            (``ray_extent_per_width`` 0), 0.2 at every range gave 0.372 m.
        ray_extent_per_width: a detection's centre is that of its points no farther along the
            viewing ray (camera to the cluster's median point), from its nearest point, than
            this many times the cluster's widest extent across the ray: a visible surface of a
            box is seldom deeper than it is wide (a cube seen from anywhere; a car seen within
            about 30 degrees of end-on is cut short), while stereo's smear of a mover's outline
            towards what lies behind it is. Its box still covers every point around that centre
            (the keep-out volume holds the smear; the pixels are filled in within the box of
            every point). 0: the centre of the box of every point. Default 1 since session 57:
            under 1.5 grey levels of camera noise a drone's box of every point reached a median
            0.7 m beyond its far face (its near face within 0.06 m; 144 detections on a drone in
            ten recorded missions, seeds 100-109, ``benchmarks/dynamic/replay_tracker.py record
            --camera-noise 1.5``), and the tracks' median position error replayed on them went
            0.556 -> 0.285 m (p95 0.99 -> 0.79 m), phantom track share 0.32 -> 0.32, recall
            within 20 m 0.236 -> 0.245; 0.75 gave 0.284 m, 1.5 0.412 m. On exact depth (the
            tests in ``tests/perception``) the centres are unchanged. Flown under the same noise
            on held-out seeds 150-159: 10/10, 0 collisions, median position error 0.76 -> 0.35
            m (p95 worst 1.37 -> 0.61 m); on seeds 100-109 0.556 -> 0.467 m (p95 worst 1.32 ->
            1.26 m) (``benchmarks/dynamic/results_noise1.5_seeds*_session57_a5d06f4.json``).
        max_push_m, side_view_cos, push_once_moving: a matched detection's centre is pushed
            away from the camera (the visible surface is nearer than the centre) by the half size
            the track has seen from the side and this view does not show: per axis with
            ``max_push_m`` None, else along the viewing ray, capped at ``max_push_m`` metres
            (0: no push; default 0.2); with ``push_once_moving`` only once the track
            has moved (a cluster that may be a new static obstacle is then taken as it is, so
            that pushes differing from view to view do not look like motion). A track learns an
            axis's size (:attr:`MoverTrack.side_half_size`) only from views whose ray makes a
            cosine of at most ``side_view_cos`` with that axis (default 0.5; 1: every view, so
            the size holds stereo's smear along the rays, metres along a far drone's ray).
            Replayed on the recorded detections of 18 dynamic missions (seeds 300-317, recorded
            in session 29; ``benchmarks/dynamic/replay_tracker.py``), the tracks' median position
            error (median of the missions' medians, the benchmark's figure) is 0.50 m with the
            per-axis push of every view (None, 1) and 0.365 m with (0.2, 0.5), the defaults
            since session 31 (flown: see ``reacquire_s``; median position error about 0.38-0.39
            m on seeds 100-149 and 200-249, against 0.525 / 0.541 m with (None, 1)).
            ``push_once_moving`` with the look-ahead back-off met a collision on held-out seed
            202 (session 26), so it stays off. On exact depth (a drone crossing 12 m ahead,
            ``tests/perception``) no push leaves the centre up to 0.54 m short when the visible
            face turns.
        motion_ratio, motion_min_contrast, motion_min_range_m, motion_max_gap_s,
        motion_patch_px, motion_slack_px: the *motion test*
            (:mod:`skyrecon.perception.motion_test`): with the left image given, a point at
            least ``motion_min_range_m`` metres away, no depth edge, and not in a voxel the map
            holds occupied (a building's outline does not line up across frames: what lies
            behind it moves otherwise in the image) is a candidate when the previous frame (at
            most ``motion_max_gap_s`` seconds older), carried to this one as a still world, does
            not show its ``motion_patch_px`` square patch (on the depth grid) within
            ``motion_slack_px``: mean absolute difference, each patch less its mean, at least
            ``motion_ratio`` times the patch's contrast (its mean absolute deviation, itself at
            least ``motion_min_contrast`` grey levels). It needs no free space in the map, so
            it finds movers where the map has seen nothing (up to ``max_range_m``). 0 (the
            default): off. Flown on the dynamic benchmark with 1.5 grey levels of camera noise,
            seeds 100-109 (session 51; ``benchmarks/dynamic/results_noise1.5_seeds100-109.json``
            against ``results_noise1.5_tried_seeds100-109.json``, ``motion_ratio=0.7``): recall
            within 20 m 0.154 -> 0.217 (10-15 m 0.28 -> 0.46, 15-20 m 0.0 -> 0.05), position
            error p95 worst 1.12 -> 1.32 m, phantom track share 0.61 -> 0.65, 10/10 delivered
            and 0 collisions both, but in seed 107 the gone container stack took 10.9 s to be
            freed (0.2 s without; target 2 s); the test costs about 15 ms a frame (320 x 240
            depth grid, a loaded 2-core machine). Earlier forms, same seeds: one patch
            displacement per point, no map rule (recall 0.280, 10-15 m 0.53, but a mover 0.37 m
            from the drone in seed 104, out of view); each pixel carried by its own depth without
            the map rule (0.200). Too little, with that regression, to be on by default.
    """

    stride: int = 1
    cluster_voxel_m: float = 0.5
    min_points: int = 12
    min_range_m: float = 0.3
    max_range_m: float = 20.0
    inside_m: float = 0.15
    free_evidence: float = 0.6
    edge_jump_frac: float = 0.1
    edge_hole_min_valid: int = 3
    min_alias_ratio: float = 1.0
    behind_m: float = 0.5
    depth_noise_frac: float = 0.02
    noise_sigmas: float = 2.5
    gate_m: float = 2.0
    gate_inflate_m: float = 0.5
    confirm_hits: int = 3
    coast_s: float = 3.0
    refute_frames: int = 0
    refute_range_m: float = 12.0
    reacquire_s: float | None = 1.0
    reacquire_gap_m: float = 1.0
    moving_speed_mps: float = 0.5
    static_speed_mps: float = 0.3
    static_frames: int = 3
    accel_noise_mps2: float = 3.0
    meas_noise_m: float = 0.2
    init_speed_sigma_mps: float = 8.0
    size_memory: float = 0.97
    keep_out_sigmas: float = 2.0
    max_keep_out_margin_m: float = 2.5
    max_speed_mps: float = 20.0
    max_climb_mps: float = 6.0
    history_s: tuple[float, ...] = ()
    box_quantile: float = 0.0
    robust_box_range_m: float = 10.0
    ray_extent_per_width: float = 1.0
    max_push_m: float | None = 0.2
    side_view_cos: float = 0.5
    push_once_moving: bool = False
    far_range_m: float = 20.0
    fine_min_range_m: float = 12.0
    fine_range_m: float = 20.0
    fine_clear_m: float = 0.5
    fine_unknown: bool = False
    see_through_frac: float = 0.1
    min_texture: float = 1.0
    min_textured_share: float = 0.25
    texture_window_px: int = 9
    edge_near_frac: float = 0.0
    edge_near_min_range_m: float = 8.0
    motion_ratio: float = 0.0
    motion_min_contrast: float = 2.0
    motion_min_range_m: float = 6.0
    motion_max_gap_s: float = 0.25
    motion_patch_px: int = 5
    motion_slack_px: int = 1

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "history_s":
                object.__setattr__(self, "history_s", tuple(float(x) for x in np.atleast_1d(v)))
                if not all(np.isfinite(x) and x > 0 for x in self.history_s):
                    raise InputError(f"mover setting history_s must hold finite ages > 0 s, got {v}")
                continue
            if v is None:  # max_push_m: the per-axis push; reacquire_s: never
                continue
            if not np.isfinite(v) or v < 0:
                raise InputError(f"mover setting {f.name} must be finite and >= 0, got {v}")
        if int(self.refute_frames) != self.refute_frames:
            raise InputError(f"mover setting refute_frames must be a whole number, got {self.refute_frames}")
        if int(self.stride) < 1 or int(self.confirm_hits) < 1 or int(self.static_frames) < 1:
            raise InputError("stride, confirm_hits and static_frames must be >= 1")
        if self.cluster_voxel_m <= 0 or self.meas_noise_m <= 0 or self.max_range_m <= self.min_range_m:
            raise InputError("need cluster_voxel_m > 0, meas_noise_m > 0 and max_range_m > min_range_m")
        if self.static_speed_mps > self.moving_speed_mps:
            raise InputError("static_speed_mps must not exceed moving_speed_mps")
        if not 0 <= self.box_quantile < 0.5:
            raise InputError(f"box_quantile must lie in [0, 0.5), got {self.box_quantile}")
        if int(self.motion_patch_px) != self.motion_patch_px or self.motion_patch_px % 2 != 1:
            raise InputError(f"motion_patch_px must be an odd whole number, got {self.motion_patch_px}")
        if int(self.motion_slack_px) != self.motion_slack_px:
            raise InputError(f"motion_slack_px must be a whole number, got {self.motion_slack_px}")
        if int(self.texture_window_px) != self.texture_window_px or self.texture_window_px % 2 != 1:
            raise InputError(f"texture_window_px must be an odd whole number, got {self.texture_window_px}")
        if not 0 <= self.min_textured_share <= 1:
            raise InputError(f"min_textured_share must lie in [0, 1], got {self.min_textured_share}")
        if not 0 <= self.size_memory < 1:
            raise InputError(f"size_memory must lie in [0, 1), got {self.size_memory}")


def parse_mover_overrides(text: str) -> dict:
    """``"max_push_m=0.2,side_view_cos=0.5,reacquire_s=None"`` -> :class:`MoverSettings`
    overrides (numbers, ``None``, ``True``/``False``, and lists of numbers joined by ``/``, as
    in ``history_s=0.3/1.0``); checked against the settings' fields.

    Raises:
        InputError: an unknown name or a value that is not a number, None, True or False.
    """
    names = {f.name for f in fields(MoverSettings)}
    out: dict = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        k, sep, v = item.partition("=")
        k, v = k.strip(), v.strip()
        if not sep or k not in names:
            raise InputError(f"mover setting {item!r}: expected name=value with a MoverSettings name")
        if v in ("None", "True", "False"):
            out[k] = {"None": None, "True": True, "False": False}[v]
            continue
        try:
            out[k] = tuple(float(x) for x in v.split("/")) if "/" in v else float(v)
        except ValueError:
            raise InputError(
                f"mover setting {k}: {v!r} is not a number, a list like 0.3/1.0, None, True or False"
            ) from None
    return out


@dataclass
class MoverDetection:
    """One cluster of motion candidates in one frame.

    Attributes:
        center: (3,) world centre of the axis-aligned bounding box of its points, metres,
            leaving out those deeper along the viewing ray than the cluster is wide (stereo's
            smear; see ``MoverSettings.ray_extent_per_width``).
        half_size: (3,) half extents of the box around ``center`` that covers every point,
            metres.
        n_points: candidate points in the cluster (at the detection stride).
        pixel_mask: (H, W) bool, its pixels in the depth image (full resolution).
        track_id: the track it was associated with (or started), -1 before tracking.
    """

    center: np.ndarray
    half_size: np.ndarray
    n_points: int
    pixel_mask: np.ndarray
    track_id: int = -1


@dataclass
class MoverTrack:
    """A tracked object (world frame, metres, seconds).

    Attributes:
        track_id: unique within a tracker, from 1.
        position, velocity: (3,) filter estimate of the centre (m) and its velocity (m/s).
        covariance: (6, 6) covariance of ``[position, velocity]``.
        half_size: (3,) half extents, a decaying maximum of the detections', metres (for the
            keep-out volume and the gates: it holds stereo's smear along the rays too).
        side_half_size: (3,) the same per axis but only from views across that axis (see
            ``MoverSettings.side_view_cos``), metres: what the centre push uses.
        hits: detections associated so far.
        age_s: time since the first detection, seconds; first_seen_s, last_seen_s: times of the
            first and of the last detection, seconds.
        first_position: (3,) centre of the first detection.
        confirmed: has had ``confirm_hits`` detections.
        moving: confirmed and faster than ``moving_speed_mps`` (as of the last update).
        was_moving: has been moving at some time (such a track is never released as static).
        static: released as a new static obstacle (its pixels go into the map).
        coasting: not detected in the last frame (predicted only).
        refuted: consecutive frames, up to the last, in which the camera saw through the
            predicted centre of this coasting track (see ``MoverSettings.refute_frames``).
    """

    track_id: int
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    half_size: np.ndarray
    side_half_size: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hits: int = 1
    age_s: float = 0.0
    first_seen_s: float = 0.0
    last_seen_s: float = 0.0
    first_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    confirmed: bool = False
    moving: bool = False
    was_moving: bool = False
    static: bool = False
    coasting: bool = False
    refuted: int = 0

    @property
    def speed(self) -> float:
        """Speed of the filter estimate, m/s."""
        return float(np.linalg.norm(self.velocity))

    @property
    def avoided(self) -> bool:
        """The planner keeps clear of it: confirmed, not a static obstacle, moving now or once."""
        return self.confirmed and not self.static and (self.moving or self.was_moving)

    @property
    def position_sigma(self) -> float:
        """Largest standard deviation of the position estimate, metres."""
        return float(np.sqrt(max(np.linalg.eigvalsh(self.covariance[:3, :3]).max(), 0.0)))

    def copy(self) -> MoverTrack:
        return replace(
            self,
            position=self.position.copy(),
            velocity=self.velocity.copy(),
            covariance=self.covariance.copy(),
            half_size=self.half_size.copy(),
            side_half_size=self.side_half_size.copy(),
            first_position=self.first_position.copy(),
        )


@dataclass
class MoverFrame:
    """What :meth:`MoverTracker.update` found in one frame.

    Attributes:
        time_s: the frame time, seconds.
        detections: the clusters of this frame (``track_id`` set).
        tracks: copies of the live tracks after the update.
        dynamic_mask: (H, W) bool, pixels to keep out of the static map this frame: those of the
            detections associated with moving or not yet decided tracks (not with static ones).
        ms: wall time of the update, milliseconds.
    """

    time_s: float
    detections: list[MoverDetection]
    tracks: list[MoverTrack]
    dynamic_mask: np.ndarray
    ms: float

    @property
    def moving_tracks(self) -> list[MoverTrack]:
        """The confirmed moving tracks of this frame."""
        return [t for t in self.tracks if t.moving]


# ----- detection ------------------------------------------------------------------------------
_RAY_CACHE: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def _decaying_max(old: np.ndarray, new: np.ndarray, memory: float) -> np.ndarray:
    """Per axis ``max(new, memory * old + (1 - memory) * new)``: a size that grows at once and
    shrinks slowly."""
    return np.maximum(new, memory * old + (1 - memory) * new)


def _rays(intr: Intrinsics, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of the strided grid: (h, w, 3) float32 camera rays with z = 1 and (h, w) their norms."""
    key = (intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy, intr.skew, tuple(intr.dist), stride)
    hit = _RAY_CACHE.get(key)
    if hit is None:
        rd = intr.ray_directions()[::stride, ::stride]
        hit = (np.ascontiguousarray(rd, np.float32), np.linalg.norm(rd, axis=2).astype(np.float32))
        if len(_RAY_CACHE) > 8:
            _RAY_CACHE.clear()
        _RAY_CACHE[key] = hit
    return hit


def _box_gates(tracks: list[MoverTrack], inflate_m: float) -> np.ndarray:
    """(K, 6) ``[lo, hi]`` world boxes of the given tracks' predicted extents, inflated."""
    if not tracks:
        return np.zeros((0, 6))
    p = np.array([t.position for t in tracks])
    h = np.array([t.half_size for t in tracks]) + inflate_m
    return np.concatenate([p - h, p + h], axis=1)


def _components(vox: np.ndarray) -> np.ndarray:
    """(M,) int component label of every voxel index (M, 3) int64 (26-connectivity, duplicates share)."""
    lo = vox.min(axis=0) - 1
    dims = vox.max(axis=0) - lo + 2
    keys = ((vox[:, 0] - lo[0]) * dims[1] + (vox[:, 1] - lo[1])) * dims[2] + (vox[:, 2] - lo[2])
    uniq, inverse = np.unique(keys, return_inverse=True)
    n = len(uniq)
    offs = (_HALF_NEIGHBOURS[:, 0] * dims[1] + _HALF_NEIGHBOURS[:, 1]) * dims[2] + _HALF_NEIGHBOURS[:, 2]
    nk = uniq[None, :] + offs[:, None]  # (13, n): padding keeps neighbours from wrapping
    idx = np.searchsorted(uniq, nk)
    idx_c = np.minimum(idx, n - 1)
    ok = (idx < n) & (uniq[idx_c] == nk)
    src = np.broadcast_to(np.arange(n), nk.shape)[ok]
    dst = idx_c[ok]
    graph = coo_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(n, n))
    _, lab = connected_components(graph, directed=False)
    return lab[inverse.reshape(-1)]


@dataclass(frozen=True)
class SeenDepth:
    """An earlier depth frame, kept for the see-through test (:func:`detect_movers`).

    Attributes:
        time_s: its time, seconds.
        nearest_m: (H, W) float32, per pixel the nearest depth in its 3x3 neighbourhood, metres
            (0 where any is invalid; inf where all saw nothing, such as the sky), so that a pixel
            counts as seen through only when its neighbours were too (edges, thin objects).
        intrinsics: its camera.
        world_from_cam: its pose.
    """

    time_s: float
    nearest_m: np.ndarray
    intrinsics: Intrinsics
    world_from_cam: Rigid3

    @classmethod
    def of(
        cls, time_s: float, depth_m: np.ndarray, intrinsics: Intrinsics, world_from_cam: Rigid3
    ) -> SeenDepth:
        """From a depth image (H, W), metres (NaN invalid, inf no return), and its camera."""
        d = np.asarray(depth_m, np.float32)
        d = np.where(np.isnan(d) | (d <= 0), np.float32(0), d)
        nearest = cv2.erode(d, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
        return cls(float(time_s), nearest, intrinsics, world_from_cam)

    def seen_through(self, pts: np.ndarray, range_m: np.ndarray, s: MoverSettings) -> np.ndarray:
        """(N,) bool: world points (N, 3) whose space this frame saw through: their pixel's
        (3x3 nearest) depth lies farther than the point by the margin (see
        :attr:`MoverSettings.see_through_frac`; ``range_m`` (N,) their ranges now, metres)."""
        pose = self.world_from_cam
        q = pose.inverse().apply(np.asarray(pts, np.float64))  # in that camera's frame
        out = np.zeros(len(q), bool)
        front = np.flatnonzero(q[:, 2] > s.min_range_m)
        if front.size == 0:
            return out
        uv = np.rint(self.intrinsics.project(q[front]))
        ok = self.intrinsics.in_image(uv)  # the rounded pixels: 0..W-1, 0..H-1 (NaN: out)
        front, uv = front[ok], uv[ok].astype(np.intp)
        seen = self.nearest_m[uv[:, 1], uv[:, 0]].astype(np.float64)
        r = np.asarray(range_m, np.float64)[front]
        r = np.maximum(r, q[front, 2])  # the farther of the two views sets the noise
        margin = s.behind_m + (s.noise_sigmas * s.depth_noise_frac + s.see_through_frac) * r
        out[front] = seen > q[front, 2] + margin
        return out


def detect_movers(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    world_from_cam: Rigid3 | np.ndarray,
    occ_map: OccupancyMap,
    settings: MoverSettings | None = None,
    gates: np.ndarray | None = None,
    references: list[SeenDepth] | None = None,
    fine: FineDepth | None = None,
    image: np.ndarray | None = None,
    motion: tuple[MotionView, MotionView] | None = None,
    matches: PairMatches | None = None,
) -> list[MoverDetection]:
    """Clusters of depth points that lie in space the static map has seen free, or that an
    earlier frame saw through (and, with ``image``, on texture stereo can measure).

    Args:
        depth_m: (H, W) depth along the optical axis, metres; NaN invalid, inf no return.
        intrinsics: the depth camera (size must match ``depth_m``).
        world_from_cam: the camera pose (Rigid3 or 4x4 / 3x4 matrix).
        occ_map: the static occupancy map (not modified).
        settings: :class:`MoverSettings` (defaults if None).
        gates: (K, 6) world boxes ``[xmin, ymin, zmin, xmax, ymax, zmax]`` in which points are
            candidates even where the map is not free (unless they look like a static surface).
        references: earlier frames (:class:`SeenDepth`) for the see-through test; points that
            every one of them saw through (see :attr:`MoverSettings.history_s`) are candidates
            too, up to ``far_range_m``, unless they lie at a surface the map holds.
        fine: the same view from a full-resolution matcher
            (:class:`~skyrecon.perception.stereo_depth.FineDepth`: ``depth_m`` (H, W) metres,
            NaN where it has none, and ``unambiguous(rows, cols)``). Where it sees a surface
            nearer than ``depth_m`` by the free-space margin, or where ``depth_m`` has nothing,
            its depth is taken (up to ``fine_range_m``): a small object, such as a drone 15 m
            away, that the coarser matcher lost against the background behind it. Such a point
            needs no free space behind it in the map where ``depth_m`` saw the background there
            in this very frame; it must be in space the map holds free (or, with
            ``fine_unknown``, has not seen, where the background was seen), no voxel around it
            within ``fine_clear_m`` (per axis) may be occupied, and its match must be
            unambiguous (checked last, on the few points left).
        image: the left image the depth was matched from ((kH, kW) grey or (kH, kW, 3) uint8
            RGB, k a whole number): clusters on too little texture are dropped (see
            :attr:`MoverSettings.min_texture`). None: no such test.
        motion: ``(now, previous)``, this frame and the one before as the motion test needs
            them (:class:`~skyrecon.perception.motion_test.MotionView`, see
            :attr:`MoverSettings.motion_ratio`); None: no such test.
        matches: the disparities of ``depth_m`` and the pair they came from
            (:class:`~skyrecon.perception.stereo_depth.PairMatches`): a cluster most of whose
            matches have a near-equal alternative farther away is an alias of a periodic
            texture, not a mover (see :attr:`MoverSettings.min_unambiguous_share`); None: no
            such test.
    Returns:
        The detections, largest first; ``track_id`` is -1.
    """
    from skyrecon.mapping.inputs import as_world_from_cam
    from skyrecon.mapping.occupancy import FREE, OCCUPIED

    s = settings or MoverSettings()
    depth = np.asarray(depth_m)
    intrinsics.check_image(depth, "depth")
    pose = as_world_from_cam(world_from_cam)
    st = int(s.stride)
    H, W = depth.shape
    taken = seen_behind = None
    if fine is not None:
        depth, taken, seen_behind = merge_fine_depth(depth, fine.depth_m, intrinsics, s)
    rays, ray_norm = _rays(intrinsics, st)
    d = np.asarray(depth[::st, ::st], np.float32)
    with np.errstate(invalid="ignore"):
        rng = d * ray_norm
        far = max(s.max_range_m, s.far_range_m) if references else s.max_range_m
        if taken is not None:
            far = max(far, s.fine_range_m)
        valid = np.isfinite(rng) & (rng >= s.min_range_m) & (rng <= far)
    flat = np.flatnonzero(valid)
    if flat.size == 0:
        return []
    dv = d.reshape(-1)[flat].astype(np.float64)
    rv = rays.reshape(-1, 3)[flat].astype(np.float64)
    p_cam = rv * dv[:, None]
    pts = p_cam @ pose.R.T + pose.t
    unit_w = (rv / ray_norm.reshape(-1)[flat, None]) @ pose.R.T
    rv_m = dv * ray_norm.reshape(-1)[flat]  # range of each point, metres
    behind = s.behind_m + s.noise_sigmas * s.depth_noise_frac * rv_m
    lo_odds = occ_map.log_odds_at(np.concatenate([pts + s.inside_m * unit_w, pts + unit_w * behind[:, None]]))
    states = occ_map.classify(lo_odds)
    here, back = states[: len(flat)], states[len(flat) :]
    with np.errstate(invalid="ignore"):
        seen_free = lo_odds <= -s.free_evidence
    edges_full, near_full = _depth_edges(
        depth, s.edge_jump_frac, s.edge_near_frac, int(s.edge_hole_min_valid)
    )
    edges = edges_full[::st, ::st].reshape(-1)[flat]
    near_edge = _near_edge_points(edges, near_full, rng, flat, st, s.edge_near_min_range_m)
    not_edge = ~edges if near_edge is None else ~edges | near_edge
    here_free = seen_free[: len(flat)]
    back_free = seen_free[len(flat) :]
    fine_f = np.zeros(len(flat), bool)
    if taken is not None and seen_behind is not None:
        fine_f = taken[::st, ::st].reshape(-1)[flat]
        behind_f = seen_behind[::st, ::st].reshape(-1)[flat]
        back_free = back_free | behind_f
        if s.fine_unknown:
            here_free = here_free | (behind_f & (here != OCCUPIED))
    limit = np.where(fine_f, s.fine_range_m, s.max_range_m)
    cand = here_free & back_free & not_edge & (rv_m <= limit)
    # a silhouette point of a static object (its ray grazes past the object into free space)
    # has an occupied voxel within inside_m across the ray: look along the axes too
    c1 = np.flatnonzero(cand & ~fine_f)
    if c1.size:
        around = (pts[c1][None, :, :] + _AXIS_STEPS[:, None, :] * s.inside_m).reshape(-1, 3)
        with np.errstate(invalid="ignore"):
            cand[c1] = np.all(occ_map.log_odds_at(around).reshape(6, -1) <= -s.free_evidence, axis=0)
    # a fine point, or the near side of a depth edge, is not a widened edge of a mapped surface
    _keep_near_edges_clear_of_surfaces(cand, near_edge, fine_f, occ_map, pts, s.fine_clear_m)
    c2 = np.flatnonzero(cand & fine_f)
    if c2.size:
        cand[c2] = _clear_of_surfaces(occ_map, pts[c2], s.fine_clear_m)
        c2 = c2[cand[c2]]
        if c2.size and fine is not None:  # last, on the few left: not an alias of a periodic texture
            rows, cols = np.divmod(flat[c2], d.shape[1])
            cand[c2] = fine.unambiguous(rows * st, cols * st)
    surface = (here == OCCUPIED) & (back != FREE)  # looks like a static surface of the map
    if references:
        # a point in front of a surface the map holds (within the depth noise) is that surface
        left = np.flatnonzero(~edges & (here != OCCUPIED) & (back != OCCUPIED))
        for ref in references:  # every earlier view must have seen through it: ask each
            if left.size == 0:  # only about the points the views before it saw through
                break
            left = left[ref.seen_through(pts[left], rv_m[left], s)]
        cand[left] = True
    if motion is not None and s.motion_ratio > 0:
        # not in a voxel the map holds occupied: a building's outline does not line up across
        # frames (what lies behind it moves otherwise), but it is the map's
        test = np.flatnonzero(~cand & ~edges & (here != OCCUPIED) & (rv_m >= s.motion_min_range_m))
        rows, cols = np.divmod(flat[test], d.shape[1])
        cand[test] = _moved(motion, rows * st, cols * st, s)
    core = cand.copy()  # candidates on their own evidence (not the gates')
    if gates is not None and len(gates):
        g = np.asarray(gates, np.float64).reshape(-1, 6)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        g = g[np.all(g[:, :3] <= hi, axis=1) & np.all(g[:, 3:] >= lo, axis=1)]
        if len(g):
            rest = np.flatnonzero(~cand & ~surface)
            q = pts[rest]
            inside = np.zeros(len(rest), bool)
            for box in g:
                inside |= np.all((q >= box[:3]) & (q <= box[3:]), axis=1)
            cand[rest[inside]] = True
    ci = np.flatnonzero(cand)
    if ci.size < s.min_points:
        return []
    cp = pts[ci]
    labels = _components(np.floor(cp / s.cluster_voxel_m).astype(np.int64))
    counts = np.bincount(labels)
    keep = np.flatnonzero(counts >= s.min_points)
    if keep.size == 0:
        return []
    keep = keep[np.argsort(-counts[keep], kind="stable")]
    # pixel (row, col) of each candidate in the full image
    h_s, w_s = d.shape
    rows, cols = np.divmod(flat[ci], w_s)
    rows, cols = rows * st, cols * st
    out = []
    core_c = core[ci]
    texture = _ClusterTexture(image, (H, W), s)
    for lab in keep:
        m = labels == lab
        lo, hi, center = _cluster_box(cp[m], core_c[m], pose.t, s)
        mask = np.zeros((H, W), bool)
        mask[rows[m], cols[m]] = True
        mask = _fill_strided(
            mask, depth, intrinsics, pose, lo, hi, max(st, 2), s.cluster_voxel_m / 2, edges_full
        )
        if texture.too_plain(mask) or _an_alias(matches, mask, s.min_alias_ratio):
            # on a plain surface (the matcher's guess, not a measurement), or a periodic
            # texture (windows, stripes) matched a period off
            continue
        # the half size covers the box around the (robust) centre
        out.append(MoverDetection(center, np.maximum(center - lo, hi - center), int(m.sum()), mask))
    return out


def _an_alias(matches: PairMatches | None, mask: np.ndarray, min_ratio: float) -> bool:
    """Whether the cluster of ``mask`` (depth grid, bool) is matched, as a whole, nearly as well
    at a farther disparity as at its own (:meth:`PairMatches.region_alias_ratio` below
    ``min_ratio``; no matches, ``min_ratio`` 0 or an empty mask: False)."""
    if matches is None or min_ratio <= 0:
        return False
    rows, cols = np.nonzero(mask)
    return rows.size > 0 and matches.region_alias_ratio(rows, cols) < min_ratio


def _moved(
    motion: tuple[MotionView, MotionView], rows: np.ndarray, cols: np.ndarray, s: MoverSettings
) -> np.ndarray:
    """(N,) bool: the motion test (:func:`skyrecon.perception.motion_test.moved`) of the
    depth-grid pixels ``rows``, ``cols`` (N,), with the settings' rules."""
    now, previous = motion
    return moved(
        now,
        previous,
        rows,
        cols,
        s.motion_ratio,
        s.motion_min_contrast,
        s.behind_m,
        s.noise_sigmas * s.depth_noise_frac,
        int(s.motion_patch_px),
        int(s.motion_slack_px),
    )


def _cluster_box(
    q: np.ndarray, core: np.ndarray, cam_center: np.ndarray, s: MoverSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lo, hi, center)`` (3,) each, world metres: the box of a cluster's points ``q`` (N, 3)
    (its pixels are filled in within it) and the detection's centre. The box spans its points
    on their own evidence (``core`` (N,) bool), and the points taken in through a gate within
    ``gate_inflate_m`` of those (all gate points would let the box, and with it the gate, grow
    frame by frame along the viewing ray: stereo smear, background). The centre is that of the
    points no deeper along the viewing ray than ``ray_extent_per_width`` (see
    :class:`MoverSettings`) times the cluster's width across it; with ``box_quantile`` (a far
    cluster) box and centre are those of the box spanning quantiles of those points."""
    if core.sum() >= max(3, s.min_points // 3):
        lo, hi = q[core].min(axis=0) - s.gate_inflate_m, q[core].max(axis=0) + s.gate_inflate_m
        q = q[np.all((q >= lo) & (q <= hi), axis=1)]
    lo, hi = q.min(axis=0), q.max(axis=0)
    c_pts = _within_ray_extent(q, cam_center, s.ray_extent_per_width) if s.ray_extent_per_width > 0 else q
    if (
        s.box_quantile > 0
        and len(c_pts) >= _MIN_ROBUST_POINTS
        and np.median(np.linalg.norm(c_pts - cam_center, axis=1)) >= s.robust_box_range_m
    ):
        lo, hi = np.quantile(c_pts, [s.box_quantile, 1 - s.box_quantile], axis=0)
        return lo, hi, (lo + hi) / 2
    return lo, hi, (c_pts.min(axis=0) + c_pts.max(axis=0)) / 2


def _within_ray_extent(q: np.ndarray, cam_center: np.ndarray, per_width: float) -> np.ndarray:
    """The points of ``q`` (N, 3) (world, metres) no farther along the viewing ray (from the
    camera centre (3,) to their median) than ``per_width`` times the cluster's widest extent
    across that ray beyond its nearest point: a visible surface of a box is seldom deeper than
    it is wide, the stereo smear of its outline towards the background is. All of them when
    fewer than 3 would remain."""
    ray = np.median(q, axis=0) - cam_center
    n = float(np.linalg.norm(ray))
    if n < 1e-9:
        return q
    ray = ray / n
    side = np.cross(ray, [0.0, 0.0, 1.0])
    if np.linalg.norm(side) < 1e-6:  # looking straight up or down
        side = np.cross(ray, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    up = np.cross(side, ray)
    rel = q - cam_center
    along = rel @ ray
    width = max(float(np.ptp(rel @ side)), float(np.ptp(rel @ up)))
    keep = along <= along.min() + per_width * width
    return q[keep] if np.count_nonzero(keep) >= 3 else q


#: pixels of a cluster whose texture is measured (evenly spread over it)
_TEXTURE_SAMPLES = 40


class _ClusterTexture:
    """Texture of clusters of depth pixels in the image they were matched from (grey converted
    once, on the first cluster asked about); no image, or ``min_texture`` 0: no test."""

    def __init__(self, image: np.ndarray | None, depth_shape: tuple[int, int], s: MoverSettings):
        self._min = float(s.min_texture) if image is not None else 0.0
        self._share = float(s.min_textured_share)
        self._grey: np.ndarray | None = None
        if self._min <= 0:
            return
        img = np.asarray(image)
        self._image, self._k = img, grid_scale(img, depth_shape, "mover detection")
        self._off = np.arange(int(s.texture_window_px)) - int(s.texture_window_px) // 2

    def too_plain(self, mask: np.ndarray) -> bool:
        """Whether less than ``min_textured_share`` of the cluster of ``mask`` lies on texture."""
        return self._min > 0 and float(np.mean(self.deviations(mask) >= self._min)) < self._share

    def deviations(self, mask: np.ndarray) -> np.ndarray:
        """(K,) for (up to :data:`_TEXTURE_SAMPLES` of) the pixels of ``mask`` (depth grid, bool,
        not empty), the grey-level standard deviation in the window around each, grey levels."""
        rows, cols = np.nonzero(mask)
        if rows.size > _TEXTURE_SAMPLES:
            pick = np.linspace(0, rows.size - 1, _TEXTURE_SAMPLES).astype(np.intp)
            rows, cols = rows[pick], cols[pick]
        if self._grey is None:
            from skyrecon.stereo.base import to_grey

            self._grey = to_grey(self._image)
        g = self._grey
        r = np.clip(rows[:, None] * self._k + self._off, 0, g.shape[0] - 1)[:, :, None]
        c = np.clip(cols[:, None] * self._k + self._off, 0, g.shape[1] - 1)[:, None, :]
        return g[r, c].astype(np.float32).std(axis=(1, 2))


def merge_fine_depth(
    depth_m: np.ndarray, fine_depth_m: np.ndarray, intrinsics: Intrinsics, settings: MoverSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Take a full-resolution matcher's depth where it sees a nearer surface (see
    :func:`detect_movers`, argument ``fine``).

    Args:
        depth_m: (H, W) depth, metres (NaN invalid, inf no return).
        fine_depth_m: (H, W) depth of the fine matcher on the same grid, metres (NaN none).
        intrinsics: the camera of both; settings: ``fine_min_range_m``, ``fine_range_m`` and the
            free-space margin (``behind_m``, ``noise_sigmas``, ``depth_noise_frac``).
    Returns:
        ``(depth, taken, seen_behind)``: the merged (H, W) float32 depth; (H, W) bool where the
        fine depth was taken; (H, W) bool where, besides, ``depth_m`` measured a surface (or no
        return) beyond the fine point by the margin.
    """
    depth = np.asarray(depth_m, np.float32)
    fine = np.asarray(fine_depth_m, np.float32)
    if fine.shape != depth.shape:
        raise InputError(f"fine depth {fine.shape} and depth {depth.shape} must have the same size")
    _, ray_norm = _rays(intrinsics, 1)
    with np.errstate(invalid="ignore"):
        r_fine = fine * ray_norm
        r_now = depth * ray_norm
        margin = settings.behind_m + settings.noise_sigmas * settings.depth_noise_frac * r_fine
        usable = (
            np.isfinite(r_fine) & (r_fine >= settings.fine_min_range_m) & (r_fine <= settings.fine_range_m)
        )
        seen_behind = usable & (r_now > r_fine + margin)
        taken = seen_behind | (usable & np.isnan(r_now))
    return np.where(taken, fine, depth), taken, seen_behind


def _depth_edges(
    depth: np.ndarray, jump_frac: float, near_frac: float = 0.0, hole_min_valid: int = 0
) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W) bool: pixels whose 3x3 neighbourhood spans a depth jump above ``jump_frac`` of
    their depth (the sky's ``inf`` counts as far: its border is an edge; so do unmeasured (NaN)
    neighbours with ``hole_min_valid`` 0, else they are left out, and a pixel with fewer than
    ``hole_min_valid`` measured neighbours of its 8 is an edge);
    and, when ``near_frac`` > 0, (H, W) bool: valid pixels within ``near_frac`` of their depth of
    the nearest depth in that neighbourhood (the near side of a jump: the foreground object's own
    pixels), else None."""
    d = np.where(np.isfinite(depth), depth, 1e4).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    nearest = cv2.erode(d, k)  # a hole's 1e4 never lowers the nearest
    if hole_min_valid <= 0:
        edges = (cv2.dilate(d, k) - nearest) > jump_frac * d
    else:
        hole = np.isnan(depth)
        edges = (cv2.dilate(np.where(hole, np.float32(0), d), k) - nearest) > jump_frac * d
        measured = cv2.boxFilter((~hole).astype(np.float32), -1, (3, 3), normalize=False)
        edges |= measured < hole_min_valid + 1  # itself and at least hole_min_valid around
    if near_frac <= 0:
        return edges, None
    return edges, (d < 1e4) & (d <= nearest * np.float32(1.0 + near_frac))


def _near_edge_points(
    edges: np.ndarray,
    near_full: np.ndarray | None,
    rng: np.ndarray,
    flat: np.ndarray,
    st: int,
    min_range_m: float,
) -> np.ndarray | None:
    """(N,) bool over the points ``flat`` (indices into the strided depth image, ranges ``rng``):
    depth-edge points on the near side of their jump (the object's own surface, ``near_full`` of
    :func:`_depth_edges`) at least ``min_range_m`` metres away; None when that option is off."""
    if near_full is None:
        return None
    near = edges & near_full[::st, ::st].reshape(-1)[flat]
    return near & (rng.reshape(-1)[flat] >= min_range_m)


def _keep_near_edges_clear_of_surfaces(
    cand: np.ndarray,
    near_edge: np.ndarray | None,
    fine_f: np.ndarray,
    occ_map: OccupancyMap,
    pts: np.ndarray,
    clear_m: float,
) -> None:
    """Drop (in ``cand``, in place) the near-edge candidates (not fine points) that lie within
    ``clear_m`` of an occupied voxel: a static surface's edge widened onto the background."""
    if near_edge is None:
        return
    c3 = np.flatnonzero(cand & near_edge & ~fine_f)
    cand[c3] = _clear_of_surfaces(occ_map, pts[c3], clear_m)


def _clear_of_surfaces(occ_map: OccupancyMap, pts: np.ndarray, clear_m: float) -> np.ndarray:
    """(N,) bool: world points (N, 3) none of whose 26 neighbours ``clear_m`` metres away (steps
    of -1, 0, 1 times it per axis) lies in an occupied voxel of the map."""
    from skyrecon.mapping.occupancy import OCCUPIED

    if not len(pts):
        return np.zeros(0, bool)
    around = (pts[None, :, :] + (_CUBE_STEPS * clear_m)[:, None, :]).reshape(-1, 3)
    state = occ_map.classify(occ_map.log_odds_at(around)).reshape(len(_CUBE_STEPS), -1)
    return np.all(state != OCCUPIED, axis=0)


def _fill_strided(
    mask: np.ndarray,
    depth: np.ndarray,
    intr: Intrinsics,
    pose: Rigid3,
    lo: np.ndarray,
    hi: np.ndarray,
    st: int,
    margin: float,
    edges: np.ndarray | None = None,
) -> np.ndarray:
    """Full-resolution pixel mask of a cluster found at stride ``st``: the pixels near a cluster
    pixel (within ``st`` pixels) whose point lies in the cluster's box ``[lo, hi]`` grown by
    ``margin``, and the depth-edge pixels (``edges`` (H, W) bool) among them: the mover's
    silhouette, where stereo puts points between it and the background."""
    # (cv2, not scipy.ndimage: importing that on a mover's first sighting stalled a cycle by 60 ms)
    near = cv2.dilate(mask.view(np.uint8), np.ones((2 * st + 1, 2 * st + 1), np.uint8)).view(bool)
    r, c = np.nonzero(near)
    z = depth[r, c].astype(np.float64)
    ok = np.isfinite(z)
    r, c, z = r[ok], c[ok], z[ok]
    xy = intr.normalized(np.stack([c, r], axis=1).astype(np.float64))
    p = (np.concatenate([xy, np.ones((len(z), 1))], axis=1) * z[:, None]) @ pose.R.T + pose.t
    inside = np.all((p >= lo - margin) & (p <= hi + margin), axis=1)
    out = np.zeros_like(mask)
    out[r[inside], c[inside]] = True
    if edges is not None:
        out |= near & edges
    return out | mask


# ----- tracking -------------------------------------------------------------------------------
class MoverTracker:
    """Detects and tracks movers frame by frame (see the module docstring).

    Args:
        settings: :class:`MoverSettings` (defaults if None).
    """

    def __init__(self, settings: MoverSettings | None = None):
        self.settings = settings or MoverSettings()
        self.reset()

    def reset(self) -> None:
        """Forget all tracks."""
        self._tracks: list[MoverTrack] = []
        self._next_id = 1
        self._time: float | None = None
        self._history: list[SeenDepth] = []  # earlier frames for the see-through test, oldest first
        self._last_view: MotionView | None = None  # the previous frame, for the motion test

    @property
    def tracks(self) -> list[MoverTrack]:
        """The live tracks (not copies)."""
        return self._tracks

    @property
    def time_s(self) -> float | None:
        """Time of the last update, seconds (None before the first)."""
        return self._time

    # ----- Kalman filter ----------------------------------------------------------------------
    def _predict_track(self, t: MoverTrack, dt: float) -> None:
        if dt <= 0:
            return
        q = self.settings.accel_noise_mps2**2
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        Q = np.zeros((6, 6))
        Q[:3, :3] = (dt**4 / 4) * q * np.eye(3)
        Q[:3, 3:] = Q[3:, :3] = (dt**3 / 2) * q * np.eye(3)
        Q[3:, 3:] = dt**2 * q * np.eye(3)
        t.position = t.position + dt * t.velocity
        t.covariance = F @ t.covariance @ F.T + Q

    def _correct_track(self, t: MoverTrack, z: np.ndarray) -> None:
        r2 = self.settings.meas_noise_m**2
        P = t.covariance
        S = P[:3, :3] + r2 * np.eye(3)
        K = P[:, :3] @ np.linalg.inv(S)
        innov = z - t.position
        x = np.concatenate([t.position, t.velocity]) + K @ innov
        IKH = np.eye(6)
        IKH[:, :3] -= K
        t.covariance = IKH @ P @ IKH.T + r2 * K @ K.T  # Joseph form
        t.position, t.velocity = x[:3], x[3:]

    def _initial_covariance(self) -> np.ndarray:
        """(6, 6) covariance of a track's first detection: the measurement noise on the position,
        ``init_speed_sigma_mps`` on the unknown velocity."""
        s = self.settings
        return np.diag([s.meas_noise_m**2] * 3 + [s.init_speed_sigma_mps**2] * 3)

    def _restart_track(self, t: MoverTrack, z: np.ndarray) -> None:
        """Start ``t``'s state afresh at the measured centre ``z`` (3,) (see
        ``MoverSettings.reacquire_s``): velocity unknown, as for a new track."""
        t.position = np.asarray(z, dtype=np.float64).copy()
        t.velocity = np.zeros(3)
        t.covariance = self._initial_covariance()

    def _new_track(self, det: MoverDetection, time_s: float) -> MoverTrack:
        s = self.settings
        P = self._initial_covariance()
        t = MoverTrack(
            track_id=self._next_id,
            position=det.center.copy(),
            velocity=np.zeros(3),
            covariance=P,
            half_size=det.half_size.copy(),
            side_half_size=det.half_size.copy(),
            first_seen_s=time_s,
            last_seen_s=time_s,
            first_position=det.center.copy(),
            confirmed=s.confirm_hits <= 1,
        )
        self._next_id += 1
        return t

    def _gate_radius(self, t: MoverTrack) -> float:
        g = self.settings.gate_m
        # a large mover seen in fragments (partly occluded) has its fragments' centres far apart
        return min(g + 3.0 * t.position_sigma, 3.0 * g) + float(t.half_size.max())

    # ----- per frame --------------------------------------------------------------------------
    def update(
        self,
        time_s: float,
        depth_m: np.ndarray,
        intrinsics: Intrinsics,
        world_from_cam: Rigid3 | np.ndarray,
        occ_map: OccupancyMap,
        fine: FineDepth | None = None,
        image: np.ndarray | None = None,
        matches: PairMatches | None = None,
    ) -> MoverFrame:
        """Detect movers in one depth frame, update the tracks, and say which pixels to keep out.

        Args:
            time_s: frame time, seconds (non-decreasing).
            depth_m: (H, W) depth along the optical axis, metres; NaN invalid, inf no return.
            intrinsics: the depth camera.
            world_from_cam: the camera pose (Rigid3 or 4x4 / 3x4 matrix).
            occ_map: the static map *before* this frame is integrated (not modified).
            fine: optional full-resolution depth of the same view (see :func:`detect_movers`).
            image: optional left image the depth was matched from, for the texture test (see
                :func:`detect_movers`).
            matches: optional disparities and pair of the depth, for the alias test (see
                :func:`detect_movers`).
        Returns:
            :class:`MoverFrame`.
        """
        from skyrecon.mapping.inputs import as_world_from_cam

        t0 = time.perf_counter()
        s = self.settings
        time_s = self._advance(time_s)
        pose = as_world_from_cam(world_from_cam)
        gated = [t for t in self._tracks if t.confirmed and t.moving]
        references = self._references(time_s)
        motion = None
        if s.motion_ratio > 0 and image is not None:
            view = MotionView.of(time_s, image, depth_m, intrinsics, pose)
            last = self._last_view
            if last is not None and time_s - last.time_s <= s.motion_max_gap_s:
                motion = (view, last)
            self._last_view = view
        dets = detect_movers(
            depth_m,
            intrinsics,
            pose,
            occ_map,
            s,
            _box_gates(gated, s.gate_inflate_m + s.meas_noise_m),
            references,
            fine,
            image,
            motion,
            matches,
        )
        seen_now = SeenDepth.of(time_s, depth_m, intrinsics, pose) if s.history_s or s.refute_frames else None
        if s.history_s and seen_now is not None:
            self._history.append(seen_now)
        live = self._track(dets, time_s, pose.t)
        if s.refute_frames and seen_now is not None:
            live = self._refute(seen_now, pose.t)
        by_id = {t.track_id: t for t in live}
        mask = np.zeros(np.asarray(depth_m).shape, bool)
        for det in dets:
            tr = by_id.get(det.track_id)
            if tr is not None and not tr.static:
                mask |= det.pixel_mask
        ms = (time.perf_counter() - t0) * 1e3
        return MoverFrame(time_s, dets, [t.copy() for t in live], mask, ms)

    def track(
        self, time_s: float, detections: list[MoverDetection], cam_center: np.ndarray
    ) -> list[MoverTrack]:
        """Update the tracks with detections made elsewhere (or recorded): what :meth:`update`
        does after its detection step. For replaying recorded detections with other settings
        (``benchmarks/dynamic/replay_tracker.py``).

        Args:
            time_s: frame time, seconds (non-decreasing).
            detections: this frame's :class:`MoverDetection` (world frame; their ``track_id`` is set).
            cam_center: (3,) camera centre, world metres.
        Returns:
            copies of the live tracks.
        """
        time_s = self._advance(time_s)
        live = self._track(list(detections), time_s, np.asarray(cam_center, dtype=np.float64))
        return [t.copy() for t in live]

    def _advance(self, time_s: float) -> float:
        """Predict every track forward to ``time_s`` (seconds, checked non-decreasing)."""
        time_s = float(time_s)
        if self._time is not None and time_s < self._time:
            raise InputError(f"mover tracker: time went backwards ({time_s} s after {self._time} s)")
        dt = 0.0 if self._time is None else time_s - self._time
        self._time = time_s
        for t in self._tracks:
            self._predict_track(t, dt)
            t.age_s = time_s - t.first_seen_s
        return time_s

    def _track(self, dets: list[MoverDetection], time_s: float, cam_center: np.ndarray) -> list[MoverTrack]:
        """Associate ``dets``, then drop the tracks unseen too long (tentative ones at their first
        miss) and those no real mover would make; the live tracks."""
        s = self.settings
        self._associate(dets, time_s, cam_center)
        live = []
        for t in self._tracks:
            t.coasting = t.last_seen_s < time_s
            if t.coasting and (not t.confirmed or time_s - t.last_seen_s > s.coast_s):
                continue
            if t.hits >= s.confirm_hits and (
                t.speed > s.max_speed_mps or abs(float(t.velocity[2])) > s.max_climb_mps
            ):
                continue  # no real mover moves like that: outliers chained by chance
            live.append(t)
        self._tracks = live
        return live

    def _refute(self, seen_now: SeenDepth, cam_center: np.ndarray) -> list[MoverTrack]:
        """Count, per coasting confirmed track, the consecutive frames that saw through its
        predicted centre, and drop those refuted ``refute_frames`` times (see
        :attr:`MoverSettings.refute_frames`); the live tracks left."""
        s = self.settings
        coasting = [t for t in self._tracks if t.coasting and t.confirmed]
        for t in self._tracks:
            if not t.coasting:
                t.refuted = 0
        if coasting:
            centres = np.array([t.position for t in coasting])
            rng = np.linalg.norm(centres - cam_center, axis=1)
            through = seen_now.seen_through(centres, rng, s) & (rng <= s.refute_range_m)
            for t, hit in zip(coasting, through):
                t.refuted = t.refuted + 1 if hit else 0
        self._tracks = [t for t in self._tracks if t.refuted < s.refute_frames]
        return self._tracks

    def _references(self, time_s: float) -> list[SeenDepth]:
        """Per age in ``history_s``, the latest remembered frame at least that much older than
        ``time_s`` (none for an age no frame has reached yet, one frame once for equal picks);
        frames older than what the longest age needs are forgotten."""
        refs: list[SeenDepth] = []
        last_k = -1
        times = np.array([f.time_s for f in self._history])
        for age in sorted(self.settings.history_s):
            k = int(np.searchsorted(times, time_s - age + 1e-9, side="right")) - 1
            if k >= 0 and all(r is not self._history[k] for r in refs):
                refs.append(self._history[k])
            last_k = k
        if last_k > 0:
            self._history = self._history[last_k:]
        return refs

    def _associate(self, dets: list[MoverDetection], time_s: float, cam_center: np.ndarray) -> None:
        """Match detections to tracks, correct matched tracks, start tracks for the others."""
        s = self.settings
        tracks = self._tracks
        pairs: list[tuple[int, int]] = []
        if tracks and dets:
            pt = np.array([t.position for t in tracks])
            pd = np.array([d.center for d in dets])
            cost = np.linalg.norm(pt[:, None, :] - pd[None, :, :], axis=2)
            gate = np.array([self._gate_radius(t) for t in tracks])
            big = 1e6
            cost = np.where(cost <= gate[:, None], cost, big)
            ri, ci = linear_sum_assignment(cost)
            pairs = [(int(i), int(j)) for i, j in zip(ri, ci) if cost[i, j] < big]
        matched_d = set()
        for i, j in pairs:
            t, det = tracks[i], dets[j]
            matched_d.add(j)
            ray = det.center - cam_center
            ray = ray / max(float(np.linalg.norm(ray)), 1e-9)
            # the visible surface is nearer than the centre: push the centre away from the camera
            # by the size the track has seen from the side and this view does not show
            # (with push_once_moving only once it has moved, see MoverSettings)
            hidden = np.maximum(t.side_half_size - det.half_size, 0.0)
            if s.push_once_moving and not t.was_moving:
                hidden[:] = 0.0
            if s.max_push_m is None:
                z = det.center + np.sign(ray) * hidden
            else:  # along the ray, capped
                z = det.center + ray * min(float(np.abs(ray) @ hidden), s.max_push_m)
            restart = (
                s.reacquire_s is not None
                and time_s - t.last_seen_s > s.reacquire_s
                and float(np.linalg.norm(z - t.position)) > s.reacquire_gap_m
            )
            if restart:
                self._restart_track(t, z)
            else:
                self._correct_track(t, z)
            t.half_size = _decaying_max(t.half_size, det.half_size, s.size_memory)
            # an axis's size seen from the side, not smeared along a viewing ray
            across = np.abs(ray) <= s.side_view_cos
            t.side_half_size = np.where(
                across, _decaying_max(t.side_half_size, det.half_size, s.size_memory), t.side_half_size
            )
            t.hits += 1
            t.last_seen_s = time_s
            det.track_id = t.track_id
            self._classify(t, time_s)
            if restart:  # its speed is unknown until the next detection: a mover stays a mover
                t.moving = t.confirmed and t.was_moving and not t.static
        for j, det in enumerate(dets):
            if j not in matched_d:
                t = self._new_track(det, time_s)
                det.track_id = t.track_id
                self._classify(t, time_s)
                tracks.append(t)

    def _classify(self, t: MoverTrack, time_s: float) -> None:
        """Update ``confirmed``, ``moving``, ``static`` of a track just detected."""
        s = self.settings
        t.confirmed = t.confirmed or t.hits >= s.confirm_hits
        speed = t.speed
        t.moving = t.confirmed and not t.static and speed > s.moving_speed_mps
        if t.static and speed > s.moving_speed_mps and t.hits > s.static_frames + 2:
            t.static, t.moving = False, True
        t.was_moving = t.was_moving or t.moving
        if not t.static and not t.was_moving and t.hits >= s.static_frames and t.age_s > 0:
            mean_speed = np.linalg.norm(t.position - t.first_position) / t.age_s
            if speed < s.static_speed_mps and mean_speed < s.static_speed_mps:
                t.static = True

    # ----- for the planner ----------------------------------------------------------------------
    def _planner_tracks(self) -> list[MoverTrack]:
        return [t for t in self._tracks if t.avoided]

    def predict(self, horizon_s: float, dt: float = 0.1) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Predicted paths of the confirmed moving (or coasting) tracks.

        Args:
            horizon_s: how far ahead, seconds; dt: step, seconds.
        Returns:
            ``[(track_id, positions (T, 3) world metres at times 0, dt, ..., horizon, half_size (3,))]``
            with ``T = floor(horizon / dt) + 1``, times relative to the last update.
        """
        if dt <= 0 or horizon_s < 0:
            raise InputError(f"need dt > 0 and horizon >= 0, got dt={dt}, horizon={horizon_s}")
        ts = np.arange(int(np.floor(horizon_s / dt + 1e-9)) + 1) * dt
        return [
            (t.track_id, t.position[None, :] + ts[:, None] * t.velocity[None, :], t.half_size.copy())
            for t in self._planner_tracks()
        ]

    def keep_out(self, horizon_s: float, margin_m: float = 0.0) -> np.ndarray:
        """(K, 7) capsules ``[x0, y0, z0, x1, y1, z1, radius]`` the planner must avoid.

        One per confirmed moving (or coasting, once moving) track: the segment from its position
        to its predicted position after ``horizon_s`` seconds, radius ``norm(half_size)`` plus
        ``keep_out_sigmas`` standard deviations of the position predicted at the horizon (capped
        at ``max_keep_out_margin_m``) plus ``margin_m`` (metres).
        """
        out = []
        for t in self._planner_tracks():
            end = t.position + horizon_s * t.velocity
            P = t.covariance
            Ph = P[:3, :3] + horizon_s * (P[:3, 3:] + P[3:, :3]) + horizon_s**2 * P[3:, 3:]
            sig = float(np.sqrt(max(np.linalg.eigvalsh(Ph).max(), 0.0)))
            margin = min(self.settings.keep_out_sigmas * sig, self.settings.max_keep_out_margin_m)
            radius = np.linalg.norm(t.half_size) + margin + margin_m
            out.append(np.concatenate([t.position, end, [radius]]))
        return np.array(out, np.float64).reshape(-1, 7)
