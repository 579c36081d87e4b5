"""Maps streamed from posed depth images (what ``skyrecon map --depth`` runs) and map previews."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.mapping import (
    MapConfig,
    OccupancyMap,
    build_map_from_depth_frames,
    map_depth_sequence,
    map_preview_image,
    write_map_preview,
)


def test_streamed_map_equals_the_batch_map(city_frames):
    cam, depths, poses = city_frames
    seen = []
    built = map_depth_sequence(
        iter(depths), cam, poses, MapConfig(voxel_size_m=0.5), progress=lambda i, n: seen.append((i, n))
    )
    batch = build_map_from_depth_frames(depths, cam, poses, voxel_size_m=0.5)
    np.testing.assert_array_equal(built.map.occupied_voxels(), batch.occupied_voxels())
    assert built.map.counts() == batch.counts()
    assert seen == [(i + 1, len(depths)) for i in range(len(depths))]
    summary = built.timings.summary()
    assert summary["frames"] == len(depths) and summary["frames_per_s"] > 0


def test_streamed_map_bad_input(city_frames):
    cam, depths, poses = city_frames
    with pytest.raises(InputError, match="only 2 poses"):
        map_depth_sequence(iter(depths), cam, poses[:2])
    with pytest.raises(InputError, match="no depth frames"):
        map_depth_sequence(iter([]), cam, poses)
    with pytest.raises(InputError, match="frame 1"):
        map_depth_sequence([depths[0], depths[1][:50]], cam, poses)


def test_preview_shows_the_map_and_the_track(city_frames, tmp_path):
    cam, depths, poses = city_frames
    occ = build_map_from_depth_frames(depths, cam, poses, voxel_size_m=0.5)
    track = np.array([p.t for p in poses])
    image = map_preview_image(occ, [track])
    assert image is not None and image.ndim == 3 and image.dtype == np.uint8
    write_map_preview(occ, tmp_path / "preview.png", [track])
    assert (tmp_path / "preview.png").stat().st_size > 0
    empty = MapConfig(voxel_size_m=0.5)
    assert map_preview_image(OccupancyMap(empty)) is None
    write_map_preview(OccupancyMap(empty), tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
