"""Planar prior for plain surfaces: candidate planes, the fallback path, and a plain ring."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import DepthMap
from skyrecon.errors import InputError
from skyrecon.eval.mvs_metrics import evaluate_cloud, reference_from_depth_maps
from skyrecon.executor import get_executor
from skyrecon.mvs import MVSSettings, depth_tasks, run_mvs
from skyrecon.mvs import planar_prior as pp
from skyrecon.mvs.inputs import load_working_views
from skyrecon.mvs.planar_prior import (
    FilledPlanes,
    PlanarPriorSettings,
    dominant_planes,
    horizontal_planes,
    planar_prior_depth,
)

from .synthetic import make_ring


def _two_planes(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-5, 5, (400, 2)), rng.normal(0, 0.002, 400)]  # z = 0
    wall = np.c_[
        np.full(300, 2.0) + rng.normal(0, 0.002, 300), rng.uniform(-5, 5, 300), rng.uniform(0, 4, 300)
    ]
    junk = rng.uniform(-5, 5, (50, 3))
    return np.concatenate([ground, wall, junk])


def test_dominant_planes_find_the_ground_and_the_wall_deterministically() -> None:
    pts = _two_planes()
    planes = dominant_planes(pts, seed=1)
    assert len(planes) >= 2
    normals = np.abs(planes[:2, :3])
    assert {int(np.argmax(n)) for n in normals} == {0, 2}  # x = 2 and z = 0
    for n, c in zip(planes[:2, :3], planes[:2, 3]):
        axis = int(np.argmax(np.abs(n)))
        assert abs(c / n[axis] - (2.0 if axis == 0 else 0.0)) < 0.01
    np.testing.assert_array_equal(planes, dominant_planes(pts, seed=1))
    assert len(dominant_planes(pts[:5])) == 0


def test_horizontal_planes_put_the_ground_first() -> None:
    rng = np.random.default_rng(2)
    # a box standing on the ground at z = 0.3: its walls spread points from 0.3 up, a roof at 2.3
    walls = np.c_[rng.uniform(-1, 1, (4000, 2)), rng.uniform(0.3, 2.3, 4000)]
    roof = np.c_[rng.uniform(-1, 1, (400, 2)), np.full(400, 2.3)]
    planes = horizontal_planes(np.concatenate([walls, roof]))
    assert planes[0, 3] == pytest.approx(0.3, abs=0.03)
    assert np.any(np.abs(planes[1:, 3] - 2.3) < 0.03)
    np.testing.assert_array_equal(planes[:, :3], np.tile([0.0, 0.0, 1.0], (len(planes), 1)))


def test_fallback_keeps_the_patchmatch_depth_and_says_why(monkeypatch) -> None:
    ring = make_ring(n=4, seed=0, plain=True)
    views = load_working_views(ring.views, ring.images, None)
    depth = np.full(views[0].shape, np.nan, np.float32)
    depth[:4, :4] = 9.0  # three support points are not enough
    cost = np.where(np.isfinite(depth), 0.1, 2.0).astype(np.float32)
    out, rep, _ = planar_prior_depth(views[0], views[1:3], depth, cost, (2.0, 30.0), 0.17)
    assert out is depth and "fallback" in rep and "support" in rep["fallback"]

    def broken(*args, **kwargs):
        raise ValueError("degenerate input")

    monkeypatch.setattr(pp, "fill_plain_segments", broken)
    out, rep, _ = planar_prior_depth(views[0], views[1:3], depth, cost, (2.0, 30.0), 0.17)
    assert out is depth and rep["fallback"] == "planar prior failed: degenerate input"


@pytest.fixture(scope="module")
def plain_ring():
    return make_ring(n=10, width=256, height=192, seed=1, plain=True)


def _ground_recall(ring, cloud, tau: float) -> tuple[float, float]:
    maps = [DepthMap(d, v.intrinsics, v.cam_from_world) for v, d in zip(ring.views, ring.depths)]
    ref = reference_from_depth_maps(maps, min_views=2, voxel_m=0.02, crop=ring.eval_box)
    ground = ref[ref[:, 2] < 0.02]
    all_ = evaluate_cloud(cloud.points, ref, [tau], crop=ring.eval_box).recall[0]
    return evaluate_cloud(cloud.points, ground, [tau], crop=ring.eval_box).recall[0], all_


def test_plain_ring_completeness_improves_with_the_prior(plain_ring, tmp_path, monkeypatch) -> None:
    ring = plain_ring
    ex = get_executor("serial")
    off = MVSSettings(max_image_size=None, planar_prior=PlanarPriorSettings(enabled=False))
    on = MVSSettings(max_image_size=None)
    r_off = run_mvs(ring.views, ring.images, off, executor=ex, progress=False)
    r_on = run_mvs(ring.views, ring.images, on, executor=ex, progress=False, workspace=tmp_path)
    tau = 0.08  # 1 % of the ring radius
    g_off, all_off = _ground_recall(ring, r_off.cloud, tau)
    g_on, all_on = _ground_recall(ring, r_on.cloud, tau)
    print(f"ground recall {g_off:.3f} -> {g_on:.3f}, all {all_off:.3f} -> {all_on:.3f}")
    assert g_on >= g_off + 0.1, (g_off, g_on)  # the plain ground, behind what stands on it
    assert all_on > all_off + 0.05, (all_off, all_on)
    # the planes are real: accuracy stays high
    dist = np.abs(ring.city.distance(r_on.cloud.points.astype(np.float64), include_ground=True))
    assert np.mean(dist <= tau) > 0.95
    assert "planar_prior" in r_on.diagnostics and "planar_prior" not in r_off.diagnostics
    # each view's prior is kept in the workspace; a rerun reuses them all (computes none) and
    # gives the same cloud
    kept = list((tmp_path / "prior_tasks").glob("*.pkl"))
    views = r_on.diagnostics["planar_prior"]["views"]  # a task per view and pass
    # the second pass filled segments of some views with planes their neighbours found
    assert sum(v.get("shared_planes", {}).get("filled_px", 0) for v in views.values()) > 0
    assert len(kept) == len(views) + sum("shared_planes" in v for v in views.values()) > 0

    def recomputed(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise AssertionError("the planar prior ran again instead of coming from the workspace")

    monkeypatch.setattr(depth_tasks, "planar_prior_depth", recomputed)
    again = run_mvs(ring.views, ring.images, on, executor=ex, progress=False, workspace=tmp_path)
    np.testing.assert_array_equal(again.cloud.points, r_on.cloud.points)


def _spread_one(uv: np.ndarray) -> float:
    """The least-direction standard deviation of one point set, computed directly (reference)."""
    if len(uv) < 3:
        return 0.0
    return float(np.sqrt(max(np.linalg.eigvalsh(np.cov(uv.T, bias=True))[0], 0.0)))


def test_spreads_match_each_subset_computed_alone() -> None:
    rng = np.random.default_rng(3)
    uv = rng.uniform(0, 640, (300, 2))
    uv[:40] = [100.0, 50.0] + rng.normal(0, 1, (40, 1)) * [3.0, 1.0]  # a nearly collinear run
    members = rng.random((50, 300)) < 0.2
    members[0] = False
    members[0, :2] = True  # too few points
    members[1] = False
    members[1, :40] = True  # the thin run: spread about 0
    got = pp._spreads(uv, members)
    want = [_spread_one(uv[m]) for m in members]
    # a spread is the square root of a difference of second moments of coordinates up to 640 px:
    # where it is about 0 (the thin run) its round-off is about sqrt(eps) * 640 = 1e-5 px, and
    # depends on the BLAS's summation order (a clean CI clone computed 4.4e-6 px)
    tol = 2.0 * np.sqrt(np.finfo(np.float64).eps) * 640.0
    np.testing.assert_allclose(got, want, atol=tol)
    assert got[0] == 0.0 and got[1] < tol and got[2:].min() > 50


def _sample_reference(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) float32 of (H, W, C) float32 ``img``, NaN outside (numpy reference)."""
    H, W, C = img.shape
    out = np.full((len(x), C), np.nan, np.float32)
    ok = (x >= 0) & (y >= 0) & (x <= W - 1) & (y <= H - 1)
    xs, ys = x[ok], y[ok]
    x0, y0 = np.minimum(xs.astype(np.int64), W - 2), np.minimum(ys.astype(np.int64), H - 2)
    ax, ay = (xs - x0).astype(np.float32)[:, None], (ys - y0).astype(np.float32)[:, None]
    top = img[y0, x0] * (1 - ax) + img[y0, x0 + 1] * ax
    bot = img[y0 + 1, x0] * (1 - ax) + img[y0 + 1, x0 + 1] * ax
    out[ok] = top * (1 - ay) + bot * ay
    return out


