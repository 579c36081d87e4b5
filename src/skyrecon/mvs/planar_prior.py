"""Planar priors for plain (textureless) surfaces: depth where photo-consistency is flat.

PatchMatch leaves plain regions (a plain wall, a grey road, glass) without depth: their matching
windows have no texture, so no cost can tell one depth from another. Their geometry is still
fixed by what surrounds them: the reliable depths at their borders (contact lines, corners,
textured neighbours) and the sparse feature points. Following ACMP (Xu & Tao, "Planar Prior
Assisted PatchMatch Multi-View Stereo", AAAI 2020), reliable support points are triangulated
(Delaunay) and each triangle's plane is a hypothesis for the plain pixels; here the hypotheses are
chosen per *plain segment* rather than per pixel, which also covers plain regions that reach
beyond the support (the ground out to the image border):

1. ``segments``: pixels without a PatchMatch depth, away from intensity edges, split into
   4-connected segments (one per plain face, as far as edges separate them); small ones are left.
2. ``support``: confident PatchMatch depths (cost at most ``support_cost``) and the sparse points
   that project into the view unoccluded.
3. ``planes``: per segment, candidates are the planes of the Delaunay triangles of the support in
   a band around the segment, and the scene's dominant planes (sequential RANSAC on the sparse
   points and the consistent PatchMatch points, :func:`dominant_planes`, and the heights where
   points gather, :func:`horizontal_planes`). A candidate needs at least ``min_inliers`` band
   support points on it (within ``inlier_rel`` relative depth; triangle planes: also spread over
   ``min_spread_px`` in both image directions; dominant planes are scored on every band point).
   A horizontal dominant plane (world z up) also qualifies with no contact point when the whole
   band lies on or in front of it: the plain ground reaching behind everything that stands on it,
   whose feet this view does not see.
   Besides, the Manhattan candidates of the band support (:func:`_manhattan_planes`): vertical
   planes through pairs of points and level planes through single points, refitted to their
   inliers. A plain wall's only support is often its two vertical corner lines, and an occluder
   in front of it (a column) adds a third: the triangles and the best supported plane by count
   then run slanted through the column, while a vertical plane through the two corners is the
   wall itself. And the walls of the dominant walls' directions (and those at right angles
   to them) through the band points on them (:func:`_direction_walls`): a plain face beside a
   textured one shares only a corner line with it, which a known direction turns into a wall.
4. ``visibility``: a candidate must not hide what was measured. Two counts: the share of the band
   support that lies *beyond* the plane (this view would not see it through the segment), and
   the share of the segment's interior whose plane point a source sees *through* (the source's
   PatchMatch depth lies beyond it: free-space violation). A wrong plane floating in front of the
   true surface (a terrace height for the ground) is caught by them; one behind it is not, which
   the contact points and the border take care of.
   A level candidate may hide at most ``max_front_hidden`` of the band; a wall more
   (``max_front_hidden_wall``): beyond its top edge and its convex corners lies what stands
   back (a set-back storey, the roof behind it), seen past it by this view.
5. ``border``: the share of the segment's border ring (``ring_px`` wide) that looks the same in
   the sources under the plane: a wrong plane carries the border pixels onto other surfaces.
   Dominant planes win over the view's own planes unless one of those matches clearly more of
   the border (``dominant_margin``); within, the score is the border share less
   ``see_through_weight`` times the two visibility shares (a wall's hidden band share weighs
   ``wall_hidden_weight``); a winner nearly matched by another plane that differs on the
   border is ambiguous and left empty (:func:`_choose_plane`).
   Nothing in a city overhangs the ground: a level winner that would go on *under* a nearer
   edge right above the segment (the ground behind a plain plinth face, below the plinth's top
   edge) or stand out *over* band points right below it (a top carried past its edge) yields to
   a well supported wall that does neither (``max_overhang``, :func:`_overhang_shares`).
6. ``check``: every pixel's plane point is projected into the sources; its colour must agree
   with the reference (``color_tol``) in at least ``min_sources`` of the sources that see it. A
   segment where fewer than ``min_pass_fraction`` of the pixels pass is dropped whole.

7. ``propagate``: a second pass offers the planes that filled a view's segments (world frame,
   with samples of their pixels) to the segments its neighbours left empty where those samples
   land, under the same checks (the multi-view propagation of planes of ACMMP, Xu & Tao 2020).
   A view often sees a plain wall's two corners and fills it while its neighbours, seeing one
   corner, find no plane; fusion keeps a wall only where three views agree on it.

The multi-view geometric-consistency fusion then keeps only the points that other views'
depth maps agree with (:mod:`skyrecon.mvs.fusion`): no texture is needed there.

Known limits (``benchmarks/mvs/diagnose_ring.py`` shows them per view): the plain rings of
``benchmarks/mvs`` reach F 0.87-0.93 at 1 % of the ring radius (target 0.9: a, f and g pass),
recall 0.76-0.88 at precision 0.93-1.0; five held-out plain rings (seeds 50-94) 0.78-0.93.
(a) The views' own walls through a wall's corner and contact lines can be a
degree or more off (a vertical corner line fixes a vertical plane only up to a rotation about
it); fusion now lets two plane-filled pixels agree within what its depth tolerance allows
(``FusionSettings.max_reproj_px_prior``), which brought back most walls the 1 px check
refused, but a wall a view fits too far off stays out. (b) A plain plinth top and the plain
ground behind it meet without an intensity edge (same grey, same light) and are one segment,
which takes one plane: the ground's (the plinth top missing, ring-plain-f: a fifth of its
misses) or the plinth's, carried over the ground (ring-plain-b: precision 0.93; views whose
ground band holds no ground contact point and the plinth's edge). Splitting such a segment
between the level planes of its band, each pixel to the plane of its nearest band point, was
tried: the boundary it draws is not the plinth's hidden back edge, and the roofs' back edges
seen against the ground split it too (plain rings worst F 0.864 -> 0.860, ring-plain-a
precision 1.0 -> 0.97); left out. (c) A level dominant plane may take a wall's segment (a
uniform face looks the same in the nearby sources under any plane behind it, and a plane behind
the true surface is caught by no visibility test); the overhang rule gives the segment back to
the wall only where the view's own wall is a well supported candidate. Applied to every
candidate (not only level winners) it lost more than it gained: the plain ground merged with a
plain roof of the same grey goes on under the top storey's edge (ring-plain-b F 0.866 -> 0.44
with the ground set aside), and PatchMatch points along a wall's top edge up to 6 % too near
put the right wall over the limit (ring-plain-d 0.864 -> 0.851 when walls yielded too). On
ring-plain-d the plinth faces have no candidate wall at all: their only support is the top
edge, one horizontal line, which the spread test refuses; letting a vertical plane through such
a line count (its spread along the plane's horizontal) gave d +0.002, b +0.004, g +0.013 but e
-0.009 (more walls, more segments left ambiguous), and the same figures when only segments
without any other wall candidate get them: left out. Also tried and left (ring-plain-e and -d, F
within -0.03 to +0.006): relaxing the hidden-band rule for every wall (now for the walls of the
frame only), refusing level planes without contact points or with contacts along one line, and
twelve dominant planes. Reading only confident source depths in the see-through test (PatchMatch
cost at most 0.3; two sources of a view of ring-plain-d held depths 4-9 % too far on a plain
face, which refused its true wall) raised ring-plain-e 0.890 -> 0.908 but let walls through the
inside of the tower of the tests' plain ring that those depths had refused: left out.

Bad input: whatever goes wrong (no support, degenerate triangulations, no plane that fits) the
view keeps its PatchMatch depth unchanged and the reason is returned (``PriorReport.fallback``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from numba import njit
from scipy.spatial import Delaunay, QhullError

from skyrecon.errors import InputError
from skyrecon.mvs.frames import WorkingView
from skyrecon.mvs.patchmatch import brightness_gain

__all__ = [
    "PlanarPriorSettings",
    "PriorReport",
    "FilledPlanes",
    "dominant_planes",
    "horizontal_planes",
    "fill_plain_segments",
    "planar_prior_depth",
]


#: a plane is level (world z up) when its unit normal's vertical component is above this
_LEVEL_COS = 0.99
#: Manhattan candidates kept per segment: vertical, level; and how far apart two must be
_MANHATTAN_KEPT = (4, 2)
_MANHATTAN_DISTINCT_DEG = 3.0


@dataclass(frozen=True)
class PlanarPriorSettings:
    """Settings of the planar prior (see the module docstring).

    Attributes:
        enabled: use the planar prior at all.
        support_cost: PatchMatch pixels with at most this cost are support points.
        edge_grad: intensity gradient (grey levels per pixel, Sobel of the image blurred with
            sigma 1, scaled for dark images like the texture thresholds) above which a pixel is an
            edge between segments.
        min_segment_fraction: smallest segment, fraction of the image.
        band_px: width of the band around a segment whose support is used, pixels.
        max_support: at most this many band support points per segment (evenly subsampled).
        inlier_rel: a support point is on a plane when their depths differ by at most this
            fraction.
        min_inliers: smallest number of band support points on the winning plane.
        min_spread_px: a triangle plane's inliers must spread over at least this many pixels
            (standard deviation) along their least spread direction (a line of points does not fix
            a plane; a dominant plane is fixed by the sparse points already).
        color_tol: largest grey-level difference between a pixel and its projection into a
            source (images blurred with sigma 1), grey levels.
        min_sources: sources that must agree (or all that see the point, if fewer).
        min_pass_fraction: a segment is kept only if at least this fraction of its pixels pass
            (and of its border ring, for the winning plane).
        max_candidates: distinct candidate planes tried per segment.
        ambiguity_margin: a segment is left empty when a different candidate's border agreement is
            within this of the winner's.
        dark_level: segments darker than this (mean grey level, scaled for dark images) are
            unlit background (a black backdrop), not surfaces: left empty.
        ring_px: width of a segment's border ring on which candidates are compared, pixels.
        max_ring_px: at most this many ring pixels are compared (evenly subsampled).
        max_planes: dominant planes from the sparse points.
        plane_tol_frac: inlier distance of the dominant planes, fraction of the sparse points'
            extent (between their 5th and 95th percentiles).
        min_plane_points: points a dominant plane needs.
        ransac_iterations: random planes tried per dominant plane.
        max_plane_input: at most this many points (evenly subsampled) go into the dominant planes.
        max_see_through: a candidate whose segment interior a source sees through in more than
            this share of the sampled pixels is set aside.
        see_through_margin: a measured depth counts as beyond a plane point when it is farther by
            more than this fraction.
        see_through_weight: weight of the visibility shares against the border share.
        max_front_fraction: a horizontal dominant plane without contact points qualifies when at
            most this share of the band support lies beyond it.
        max_front_hidden: a candidate that would hide more than this share of the band support is
            set aside.
        see_through_samples: interior pixels sampled (evenly) for the see-through test.
        manhattan_hypotheses: vertical planes (through random pairs of band support points, a
            fixed seed) and level planes (through single points) tried per segment; the 4
            best supported vertical and 2 level ones, distinct by more than 3 degrees or
            ``2 * inlier_rel`` of the depth, are candidates (0: none). With
            ``max_front_hidden_wall`` they fill plain walls of the rings in ``benchmarks/mvs``
            that were left empty in every view; fusion keeps a wall only where two other views
            filled it too (``FusionSettings.min_consistent_prior``).
        max_front_hidden_wall: as ``max_front_hidden`` for candidates that are not level (world
            z up): a wall hides what lies beyond its top edge and convex corners.
        wall_hidden_weight: weight of the hidden band share (``max_front_hidden``) in the
            ranking of candidates that are not level, in place of ``see_through_weight``: a
            plain tower wall hid a quarter of its band (the roof beyond its top edge) and lost
            to a slanted plane through a column that hid less but matched less of the border.
        dominant_margin: a dominant plane wins over the view's own planes unless one of those
            matches more of the border by more than this (:func:`_choose_plane`).
        dominant_wall_min_support: ... and a dominant *wall* wins that way only with at least
            this fraction of the band support of the best supported wall of the view's own
            (0: always). Beside a plain wall, the dominant planes hold textured faces set back
            from it (a storey above: 4.7 % deeper on ring-plain-e). With 0.5 and the refits
            below, the plain rings' F at 1 % of the radius: worst 0.840 -> 0.848, mean 0.856
            -> 0.866 (ring-plain-a 0.877 -> 0.906, c 0.865 -> 0.854); the textured rings, rock
            and temple within 0.001.
        level_top_min_support: a level candidate with at least this share of the segment's
            band support on it (within ``inlier_rel``) is a raised top (a plinth, a terrace, a
            flat roof): it may hide as much of the band as a wall (``max_front_hidden_wall``)
            and that share is not held against it in the ranking, because what it hides is the
            lower surfaces around it that the view sees past its convex edges (a plane a little
            lower hides less and won the plinth tops of the plain rings). A level plane floating
            in front of the true surface (a terrace height over the ground) has few band points
            on it and keeps the strict rule. Above 1: never.
        max_overhang, overhang_rival_max, overhang_rival_support: a level winner (the ground, a
            terrace) that would meet more than ``max_overhang`` of the band support as an
            overhang (:func:`_overhang_shares`: the segment going on *under* a nearer edge right
            above it, or standing out *over* band points right below it) yields to the best
            good wall that meets at most ``overhang_rival_max`` of it so, with at least
            ``overhang_rival_support`` of the band support on it. A plain plinth's front face
            took the ground plane behind it (a dominant plane, its precedence kept on a border
            that looks the same under any plane) in most views of ring-plain-e although its own
            wall through its top edge and foot was a candidate: ring-plain-e's F at 1 % of the
            radius 0.863 -> 0.885, g 0.901 -> 0.915, the other rings within 0.002. Only with
            ``hidden_band`` (oblique views; off for ``skyrecon survey``'s nadir photos, where it
            was not measured).
        manhattan_refits: the Manhattan planes are refitted this many times more to the band
            points within ``manhattan_refit_rel`` of the depth of the last fit (the first fit's
            inliers, within ``inlier_rel``, include points of the neighbouring face near a
            corner and tilt the wall by a degree or two); 0: one fit.
        manhattan_refit_rel: the refits' inlier distance, fraction of the depth.
        propagate: a second pass offers the planes that filled segments of a view to the
            segments its neighbours left empty (:class:`FilledPlanes`, ACMMP's multi-view
            propagation of planes): a plain wall that one view filled from its corners is tried
            where the others saw too little support to find it, under the same checks, so that
            the views agree on it in fusion.
        propagate_samples: pixels (evenly spaced) kept per filled segment to tell which segments
            of another view it covers.
        propagate_min_hits: an offered plane is tried on a segment when at least this many of
            its samples project into it.
        direction_walls: candidates per segment and per direction of the scene's frame
            (:func:`_direction_walls`): walls of the dominant walls' normals (those another
            dominant wall is parallel or at right angles to) and of the normals at right angles
            to them, through the band support on them, even along one line (0: none, and no
            frame for ``framed_front_hidden``). A plain face of a tower beside a textured one
            has the corner line they share as its only support, and a vertical line fixes no
            wall (the Manhattan pairs above tilt about it); a direction of the frame does.
            Session 60, ring-plain-d: in 14 of the 16 views' segments on its plain tower faces
            no candidate lay within 10 degrees of the truth; with these, the true wall was a
            candidate in each (within 0.2 degrees and 3 cm), but it hid 0.6-0.8 of its band
            (the textured face beyond their common corner carries most of the band support)
            and lost on that: hence ``framed_front_hidden``.
        framed_front_hidden, framed_hidden_weight: ``max_front_hidden_wall`` and
            ``wall_hidden_weight`` for walls of the scene's frame (normal within 3 degrees of
            one of its directions, see ``direction_walls``): at a convex corner of a building
            the face beyond lies at right angles, and a wall of the frame hides it legitimately.
            Slanted walls keep the strict rule: given to every wall, planes through two opposite
            corners of a tower (RANSAC's, or a Manhattan pair's) won in the plain test ring of
            ``tests/mvs`` (seed 1: 19 % of the cloud more than 8 cm off, against 2 %). The
            weight: 0.2 lost ring-plain-f 0.03 of F (0.902 at 0.6, 0.873 at 0.5 and below) and
            gained held-out rings 0.007-0.02; 0.6 changes no ring by more than 0.01 from 0.2's
            but f.
        hidden_band: use the band-hidden test (off: only the sources' see-through test). It
            tells the plain ground from a terrace height on oblique views (a floating plane hides
            the feet of what stands on the ground); on nadir survey photos every plain roof hides
            the street beyond its edges, and the test lowered the DSM's share within 0.3 m (100
            photos: 96.1 % without it, 94.7 % with it), so ``skyrecon survey`` turns it off.
    """

    enabled: bool = True
    support_cost: float = 0.3
    edge_grad: float = 2.0
    min_segment_fraction: float = 0.0005
    band_px: int = 6
    max_support: int = 400
    inlier_rel: float = 0.01
    min_inliers: int = 8
    min_spread_px: float = 3.0
    color_tol: float = 6.0
    min_sources: int = 2
    min_pass_fraction: float = 0.5
    max_candidates: int = 12
    dark_level: float = 12.0
    ambiguity_margin: float = 0.05
    ring_px: int = 4
    max_ring_px: int = 3000
    max_planes: int = 6
    plane_tol_frac: float = 0.004
    min_plane_points: int = 20
    ransac_iterations: int = 512
    max_plane_input: int = 40000
    max_see_through: float = 0.02
    see_through_margin: float = 0.02
    see_through_weight: float = 10.0
    max_front_fraction: float = 0.01
    max_front_hidden: float = 0.2
    hidden_band: bool = True
    see_through_samples: int = 1000
    manhattan_hypotheses: int = 200
    max_front_hidden_wall: float = 0.5
    wall_hidden_weight: float = 1.0
    dominant_margin: float = 0.2
    dominant_wall_min_support: float = 0.5
    level_top_min_support: float = 0.5
    max_overhang: float = 0.05
    overhang_rival_max: float = 0.02
    overhang_rival_support: float = 0.5
    manhattan_refits: int = 2
    manhattan_refit_rel: float = 0.005
    propagate: bool = True
    propagate_samples: int = 64
    propagate_min_hits: int = 4
    direction_walls: int = 2
    framed_front_hidden: float = 0.95
    framed_hidden_weight: float = 0.6

    def __post_init__(self) -> None:
        if not (0 < self.support_cost <= 2) or self.edge_grad <= 0 or self.band_px < 1:
            raise InputError("planar prior: need 0 < support_cost <= 2, edge_grad > 0, band_px >= 1")
        if self.min_inliers < 3 or self.min_sources < 1 or self.max_support < 3:
            raise InputError("planar prior: need min_inliers >= 3, min_sources >= 1, max_support >= 3")
        if not (0 < self.inlier_rel < 1) or self.color_tol <= 0 or not (0 <= self.min_pass_fraction <= 1):
            raise InputError(
                "planar prior: need 0 < inlier_rel < 1, color_tol > 0, 0 <= min_pass_fraction <= 1"
            )
        if (
            self.propagate_samples < 1
            or self.propagate_min_hits < 1
            or self.propagate_min_hits > self.propagate_samples
        ):
            raise InputError("planar prior: need 1 <= propagate_min_hits <= propagate_samples")
        if min(self.max_overhang, self.overhang_rival_max, self.overhang_rival_support) < 0:
            raise InputError(
                "planar prior: need max_overhang, overhang_rival_max and overhang_rival_support >= 0"
            )
        if self.dominant_margin < 0 or self.wall_hidden_weight < 0:
            raise InputError("planar prior: need dominant_margin >= 0 and wall_hidden_weight >= 0")
        if (
            self.dominant_wall_min_support < 0
            or self.manhattan_refits < 0
            or not (0 < self.manhattan_refit_rel < 1)
        ):
            raise InputError(
                "planar prior: need dominant_wall_min_support >= 0, manhattan_refits >= 0 and "
                "0 < manhattan_refit_rel < 1"
            )
        if self.direction_walls < 0:
            raise InputError("planar prior: need direction_walls >= 0")
        if not (0 <= self.framed_front_hidden <= 1) or self.framed_hidden_weight < 0:
            raise InputError("planar prior: need 0 <= framed_front_hidden <= 1 and framed_hidden_weight >= 0")


class FilledPlanes(NamedTuple):
    """The planes that filled plain segments, to offer to other views (the second pass).

    Attributes:
        planes: (K, 4) float64 world planes (n, c), n . X = c, unit n.
        points: (M, 3) float64 world metres: samples of the pixels each plane filled.
        plane_of: (M,) int64 index into ``planes`` of each sample.
    """

    planes: np.ndarray
    points: np.ndarray
    plane_of: np.ndarray

    @staticmethod
    def empty() -> FilledPlanes:
        return FilledPlanes(np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0, np.int64))

    @staticmethod
    def concat(parts: list[FilledPlanes]) -> FilledPlanes:
        """One set of several views' planes (indices renumbered)."""
        parts = [p for p in parts if len(p.planes)]
        if not parts:
            return FilledPlanes.empty()
        offsets = np.cumsum([0] + [len(p.planes) for p in parts[:-1]])
        return FilledPlanes(
            np.concatenate([p.planes for p in parts]),
            np.concatenate([p.points for p in parts]),
            np.concatenate([p.plane_of + o for p, o in zip(parts, offsets)]),
        )


