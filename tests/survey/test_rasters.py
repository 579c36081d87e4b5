"""DSM, orthophoto, GeoTIFF and footprint of :mod:`skyrecon.survey.rasters`."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.survey.geo import GeoOrigin, lla_from_enu, projected_from_enu
from skyrecon.survey.rasters import default_cell_m, footprint_geojson, surface_rasters, write_geotiff

pytest.importorskip("pyproj")

ORIGIN = GeoOrigin(47.3769, 8.5417, 450.0)


def _block_scene(seed: int = 0, spacing: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Ground at z=0 (grey) over 40 x 30 m, a 10 x 8 x 12 m box (red) on it, noisy points."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(-20, 20, spacing), np.arange(-15, 15, spacing))
    ground = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    inside = (np.abs(ground[:, 0] - 5) < 5) & (np.abs(ground[:, 1]) < 4)
    roof = ground[inside].copy()
    roof[:, 2] = 12.0
    # wall points below the roof edge (seen obliquely): must not lower the roof cells
    wall = roof[np.abs(roof[:, 0] - 10) < spacing].copy()
    wall[:, 2] = rng.uniform(0, 12, len(wall))
    pts = np.concatenate([ground[~inside], roof, wall])
    pts += rng.normal(0, 0.02, pts.shape)
    rgb = np.concatenate(
        [
            np.full((int((~inside).sum()), 3), 128, np.uint8),
            np.tile(np.array([[200, 30, 30]], np.uint8), (len(roof), 1)),
            np.full((len(wall), 3), 60, np.uint8),
        ]
    )
    return pts, rgb


def test_dsm_holds_the_top_surface_and_ortho_its_colour():
    pts, rgb = _block_scene()
    r = surface_rasters(pts, rgb, ORIGIN, cell_m=0.5)
    assert r.epsg == 32632 and r.cell_m == 0.5
    # sample the DSM at the true positions of roof centre and open ground
    probes = np.array([[5.0, 0.0, 0.0], [-15.0, 10.0, 0.0]])
    proj, _ = projected_from_enu(ORIGIN, probes)
    row, col = r.cell_of(proj[:, 0], proj[:, 1])
    base = projected_from_enu(ORIGIN, np.zeros((1, 3)))[0][0, 2]
    assert abs(r.dsm_m[row[0], col[0]] - base - 12.0) < 0.1
    assert abs(r.dsm_m[row[1], col[1]] - base) < 0.1
    assert tuple(r.ortho_rgb[row[0], col[0]]) == (200, 30, 30)
    assert tuple(r.ortho_rgb[row[1], col[1]]) == (128, 128, 128)
    # coverage: nearly every cell of the 40 x 30 m rectangle
    assert r.valid.sum() >= 0.95 * (40 * 30 / 0.25)
    # ellipsoidal heights: the ENU origin sits at the origin's height (curvature is centimetres here)
    assert abs(base - ORIGIN.alt_m) < 0.2


def test_quantile_rejects_single_spikes():
    pts, rgb = _block_scene(spacing=0.1)
    spike = np.array([[-10.0, -10.0, 30.0]])
    r = surface_rasters(np.concatenate([pts, spike]), np.concatenate([rgb, [[0, 0, 0]]]), ORIGIN, cell_m=0.5)
    proj, _ = projected_from_enu(ORIGIN, spike)
    row, col = r.cell_of(proj[:, 0], proj[:, 1])
    assert r.dsm_m[row[0], col[0]] - ORIGIN.alt_m < 1.0
    top = surface_rasters(np.concatenate([pts, spike]), None, ORIGIN, cell_m=0.5, quantile=1.0)
    assert top.dsm_m[row[0], col[0]] - ORIGIN.alt_m > 29.0


def test_single_cell_holes_are_filled_but_edges_are_not():
    pts, rgb = _block_scene()
    hole = np.linalg.norm(pts[:, :2] - [-10.0, 5.0], axis=1) < 0.3
    r = surface_rasters(pts[~hole], rgb[~hole], ORIGIN, cell_m=0.5)
    proj, _ = projected_from_enu(ORIGIN, np.array([[-10.0, 5.0, 0.0]]))
    row, col = r.cell_of(proj[:, 0], proj[:, 1])
    assert r.valid[row[0], col[0]]
    assert r.points_per_cell[row[0], col[0]] == 0
    raw = surface_rasters(pts[~hole], rgb[~hole], ORIGIN, cell_m=0.5, fill_gaps=False)
    assert not raw.valid[row[0], col[0]]


def test_geotiffs_read_back_with_their_georeferencing(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    pts, rgb = _block_scene()
    r = surface_rasters(pts, rgb, ORIGIN, cell_m=0.5)
    dsm_path = write_geotiff(tmp_path / "dsm.tif", r, "dsm")
    ortho_path = write_geotiff(tmp_path / "ortho.tif", r, "ortho")
    with rasterio.open(dsm_path) as ds:
        assert ds.crs.to_epsg() == 32632
        assert ds.count == 1 and ds.dtypes[0] == "float32"
        band = ds.read(1)
        np.testing.assert_array_equal(np.isnan(band), ~r.valid)
        # the roof centre: projected coordinate -> pixel through the file's own transform
        proj, _ = projected_from_enu(ORIGIN, np.array([[5.0, 0.0, 0.0]]))
        row, col = ds.index(proj[0, 0], proj[0, 1])
        assert abs(band[row, col] - ORIGIN.alt_m - 12.0) < 0.2
    with rasterio.open(ortho_path) as ds:
        assert ds.count == 4 and ds.dtypes[0] == "uint8"
        alpha = ds.read(4)
        assert ((alpha == 255) == r.valid).all()
    assert not list(tmp_path.glob(".*"))  # no temporaries left


def test_footprint_is_a_lonlat_polygon_around_the_cloud():
    pts, rgb = _block_scene()
    r = surface_rasters(pts, rgb, ORIGIN, cell_m=0.5)
    fc = footprint_geojson(r)
    geom = fc["features"][0]["geometry"]
    assert geom["type"] == "Polygon"
    ring = np.array(geom["coordinates"][0])
    assert (ring[0] == ring[-1]).all() and len(ring) >= 5
    corners_lat, corners_lon, _ = lla_from_enu(ORIGIN, np.array([[-20.0, -15.0, 0], [20.0, 15.0, 0]]))
    assert ring[:, 0].min() == pytest.approx(corners_lon[0], abs=2e-5)
    assert ring[:, 0].max() == pytest.approx(corners_lon[1], abs=2e-5)
    assert ring[:, 1].min() == pytest.approx(corners_lat[0], abs=2e-5)
    assert ring[:, 1].max() == pytest.approx(corners_lat[1], abs=2e-5)
    # counter-clockwise (shoelace area > 0 in lon/lat)
    x, y = ring[:, 0], ring[:, 1]
    assert np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) > 0
    area = fc["features"][0]["properties"]["covered_area_m2"]
    assert 0.9 * 1200 < area < 1.1 * 1200


def test_default_cell_and_bad_input():
    pts, _ = _block_scene(spacing=0.2)
    assert default_cell_m(pts) in (0.2, 0.5)
    with pytest.raises(InputError):
        surface_rasters(np.full((3, 3), np.nan), None, ORIGIN)
    with pytest.raises(InputError):
        surface_rasters(pts, None, ORIGIN, cell_m=-1)
    with pytest.raises(InputError):
        surface_rasters(pts, None, ORIGIN, cell_m=1e-5)