def test_count_agreement_samples_bilinearly_and_counts_like_the_reference() -> None:
    rng = np.random.default_rng(4)
    img = rng.uniform(0, 255, (12, 9, 3)).astype(np.float32)
    img[5, 4, 1] = np.nan
    n = 400
    x = np.concatenate([rng.uniform(-1, 9, n - 4), [0.0, 8.0, 3.5, 4.5]])
    y = np.concatenate([rng.uniform(-1, 12, n - 4), [0.0, 11.0, 2.0, 5.0]])
    ref = _sample_reference(img, x, y)
    g = (np.nan_to_num(ref, nan=0.0) + rng.normal(0, 5, ref.shape)).astype(np.float32)
    inside = rng.random(n) < 0.9
    inside[-4:] = True
    tol = np.float32(6.0)
    seen, agree = np.zeros(n, np.int32), np.zeros(n, np.int32)
    pp._count_agreement(img, x, y, inside, g, tol, seen, agree)
    number = np.isfinite(ref).all(axis=1) & inside
    with np.errstate(invalid="ignore"):
        close = (np.abs(ref - g) <= tol).all(axis=1)
    np.testing.assert_array_equal(seen, number.astype(np.int32))
    np.testing.assert_array_equal(agree, (number & close).astype(np.int32))
    assert seen[-4] == 1 and seen[-3] == 1  # the corners are inside
    assert seen[-1] == 0  # next to the NaN pixel
    assert 0 < agree.sum() < seen.sum() < n  # the test has points of every kind


