"""FlyingThings-style stereo pairs: random textured planar objects at random depths.

Every object is a planar patch (an ellipse, a rectangle or a triangle in the left image) whose
disparity is affine in the left image, ``d(x, y) = a + b x + c y``, painted with its own
random texture (band-limited noise of some scale, stripes, a checkerboard, a smooth gradient
or a nearly plain colour). Both views are rendered exactly: a right-image pixel ``x_r`` on an
object shows the texture at the left column solving ``x_r = x - d(x, y)``, and the nearer
object (larger disparity) wins in each view, so occlusions are exact. Pixels are
supersampled 3x3 (antialiased edges); the ground truth is the disparity at pixel centres.

    left, right, disparity = render_flying_pair(seed=1)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyrecon.errors import InputError

__all__ = ["render_flying_pair"]

_SS = 3  # supersampling per axis


@dataclass(frozen=True)
class _Patch:
    shape: int  # 0 background (everywhere), 1 ellipse, 2 rotated rectangle, 3 triangle
    geom: np.ndarray  # shape parameters (left-image pixels)
    plane: tuple[float, float, float]  # d = a + b x + c y
    texture: np.ndarray  # (Ht, Wt, 3) float32, left-image coordinates offset by ``pad``


def _texture(rng: np.random.Generator, h: int, w: int, plain: bool) -> np.ndarray:
    """(h, w, 3) float32 random texture in 0..255."""
    base = rng.uniform(30, 225, 3).astype(np.float32)
    kind = 4 if plain else int(rng.integers(0, 4))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if kind == 0:  # band-limited noise
        sigma = float(rng.choice([0.8, 1.5, 3.0, 6.0]))
        n = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), sigma)
        g = n / (n.std() + 1e-6) * rng.uniform(20, 50)
    elif kind == 1:  # stripes with a random direction and period
        th, per = rng.uniform(0, np.pi), rng.uniform(6, 30)
        g = 40 * np.sin(2 * np.pi * (xx * np.cos(th) + yy * np.sin(th)) / per)
    elif kind == 2:  # checkerboard, rotated
        th, per = rng.uniform(0, np.pi), rng.uniform(8, 24)
        u = xx * np.cos(th) + yy * np.sin(th)
        v = -xx * np.sin(th) + yy * np.cos(th)
        g = 45 * (((np.floor(u / per) + np.floor(v / per)) % 2) * 2 - 1)
    elif kind == 3:  # smooth gradient plus fine noise
        th = rng.uniform(0, 2 * np.pi)
        g = 60 * ((xx * np.cos(th) + yy * np.sin(th)) / max(h, w)) + rng.normal(0, 4, (h, w))
    else:  # nearly plain: faint low-frequency shading and weak noise
        n = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 20.0)
        g = n / (n.std() + 1e-6) * 8 + rng.normal(0, 2, (h, w))
    tint = rng.uniform(0.6, 1.0, 3).astype(np.float32)
    out = base[None, None, :] + g[..., None] * tint[None, None, :]
    return np.clip(out, 0, 255).astype(np.float32)


def _inside(p: _Patch, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether left-image points (x, y) lie on the patch."""
    if p.shape == 0:
        return np.ones(x.shape, bool)
    g = p.geom
    if p.shape == 1:  # cx, cy, rx, ry, angle
        cx, cy, rx, ry, th = g
        u = (x - cx) * np.cos(th) + (y - cy) * np.sin(th)
        v = -(x - cx) * np.sin(th) + (y - cy) * np.cos(th)
        return (u / rx) ** 2 + (v / ry) ** 2 <= 1.0
    if p.shape == 2:  # cx, cy, hx, hy, angle
        cx, cy, hx, hy, th = g
        u = (x - cx) * np.cos(th) + (y - cy) * np.sin(th)
        v = -(x - cx) * np.sin(th) + (y - cy) * np.cos(th)
        return (np.abs(u) <= hx) & (np.abs(v) <= hy)
    # triangle: three vertices
    (x0, y0), (x1, y1), (x2, y2) = g.reshape(3, 2)
    s = np.sign((x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0))
    e0 = s * ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) >= 0
    e1 = s * ((x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)) >= 0
    e2 = s * ((x0 - x2) * (y - y2) - (y0 - y2) * (x - x2)) >= 0
    return e0 & e1 & e2


