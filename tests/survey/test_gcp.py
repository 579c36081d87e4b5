"""OpenDroneMap GCP files: coordinate-system lines, observations grouped by point, errors that name the line."""

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.survey.gcp import read_gcp_list
from skyrecon.survey.geo import GeoOrigin, enu_from_lla, projected_from_enu

ORIGIN = GeoOrigin(47.3769, 8.5417, 408.0)


def _utm(enu):
    return projected_from_enu(ORIGIN, np.asarray(enu, float).reshape(-1, 3))


@pytest.mark.parametrize(
    "header", ["EPSG:{epsg}", "WGS84 UTM 32N", "+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs"]
)
def test_points_convert_back_to_their_enu_position(tmp_path, header):
    xyz, epsg = _utm([[10.0, -20.0, 3.0], [-30.0, 40.0, 0.5]])
    assert epsg == 32632
    lines = [header.format(epsg=epsg)]
    for k, p in enumerate(xyz):
        lines.append(f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f} 100.5 200.5 IMG_1.jpg gcp{k}")
        lines.append(f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f} 300.5 50.5 IMG_2.jpg gcp{k}")
    f = tmp_path / "gcp_list.txt"
    f.write_text("\n".join(lines) + "\n")
    g = read_gcp_list(f)
    assert [p.name for p in g.points] == ["gcp0", "gcp1"]
    back = np.concatenate([enu_from_lla(ORIGIN, p.lat_deg, p.lon_deg, p.alt_m) for p in g.points])
    assert np.allclose(back, [[10.0, -20.0, 3.0], [-30.0, 40.0, 0.5]], atol=1e-3)
    # ODM pixels have the top-left corner at 0: skyrecon's have its centre at 0
    assert np.allclose(g.points[0].observations["IMG_1.jpg"], [100.0, 200.0])
    assert set(g.points[1].observations) == {"IMG_1.jpg", "IMG_2.jpg"}


def test_lon_lat_file_and_unnamed_points(tmp_path):
    f = tmp_path / "g.txt"
    f.write_text(
        "EPSG:4326\n8.5417 47.3769 408 10 10 a.jpg\n8.5417 47.3769 408 20 20 b.jpg\n8.5420 47.3770 409 5 5 a.jpg\n"
    )
    g = read_gcp_list(f)
    assert len(g.points) == 2 and len(g.points[0].observations) == 2
    assert g.points[0].lat_deg == pytest.approx(47.3769) and g.points[0].lon_deg == pytest.approx(8.5417)


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("not a crs at all\n1 2 3 4 5 a.jpg\n", "coordinate system"),
        ("EPSG:32632\n1 2 3 4 a.jpg\n", "line 2"),
        ("EPSG:32632\n1 2 x 4 5 a.jpg\n", "line 2"),
        ("EPSG:32632\n", "no observation"),
        ("WGS84 UTM 61N\n1 2 3 4 5 a.jpg\n", "zone"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, match):
    f = tmp_path / "g.txt"
    f.write_text(text)
    with pytest.raises(InputError, match=match):
        read_gcp_list(f)