def test_sources_see_through_a_plane_floating_in_front_of_the_surface() -> None:
    ring = make_ring(n=3, width=96, height=72, seed=1)
    views = load_working_views(ring.views, ring.images, None)
    ref, src = views[0], views[1]
    true = ring.depths[0]
    v, u = np.nonzero(np.isfinite(true))
    d = true[v, u].astype(np.float64)
    src_depth = ring.depths[1].astype(np.float32)

    def share(scale: float) -> float:
        return float(pp._seen_through(ref, [src], [src_depth], u, v, d * scale, 0.02).mean())

    assert share(1.0) < 0.02  # the surface itself: nothing is seen beyond it
    # behind the surface: hidden from the source (only beside silhouettes does it see farther)
    assert share(1.3) < 0.1
    assert share(0.7) > max(0.3, 3 * share(1.3))  # floating in front: the source sees behind it
    assert not pp._seen_through(ref, [src], [None], u, v, d * 0.7, 0.02).any()  # no depth, no evidence


def _camera_rays(n: int, y_lo: float, y_hi: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-0.4, 0.4, n), rng.uniform(y_lo, y_hi, n), np.ones(n)]


def test_the_ground_reaches_behind_what_stands_on_it_without_contact_points() -> None:
    """A horizontal dominant plane with no band point on it is still a candidate when the whole
    band lies in front of it (the plain ground behind a box whose feet are hidden); a vertical
    plane behind everything is not (it would fill the sky), nor the ground when the view
    measured something beyond it."""
    s = PlanarPriorSettings()
    rays = _camera_rays(300, 0.1, 0.3, 0)  # a box face 5 m away, above where those rays meet the ground
    d = np.full(len(rays), 5.0)
    uv = rays[:, :2] * 500 + [320, 240]
    ground = [0.0, -1.0, 0.0, -2.0]  # camera frame (y down): the ground 2 m below the camera
    far_wall = [0.0, 0.0, -1.0, -30.0]
    planes = np.array([ground, far_wall])
    centre = np.array([0.0, 0.5, 1.0])
    cos_max = float(np.cos(np.radians(80)))
    horizontal = np.array([True, False])

    def kept(depths: np.ndarray) -> list[list[float]]:
        cands, is_global = pp._candidate_planes(
            uv, depths, rays, planes, centre, cos_max, s, rays, depths, horizontal
        )
        return cands[is_global].round(6).tolist()

    assert kept(d) == [ground]
    beyond = d.copy()
    beyond[:30] = 40.0  # a tenth of the band measured beyond the ground: it is not behind all
    assert kept(beyond) == []
    # without the horizontal flag nothing qualifies without contact points
    cands, is_global = pp._candidate_planes(uv, d, rays, planes, centre, cos_max, s, rays, d, None)
    assert not is_global.any()