def _patches(
    rng: np.random.Generator, width: int, height: int, n: int, dmax: float, pad: int, plain_fraction: float
) -> list[_Patch]:
    th, tw = height + 2 * pad, width + 2 * pad
    d_bg = rng.uniform(0.05, 0.25) * dmax
    slope = 0.15 * d_bg / width
    out = [
        _Patch(
            0,
            np.zeros(0),
            (d_bg, rng.uniform(-slope, slope), rng.uniform(0, 2 * slope)),
            _texture(rng, th, tw, False),
        )
    ]
    for _ in range(n):
        size = rng.uniform(0.04, 0.2) * width
        cx, cy = rng.uniform(-0.05, 1.05) * width, rng.uniform(-0.05, 1.05) * height
        d0 = rng.uniform(0.3, 0.95) * dmax
        b, c = rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06)
        shape = int(rng.integers(1, 4))
        if shape == 3:
            ang = np.sort(rng.uniform(0, 2 * np.pi, 3))
            geom = np.column_stack([cx + size * np.cos(ang), cy + size * np.sin(ang)]).ravel()
        else:
            geom = np.array([cx, cy, size, size * rng.uniform(0.4, 1.0), rng.uniform(0, np.pi)])
        # disparity within [1, dmax - 1] over the object: a + b x + c y at its centre is d0
        a = d0 - b * cx - c * cy
        out.append(_Patch(shape, geom, (a, b, c), _texture(rng, th, tw, rng.random() < plain_fraction)))
    return out


def _render_view(
    patches: list[_Patch], width: int, height: int, pad: int, right: bool, dmax: float
) -> tuple[np.ndarray, np.ndarray]:
    """Render one view supersampled: (colour (H, W, 3) float32, disparity at centres (H, W))."""
    H, W = height * _SS, width * _SS
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    xs = (xs + 0.5) / _SS - 0.5
    ys = (ys + 0.5) / _SS - 0.5
    best = np.full((H, W), -np.inf)
    img = np.zeros((H, W, 3), np.float32)
    for p in patches:
        a, b, c = p.plane
        # left column seen at this pixel: x_l itself, or x_r = x_l - d(x_l, y) solved for x_l
        xl = (xs + a + c * ys) / (1.0 - b) if right else xs
        d = a + b * xl + c * ys
        on = _inside(p, xl, ys) & (d > best) & (d > 0.5) & (d < dmax - 0.5)
        if not on.any():
            continue
        best[on] = d[on]
        mx = (xl + pad).astype(np.float32)
        my = (ys + pad).astype(np.float32)
        vals = cv2.remap(p.texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        img[on] = vals[on]
    colour = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    centre = _SS // 2
    disp = best[centre::_SS, centre::_SS].astype(np.float32)
    return colour, disp


def render_flying_pair(
    seed: int,
    width: int = 480,
    height: int = 360,
    max_disparity: float = 64.0,
    n_objects: int = 18,
    plain_fraction: float = 0.25,
    noise: float = 1.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a FlyingThings-style rectified pair with exact left disparity.

    Args:
        seed: the only source of randomness.
        width, height: image size, pixels.
        max_disparity: disparities lie in (0.5, max_disparity - 0.5), pixels.
        n_objects: number of objects in front of the (slanted, textured) background.
        plain_fraction: share of objects with a nearly plain texture.
        noise: standard deviation of the Gaussian sensor noise added to each view, grey levels.
    Returns:
        left, right: (H, W, 3) uint8 RGB; disparity: (H, W) float32 left disparity in pixels
        (``x_right = x_left - d``), NaN where no surface (never, the background fills the view).
    Raises:
        InputError: a non-positive size or disparity range.
    """
    if width < 32 or height < 32 or not (max_disparity > 2):
        raise InputError(
            f"need width, height >= 32 and max_disparity > 2, got {width}, {height}, {max_disparity}"
        )
    rng = np.random.default_rng(seed)
    pad = int(np.ceil(max_disparity * 1.2)) + 16
    patches = _patches(rng, width, height, n_objects, float(max_disparity), pad, plain_fraction)
    left, disp = _render_view(patches, width, height, pad, False, float(max_disparity))
    right, _ = _render_view(patches, width, height, pad, True, float(max_disparity))
    left = left + rng.normal(0, noise, left.shape).astype(np.float32)
    right = right + rng.normal(0, noise, right.shape).astype(np.float32)
    disp[~np.isfinite(disp)] = np.nan
    return (
        np.clip(np.rint(left), 0, 255).astype(np.uint8),
        np.clip(np.rint(right), 0, 255).astype(np.uint8),
        disp,
    )
