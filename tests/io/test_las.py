"""LAS/LAZ point clouds read back with laspy: coordinates within 1 mm, colours, the install hint."""

from __future__ import annotations

import sys

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")

from skyrecon.core.depth import PointCloud  # noqa: E402
from skyrecon.errors import InputError  # noqa: E402
from skyrecon.io.las import write_point_cloud  # noqa: E402


@pytest.mark.parametrize("fmt", ["las", "laz"])
@pytest.mark.parametrize("coloured", [True, False])
def test_las_round_trip(tmp_path, fmt, coloured):
    rng = np.random.default_rng(0)
    pts = (rng.normal(size=(500, 3)) * [100, 100, 20] + [1000, -2000, 50]).astype(np.float32)
    colors = rng.integers(0, 256, (500, 3), dtype=np.uint8) if coloured else None
    path = write_point_cloud(tmp_path / "cloud.ply", PointCloud(pts, colors), fmt)
    assert path == tmp_path / f"cloud.{fmt}" and not (tmp_path / "cloud.ply").exists()
    las = laspy.read(path)
    xyz = np.column_stack([las.x, las.y, las.z])
    np.testing.assert_allclose(xyz, pts.astype(np.float64), rtol=0, atol=0.0005 + 1e-9)
    np.testing.assert_allclose(las.header.offsets, pts.astype(np.float64).min(axis=0))
    np.testing.assert_allclose(las.header.scales, 0.001)
    if coloured:
        rgb = np.column_stack([las.red, las.green, las.blue]) >> 8
        np.testing.assert_array_equal(rgb, colors)
    else:
        assert las.header.point_format.id == 0


@pytest.mark.parametrize("fmt", ["las", "laz"])
def test_a_cloud_written_in_chunks_reads_back_whole(tmp_path, fmt, monkeypatch):
    from skyrecon.io import las as las_module

    rng = np.random.default_rng(1)
    pts = (rng.normal(size=(2503, 3)) * [50, 50, 10] + [500, 300, 20]).astype(np.float32)
    colors = rng.integers(0, 256, (2503, 3), dtype=np.uint8)
    whole = write_point_cloud(tmp_path / "whole", PointCloud(pts, colors), fmt, crs="EPSG:32632")
    monkeypatch.setattr(las_module, "_WRITE_CHUNK", 1000)  # three chunks, the last one short
    chunked = write_point_cloud(tmp_path / "chunked", PointCloud(pts, colors), fmt, crs="EPSG:32632")
    a, b = laspy.read(whole), laspy.read(chunked)
    assert b.header.point_count == 2503
    np.testing.assert_array_equal(b.header.mins, a.header.mins)
    np.testing.assert_array_equal(b.header.maxs, a.header.maxs)
    np.testing.assert_array_equal(np.asarray(b.points.array), np.asarray(a.points.array))
    assert b.header.parse_crs() == a.header.parse_crs()


def test_ply_is_the_default(tmp_path):
    path = write_point_cloud(tmp_path / "p.ply", PointCloud(np.zeros((2, 3))))
    assert path.suffix == ".ply" and path.is_file()


def test_missing_laspy_gives_the_install_hint(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "laspy", None)
    with pytest.raises(InputError, match=r"pip install 'skyrecon\[geo\]'"):
        write_point_cloud(tmp_path / "p.ply", PointCloud(np.zeros((2, 3))), "las")