def test_dominant_planes_count_contact_points_on_the_whole_band() -> None:
    """A long border's few contact points are found on the whole band, not on the thinned
    subsample that the triangle planes use."""
    s = PlanarPriorSettings()
    rays = _camera_rays(4000, 0.2, 0.4, 1)
    d = np.full(len(rays), 4.0)  # a box face in front of the ground...
    on_ground = np.arange(0, 4000, 200)  # ...and 20 scattered contact points on the ground
    d[on_ground] = 2.0 / rays[on_ground, 1]
    ground = np.array([[0.0, -1.0, 0.0, -2.0]])
    uv = rays[:, :2] * 500 + [320, 240]
    keep = np.linspace(0, len(d) - 1, s.max_support).astype(np.int64)
    assert np.isin(keep, on_ground).sum() < s.min_inliers  # the subsample misses most of them
    args = (uv[keep], d[keep], rays[keep], ground, np.array([0.0, 0.5, 1.0]), 0.17, s)
    _, is_global = pp._candidate_planes(*args)
    assert not is_global.any()
    _, is_global = pp._candidate_planes(*args, rays, d)
    assert is_global.sum() == 1


def test_manhattan_planes_put_a_wall_through_its_two_corner_lines() -> None:
    """A plain wall's support is its two vertical corner lines, and a column in front of it adds a
    third line: the best supported plane by count runs through the column and one corner, slanted.
    The vertical hypotheses keep the wall itself among the candidates, refitted to its corners."""
    rng = np.random.default_rng(3)
    pitch = np.radians(25.0)  # camera pitched down; world z up in the camera frame
    up = np.array([0.0, -np.cos(pitch), -np.sin(pitch)])
    normal = np.array([0.0, np.sin(pitch), -np.cos(pitch)])  # the wall faces the camera, vertical
    assert abs(normal @ up) < 1e-12
    h = -7.4  # n . X = h: 7.4 m in front of the camera
    side = np.cross(up, normal)

    def line(offset_m: float, depth_shift_m: float, n: int) -> np.ndarray:
        t = rng.uniform(-1.0, 1.0, n)
        base = h * normal  # the point of the wall nearest the camera (n . X = h)
        pts = base[None] + offset_m * side + t[:, None] * up + depth_shift_m * normal
        return pts + rng.normal(0.0, 0.01, pts.shape)

    left, right = line(-1.2, 0.0, 60), line(1.2, 0.0, 120)
    column = line(-0.8, 0.5, 160)  # 0.5 m in front of the wall, more points than a corner
    X = np.concatenate([left, right, column])
    X = X[X[:, 2] > 0]
    planes = pp._manhattan_planes(X, up, PlanarPriorSettings())
    assert len(planes) >= 1 and np.all(planes[:, 3] < 0)
    # the wall is among them within 1 degree and 3 cm
    angle = np.degrees(np.arccos(np.clip(planes[:, :3] @ normal, -1, 1)))
    wall = (angle < 1.0) & (np.abs(planes[:, 3] - h) < 0.03)
    assert wall.any(), (angle, planes[:, 3])
    # vertical ones are vertical, level ones level
    dots = np.abs(planes[:, :3] @ up)
    assert np.all((dots < 1e-9) | (dots > 1 - 1e-9))
    # same input, same planes; no hypotheses, no planes
    assert np.array_equal(planes, pp._manhattan_planes(X, up, PlanarPriorSettings()))
    assert len(pp._manhattan_planes(X, up, PlanarPriorSettings(manhattan_hypotheses=0))) == 0


