"""EXIF/XMP tags of survey photos: write then read, hemispheres, DJI altitudes, the camera from the tags."""

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.survey.exif import dji_xmp, intrinsics_from_meta, read_photo_meta, write_geotagged_jpeg

IMG = np.random.default_rng(0).integers(0, 255, (60, 80, 3)).astype(np.uint8)


@pytest.mark.parametrize(
    "lat, lon", [(47.376912345, 8.54171234), (-33.8688, 151.2093), (40.7128, -74.0060), (-0.5, -0.25)]
)
def test_gps_round_trip_to_a_millimetre(tmp_path, lat, lon):
    p = tmp_path / "a.jpg"
    write_geotagged_jpeg(p, IMG, lat, lon, 480.25, 8.8, 13.2)
    m = read_photo_meta(p)
    assert m.has_gps and m.alt_source == "exif"
    # 1e-5 arc seconds = 0.3 mm of latitude
    assert abs(m.lat_deg - lat) * 111_000 < 1e-3
    assert abs(m.lon_deg - lon) * 111_000 < 1e-3
    assert m.alt_m == pytest.approx(480.25, abs=1e-3)
    assert (m.width, m.height) == (80, 60)


def test_negative_altitude_and_xmp_absolute_altitude_is_preferred(tmp_path):
    p = tmp_path / "below.jpg"
    write_geotagged_jpeg(p, IMG, 31.5, 35.5, -410.0, 8.8, 13.2)
    assert read_photo_meta(p).alt_m == pytest.approx(-410.0)
    q = tmp_path / "dji.jpg"
    write_geotagged_jpeg(q, IMG, 31.5, 35.5, 100.0, 8.8, 13.2, xmp=dji_xmp(512.3, 85.1))
    m = read_photo_meta(q)
    assert m.alt_m == pytest.approx(512.3) and m.alt_source == "xmp"
    assert m.relative_alt_m == pytest.approx(85.1)


def test_camera_from_focal_length_and_sensor_width(tmp_path):
    p = tmp_path / "a.jpg"
    write_geotagged_jpeg(p, IMG, 1.0, 2.0, 3.0, 8.8, 13.2)
    cam = intrinsics_from_meta(read_photo_meta(p))
    assert cam.fx == pytest.approx(8.8 / 13.2 * 80, rel=1e-5)
    assert (cam.cx, cam.cy) == (39.5, 29.5)


def test_untagged_photo_has_no_gps_and_no_camera(tmp_path):
    from PIL import Image

    p = tmp_path / "plain.jpg"
    Image.fromarray(IMG).save(p)
    m = read_photo_meta(p)
    assert not m.has_gps and m.focal_mm is None
    with pytest.raises(InputError, match="--camera"):
        intrinsics_from_meta(m)


def test_unreadable_file_is_an_input_error(tmp_path):
    p = tmp_path / "bad.jpg"
    p.write_bytes(b"not a jpeg")
    with pytest.raises(InputError, match="bad.jpg"):
        read_photo_meta(p)