@dataclass
class PriorReport:
    """What the planar prior did in one view.

    Attributes:
        segments: plain segments considered.
        filled_segments: segments that received a plane.
        filled_px: pixels that received a depth from a plane.
        support_px: support points (PatchMatch and sparse).
        fallback: why the prior was not applied (the PatchMatch depth is kept as it was), or "".
        details: counts of segments set aside, by reason.
        planes: the planes that filled segments, with samples of their pixels (world frame).
    """

    segments: int = 0
    filled_segments: int = 0
    filled_px: int = 0
    support_px: int = 0
    fallback: str = ""
    details: dict[str, int] = field(default_factory=dict)
    planes: FilledPlanes = field(default_factory=FilledPlanes.empty)

    def as_dict(self) -> dict[str, int | str]:
        out: dict[str, int | str] = dict(
            segments=self.segments,
            filled_segments=self.filled_segments,
            filled_px=self.filled_px,
            support_px=self.support_px,
        )
        if self.fallback:
            out["fallback"] = self.fallback
        return out


# ------------------------------------------------------------------------------------------------
# dominant planes of the sparse points
# ------------------------------------------------------------------------------------------------
def dominant_planes(
    points: np.ndarray, settings: PlanarPriorSettings = PlanarPriorSettings(), seed: int = 0
) -> np.ndarray:
    """Sequential RANSAC planes of a point set (the scene's dominant planes).

    Args:
        points: (N, 3) world points, metres (the multi-view consistent PatchMatch points and the
            sparse points).
        settings: ``max_planes``, ``plane_tol_frac``, ``min_plane_points``.
        seed: seed of the random samples.
    Returns:
        (P, 4) float64 planes ``(n, c)`` with ``n . X = c``, ``|n| = 1``, world frame, most
        supported first (refit by least squares on their inliers); (0, 4) if none.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) > settings.max_plane_input:
        pts = pts[np.linspace(0, len(pts) - 1, settings.max_plane_input).astype(np.int64)]
    out: list[np.ndarray] = []
    if len(pts) < settings.min_plane_points:
        return np.zeros((0, 4))
    extent = float(np.linalg.norm(np.percentile(pts, 95, axis=0) - np.percentile(pts, 5, axis=0)))
    tol = settings.plane_tol_frac * max(extent, 1e-9)
    rng = np.random.default_rng(seed)
    remaining = pts
    for _ in range(settings.max_planes):
        if len(remaining) < settings.min_plane_points:
            break
        idx = rng.integers(0, len(remaining), (settings.ransac_iterations, 3))
        a, b, c = remaining[idx[:, 0]], remaining[idx[:, 1]], remaining[idx[:, 2]]
        n = np.cross(b - a, c - a)
        nn = np.linalg.norm(n, axis=1)
        ok = nn > 1e-12
        if not ok.any():
            break
        n = n[ok] / nn[ok, None]
        off = np.sum(n * a[ok], axis=1)
        dist = np.abs(remaining @ n.T - off[None, :])  # (N, T)
        counts = (dist <= tol).sum(0)
        best = int(np.argmax(counts))
        inl = dist[:, best] <= tol
        if counts[best] < settings.min_plane_points:
            break
        plane = _fit_plane(remaining[inl])
        inl = np.abs(remaining @ plane[:3] - plane[3]) <= tol
        if inl.sum() < settings.min_plane_points:
            break
        out.append(_fit_plane(remaining[inl]))
        remaining = remaining[~inl]
    return np.array(out).reshape(-1, 4)


def horizontal_planes(
    points: np.ndarray, settings: PlanarPriorSettings = PlanarPriorSettings()
) -> np.ndarray:
    """Horizontal candidate planes: the ground under the scene and the heights where points gather
    (world z up, see DESIGN).

    City scenes are full of horizontal surfaces (the ground, roofs, terraces) whose plain interior
    gives PatchMatch nothing while their borders (contact lines with walls, corners) give a few
    points at their height. Like the Manhattan-world prior of urban MVS, candidates are: the
    lowest height where at least ``min_plane_points`` points gather within two bins (the ground the
    scene stands on), and the peaks of the height histogram with at least that many points more
    than their surroundings (bins of the dominant planes' tolerance). They are only candidates:
    each plain segment still needs band support on the plane and photometric agreement.

    Args:
        points: (N, 3) world points, metres.
        settings: ``plane_tol_frac``, ``min_plane_points``, ``max_planes``.
    Returns:
        (P, 4) float64 planes ``(0, 0, 1, z)`` (``n . X = c``), the ground first; (0, 4) if none.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < settings.min_plane_points:
        return np.zeros((0, 4))
    extent = float(np.linalg.norm(np.percentile(pts, 95, axis=0) - np.percentile(pts, 5, axis=0)))
    tol = settings.plane_tol_frac * max(extent, 1e-9)
    z = pts[:, 2]
    lo, hi = float(z.min()), float(z.max())
    nb = int(min(100000, max(2, np.ceil((hi - lo) / tol) + 1)))
    counts, edges = np.histogram(z, bins=nb, range=(lo, lo + nb * tol))
    heights: list[float] = []
    pair = counts[:-1] + counts[1:]
    first = np.nonzero(pair >= settings.min_plane_points)[0]
    if len(first):
        i = int(first[0])
        h = float(z[(z >= edges[i]) & (z < edges[i + 2])].mean())
        for _ in range(3):  # settle on the median of the points within the tolerance
            h = float(np.median(z[np.abs(z - h) <= tol]))
        heights.append(h)
    k = 10
    padded = np.pad(counts.astype(np.float64), k, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1)
    prominence = counts - np.median(windows, axis=1)
    local_max = counts >= np.max(windows[:, k - 1 : k + 2], axis=1)
    idx = np.nonzero(local_max & (prominence >= settings.min_plane_points))[0]
    idx = idx[np.argsort(-prominence[idx], kind="stable")]
    for i in idx[: settings.max_planes]:
        c = 0.5 * (edges[i] + edges[i + 1])
        h = float(z[np.abs(z - c) <= tol].mean())
        if all(abs(h - o) > 2 * tol for o in heights):
            heights.append(h)
    return np.array([[0.0, 0.0, 1.0, h] for h in heights], np.float64).reshape(-1, 4)


def _fit_plane(p: np.ndarray) -> np.ndarray:
    """Least-squares plane (n, c) of (N, 3) points, n . X = c."""
    m = p.mean(0)
    _, _, vt = np.linalg.svd(p - m, full_matrices=False)
    n = vt[-1]
    return np.array([*n, float(n @ m)])


# ------------------------------------------------------------------------------------------------
# per view
# ------------------------------------------------------------------------------------------------
def _rays(view: WorkingView, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame rays (x, y, 1) of pixels (u, v)."""
    k = view.intrinsics
    return np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=np.float64)], axis=1)


def _sparse_support(
    view: WorkingView, points: np.ndarray | None, depth: np.ndarray, near: float, far: float
) -> np.ndarray:
    """(H, W) float64 depth of the sparse points seen in ``view`` (NaN elsewhere); points behind a
    confident PatchMatch depth (occluded here) are left out."""
    H, W = view.shape
    out = np.full((H, W), np.nan)
    if points is None or len(points) == 0:
        return out
    Xc = view.cam_from_world.apply(np.asarray(points, np.float64))
    z = Xc[:, 2]
    k = view.intrinsics
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(k.fx * Xc[:, 0] / z + k.cx)
        v = np.rint(k.fy * Xc[:, 1] / z + k.cy)
    ok = (z >= near) & (z <= far) & (u >= 0) & (v >= 0) & (u < W) & (v < H)
    u, v, z = u[ok].astype(np.int64), v[ok].astype(np.int64), z[ok]
    ok = view.valid[v, u]
    dz = depth[v, u]
    with np.errstate(invalid="ignore"):
        ok &= ~(dz < z * 0.98)  # something confident in front of it: occluded here
    order = np.argsort(-z[ok], kind="stable")  # nearest written last
    out[v[ok][order], u[ok][order]] = z[ok][order]
    return out


def _plane_depth(n: np.ndarray, h: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Depth along the optical axis of rays (N, 3) on planes n . X = h: (P, N); NaN where the ray
    meets the plane from behind or not at all. ``n`` (P, 3), ``h`` (P,)."""
    den = n @ rays.T  # (P, N)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = h[:, None] / den
    d[~(den < -1e-9) | ~(d > 0)] = np.nan
    return d


def _triangle_planes(uv: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(T, 4) camera-frame planes (n, h), n . X = h, n facing the camera (h < 0), of the Delaunay
    triangles of the image points ``uv`` (N, 2) with camera-frame points ``X`` (N, 3)."""
    if len(uv) < 3:
        return np.zeros((0, 4))
    try:
        tri = Delaunay(uv)
    except (QhullError, ValueError):  # collinear or duplicate points: no triangles
        return np.zeros((0, 4))
    s = tri.simplices
    a, b, c = X[s[:, 0]], X[s[:, 1]], X[s[:, 2]]
    n = np.cross(b - a, c - a)
    nn = np.linalg.norm(n, axis=1)
    ok = nn > 1e-12 * np.maximum(np.linalg.norm(a, axis=1), 1.0) ** 2
    n = n[ok] / nn[ok, None]
    h = np.sum(n * a[ok], axis=1)
    flip = h > 0
    n[flip] *= -1
    h[flip] *= -1
    return np.concatenate([n, h[:, None]], axis=1)


def _manhattan_planes(X: np.ndarray, up: np.ndarray, s: PlanarPriorSettings) -> np.ndarray:
    """(K, 4) camera-frame planes (n, h), n . X = h, facing the camera (h < 0): vertical and
    horizontal planes (world z up, ``up`` (3,) its direction in the camera frame) through the
    band support points ``X`` (N, 3) metres, camera frame.

    City walls are vertical and roofs, terraces and roads horizontal (the Manhattan-world prior
    of urban MVS, used for the heights in :func:`horizontal_planes`). A plain wall's support is
    its two vertical corner lines, and a triangle through three noisy corner points tilts; a
    vertical plane is fixed by two of them. Hypotheses: ``manhattan_hypotheses`` vertical planes
    through random pairs of the points (a fixed seed: same input, same planes) and as many
    horizontal planes through single points; the best supported of each kind are refitted to
    their inliers (least squares under the constraint). They only add candidates: each still
    needs its inliers' spread and the visibility and photometric checks.
    """
    up = np.asarray(up, np.float64)
    up = up / np.linalg.norm(up)
    n_pts = len(X)
    k = int(s.manhattan_hypotheses)
    if n_pts < 3 or k <= 0:
        return np.zeros((0, 4))
    rng = np.random.default_rng(n_pts)
    i, j = rng.integers(0, n_pts, (2, k))
    nv = np.cross(X[j] - X[i], up)
    nn = np.linalg.norm(nv, axis=1)
    ok = nn > 1e-6 * np.maximum(np.linalg.norm(X[i], axis=1), 1.0)
    nv = nv[ok] / nn[ok, None]
    hv = np.sum(nv * X[i[ok]], axis=1)
    ih = rng.choice(n_pts, min(k, n_pts), replace=False)
    nh = np.repeat(up[None], len(ih), axis=0)
    hh = X[ih] @ up
    P = np.concatenate([np.c_[nv, hv], np.c_[nh, hh]], axis=0)
    flip = P[:, 3] > 0
    P[flip] *= -1
    rays = X / X[:, 2:3]
    depth = X[:, 2].copy()
    inl, score = _plane_inliers(P[:, :3] @ rays.T, P[:, 3].copy(), depth, float(s.inlier_rel))
    vertical = np.arange(len(P)) < len(nv)
    depth_scale = float(np.median(X[:, 2]))
    cos_distinct = np.cos(np.radians(_MANHATTAN_DISTINCT_DEG))
    out: list[np.ndarray] = []
    for is_vertical, limit in zip((True, False), _MANHATTAN_KEPT):
        order = np.nonzero((vertical == is_vertical) & (score >= s.min_inliers))[0]
        order = order[np.argsort(-score[order], kind="stable")]
        kept: list[np.ndarray] = []
        for q in order:
            if len(kept) >= limit:
                break
            members = inl[q]
            for refit in range(1 + int(s.manhattan_refits)):
                pts = X[members]
                if is_vertical:  # the line of the points' footprints on the horizontal plane
                    flat = pts - np.outer(pts @ up, up)
                    _, _, vt = np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)
                    n = np.cross(vt[0], up)
                    n /= np.linalg.norm(n)
                    h = float(n @ pts.mean(axis=0))
                else:
                    n, h = up.copy(), float(np.median(pts @ up))
                if h > 0:
                    n, h = -n, -h
                if refit == s.manhattan_refits:
                    break
                # refit to the points on the fitted plane, closer: a random pair's inliers
                # include points of a neighbouring face near their common edge
                on, count = _plane_inliers(
                    (n @ rays.T)[None], np.array([h]), depth, float(s.manhattan_refit_rel)
                )
                if count[0] < 3:
                    break
                members = on[0]
            # distinct planes, not distinct inlier sets: a wall and a slanted plane through its
            # far corner and an occluder in front share half their support
            if any(
                float(n @ k[:3]) > cos_distinct and abs(h - k[3]) < 2 * s.inlier_rel * depth_scale
                for k in kept
            ):
                continue
            kept.append(np.array([*n, h]))
        out += kept
    return np.array(out, np.float64).reshape(-1, 4)


def _level_units(normals: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(P, 3) the normals (P, 3) made exactly horizontal (their ``up`` (3,) unit component taken
    out) and unit length: a wall's direction."""
    flat = normals - np.outer(normals @ up, up)
    return flat / np.linalg.norm(flat, axis=1, keepdims=True)


def _framed_walls(planes: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(P,) bool: which of the planes (P, 4) (n, h) are walls (within 0.1 of vertical, ``up``
    (3,) the world's z in their frame) that another of them is parallel or at right angles to
    (within ``_MANHATTAN_DISTINCT_DEG``): the directions of the scene's frame. A lone slanted
    wall is most often RANSAC's plane through two opposite corner lines of a tower."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    is_wall = np.abs(planes[:, :3] @ up) <= 0.1
    out = np.zeros(len(planes), bool)
    if is_wall.sum() < 2:
        return out
    same = np.cos(np.radians(_MANHATTAN_DISTINCT_DEG))
    walls = _level_units(planes[is_wall, :3], up)
    across = np.cross(up, walls)
    out[is_wall] = ((np.abs(walls @ walls.T) > same) | (np.abs(walls @ across.T) > same)).sum(axis=1) >= 2
    return out


def _frame_normals(planes: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the scene's frame: of the walls among ``planes`` (P, 4) that
    :func:`_framed_walls` keeps, made exactly vertical, and those at right angles to them,
    distinct by ``_MANHATTAN_DISTINCT_DEG`` (up to sign)."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    walls = _level_units(planes[_framed_walls(planes, up), :3], up)
    same = np.cos(np.radians(_MANHATTAN_DISTINCT_DEG))
    normals: list[np.ndarray] = []
    for n in walls:
        for m in (n, np.cross(up, n)):  # the wall and the one at right angles to it
            if all(abs(float(m @ k)) < same for k in normals):
                normals.append(m)
    return np.array(normals, np.float64).reshape(-1, 3)


def _in_frame(planes: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(K,) bool: planes (K, 4) whose normal is within ``_MANHATTAN_DISTINCT_DEG`` of one of the
    ``frame`` normals (F, 3) (up to sign)."""
    if len(frame) == 0 or len(planes) == 0:
        return np.zeros(len(planes), bool)
    n = planes[:, :3] / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
    return (np.abs(n @ frame.T) > np.cos(np.radians(_MANHATTAN_DISTINCT_DEG))).any(axis=1)


def _direction_walls(X: np.ndarray, uv: np.ndarray, frame: np.ndarray, s: PlanarPriorSettings) -> np.ndarray:
    """(K, 4) camera-frame walls (n, h), n . X = h, facing the camera (h < 0), with the normals
    of the scene's frame (``frame`` (F, 3) camera frame, :func:`_frame_normals` of the dominant
    planes), through the band support ``X`` (N, 3) metres (pixels ``uv`` (N, 2)): per
    direction, the offsets of the most band points, up to ``direction_walls`` distinct ones,
    each refitted to its inliers (their median offset).

    A city's walls share a few directions, and a plain wall often has one supported line only:
    a vertical corner line it shares with a textured face, or its foot. A line fixes no plane,
    but a line and a known direction do. Each needs ``min_inliers`` points whose image extent
    (along u or v) is at least ``min_spread_px`` (a line counts, a speck not); the caller's
    spread test (:func:`_spreads`, across the points' line) does not apply to them."""
    k = int(s.direction_walls)
    if k <= 0 or len(frame) == 0 or len(X) < s.min_inliers:
        return np.zeros((0, 4))
    rays = X / X[:, 2:3]
    depth = X[:, 2].copy()
    depth_scale = float(np.median(depth))
    out: list[np.ndarray] = []
    for n0 in frame:
        for n in (n0, -n0):
            h_all = X @ n
            if not (h_all < 0).any():
                continue
            pick = np.nonzero(h_all < 0)[0]
            if len(pick) > s.manhattan_hypotheses:
                pick = pick[np.linspace(0, len(pick) - 1, s.manhattan_hypotheses).astype(np.int64)]
            den = np.repeat((n @ rays.T)[None], len(pick), axis=0)
            inl, score = _plane_inliers(den, h_all[pick].copy(), depth, float(s.inlier_rel))
            order = np.argsort(-score, kind="stable")
            kept: list[float] = []
            for q in order:
                if len(kept) >= k or score[q] < s.min_inliers:
                    break
                members = inl[q]
                h = float(np.median(h_all[members]))
                if any(abs(h - g) < 2 * s.inlier_rel * depth_scale for g in kept):
                    continue
                u = uv[members]
                extent = max(float(np.ptp(u[:, 0])), float(np.ptp(u[:, 1])))
                if extent < s.min_spread_px:
                    continue
                kept.append(h)
                out.append(np.array([*n, h]))
    return np.array(out, np.float64).reshape(-1, 4)


def _spreads(uv: np.ndarray, members: np.ndarray) -> np.ndarray:
    """How far each subset of image points spreads: the standard deviation along its least spread
    direction (the square root of the smaller eigenvalue of its 2x2 covariance), (K,) pixels, for
    the (K, N) bool ``members`` of the points ``uv`` (N, 2); 0 for subsets of fewer than 3 points.
    One matrix product for every subset (a segment has hundreds of candidate triangle planes)."""
    if len(members) == 0:
        return np.zeros(0)
    w = members.astype(np.float64)
    count = w.sum(axis=1)
    c0 = uv - uv.mean(axis=0)  # centred once, so that the moments below lose no precision
    m = (w @ c0) / np.maximum(count, 1.0)[:, None]  # (K, 2) subset means
    sq = np.stack([c0[:, 0] ** 2, c0[:, 0] * c0[:, 1], c0[:, 1] ** 2], axis=1)
    mom = (w @ sq) / np.maximum(count, 1.0)[:, None]  # (K, 3) raw second moments
    a = mom[:, 0] - m[:, 0] ** 2
    b = mom[:, 1] - m[:, 0] * m[:, 1]
    d = mom[:, 2] - m[:, 1] ** 2
    smallest = 0.5 * (a + d) - np.hypot(0.5 * (a - d), b)
    out = np.sqrt(np.maximum(smallest, 0.0))
    out[count < 3] = 0.0
    return out


def _candidate_planes(
    uv: np.ndarray,
    d: np.ndarray,
    rays: np.ndarray,
    global_planes: np.ndarray,
    seg_ray: np.ndarray,
    cos_max: float,
    s: PlanarPriorSettings,
    all_rays: np.ndarray | None = None,
    all_d: np.ndarray | None = None,
    horizontal: np.ndarray | None = None,
    up: np.ndarray | None = None,
    own: bool = True,
    frame: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Distinct supported planes (K, 4) for one segment from its band support, best supported
    first, and (K,) bool which of them are dominant (``global_planes``) planes.

    A plane qualifies with at least ``min_inliers`` band support points on it (triangle planes:
    spread over ``min_spread_px``), facing the camera within the incidence limit at the segment's
    centre ray. Every qualifying dominant plane is kept; of triangle planes whose inlier sets
    overlap by more than half, only the better supported one, at most ``max_candidates``.
    Triangle planes come from (and are scored on) the band support ``uv`` (N, 2) pixels, ``d``
    (N,) metres, ``rays`` (N, 3), at most ``max_support`` of them; dominant planes are few and
    are scored on every band support point (``all_rays`` (M, 3), ``all_d`` (M,); default the
    same points), so that a long border's few contact points (a big plain ground segment's
    feet of walls) are not thinned away. A ``horizontal`` (P,) dominant plane (world z up: the
    ground, a terrace) also qualifies without contact points when every band support point lies
    on or in front of it (at most ``max_front_fraction`` beyond): the ground reaching behind all
    that stands on it, whose feet this view does not see. ``own=False``: only the dominant
    planes (no triangle or Manhattan planes of this band). ``frame`` (F, 3): the view's frame
    directions (:func:`_frame_normals`) for :func:`_direction_walls` (None: none).
    """
    X = rays * d[:, None]
    n_global = len(global_planes)
    tri = _triangle_planes(uv, X) if own else np.zeros((0, 4))
    manhattan = _manhattan_planes(X, up, s) if up is not None and own else np.zeros((0, 4))
    # walls of the dominant directions: fixed by one supported line, so no spread test below
    directed = _direction_walls(X, uv, frame, s) if frame is not None and own else np.zeros((0, 4))
    n_directed = len(directed)
    manhattan = np.concatenate([manhattan, directed], axis=0)
    if n_global + len(tri) + len(manhattan) == 0:
        return np.zeros((0, 4)), np.zeros(0, bool)
    r = seg_ray / np.linalg.norm(seg_ray)
    kept_global: list[int] = []
    if n_global:
        g_rays, g_d = (rays, d) if all_rays is None or all_d is None else (all_rays, all_d)
        _, g_score = _plane_inliers(
            global_planes[:, :3] @ g_rays.T, global_planes[:, 3].copy(), g_d, float(s.inlier_rel)
        )
        g_facing = -(global_planes[:, :3] @ r) >= cos_max
        gd = _plane_depth(global_planes[:, :3], global_planes[:, 3], g_rays)
        with np.errstate(invalid="ignore"):
            g_front = np.count_nonzero(g_d[None, :] > gd * (1.0 + s.see_through_margin), axis=1)
            g_behind = np.all(np.isfinite(gd), axis=1) & (g_front <= s.max_front_fraction * len(g_d))
        g_behind &= np.zeros(n_global, bool) if horizontal is None else horizontal
        kept_global = [
            i for i in range(n_global) if g_facing[i] and (g_score[i] >= s.min_inliers or g_behind[i])
        ]
    kept_tri: list[int] = []
    if len(tri):
        inl, score = _plane_inliers(tri[:, :3] @ rays.T, tri[:, 3].copy(), d, float(s.inlier_rel))
        score[~(-(tri[:, :3] @ r) >= cos_max)] = -1
        order = np.argsort(-score, kind="stable")
        order = order[score[order] >= s.min_inliers]
        spread = _spreads(uv, inl[order])
        kept_tri = [
            int(i)
            for i in _distinct_planes(
                inl, score, order, spread, float(s.min_spread_px), int(s.max_candidates)
            )
        ]
    kept_manhattan: list[int] = []
    if len(manhattan):  # kept on their own (not thinned by shared support with triangle planes)
        inl, score = _plane_inliers(manhattan[:, :3] @ rays.T, manhattan[:, 3].copy(), d, float(s.inlier_rel))
        spread = _spreads(uv, inl)
        facing = -(manhattan[:, :3] @ r) >= cos_max
        spread[len(manhattan) - n_directed :] = np.inf
        kept_manhattan = [
            i
            for i in range(len(manhattan))
            if facing[i] and score[i] >= s.min_inliers and spread[i] >= s.min_spread_px
        ]
    P = np.concatenate(
        [global_planes[kept_global], manhattan[kept_manhattan], tri[kept_tri]], axis=0
    ).reshape(-1, 4)
    return P, np.arange(len(P)) < len(kept_global)


@njit(cache=True, nogil=True, boundscheck=False)
def _plane_inliers(
    den: np.ndarray, h: np.ndarray, d: np.ndarray, inlier_rel: float
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - jit
    """Which of N support points lie on each of P planes, and how many.

    ``den`` (P, N) is ``n . ray`` of each plane's normal and each point's ray, ``h`` (P,) the
    planes' offsets, ``d`` (N,) the points' depths (metres). A point is on a plane when the ray
    meets the plane from the front (``den < -1e-9``) at a positive depth within ``inlier_rel *
    d`` of its own (:func:`_plane_depth`, same arithmetic). Returns ((P, N) bool, (P,) int64).
    """
    P, N = den.shape
    inl = np.zeros((P, N), np.bool_)
    score = np.zeros(P, np.int64)
    for p in range(P):
        c = 0
        for j in range(N):
            dn = den[p, j]
            if dn < -1e-9:
                z = h[p] / dn
                if z > 0 and abs(z - d[j]) <= inlier_rel * d[j]:
                    inl[p, j] = True
                    c += 1
        score[p] = c
    return inl, score


@njit(cache=True, nogil=True, boundscheck=False)
def _distinct_planes(
    inl: np.ndarray,
    score: np.ndarray,
    order: np.ndarray,
    spread: np.ndarray,
    min_spread: float,
    max_kept: int,
) -> np.ndarray:  # pragma: no cover - jit
    """The planes ``order`` (best first) kept greedily: spread at least ``min_spread`` pixels
    (``spread`` per entry of ``order``), and sharing at most half of the smaller inlier set
    (rows of ``inl``, sizes ``score``) with every plane kept before; at most ``max_kept``."""
    N = inl.shape[1]
    kept = np.empty(max(max_kept, 0), np.int64)
    m = 0
    for t in range(len(order)):
        if m >= max_kept:
            break
        if spread[t] < min_spread:
            continue
        i = order[t]
        distinct = True
        for q in range(m):
            k = kept[q]
            shared = 0
            for j in range(N):
                if inl[i, j] and inl[k, j]:
                    shared += 1
            if shared > 0.5 * min(score[i], score[k]):
                distinct = False
                break
        if distinct:
            kept[m] = i
            m += 1
    return kept[:m]


def _ambiguous(
    cands: np.ndarray, fracs: np.ndarray, win: int, rays: np.ndarray, s: PlanarPriorSettings
) -> bool:
    """Whether a candidate whose depths on the ring rays (N, 3) differ from the winner's (by more
    than ``2 * inlier_rel`` on a tenth of them) looks nearly as right (``ambiguity_margin``)."""
    dw = _plane_depth(cands[win : win + 1, :3], cands[win, 3:], rays)[0]
    for k in np.nonzero(fracs > fracs[win] - s.ambiguity_margin)[0]:
        if k == win:
            continue
        dk = _plane_depth(cands[k : k + 1, :3], cands[k, 3:], rays)[0]
        with np.errstate(invalid="ignore"):
            differ = ~(np.abs(dk - dw) <= 2 * s.inlier_rel * dw)
        if differ.mean() > 0.1:
            return True
    return False


def _boundary_ring(seg: np.ndarray, width: int) -> np.ndarray:
    """(h, w) bool: the pixels of ``seg`` within ``width`` pixels of its border (4-connected)."""
    inner = cv2.erode(seg.astype(np.uint8), np.ones((2 * width + 1, 2 * width + 1), np.uint8), borderValue=1)
    return seg & (inner == 0)


def _segment_beside_band(
    ref: WorkingView,
    segment: tuple[np.ndarray, int, int],
    uu: np.ndarray,
    vv: np.ndarray,
    up: np.ndarray,
    steps: int,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The band support points with the segment right below them in the image, and those with
    the segment right above them, each with the segment pixel there.

    "Above" is the image direction of world up at the band pixel: the way its image moves when
    the point is lifted, ``(fx (up_x - x up_z), fy (up_y - y up_z))`` for the normalised pixel
    (x, y) (a vertical edge of the world runs along it). The first segment pixel along it (or
    against it, below) within ``steps`` pixels is taken; a pixel whose ray runs along ``up`` has
    no such direction.

    Args:
        segment: the segment's (h, w) bool mask in its bounding box and the box's corner x0, y0.
        uu, vv: (M,) int pixel coordinates of the band support points in that box.
        up: (3,) world z (up) in the camera frame.
    Returns:
        (below, above), each ((N,) indices into the M band points, (N, 3) camera rays (x, y, 1)
        of the segment pixels beside them).
    """
    seg, bx0, by0 = segment
    k = ref.intrinsics
    x = (uu + bx0 - k.cx) / k.fx
    y = (vv + by0 - k.cy) / k.fy
    du, dv = k.fx * (up[0] - x * up[2]), k.fy * (up[1] - y * up[2])
    norm = np.hypot(du, dv)
    has_up = norm > 1e-9 * max(k.fx, k.fy)
    norm[~has_up] = 1.0
    du, dv = du / norm, dv / norm
    h, w = seg.shape
    out = []
    for side in (-1, 1):
        found = np.zeros(len(uu), bool)
        su, sv = np.zeros(len(uu), np.int64), np.zeros(len(uu), np.int64)
        for step in range(side, side * (steps + 1), side):
            cu = np.rint(uu + step * du).astype(np.int64)
            cv_ = np.rint(vv + step * dv).astype(np.int64)
            look = has_up & ~found & (cu >= 0) & (cv_ >= 0) & (cu < w) & (cv_ < h)
            hit = np.zeros(len(uu), bool)
            hit[look] = seg[cv_[look], cu[look]]
            found |= hit
            su[hit], sv[hit] = cu[hit], cv_[hit]
        idx = np.nonzero(found)[0]
        out.append((idx, _rays(ref, (su[idx] + bx0).astype(np.float64), (sv[idx] + by0).astype(np.float64))))
    return out[0], out[1]


def _overhang_shares(
    cands: np.ndarray,
    band_d: np.ndarray,
    below: tuple[np.ndarray, np.ndarray],
    above: tuple[np.ndarray, np.ndarray],
    margin: float,
) -> np.ndarray:
    """(K,) share of the band support that each candidate plane (K, 4) would meet as an
    overhang: a band point with the segment right below it that lies nearer, by more than
    ``margin`` of the depth, than the plane at that segment pixel (the segment would go on under
    it), or one with the segment right above it that lies farther than the plane there (the
    segment would stand out over it, a ledge). Standing things (walls on the ground, a plinth,
    a column) meet what lies below their edges; a wrong plane behind a plain face, or one
    carried out past a top's edge, does not.

    Args:
        band_d: (M,) depths of the band support points, metres.
        below, above: :func:`_segment_beside_band`.
    """
    n_band = max(len(band_d), 1)
    count = np.zeros(len(cands))
    for (idx, rays), sign in ((below, -1.0), (above, 1.0)):
        if len(idx) == 0:
            continue
        plane_d = _plane_depth(cands[:, :3], cands[:, 3], rays)  # (K, N)
        with np.errstate(invalid="ignore"):
            count += np.count_nonzero(sign * (band_d[idx] - plane_d) > margin * plane_d, axis=1)
    return count / n_band


def _pixel_points_world(ref: WorkingView, u: np.ndarray, v: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N, 3) world points, metres, of pixels (u, v) of ``ref`` at depths d (N,) metres."""
    return ref.cam_from_world.inverse().apply(
        _rays(ref, u.astype(np.float64), v.astype(np.float64)) * d[:, None]
    )


def _photo_check(
    ref: WorkingView,
    sources: list[WorkingView],
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    ref_blur: np.ndarray,
    src_blur: list[np.ndarray],
    tol: float,
    min_sources: int,
) -> np.ndarray:
    """(N,) bool: the plane points of pixels (u, v) at depths d (N,) metres look the same in enough
    sources: every colour channel (blurred images, (H, W, C) float32, NaN without data) within
    ``tol`` in at least ``min_sources`` of the sources that see the point (or all, if fewer)."""
    X = _pixel_points_world(ref, u, v, d)
    g = ref_blur[v, u]
    seen = np.zeros(len(u), np.int32)
    agree = np.zeros(len(u), np.int32)
    for src, sb in zip(sources, src_blur):
        Xs = src.cam_from_world.apply(X)
        k = src.intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            x = k.fx * Xs[:, 0] / Xs[:, 2] + k.cx
            y = k.fy * Xs[:, 1] / Xs[:, 2] + k.cy
        inside = (Xs[:, 2] > 0) & np.isfinite(x) & np.isfinite(y)
        _count_agreement(sb, x, y, inside, g, np.float32(tol), seen, agree)
    return (seen > 0) & (agree >= np.minimum(min_sources, seen))


def _seen_through(
    ref: WorkingView,
    sources: list[WorkingView],
    source_depths: list[np.ndarray | None],
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    margin_rel: float,
) -> np.ndarray:
    """(N,) bool: a source's own depth lies beyond the plane point of pixel (u, v) at depth d (N,)
    metres, by more than ``margin_rel`` of the point's depth in that source: the source sees
    *through* the hypothesised surface there (free-space violation). Sources' depths are (H, W)
    metres, NaN without a measurement; a source that sees something nearer (an occluder) or
    nothing says nothing."""
    X = _pixel_points_world(ref, u, v, d)
    out = np.zeros(len(u), bool)
    for src, sd in zip(sources, source_depths):
        if sd is None:
            continue
        uv, z = src.posed().project(X)  # NaN pixels behind the camera
        h, w = sd.shape
        with np.errstate(invalid="ignore"):
            x, y = np.rint(uv[:, 0]), np.rint(uv[:, 1])
            i = np.flatnonzero((x >= 0) & (y >= 0) & (x < w) & (y < h))
            ds = sd[y[i].astype(np.int64), x[i].astype(np.int64)]
            out[i[ds > z[i] * (1.0 + margin_rel)]] = True
    return out


@njit(cache=True, nogil=True, boundscheck=False)
def _count_agreement(
    img: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    inside: np.ndarray,
    g: np.ndarray,
    tol: np.float32,
    seen: np.ndarray,
    agree: np.ndarray,
) -> None:  # pragma: no cover - jit
    """Per point i with ``inside[i]``: the source image (H, W, C) float32 sampled bilinearly at
    (x[i], y[i]) pixels, in float32. A point within the image whose samples are all numbers (no
    NaN pixel among its four neighbours) is ``seen`` (+1); if every channel is also within ``tol``
    of ``g[i]`` ((N, C) float32, the reference's colour) it ``agree``s (+1). Counts (N,) int32,
    updated in place."""
    H, W, C = img.shape
    one = np.float32(1.0)
    for i in range(len(x)):
        if not inside[i]:
            continue
        xi, yi = x[i], y[i]
        if xi < 0 or yi < 0 or xi > W - 1 or yi > H - 1:
            continue
        x0 = min(int(xi), W - 2) if W > 1 else 0
        y0 = min(int(yi), H - 2) if H > 1 else 0
        x1, y1 = min(x0 + 1, W - 1), min(y0 + 1, H - 1)
        ax, ay = np.float32(xi - x0), np.float32(yi - y0)
        worst = np.float32(0.0)
        number = True
        for c in range(C):
            top = img[y0, x0, c] * (one - ax) + img[y0, x1, c] * ax
            bot = img[y1, x0, c] * (one - ax) + img[y1, x1, c] * ax
            diff = abs(top * (one - ay) + bot * ay - g[i, c])
            if np.isnan(diff):
                number = False
                break
            worst = max(worst, diff)
        if number:
            seen[i] += 1
            if worst <= tol:
                agree[i] += 1


def _blurred_colours(ref: WorkingView, sources: list[WorkingView]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The images the photometric check compares (:func:`_blurred_colour` of the reference and
    of each source): grey for all when any of them carries no colour."""
    ref_blur = _blurred_colour(ref)
    src_blur = [_blurred_colour(sv) for sv in sources]
    if ref_blur.shape[2] != 3 or any(sb.shape[2] != 3 for sb in src_blur):  # some without colour: grey
        ref_blur = ref_blur.mean(axis=2, keepdims=True) if ref_blur.shape[2] == 3 else ref_blur
        src_blur = [sb.mean(axis=2, keepdims=True) if sb.shape[2] == 3 else sb for sb in src_blur]
    return ref_blur, src_blur


def _blurred_colour(view: WorkingView) -> np.ndarray:
    """(H, W, C) float32: the colour image (grey when the view carries none) blurred with sigma 1,
    NaN where the image has no data."""
    img = view.rgb if view.rgb.size else view.grey[..., None]
    b = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)
    b = b.reshape(*view.shape, -1)
    b[~view.valid] = np.nan
    return b


def _plain_segments(
    ref: WorkingView, accepted: np.ndarray, gain: float, settings: PlanarPriorSettings
) -> tuple[np.ndarray, np.ndarray, list[int], np.ndarray]:
    """The plain segments of a view: pixels without an ``accepted`` depth, away from intensity
    edges (``edge_grad``), 4-connected, at least ``min_segment_fraction`` of the image.

    Returns:
        ((H, W) int32 labels, (L, 5) int32 label stats of ``cv2.connectedComponentsWithStats``,
        the labels of the segments big enough, the (H, W) float32 grey image blurred with sigma 1).
    """
    s = settings
    H, W = ref.shape
    blur = cv2.GaussianBlur(ref.grey.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(blur, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(blur, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    edges = np.hypot(gx, gy) > s.edge_grad / gain
    free = ref.valid & ~accepted & ~edges
    n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(free.astype(np.uint8), connectivity=4)
    min_area = max(16, int(s.min_segment_fraction * H * W))
    segs = [i for i in range(1, n_lab) if stats[i, cv2.CC_STAT_AREA] >= min_area]
    return labels, stats, segs, blur


def _judge_candidates(
    ref: WorkingView,
    sources: list[WorkingView],
    source_depths: list[np.ndarray | None] | None,
    cands: np.ndarray,
    segment: tuple[np.ndarray, int, int],
    ring: tuple[np.ndarray, np.ndarray, np.ndarray],
    band: tuple[np.ndarray, np.ndarray],
    depth_range: tuple[float, float],
    colours: tuple[np.ndarray, list[np.ndarray], float],
    s: PlanarPriorSettings,
    wall: np.ndarray | None = None,
    framed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The evidence on each candidate plane (K, 4) (camera frame) of one segment.

    Args:
        wall: (K,) bool candidates that are not level (:func:`_walls`); None: all level.
        segment: the segment's (h, w) bool mask in its bounding box and the box's corner x0, y0.
        ring: the border ring's pixels u, v (N,) and rays (N, 3).
        band: the band support's rays (M, 3) and depths (M,) metres.
        colours: blurred reference and source images and the grey-level tolerance
            (:func:`_photo_check`).
    Returns:
        ((K,) share of the ring that looks the same in the sources, 0 for a candidate set aside;
        (K,) share of the interior samples a source sees through; (K,) share of the band support
        beyond the plane; (K,) share of the band support on the plane, within ``inlier_rel``
        of its depth, as :func:`_plane_inliers` counts it).
    """
    seg, bx0, by0 = segment
    ru, rv, rrays = ring
    all_rays, all_d = band
    ref_blur, src_blur, tol = colours
    near, far = depth_range
    fracs = np.zeros(len(cands))
    through = np.zeros(len(cands))
    front = np.zeros(len(cands))
    bd = _plane_depth(cands[:, :3], cands[:, 3], all_rays)  # (K, M) depth of each band ray on each plane
    with np.errstate(invalid="ignore"):
        on_plane = np.count_nonzero(np.abs(bd - all_d) <= s.inlier_rel * all_d, axis=1) / len(all_d)
        if s.hidden_band:
            # the share of the band support each plane would hide (this view measured it beyond
            # the plane: the segment cannot lie there unless it ends at its border)
            front = np.count_nonzero(all_d > bd * (1.0 + s.see_through_margin), axis=1) / len(all_d)
    # a level plane (the ground) hides nothing that stands on it; a wall hides what lies beyond
    # its convex corners and top edge (a set-back storey, the roof behind it), and so does a
    # raised level top that the band supports (what lies lower around it)
    limit = np.full(len(cands), s.max_front_hidden)
    limit[_level_tops(wall, on_plane, s)] = s.max_front_hidden_wall
    if wall is not None:
        limit[wall] = s.max_front_hidden_wall
    if framed is not None:
        limit[framed] = s.framed_front_hidden
    if source_depths is not None:
        # the see-through test samples the segment's interior: at its border a source's depth
        # edge (a few pixels off) reads as a view through the plane
        inner = cv2.erode(seg.astype(np.uint8), np.ones((2 * s.ring_px + 1,) * 2, np.uint8), borderValue=1)
        iv, iu = np.nonzero(inner)
        if len(iv) < s.min_inliers:
            iv, iu = np.nonzero(seg)
        keep = np.linspace(0, len(iv) - 1, min(len(iv), s.see_through_samples)).astype(np.int64)
        tu, tv = iu[keep] + bx0, iv[keep] + by0
        trays = _rays(ref, tu.astype(np.float64), tv.astype(np.float64))
    for ci, plane in enumerate(cands):
        rd = _plane_depth(plane[None, :3], plane[3:], rrays)[0]
        with np.errstate(invalid="ignore"):
            ok = (rd >= near) & (rd <= far)
            # behind the camera or too near: the plane does not fit; beyond the far end of
            # the range (a ground reaching the horizon) is only not compared
            misses = np.count_nonzero(~(rd >= near))
        if misses > 0.5 * len(rd) or ok.sum() < s.min_inliers or front[ci] > limit[ci]:
            continue
        if source_depths is not None:
            td = _plane_depth(plane[None, :3], plane[3:], trays)[0]
            with np.errstate(invalid="ignore"):
                tok = (td >= near) & (td <= far)
            through[ci] = _seen_through(
                ref, sources, source_depths, tu[tok], tv[tok], td[tok], s.see_through_margin
            ).sum() / max(int(tok.sum()), 1)
        fracs[ci] = _photo_check(
            ref, sources, ru[ok], rv[ok], rd[ok], ref_blur, src_blur, tol, s.min_sources
        ).mean()
    return fracs, through, front, on_plane


def _planes_in_camera(ref: WorkingView, planes_world: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """World planes (P, 4) (n, c), n . X = c, in ``ref``'s camera frame (n_c = R n, h = c + n_c .
    t), facing the camera (h < 0): ((P, 4), (P,) bool level in the world (z up))."""
    if planes_world is None or len(planes_world) == 0:
        return np.zeros((0, 4)), np.zeros(0, bool)
    R, t = ref.cam_from_world.R, ref.cam_from_world.t
    nc = planes_world[:, :3] @ R.T
    hc = planes_world[:, 3] + nc @ t
    flip = hc > 0
    nc[flip] *= -1
    hc[flip] *= -1
    return np.concatenate([nc, hc[:, None]], axis=1), np.abs(planes_world[:, 2]) > _LEVEL_COS


def _filled_plane(
    ref: WorkingView, plane: np.ndarray, u: np.ndarray, v: np.ndarray, d: np.ndarray, samples: int
) -> FilledPlanes:
    """One filled segment as a world plane (camera plane (4,) of ``ref``: n_w = R^T n_c, c = h -
    n_c . t) with ``samples`` of its pixels (u, v) at depths d (N,) metres, evenly spaced."""
    R, t = ref.cam_from_world.R, ref.cam_from_world.t
    nw = R.T @ plane[:3]
    world = np.array([*nw, float(plane[3] - plane[:3] @ t)])[None]
    keep = np.linspace(0, len(u) - 1, min(len(u), samples)).astype(np.int64)
    pts = _pixel_points_world(ref, u[keep], v[keep], d[keep])
    return FilledPlanes(world, pts, np.zeros(len(pts), np.int64))


def _offered_per_segment(
    ref: WorkingView, offered: FilledPlanes, labels: np.ndarray, segs: list[int], min_hits: int
) -> list[np.ndarray]:
    """Per segment of ``segs`` (labels of the (H, W) int32 ``labels``) the indices of the offered
    planes with at least ``min_hits`` samples projecting into it."""
    H, W = labels.shape
    out = [np.zeros(0, np.int64) for _ in segs]
    if len(offered.planes) == 0:
        return out
    uv, z = ref.posed().project(offered.points)
    u, v = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    ok = (z > 0) & (u >= 0) & (v >= 0) & (u < W) & (v < H)
    seg_of_label = np.full(int(labels.max()) + 1, -1, np.int64)  # label -> row of ``segs``
    seg_of_label[segs] = np.arange(len(segs))
    k = seg_of_label[labels[v[ok].astype(np.int64), u[ok].astype(np.int64)]]
    hits = np.zeros((len(segs), len(offered.planes)), np.int64)
    np.add.at(hits, (k[k >= 0], offered.plane_of[ok][k >= 0]), 1)
    return [np.nonzero(row >= min_hits)[0] for row in hits]


def _walls(planes: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(P,) bool: which planes (P, 4) (n, h) are not level, ``up`` (3,) the world's z in their
    frame: walls (and slanted planes), which may hide more of their band
    (``max_front_hidden_wall``, ``wall_hidden_weight``)."""
    return np.abs(planes[:, :3] @ up) < _LEVEL_COS


def _level_tops(wall: np.ndarray | None, on_plane: np.ndarray, s: PlanarPriorSettings) -> np.ndarray:
    """(K,) bool: the level candidates (``wall`` (K,) bool False, None: all level) with at least
    ``level_top_min_support`` of the band support on them (``on_plane`` (K,)): raised tops, past
    whose edges this view sees the lower surfaces around them."""
    tops = on_plane >= s.level_top_min_support
    return tops if wall is None else tops & ~wall


def _choose_plane(
    is_global: np.ndarray,
    fracs: np.ndarray,
    through: np.ndarray,
    front: np.ndarray,
    wall: np.ndarray,
    s: PlanarPriorSettings,
    support: np.ndarray | None = None,
    overhang: np.ndarray | None = None,
    framed: np.ndarray | None = None,
) -> tuple[int, np.ndarray] | None:
    """The winning candidate of a segment and the scores it was chosen among.

    A candidate is good when at least ``min_pass_fraction`` of the segment's border ring looks
    the same in the sources under it (``fracs`` (K,)) and the sources see through at most
    ``max_see_through`` of its interior (``through`` (K,)). A dominant plane (``is_global``
    (K,): multi-view support) wins over a view's own triangle and Manhattan planes unless one
    of those looks clearly better on the border (by more than ``dominant_margin``: the wall a
    view's corners fix beside a dominant plane that fits a few of its points). Within that
    pool the score is the border share less ``see_through_weight`` times the see-through share
    and the share of the band it would hide (``front`` (K,)), that last weighed by
    ``wall_hidden_weight`` for walls (``wall`` (K,) bool, :func:`_walls`): a wall hides what
    stands back beyond its top edge and corners, the ground nothing.

    With ``support`` (K,), each candidate's share of the segment's band support lying on it, a
    dominant wall keeps that precedence only with at least ``dominant_wall_min_support`` times
    the support of the best supported good wall of the view's own. A plain wall is seldom a
    dominant plane (its few consistent points are its outline); the dominant wall nearest it
    is often a textured face set back from it (a storey above) that fits its top edge, while
    the view's own wall through its corner and contact lines carries most of the band.

    With ``overhang`` (K,) too (:func:`_overhang_shares`), a level winner meeting more than
    ``max_overhang`` of the band as an overhang yields to the best good wall that meets at
    most ``overhang_rival_max`` of it so and has ``overhang_rival_support`` of the band on it
    (the ground behind a plain plinth face against the face itself).

    Returns:
        (the winner's index among the K candidates, (K,) scores with -inf outside the pool), or
        None when no candidate is good.
    """
    good = (fracs >= s.min_pass_fraction) & (through <= s.max_see_through)
    if not good.any():
        return None
    dominant = good & is_global
    own_walls = good & ~is_global & wall
    if support is not None and own_walls.any():
        # a dominant wall with much less band support than a wall of the view's own is most
        # likely another face (the set-back storey above a plain wall): no precedence for it
        dominant &= ~wall | (support >= s.dominant_wall_min_support * support[own_walls].max())
    pool = (
        dominant
        if dominant.any() and fracs[dominant].max() >= fracs[good].max() - s.dominant_margin
        else good
    )
    hidden_weight = np.where(wall, s.wall_hidden_weight, s.see_through_weight)
    if framed is not None:
        hidden_weight[framed] = s.framed_hidden_weight
    if support is not None:  # what a supported raised top hides lies lower, past its edges
        hidden_weight[_level_tops(wall, support, s)] = 0.0
    score = fracs - s.see_through_weight * through - hidden_weight * front
    rivals = np.where(pool, score, -np.inf)
    win = int(np.argmax(rivals))
    if overhang is not None and support is not None and not wall[win] and overhang[win] > s.max_overhang:
        sound = good & wall & (overhang <= s.overhang_rival_max) & (support >= s.overhang_rival_support)
        if sound.any():
            rivals = np.where(sound, score, -np.inf)
            win = int(np.argmax(rivals))
    return win, rivals


def fill_plain_segments(
    ref: WorkingView,
    sources: list[WorkingView],
    depth: np.ndarray,
    cost: np.ndarray,
    accepted: np.ndarray,
    depth_range: tuple[float, float],
    cos_max_incidence: float,
    gain: float,
    settings: PlanarPriorSettings = PlanarPriorSettings(),
    sparse_points: np.ndarray | None = None,
    planes_world: np.ndarray | None = None,
    source_depths: list[np.ndarray | None] | None = None,
    offered: FilledPlanes | None = None,
) -> tuple[np.ndarray, PriorReport]:
    """Give the plain segments of one view the depth of their best-supported plane.

    Args:
        ref: the reference view (working resolution); sources: its source views.
        depth: (H, W) float32 PatchMatch depth, metres (values outside ``accepted`` ignored);
            filled in place where a plane is accepted.
        cost: (H, W) float32 PatchMatch cost (support: ``accepted`` and ``cost <= support_cost``).
        accepted: (H, W) bool pixels whose PatchMatch depth is kept.
        depth_range: (near, far) metres; plane depths outside are not used.
        cos_max_incidence: cos of the largest angle between a plane's normal and the viewing ray.
        gain: brightness gain of the view (:func:`skyrecon.mvs.patchmatch.brightness_gain`):
            grey-level thresholds are divided by it.
        settings: see :class:`PlanarPriorSettings`.
        sparse_points: (N, 3) world points, metres (sparse feature points) or None.
        planes_world: (P, 4) world planes from :func:`dominant_planes` or None.
        source_depths: per source its (H, W) depth, metres, NaN without one (PatchMatch's), or
            None: candidates a source sees through (its depth lies beyond the plane inside the
            segment) are set aside (``max_see_through``) and ranked lower.
        offered: the second pass (``propagate``): the planes other views filled. A segment's
            candidates are then only those of them whose samples land in it (at least
            ``propagate_min_hits``), as dominant planes (``planes_world`` is not read); no
            triangle or Manhattan planes of its own (they failed in the first pass).
    Returns:
        ((H, W) bool pixels filled by a plane, PriorReport with the planes used). Nothing is
        changed when the report has a ``fallback``.
    """
    s = settings
    H, W = ref.shape
    near, far = depth_range
    report = PriorReport()
    filled = np.zeros((H, W), bool)
    labels, stats, segs, blur = _plain_segments(ref, accepted, gain, s)
    report.segments = len(segs)
    if not segs:
        report.fallback = "no plain segments"
        return filled, report
    support = np.where(accepted & (cost <= s.support_cost) & np.isfinite(depth), depth, np.nan).astype(
        np.float64
    )
    sparse = _sparse_support(ref, sparse_points, np.where(accepted, depth, np.nan), near, far)
    support = np.where(np.isfinite(sparse), sparse, support)
    report.support_px = int(np.isfinite(support).sum())
    if report.support_px < 3:
        report.fallback = f"only {report.support_px} support points"
        return filled, report
    offered_in: list[np.ndarray] = []  # per segment of ``segs``: the offered planes it may take
    if offered is not None:
        planes_world = offered.planes
        offered_in = _offered_per_segment(ref, offered, labels, segs, s.propagate_min_hits)
    gplanes, horizontal = _planes_in_camera(ref, planes_world)
    up_cam = ref.cam_from_world.R @ np.array([0.0, 0.0, 1.0])  # world z up (DESIGN)
    frame = _frame_normals(gplanes, up_cam) if s.direction_walls > 0 else np.zeros((0, 3))
    ref_blur, src_blur = _blurred_colours(ref, sources)
    tol = s.color_tol / gain
    band_k = np.ones((2 * s.band_px + 1, 2 * s.band_px + 1), np.uint8)
    rejected = 0
    dark = 0
    ambiguous = 0
    won: list[FilledPlanes] = []
    for si, i in enumerate(segs):
        seg_planes, seg_horizontal = gplanes, horizontal
        if offered is not None:
            if len(offered_in[si]) == 0:
                continue
            seg_planes, seg_horizontal = gplanes[offered_in[si]], horizontal[offered_in[si]]
        if float(blur[labels == i].mean()) * gain < s.dark_level:  # unlit background, not a surface
            dark += 1
            continue
        x0, y0, w, h = (int(a) for a in stats[i, :4])
        bx0, by0 = max(0, x0 - s.band_px), max(0, y0 - s.band_px)
        bx1, by1 = min(W, x0 + w + s.band_px), min(H, y0 + h + s.band_px)
        seg = labels[by0:by1, bx0:bx1] == i
        band = (cv2.dilate(seg.astype(np.uint8), band_k) > 0) & ~seg
        sup = support[by0:by1, bx0:bx1]
        vv, uu = np.nonzero(band & np.isfinite(sup))
        if len(vv) < s.min_inliers:
            continue
        all_d = sup[vv, uu]
        all_rays = _rays(ref, (uu + bx0).astype(np.float64), (vv + by0).astype(np.float64))
        keep = np.arange(len(vv))
        if len(vv) > s.max_support:
            keep = np.linspace(0, len(vv) - 1, s.max_support).astype(np.int64)
        d = all_d[keep]
        uf, vf = (uu[keep] + bx0).astype(np.float64), (vv[keep] + by0).astype(np.float64)
        sv_, su_ = np.nonzero(seg)
        centre = _rays(ref, np.array([su_.mean() + bx0]), np.array([sv_.mean() + by0]))[0]
        cands, is_global = _candidate_planes(
            np.stack([uf, vf], axis=1),
            d,
            all_rays[keep],
            seg_planes,
            centre,
            cos_max_incidence,
            s,
            all_rays,
            all_d,
            seg_horizontal,
            up_cam,
            own=offered is None,
            frame=frame,
        )
        if len(cands) == 0:
            continue
        wall = _walls(cands, up_cam)
        framed = wall & _in_frame(cands, frame)
        # the candidate whose segment border looks the same in the sources wins (a wrong plane
        # carries the border pixels onto other surfaces there)
        rv, ru = np.nonzero(_boundary_ring(seg, s.ring_px))
        if len(rv) > s.max_ring_px:
            keep = np.linspace(0, len(rv) - 1, s.max_ring_px).astype(np.int64)
            rv, ru = rv[keep], ru[keep]
        ru, rv = ru + bx0, rv + by0
        rrays = _rays(ref, ru.astype(np.float64), rv.astype(np.float64))
        fracs, through, front, on_plane = _judge_candidates(
            ref,
            sources,
            source_depths,
            cands,
            (seg, bx0, by0),
            (ru, rv, rrays),
            (all_rays, all_d),
            depth_range,
            (ref_blur, src_blur, tol),
            s,
            wall,
            framed,
        )
        choice = _choose_plane(is_global, fracs, through, front, wall, s, on_plane, framed=framed)
        if choice is not None and s.hidden_band and not wall[choice[0]]:
            # only a level winner may yield for an overhang: the shares are computed for it
            below, above = _segment_beside_band(ref, (seg, bx0, by0), uu, vv, up_cam, s.band_px + 1)
            overhang = _overhang_shares(cands, all_d, below, above, s.see_through_margin)
            choice = _choose_plane(is_global, fracs, through, front, wall, s, on_plane, overhang, framed)
        if choice is None:
            rejected += 1
            continue
        win, rivals = choice
        if _ambiguous(cands, rivals, win, rrays, s):
            ambiguous += 1
            continue
        plane = cands[win]
        pu, pv = (su_ + bx0).astype(np.int64), (sv_ + by0).astype(np.int64)
        pd = _plane_depth(
            plane[None, :3], plane[3:], _rays(ref, pu.astype(np.float64), pv.astype(np.float64))
        )[0]
        with np.errstate(invalid="ignore"):
            ok = (pd >= near) & (pd <= far)
        if not ok.any():
            continue
        pu, pv, pd = pu[ok], pv[ok], pd[ok]
        passed = _photo_check(ref, sources, pu, pv, pd, ref_blur, src_blur, tol, s.min_sources)
        if passed.sum() < s.min_pass_fraction * len(pd):
            rejected += 1
            continue
        pu, pv, pd = pu[passed], pv[passed], pd[passed]
        depth[pv, pu] = pd
        filled[pv, pu] = True
        report.filled_segments += 1
        won.append(_filled_plane(ref, plane, pu, pv, pd, s.propagate_samples))
    report.filled_px = int(filled.sum())
    report.planes = FilledPlanes.concat(won)
    report.details = dict(
        photo_rejected_segments=rejected,
        ambiguous_segments=ambiguous,
        dark_segments=dark,
        dominant_planes=len(gplanes),
    )
    if report.filled_px == 0:
        report.fallback = "no plain segment fits a supported plane"
    return filled, report


def planar_prior_depth(
    ref: WorkingView,
    sources: list[WorkingView],
    depth: np.ndarray,
    cost: np.ndarray,
    depth_range: tuple[float, float],
    cos_max_incidence: float,
    settings: PlanarPriorSettings = PlanarPriorSettings(),
    sparse_points: np.ndarray | None = None,
    planes_world: np.ndarray | None = None,
    source_depths: list[np.ndarray | None] | None = None,
    offered: FilledPlanes | None = None,
) -> tuple[np.ndarray, dict[str, int | str], FilledPlanes]:
    """One view's depth with its plain segments filled from planes (never worse than without).

    Args:
        ref, sources: the views (with colour for the photometric checks).
        depth: (H, W) float32 PatchMatch depth, metres, NaN where none (not modified).
        cost: (H, W) float32 PatchMatch cost.
        depth_range, cos_max_incidence, settings, sparse_points, planes_world, source_depths,
            offered: see :func:`fill_plain_segments`.
    Returns:
        ((H, W) float32 depth: a copy of ``depth`` with the filled pixels, or ``depth`` itself
        when the prior was not applied; the report (:meth:`PriorReport.as_dict`) whose
        ``fallback`` says why not; the planes that filled segments, world frame).
    """
    out = np.array(depth, np.float32, copy=True)
    try:
        filled, rep = fill_plain_segments(
            ref,
            sources,
            out,
            cost,
            np.isfinite(depth),
            depth_range,
            cos_max_incidence,
            brightness_gain(ref),
            settings,
            sparse_points,
            planes_world,
            source_depths,
            offered,
        )
    except (ValueError, np.linalg.LinAlgError, cv2.error) as exc:  # never worse than without it
        msg = str(exc).strip().splitlines()
        failed: dict[str, int | str] = {
            "fallback": f"planar prior failed: {msg[-1] if msg else type(exc).__name__}"
        }
        return depth, failed, FilledPlanes.empty()
    if rep.fallback:
        return depth, rep.as_dict(), FilledPlanes.empty()
    return out, rep.as_dict(), rep.planes