def test_a_plain_face_beside_a_textured_one_gets_its_wall_from_their_corner_line() -> None:
    """A plain tower face's only support is the vertical corner line it shares with a textured
    face (a dominant plane): a line fixes no wall (the Manhattan pairs tilt about it), but the
    dominant directions do: the wall across the textured face through the line is a candidate,
    and so is the textured face's own plane. No dominant wall, no such candidate; a speck is
    no line."""
    rng = np.random.default_rng(7)
    pitch = np.radians(20.0)
    yaw = np.radians(35.0)  # both faces seen obliquely
    level = np.array([[np.cos(yaw), 0.0, np.sin(yaw)], [0.0, 1.0, 0.0], [-np.sin(yaw), 0.0, np.cos(yaw)]])
    tilt = np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(pitch), np.sin(pitch)], [0.0, -np.sin(pitch), np.cos(pitch)]]
    )
    R = tilt @ level  # world (x right, y down, z forward at zero yaw and pitch) to camera
    up = R @ np.array([0.0, -1.0, 0.0])
    corner_world = np.array([0.5, 0.0, 9.0])
    plain_n, textured_n = R @ np.array([-1.0, 0.0, 0.0]), R @ np.array([0.0, 0.0, -1.0])
    corner = R @ corner_world
    heights = rng.uniform(-2.0, 2.0, 60)
    line = corner[None] + heights[:, None] * up[None] + rng.normal(0, 0.003, (60, 3))
    face = corner[None] + rng.uniform(0.0, 2.0, (150, 1)) * np.cross(up, textured_n)[None]
    face += rng.uniform(-2.0, 2.0, (150, 1)) * up[None] + rng.normal(0, 0.003, (150, 3))
    X = np.concatenate([line, face])
    uv = 500.0 * X[:, :2] / X[:, 2:3]
    # the textured face and a face parallel to it 3 m behind (a dominant wall's direction
    # counts when another dominant wall is parallel or at right angles to it)
    dominant = np.array([[*textured_n, textured_n @ corner], [*textured_n, textured_n @ corner - 3.0]])
    dominant[dominant[:, 3] > 0] *= -1
    walls = pp._direction_walls(X, uv, pp._frame_normals(dominant, up), PlanarPriorSettings())
    assert len(walls) >= 2 and np.all(walls[:, 3] < 0)
    for n in (plain_n, textured_n):
        h = (n @ corner) * np.sign(-(n @ corner))
        angle = np.degrees(np.arccos(np.clip(np.abs(walls[:, :3] @ n), -1, 1)))
        assert ((angle < 0.5) & (np.abs(np.abs(walls[:, 3]) - abs(h)) < 0.02)).any(), (angle, walls[:, 3], h)
    assert (
        len(pp._direction_walls(X, uv, pp._frame_normals(np.zeros((0, 4)), up), PlanarPriorSettings())) == 0
    )
    # a lone dominant wall (RANSAC's plane through two opposite corners of a tower) gives none
    assert len(pp._direction_walls(X, uv, pp._frame_normals(dominant[:1], up), PlanarPriorSettings())) == 0
    assert (
        len(
            pp._direction_walls(
                X, uv, pp._frame_normals(dominant, up), PlanarPriorSettings(direction_walls=0)
            )
        )
        == 0
    )
    speck = corner[None] + rng.normal(0, 0.003, (30, 3))
    speck_uv = np.full((30, 2), 100.0) + rng.uniform(0, 1.0, (30, 2))
    assert (
        len(pp._direction_walls(speck, speck_uv, pp._frame_normals(dominant, up), PlanarPriorSettings())) == 0
    )


def test_manhattan_refits_take_the_neighbouring_face_out_of_a_wall() -> None:
    """A wall's corner and foot lines, with points of the face around its corner within a few
    centimetres of its depth there: the first fit includes them and tilts; the refits, closer,
    drop them and keep the wall within a quarter of a degree."""
    rng = np.random.default_rng(5)
    pitch = np.radians(25.0)
    up = np.array([0.0, -np.cos(pitch), -np.sin(pitch)])
    normal = np.array([0.0, np.sin(pitch), -np.cos(pitch)])
    h = -7.4
    side = np.cross(up, normal)
    base = h * normal

    def pts(offset: np.ndarray, along: np.ndarray, t: np.ndarray) -> np.ndarray:
        p = base[None] + offset[None] + t[:, None] * along[None]
        return p + rng.normal(0.0, 0.005, p.shape)

    left = pts(-1.2 * side, up, rng.uniform(-1, 1, 80))
    right = pts(1.2 * side, up, rng.uniform(-1, 1, 80))
    foot = pts(-up, side, rng.uniform(-1.2, 1.2, 80))
    # the face around the right corner runs away from the camera (-normal); its first 15 cm
    around = pts(1.2 * side, -normal, rng.uniform(0.0, 0.15, 120))
    around += rng.uniform(-1, 1, (len(around), 1)) * up[None]  # at every height of the corner
    X = np.concatenate([left, right, foot, around])

    def tilt(s: PlanarPriorSettings) -> float:
        planes = pp._manhattan_planes(X, up, s)
        angle = np.degrees(np.arccos(np.clip(np.abs(planes[:, :3] @ normal), -1, 1)))
        near = np.abs(np.abs(planes[:, 3]) - abs(h)) < 0.1
        return float(angle[near].min())

    assert tilt(PlanarPriorSettings()) < 0.25
    assert tilt(PlanarPriorSettings(manhattan_refits=0)) > tilt(PlanarPriorSettings())


