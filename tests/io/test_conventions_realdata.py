"""Proof, on the real data sets, that the multi-view readers interpret each file's pose correctly.

Two independent checks per data set, each also run on the *other* reading of the same numbers
(the pose inverted: world-to-camera taken as camera-to-world or the reverse) to show that the
check can fail:

1. Visibility: a point every camera sees (the temple's bounding box from its README, the point
   nearest the fountain cameras' optical axes, the rock's reference cloud) projects inside every
   image with positive depth.
2. Epipolar geometry: SIFT matches between two neighbouring real images lie on the epipolar
   lines of the fundamental matrix built from the ground-truth cameras.

Skipped when ``$SKYRECON_DATA`` (default ``../shared/data``) lacks the data.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from skyrecon.core import PosedView
from skyrecon.eval.gt_geometry import fundamental_from_views, symmetric_epipolar_distance
from skyrecon.io.images import read_image_with_alpha
from skyrecon.io.multiview import read_cameras, read_halcon_cameras, read_middlebury_par, read_strecha_cameras
from tests.conftest import require

pytestmark = pytest.mark.realdata

TEMPLE = "middlebury-mview-templeSparseRing/templeSR_par.txt"
FOUNTAIN = "strecha-fountain-P11"
ROCK = "robovision-rock/2016_10_25__12_11_32"

#: The tight bounding box of the temple, from the data set's README.txt (metres, world frame).
TEMPLE_BOX = (np.array([-0.073568, 0.021728, -0.012445]), np.array([0.028855, 0.181892, 0.062736]))


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def other_reading(views: list[PosedView]) -> list[PosedView]:
    """The wrong reading of the same file: the stored pose taken the other way round.

    Middlebury stores world-to-camera, so the wrong reading takes it as camera-to-world; Strecha
    and HALCON store camera-to-world, so the wrong reading takes it as world-to-camera. Either way
    the wrong ``cam_from_world`` is the inverse of the right one.
    """
    return [
        PosedView(v.name, v.intrinsics, v.cam_from_world.inverse().with_frames("cam", "world"), v.image_path)
        for v in views
    ]


def visible(views: list[PosedView], points_world: np.ndarray) -> np.ndarray:
    """(n_views, N) bool: point projects inside the image with positive depth."""
    out = []
    for v in views:
        uv, depth = v.project(points_world)
        out.append(v.intrinsics.in_image(uv) & (depth > 0))
    return np.array(out)


def nearest_point_to_axes(views: list[PosedView]) -> np.ndarray:
    """(3,) least-squares point closest to the optical axes (centre + s * z-axis) of the views."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for v in views:
        d = v.cam_from_world.R[2]  # optical axis (camera z) in the world frame
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ v.center_world
    return np.linalg.solve(A, b)


def read_ascii_ply_xyz(path: Path) -> np.ndarray:
    """(N, 3) float64 vertex positions of an ASCII PLY whose first three properties are x y z."""
    with open(path, "rb") as f:
        n_header = 0
        for line in f:
            n_header += 1
            if line.strip() == b"end_header":
                break
    return np.loadtxt(path, skiprows=n_header, usecols=(0, 1, 2), dtype=np.float64).reshape(-1, 3)


