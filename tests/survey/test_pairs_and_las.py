"""Survey pairs by GPS proximity, and LAS/LAZ with a coordinate system."""

import numpy as np
import pytest

from skyrecon.core.depth import PointCloud
from skyrecon.io.las import read_las, write_point_cloud
from skyrecon.survey.pipeline import gps_pairs


def test_gps_pairs_join_strip_neighbours_and_keep_untagged_photos_in_flight_order():
    # two strips of 6 photos, 20 m apart, flown in serpentine order; photo 3 has no tag
    pos = [np.array([0.0, 10.0 * k, 80]) for k in range(6)] + [
        np.array([20.0, 10.0 * k, 80]) for k in range(5, -1, -1)
    ]
    pos[3] = None
    pairs = gps_pairs(pos, neighbors=4, window=2)
    as_set = {tuple(p) for p in pairs.tolist()}
    assert np.all(pairs[:, 0] < pairs[:, 1]) and len(as_set) == len(pairs)
    assert (0, 11) in as_set  # across strips: photo 0 and photo 11 are 20 m apart
    assert (2, 3) in as_set and (3, 4) in as_set and (3, 5) in as_set  # the untagged one by flight order
    assert not any(3 in p for p in as_set if abs(p[0] - p[1]) > 2)
    assert all(abs(a - b) <= 2 or np.linalg.norm(pos[a][:2] - pos[b][:2]) < 35 for a, b in as_set)


@pytest.mark.parametrize("fmt", ["las", "laz"])
def test_las_with_crs_keeps_utm_coordinates_to_a_millimetre(tmp_path, fmt):
    laspy = pytest.importorskip("laspy")
    pytest.importorskip("pyproj")
    utm = np.array([[465383.6975, 5247141.2453, 408.0], [465400.1234, 5247150.9876, 430.25]])
    cloud = PointCloud(np.zeros((2, 3)), np.array([[255, 0, 0], [0, 128, 255]], np.uint8))
    path = write_point_cloud(tmp_path / "cloud.laz", cloud, fmt, crs="EPSG:32632", points=utm)
    pts, colors = read_las(path)
    assert np.allclose(pts, utm, atol=1e-3)
    assert colors is not None and colors.tolist() == [[255, 0, 0], [0, 128, 255]]
    assert laspy.read(path).header.parse_crs().to_epsg() == 32632


def test_small_sets_match_every_pair():
    pos = [np.array([float(k), 0.0, 0.0]) for k in range(5)]
    assert len(gps_pairs(pos, neighbors=1, window=1, exhaustive_up_to=5)) == 10
    assert len(gps_pairs(pos, neighbors=1, window=1, exhaustive_up_to=4)) == 4