def test_a_dominant_wall_with_little_band_support_loses_its_precedence() -> None:
    """A dominant wall (a set-back storey above a plain wall) that fits little of the band loses
    its precedence to the view's own wall through the corners, which carries most of it; with
    enough support, or without support figures, it keeps it; a dominant level plane (the ground,
    seen without contact points) keeps it whatever its support."""
    s = PlanarPriorSettings()
    up = np.array([0.0, -1.0, 0.0])
    wall, storey, level = [0.0, 0.0, -1.0, -8.0], [0.0, 0.0, -1.0, -8.4], [0.0, -1.0, 0.0, -2.0]
    cands = np.array([storey, wall])
    walls = pp._walls(cands, up)
    is_global = np.array([True, False])
    fracs, zero = np.array([0.9, 1.0]), np.zeros(2)
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s)[0] == 0  # about as right
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s, np.array([0.1, 0.6]))[0] == 1
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s, np.array([0.4, 0.6]))[0] == 0
    off = PlanarPriorSettings(dominant_wall_min_support=0.0)
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, off, np.array([0.1, 0.6]))[0] == 0
    cands = np.array([level, wall])
    walls = pp._walls(cands, up)
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s, np.array([0.0, 0.6]))[0] == 0


def test_filled_planes_reach_the_segments_of_another_view_they_cover() -> None:
    """A segment filled in one view is offered, as a world plane with samples of its pixels, to
    the segments of another view that those samples land in (the second pass)."""
    ring = make_ring(n=3, width=96, height=72, seed=1)
    views = load_working_views(ring.views, ring.images, None)
    a, b = views[0], views[1]
    z0 = float(np.nanmedian(ring.depths[0]))
    plane = np.array([0.0, 0.0, -1.0, -z0])  # view a's camera frame: fronto-parallel at z0 (n . X = h)
    v, u = np.mgrid[20:52, 30:66]
    u, v = u.ravel(), v.ravel()
    fp = pp._filled_plane(a, plane, u, v, np.full(len(u), z0), 16)
    assert fp.planes.shape == (1, 4) and fp.points.shape == (16, 3) and not fp.plane_of.any()
    # the world plane holds its samples, which lie on view a's rays at z0
    np.testing.assert_allclose(fp.points @ fp.planes[0, :3], fp.planes[0, 3], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(fp.planes[0, :3]), 1.0)
    _, z = a.posed().project(fp.points)
    np.testing.assert_allclose(z, z0)
    # in view b: segment 1 where the samples land, segment 2 everywhere else
    uv, zb = b.posed().project(fp.points)
    H, W = b.shape
    inside = (zb > 0) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] < H - 0.5)
    assert inside.sum() >= 8
    labels = np.full(b.shape, 2, np.int32)
    labels[np.rint(uv[inside, 1]).astype(int), np.rint(uv[inside, 0]).astype(int)] = 1
    hits = pp._offered_per_segment(b, fp, labels, [1, 2], min_hits=4)
    assert hits[0].tolist() == [0] and hits[1].tolist() == []
    assert pp._offered_per_segment(b, fp, labels, [1, 2], min_hits=int(inside.sum()) + 1)[0].tolist() == []
    # several views' planes in one set, renumbered; none offered, none reached
    both = FilledPlanes.concat([fp, FilledPlanes.empty(), fp])
    assert both.plane_of.tolist() == [0] * 16 + [1] * 16 and len(both.planes) == 2
    assert [len(h) for h in pp._offered_per_segment(b, FilledPlanes.empty(), labels, [1, 2], 1)] == [0, 0]


def test_choose_plane_lets_a_clearly_better_own_wall_beat_a_dominant_plane() -> None:
    """A dominant plane wins over a view's own planes when it looks about as right on the border;
    a wall of the view's own that matches clearly more of it wins even though it hides more of
    the band (what stands back beyond its top edge), and nothing good means no winner."""
    s = PlanarPriorSettings()
    up = np.array([0.0, -1.0, 0.0])  # camera frame, y down
    wall = [0.0, 0.0, -1.0, -8.0]  # vertical, facing the camera
    level = [0.0, -1.0, 0.0, -2.0]  # the ground 2 m below
    cands = np.array([level, wall, wall])
    assert pp._walls(cands, up).tolist() == [False, True, True]
    is_global = np.array([True, False, False])
    through = np.zeros(3)
    front = np.array([0.08, 0.27, 0.0])
    # the dominant plane fits 0.6 of the border, the own wall 1.0: the wall, despite its hidden band
    win, rivals = pp._choose_plane(
        is_global, np.array([0.6, 1.0, 0.0]), through, front, pp._walls(cands, up), s
    )
    assert win == 1 and np.isneginf(rivals[2])  # the third is not good (border share 0)
    # about as right: the dominant plane
    win, rivals = pp._choose_plane(
        is_global, np.array([0.9, 1.0, 0.0]), through, front, pp._walls(cands, up), s
    )
    assert win == 0 and np.isneginf(rivals[1:]).all()
    # the hidden share weighs fully on a level plane: with see_through_weight 10 it loses
    flat = np.array([level, level])
    win, _ = pp._choose_plane(
        np.zeros(2, bool),
        np.array([1.0, 0.6]),
        np.zeros(2),
        np.array([0.27, 0.0]),
        pp._walls(flat, up),
        s,
    )
    assert win == 1
    # seen through, or too little of the border: no winner
    assert pp._choose_plane(is_global, np.ones(3), np.full(3, 0.5), front, pp._walls(cands, up), s) is None
    assert pp._choose_plane(is_global, np.full(3, 0.4), through, front, pp._walls(cands, up), s) is None