def sift_matches(
    view1: PosedView,
    view2: PosedView,
    longer_side: int | None = None,
    clahe: bool = False,
    use_alpha: bool = False,
    ratio: float = 0.7,
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual, ratio-tested SIFT matches between two views' images.

    Images are read grey, optionally contrast-equalised (CLAHE, for the dark rock images),
    downscaled so that the longer side is ``longer_side`` and masked by alpha (eroded) when
    ``use_alpha``. Returns (M, 2) pixel arrays in each view's **full-resolution** pixels
    (skyrecon convention, top-left pixel centre at (0, 0)).
    """
    sift = cv2.SIFT_create()
    feats = []
    for v in (view1, view2):
        assert v.image_path is not None, f"{v.name}: image missing"
        gray, alpha = read_image_with_alpha(v.image_path, "gray")
        h, w = gray.shape
        if clahe:
            gray = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)).apply(gray)
        s = 1.0 if longer_side is None else min(1.0, longer_side / max(h, w))
        if s < 1.0:
            gray = cv2.resize(gray, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
        mask = None
        if use_alpha and alpha is not None:
            a = cv2.resize(alpha, gray.shape[::-1], interpolation=cv2.INTER_NEAREST) if s < 1.0 else alpha
            mask = cv2.erode((a > 0).astype(np.uint8) * 255, np.ones((9, 9), np.uint8))
        kp, desc = sift.detectAndCompute(gray, mask)
        pts = np.array([k.pt for k in kp], dtype=np.float64).reshape(-1, 2)
        scale = np.array([w / gray.shape[1], h / gray.shape[0]])
        feats.append(((pts + 0.5) * scale - 0.5, desc))  # back to full-resolution pixel centres
    (p1, d1), (p2, d2) = feats
    bf = cv2.BFMatcher(cv2.NORM_L2)
    fwd = {m.queryIdx: m.trainIdx for m, n in bf.knnMatch(d1, d2, k=2) if m.distance < ratio * n.distance}
    back = {m.queryIdx: m.trainIdx for m in bf.match(d2, d1)}
    pairs = np.array([(q, t) for q, t in fwd.items() if back.get(t) == q], dtype=np.int64).reshape(-1, 2)
    return p1[pairs[:, 0]], p2[pairs[:, 1]]


def epipolar_stats(view1: PosedView, view2: PosedView, x1: np.ndarray, x2: np.ndarray) -> tuple[float, float]:
    """(median symmetric epipolar distance in px, fraction within 3 px) under the GT cameras."""
    d = symmetric_epipolar_distance(fundamental_from_views(view1, view2), x1, x2)
    return float(np.median(d)), float(np.mean(d < 3.0))


# ----------------------------------------------------------------------------------------------
# 1. visibility
# ----------------------------------------------------------------------------------------------
def test_temple_bounding_box_seen_by_every_camera(real_data: Path) -> None:
    views = read_middlebury_par(require(real_data, TEMPLE))
    assert len(views) == 16 and all(v.intrinsics.size == (640, 480) for v in views)
    lo, hi = TEMPLE_BOX
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pts = np.vstack([corners, (lo + hi) / 2])
    right = visible(views, pts)
    assert right.all(), f"{(~right).sum()} of {right.size} (point, camera) pairs outside"
    # Cameras 0.5-0.65 m from the object.
    depths = np.array([v.project(pts[-1:])[1][0] for v in views])
    assert np.all((depths > 0.45) & (depths < 0.7))
    wrong = visible(other_reading(views), pts)
    print(
        f"temple: box corners + centre inside {right.mean():.0%} of (point, camera) pairs; "
        f"inverted {wrong.mean():.0%}"
    )
    assert wrong.mean() < 0.2, f"the inverted reading also sees the temple ({wrong.mean():.0%})"


def test_fountain_axes_point_seen_by_every_camera(real_data: Path) -> None:
    views = read_strecha_cameras(require(real_data, FOUNTAIN))
    assert len(views) == 11 and all(v.intrinsics.size == (3072, 2048) for v in views)
    assert all(v.image_path is not None and v.image_path.parent.name == "images" for v in views)

    def check(vs: list[PosedView]) -> np.ndarray:
        X = nearest_point_to_axes([vs[0], vs[len(vs) // 2]])
        return visible(vs, X[None])[:, 0]

    right = check(views)
    assert right.all(), f"cameras {[v.name for v, ok in zip(views, right) if not ok]} do not see the point"
    wrong = check(other_reading(views))
    print(
        f"fountain: axes point inside {right.sum()}/{len(views)} images; inverted {wrong.sum()}/{len(views)}"
    )
    assert wrong.mean() < 0.2, f"the inverted reading also sees it in {wrong.sum()} cameras"


def test_rock_reference_cloud_seen_by_every_camera(real_data: Path) -> None:
    directory = require(real_data, ROCK)
    views = read_halcon_cameras(directory)
    assert len(views) == 12 and all(v.intrinsics.size == (1280, 1024) for v in views)
    cloud = read_ascii_ply_xyz(require(real_data, f"{ROCK}/reference.ply"))
    assert len(cloud) > 1000

    centroid = visible(views, cloud.mean(axis=0)[None])[:, 0]
    assert centroid.all()
    right = visible(views, cloud).all(axis=0).mean()  # fraction of points inside all 12 images
    assert right >= 0.95, f"only {right:.1%} of the reference points are seen by every camera"
    # About 0.20 m from each camera.
    depth = np.median([v.project(cloud)[1] for v in views])
    assert 0.15 < depth < 0.25

    wrong_views = other_reading(views)
    assert not visible(wrong_views, cloud.mean(axis=0)[None]).all()
    wrong = visible(wrong_views, cloud).all(axis=0).mean()
    print(
        f"rock: {right:.1%} of reference points inside all 12 images (median depth {depth:.3f} m); "
        f"inverted {wrong:.1%}"
    )
    assert wrong < 0.5, f"the inverted reading also sees {wrong:.1%} of the points"


# ----------------------------------------------------------------------------------------------
# 2. epipolar geometry against real matches
# ----------------------------------------------------------------------------------------------
CASES = {
    # id: (relative path, names, matcher options, max median px, min fraction within 3 px)
    "fountain-0004-0005": (FOUNTAIN, ("0004.jpg", "0005.jpg"), dict(longer_side=1000), 2.0, 0.6),
    "temple-0001-0002": (TEMPLE, ("templeSR0001.png", "templeSR0002.png"), dict(), 1.5, 0.6),
    "temple-0008-0009": (TEMPLE, ("templeSR0008.png", "templeSR0009.png"), dict(), 1.5, 0.6),
    "rock-01-02": (
        ROCK,
        ("image_camera01.png", "image_camera02.png"),
        dict(longer_side=640, clahe=True, use_alpha=True),
        1.5,
        0.6,
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_ground_truth_epipolar_geometry_matches_sift(real_data: Path, case: str) -> None:
    rel, (n1, n2), options, max_median, min_fraction = CASES[case]
    views = {v.name: v for v in read_cameras(require(real_data, rel))}
    v1, v2 = views[n1], views[n2]
    x1, x2 = sift_matches(v1, v2, **options)
    assert len(x1) >= 30, f"{case}: only {len(x1)} matches"

    median, fraction = epipolar_stats(v1, v2, x1, x2)
    w1, w2 = other_reading([v1, v2])
    wrong_median, wrong_fraction = epipolar_stats(w1, w2, x1, x2)
    print(
        f"{case}: {len(x1)} matches; right reading median {median:.3f} px, {fraction:.1%} within 3 px; "
        f"inverted reading median {wrong_median:.1f} px, {wrong_fraction:.1%} within 3 px"
    )
    assert median < max_median, f"{case}: median epipolar distance {median:.2f} px"
    assert fraction > min_fraction, f"{case}: only {fraction:.1%} of matches within 3 px"
    assert wrong_median > 5 * max_median, f"{case}: the inverted reading is not clearly worse"
    assert wrong_fraction < 0.25
