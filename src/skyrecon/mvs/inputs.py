"""Inputs of MVS: cameras matched to image files, and images loaded at the working resolution."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from skyrecon.core import PosedView
from skyrecon.errors import InputError
from skyrecon.io import read_cameras, read_image_with_alpha
from skyrecon.io.multiview import image_size_from_header
from skyrecon.mvs.frames import WorkingView, make_working_view

__all__ = ["IMAGE_EXTENSIONS", "ImagesArg", "load_views_and_images", "load_working_views"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".tif", ".tiff", ".bmp")

#: What :func:`skyrecon.mvs.run_mvs` accepts as images: None (each view's ``image_path``), a
#: sequence with one entry per view (an (H, W[, 3]) uint8 array, an ``(image, alpha)`` tuple or a
#: path), or a callable ``f(index) -> array | (image, alpha) | path``.
ImagesArg = Sequence | Callable[[int], object] | None


def _listing(names: list[str], limit: int = 6) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def load_views_and_images(
    images_dir: str | Path, cameras_spec: str | Path, allow_extra_images: bool = False
) -> tuple[list[PosedView], list[Path]]:
    """Read the cameras and match each to its image file in ``images_dir`` by name.

    A camera named ``a.png`` matches ``images_dir/a.png``, or failing that the only image file
    with the same stem (``a.jpg``). Image sizes are read from the file headers and must equal
    the cameras' calibrated sizes.

    Args:
        images_dir: directory of the images.
        cameras_spec: anything :func:`skyrecon.io.read_cameras` accepts (COLMAP text model,
            Middlebury ``*_par.txt``, Strecha ``*.camera`` directory, HALCON directory).
        allow_extra_images: accept image files that no camera refers to (ignored); by default
            they are an error, since they usually mean the wrong camera file.
    Returns:
        (views with ``image_path`` set, the image paths), in camera order.
    Raises:
        InputError: the directory is missing or holds no images; cameras without an image;
            images without a camera (unless allowed); image sizes that differ from the
            calibration; fewer than 2 views. The message names the views.
    """
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise InputError("image directory not found; check the path", images_dir)
    files = sorted(p for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise InputError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in this directory", images_dir)
    views = read_cameras(cameras_spec, image_dir=images_dir)
    if len(views) < 2:
        raise InputError(
            f"MVS needs at least 2 cameras, the camera specification has {len(views)}", cameras_spec
        )
    by_name = {p.name: p for p in files}
    by_stem: dict[str, list[Path]] = {}
    for p in files:
        by_stem.setdefault(p.stem, []).append(p)
    paths: list[Path] = []
    missing: list[str] = []
    for v in views:
        found = by_name.get(v.name)
        if found is None:
            cands = by_stem.get(Path(v.name).stem, [])
            found = cands[0] if len(cands) == 1 else None
        if found is None:
            missing.append(v.name)
        else:
            paths.append(found)
    if missing:
        raise InputError(
            f"{len(missing)} of {len(views)} cameras have no image in {images_dir}: {_listing(missing)}; "
            f"the directory has {_listing([p.name for p in files])}. Check that the cameras belong to these images",
        )
    extra = sorted(set(files) - set(paths))
    if extra and not allow_extra_images:
        raise InputError(
            f"{len(files)} images but {len(views)} cameras: no camera for {_listing([p.name for p in extra])}; "
            "use the camera file that belongs to these images (or remove the extra images)",
            images_dir,
        )
    wrong = []
    for v, p in zip(views, paths):
        size = image_size_from_header(p)
        if size is None:
            raise InputError("cannot read this image's header; the file is corrupt or not an image", p)
        if size != (v.intrinsics.width, v.intrinsics.height):
            wrong.append(
                f"{p.name} is {size[0]}x{size[1]} but its camera is "
                f"{v.intrinsics.width}x{v.intrinsics.height}"
            )
    if wrong:
        raise InputError(
            f"image sizes do not match the cameras: {_listing(wrong, 4)}; use the images the cameras were "
            "calibrated for (or scale the calibration)"
        )
    views = [replace(v, image_path=p) for v, p in zip(views, paths)]
    return views, paths


def _get_image(views: Sequence[PosedView], images: ImagesArg, i: int) -> tuple[np.ndarray, np.ndarray | None]:
    view = views[i]
    if images is None:
        item: object = view.image_path
        if item is None:
            raise InputError(f"view {view.name} has no image: pass images= or set its image_path")
    elif callable(images):
        item = images(i)
    else:
        item = images[i]
    if isinstance(item, (str, Path)):
        return read_image_with_alpha(item, "rgb")
    if isinstance(item, tuple) and len(item) == 2:
        return np.asarray(item[0]), None if item[1] is None else np.asarray(item[1])
    if isinstance(item, np.ndarray):
        return item, None
    raise InputError(
        f"view {view.name}: expected an image array, an (image, alpha) tuple or a path, "
        f"got {type(item).__name__}"
    )


def load_working_views(
    views: Sequence[PosedView], images: ImagesArg, max_image_size: int | None
) -> list[WorkingView]:
    """Load every view's image and resize it to the working resolution (one full image at a time).

    Raises:
        InputError: wrong number of images, unreadable images, size mismatches (naming the view).
    """
    if images is not None and not callable(images) and len(images) != len(views):
        raise InputError(f"{len(images)} images for {len(views)} cameras; give one image per camera")
    out = []
    for i, v in enumerate(views):
        img, alpha = _get_image(views, images, i)
        out.append(make_working_view(v, img, alpha, max_image_size))
    return out
