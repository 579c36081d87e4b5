"""Matching cameras to image files: counts, names and sizes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skyrecon.core import Image, Reconstruction
from skyrecon.errors import InputError
from skyrecon.io import write_colmap_text, write_image
from skyrecon.mvs import load_views_and_images
from tests.mvs.synthetic import make_ring


def write_set(tmp: Path, n: int = 4, names: list[str] | None = None) -> Path:
    """Images of a ring and a COLMAP text model (explicit image sizes) for them."""
    ring = make_ring()
    names = names or [f"img{i:02d}.png" for i in range(n)]
    rec = Reconstruction(cameras={1: ring.views[0].intrinsics})
    for i in range(n):
        write_image(tmp / names[i], ring.images[i])
        rec.images[i + 1] = Image(i + 1, names[i], 1, ring.views[i].cam_from_world)
    model = tmp / "model"
    write_colmap_text(model, rec)
    return model


def rename_in_model(model: Path, old: str, new: str) -> None:
    p = model / "images.txt"
    p.write_text(p.read_text().replace(old, new))


def test_matching_set_loads(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    views, paths = load_views_and_images(tmp_path, par)
    assert [p.name for p in paths] == [f"img{i:02d}.png" for i in range(4)]
    assert all(v.image_path == p for v, p in zip(views, paths))


def test_camera_without_image_is_named(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    (tmp_path / "img02.png").unlink()
    with pytest.raises(InputError, match="img02.png"):
        load_views_and_images(tmp_path, par)


def test_extra_image_is_named(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    write_image(tmp_path / "stray.png", np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InputError, match="stray.png"):
        load_views_and_images(tmp_path, par)
    views, _ = load_views_and_images(tmp_path, par, allow_extra_images=True)
    assert len(views) == 4


def test_wrong_image_size_is_named(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    write_image(tmp_path / "img01.png", np.zeros((50, 60, 3), np.uint8))
    with pytest.raises(InputError, match="img01.png is 60x50"):
        load_views_and_images(tmp_path, par)


def test_same_stem_other_extension_matches(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    rename_in_model(par, ".png", ".jpg")
    views, paths = load_views_and_images(tmp_path, par)
    assert [v.name for v in views][0] == "img00.jpg" and paths[0].name == "img00.png"


def test_missing_directory_and_empty_directory(tmp_path: Path) -> None:
    par = write_set(tmp_path)
    with pytest.raises(InputError, match="not found"):
        load_views_and_images(tmp_path / "nope", par)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no images"):
        load_views_and_images(empty, par)
