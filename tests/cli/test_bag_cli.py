"""A rendered flight as a ROS 2 bag and as MCAP maps and odometers exactly like its KITTI layout."""

from __future__ import annotations

import pytest

pytest.importorskip("rosbags")

from skyrecon.cli.main import main  # noqa: E402

SMALL = ["--frames", "5", "--width", "320", "--height", "240", "--seed", "3", "--quiet"]
TOPICS = ["--left-topic", "/stereo/left/image_raw", "--right-topic", "/stereo/right/image_raw"]
POSES = ["--pose-topic", "/stereo/left/pose"]


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    paths = {}
    for fmt in ("kitti", "ros2", "mcap"):
        assert main(["render", "sequence", "--format", fmt, "--out", str(root / fmt), *SMALL]) == 0
        paths[fmt] = root / fmt / "flight.mcap" if fmt == "mcap" else root / fmt
    assert sorted(p.name for p in (root / "ros2").iterdir()) == [
        "depth_2", "metadata.yaml", "preview.png", "ros2.db3", "scene.json"
    ]  # fmt: skip
    return paths


@pytest.fixture(scope="module")
def kitti_map(flights, tmp_path_factory):
    out = tmp_path_factory.mktemp("kitti_map") / "map"
    assert main(["map", str(flights["kitti"]), "--voxel-size", "0.5", "--out", str(out), "--quiet"]) == 0
    return out


@pytest.mark.parametrize("fmt", ["ros2", "mcap"])
def test_bag_map_is_byte_identical(flights, kitti_map, tmp_path, fmt):
    out = tmp_path / "map"
    args = ["map", str(flights[fmt]), *TOPICS, *POSES, "--voxel-size", "0.5", "--out", str(out), "--quiet"]
    assert main(args) == 0
    for name in ("map.json", "blocks.npz", "occupied.ply", "flown_path.json"):
        assert (out / name).read_bytes() == (kitti_map / name).read_bytes(), name


def test_bag_odometry_gives_the_same_poses(flights, tmp_path):
    ref, got = tmp_path / "kitti", tmp_path / "mcap"
    assert main(["odometry", str(flights["kitti"]), "--out", str(ref), "--quiet"]) == 0
    assert main(["odometry", str(flights["mcap"]), *TOPICS, *POSES, "--out", str(got), "--quiet"]) == 0
    for name in ("poses.txt", "trajectory.txt"):
        assert (got / name).read_bytes() == (ref / name).read_bytes(), name


def test_stereo_reads_the_first_pair_of_a_bag(flights, tmp_path):
    out = tmp_path / "st"
    args = [
        "stereo",
        str(flights["ros2"]),
        *TOPICS,
        "--frames",
        "1",
        "--method",
        "opencv-bm",
        "--out",
        str(out),
    ]
    assert main([*args, "--quiet"]) == 0
    assert (out / "disparity" / "000000.pfm").is_file() and (out / "depth" / "000000.pfm").is_file()


def test_bad_bags_are_one_line_exit_2(flights, tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    cases = [
        (
            ["map", str(flights["ros2"]), "--left-topic", "/a", "--right-topic", "/b"],
            "no topic /a in the bag",
        ),
        (["map", str(flights["ros2"]), *TOPICS], "has no poses (a --pose-topic)"),
        (["odometry", str(junk), *TOPICS], "not a readable ROS bag"),
    ]
    for args, message in cases:
        assert main([*args, "--out", str(tmp_path / "o"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
        assert str(args[1]) in err[0]


def test_map_writes_laz_and_footprint(flights, tmp_path):
    laspy = pytest.importorskip("laspy")
    import json

    out = tmp_path / "map"
    args = ["map", str(flights["kitti"]), "--voxel-size", "0.5", "--format", "laz", "--out", str(out)]
    assert main([*args, "--geo-origin", "47.3769", "8.5417", "408", "--quiet"]) == 0
    assert len(laspy.read(out / "occupied.laz").points) > 0 and not (out / "occupied.ply").exists()
    doc = json.loads((out / "footprint.geojson").read_text())
    assert (
        doc["features"][0]["geometry"]["type"] == "MultiPolygon"
        and "note" not in doc["features"][0]["properties"]
    )