def test_a_failing_second_pass_keeps_the_first_and_says_so(plain_ring, monkeypatch) -> None:
    """The second pass (planes shared between views) failing in every view leaves the first
    pass's depths: the same cloud as without it, and a warning naming the views."""
    ring = plain_ring
    ex = get_executor("serial")
    first_only = run_mvs(
        ring.views,
        ring.images,
        MVSSettings(max_image_size=None, planar_prior=PlanarPriorSettings(propagate=False)),
        executor=ex,
        progress=False,
    )
    real = pp.fill_plain_segments

    def second_fails(*args, **kwargs):  # type: ignore[no-untyped-def]
        if args[-1] is not None:  # offered: the second pass
            raise np.linalg.LinAlgError("singular matrix")
        return real(*args, **kwargs)

    monkeypatch.setattr(pp, "fill_plain_segments", second_fails)
    res = run_mvs(ring.views, ring.images, MVSSettings(max_image_size=None), executor=ex, progress=False)
    np.testing.assert_array_equal(res.cloud.points, first_only.cloud.points)
    assert any(w.startswith("planar prior's second pass failed (first pass kept) in ") for w in res.warnings)
    assert "singular matrix" in " ".join(res.warnings)


@pytest.mark.parametrize(
    "bad",
    [
        dict(propagate_samples=0),
        dict(propagate_min_hits=0),
        dict(propagate_samples=8, propagate_min_hits=9),
        dict(dominant_margin=-0.1),
        dict(wall_hidden_weight=-1.0),
        dict(dominant_wall_min_support=-0.5),
        dict(manhattan_refits=-1),
        dict(manhattan_refit_rel=0.0),
        dict(direction_walls=-1),
        dict(framed_front_hidden=1.5),
        dict(framed_hidden_weight=-0.1),
    ],
)
def test_second_pass_and_ranking_settings_are_checked(bad: dict) -> None:
    with pytest.raises(InputError, match="planar prior"):
        PlanarPriorSettings(**bad)


def test_a_supported_raised_top_may_hide_what_lies_lower_around_it() -> None:
    """A plinth top (a level plane most of the band lies on) hides the band points seen past its
    edges (the lower ground): that is neither held against it nor sets it aside, so it beats a
    plane a little lower that hides less but has hardly any band point on it; a level plane
    with little support keeps the strict rule."""
    s = PlanarPriorSettings()
    up = np.array([0.0, -1.0, 0.0])
    top, lower = [0.0, -1.0, 0.0, -5.6], [0.0, -1.0, 0.0, -5.7]
    cands = np.array([top, lower])
    walls = pp._walls(cands, up)
    assert not walls.any()
    is_global = np.array([True, True])
    fracs, zero = np.array([1.0, 0.96]), np.zeros(2)
    front = np.array([0.2, 0.01])  # the share of the band each would hide
    support = np.array([0.72, 0.16])
    assert pp._choose_plane(is_global, fracs, zero, front, walls, s, support)[0] == 0
    never = PlanarPriorSettings(level_top_min_support=1.5)
    assert pp._choose_plane(is_global, fracs, zero, front, walls, never, support)[0] == 1
    assert pp._choose_plane(is_global, fracs, zero, front, walls, s, np.array([0.3, 0.16]))[0] == 1
    # which candidates count as raised tops: level, and enough of the band on them
    tops = pp._level_tops(np.array([False, False, True]), np.array([0.6, 0.2, 0.9]), s)
    assert tops.tolist() == [True, False, False]


def test_a_level_plane_behind_a_plain_plinth_face_yields_to_the_face() -> None:
    """A camera 2 m above the ground looks level at a plinth's plain front face (z = 10 m, 0.5 m
    high, rows 48-51). The ground plane behind the face goes on *under* the plinth's top edge
    right above the segment, and the plinth top carried out past its edge stands *over* the
    ground right below it: both meet the band as an overhang; the face itself does not. The
    ground, winning as a dominant plane, yields to the well supported face; without enough
    support on the face, or without the shares, it keeps the segment."""
    from types import SimpleNamespace

    from skyrecon.core.intrinsics import Intrinsics

    view = SimpleNamespace(intrinsics=Intrinsics(fx=100.0, fy=100.0, cx=32.0, cy=32.0, width=64, height=80))
    up = np.array([0.0, -1.0, 0.0])  # camera y down
    seg = np.zeros((80, 64), bool)
    seg[48:52, 10:50] = True
    cols = np.arange(12, 48)
    top_v, foot_v = np.array([45, 46]), np.array([53, 54])  # the plinth top, the ground in front
    vv = np.r_[np.repeat(top_v, len(cols)), np.repeat(foot_v, len(cols))]
    uu = np.tile(cols, 4)
    depth = np.where(vv < 48, 150.0 / (vv - 32.0), 200.0 / (vv - 32.0))  # y = 1.5 m and 2 m
    below, above = pp._segment_beside_band(view, (seg, 0, 0), uu, vv, up, 7)
    assert set(vv[below[0]]) == {45, 46} and set(vv[above[0]]) == {53, 54}
    np.testing.assert_allclose(below[1][:, 1], (48 - 32) / 100.0)  # the segment's first row below
    ground, face, top = [0.0, -1.0, 0.0, -2.0], [0.0, 0.0, -1.0, -10.0], [0.0, -1.0, 0.0, -1.5]
    cands = np.array([ground, face, top])
    shares = pp._overhang_shares(cands, depth, below, above, 0.02)
    np.testing.assert_allclose(shares, [0.5, 0.0, 0.5])
    s = PlanarPriorSettings()
    walls = pp._walls(cands, up)
    is_global = np.array([True, False, True])
    fracs, zero = np.array([0.92, 1.0, 0.9]), np.zeros(3)
    support = np.array([0.45, 0.84, 0.5])
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s, support)[0] == 0
    win, rivals = pp._choose_plane(is_global, fracs, zero, zero, walls, s, support, shares)
    assert win == 1 and np.isneginf(rivals[[0, 2]]).all()
    weak = np.array([0.45, 0.3, 0.5])
    assert pp._choose_plane(is_global, fracs, zero, zero, walls, s, weak, shares)[0] == 0
    # a camera looking straight down has no image "up" at its principal point
    nadir, _ = pp._segment_beside_band(
        view, (seg, 0, 0), np.array([32]), np.array([32]), np.array([0, 0, -1.0]), 7
    )
    assert len(nadir[0]) == 0


def test_overhang_settings_are_checked() -> None:
    with pytest.raises(InputError, match="max_overhang"):
        PlanarPriorSettings(max_overhang=-0.1)


def test_a_wall_of_the_frame_may_hide_the_face_beyond_its_corner() -> None:
    """A wall of the scene's frame hides the face beyond a convex corner of its building (at right
    angles to it): its hidden band share weighs ``framed_hidden_weight`` and it beats a slanted
    wall that hides nothing but matches less of the border; not framed, the strict weight holds."""
    s = PlanarPriorSettings()
    is_global = np.zeros(2, bool)
    walls = np.ones(2, bool)
    fracs, zero = np.array([1.0, 0.5]), np.zeros(2)
    front = np.array([0.7, 0.0])
    assert pp._choose_plane(is_global, fracs, zero, front, walls, s)[0] == 1
    assert pp._choose_plane(is_global, fracs, zero, front, walls, s, framed=np.array([True, False]))[0] == 0


def test_the_frame_leaves_out_a_lone_slanted_wall() -> None:
    """The frame's directions: walls another dominant wall is parallel or at right angles to, and
    the normals at right angles to them; a lone slanted wall and level planes give none."""
    up = np.array([0.0, 0.0, 1.0])
    x, y = [1.0, 0.0, 0.0, -2.0], [0.0, 1.0, 0.0, -1.0]
    slanted = [np.cos(0.8), np.sin(0.8), 0.0, -0.5]
    level = [0.0, 0.0, 1.0, -3.0]
    planes = np.array([x, y, slanted, level])
    assert pp._framed_walls(planes, up).tolist() == [True, True, False, False]
    frame = pp._frame_normals(planes, up)
    assert len(frame) == 2
    assert pp._in_frame(planes, frame).tolist() == [True, True, False, False]
    assert len(pp._frame_normals(np.array([x, slanted]), up)) == 0
