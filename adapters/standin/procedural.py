"""Procedural stereo pairs with exact disparity, for training and testing the stand-in.

A pair is a stack of textured planar layers seen by a rectified stereo rig: a slanted
background plane and a few occluding foreground layers (ellipses, polygons, rectangles),
each with its own plane ``d(x, y) = a + b x + c y`` in left-image pixels. The left
image and its ground truth come from a z-buffer over the layers (larger disparity is
closer); the right image samples every layer where it lands in the right view,
``x_r = x_l - d(x_l, y)``, which is solved in closed form for a plane, and z-buffers
again. Occlusions are therefore exact, including slanted surfaces.

Textures mix band-limited noise over several octaves with random strokes, in random
colours and contrasts; a few layers are nearly textureless, where matching is ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["StereoSample", "random_stereo_pair", "random_stereo_batch"]

_MAX_SLANT = 0.35  # |dd/dx| and |dd/dy| of the planes; |dd/dx| < 1 keeps x_r monotonic
_TEXTURELESS_PROB = 0.08
_MAX_FOREGROUND_LAYERS = 4


@dataclass(frozen=True)
class StereoSample:
    """One rendered pair.

    Attributes
    ----------
    left, right : numpy.ndarray, (H, W, 3), uint8
        Rectified RGB images.
    disparity_px : numpy.ndarray, (H, W), float32, pixels
        Exact disparity of every left pixel (``x_right = x_left - d``); occluded pixels
        keep the disparity of the surface they show.
    """

    left: np.ndarray
    right: np.ndarray
    disparity_px: np.ndarray


def _texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W, 3) float32 texture in [0, 1]."""
    base = rng.uniform(0.15, 0.85, size=3).astype(np.float32)
    if rng.random() < _TEXTURELESS_PROB:
        return np.clip(base + rng.normal(0, 0.004, (height, width, 3)), 0, 1).astype(np.float32)
    grey = np.zeros((height, width), np.float32)
    for cell_px in (2, 4, 8, 16, 32):
        if rng.random() < 0.75:
            coarse = rng.random((height // cell_px + 2, width // cell_px + 2)).astype(np.float32)
            layer = cv2.resize(coarse, ((width // cell_px + 2) * cell_px,
                                        (height // cell_px + 2) * cell_px),
                               interpolation=cv2.INTER_CUBIC)[:height, :width]
            grey += rng.uniform(0.2, 1.0) * (layer - 0.5)
    canvas = np.zeros((height, width), np.float32)
    for _ in range(rng.integers(0, 12)):
        p1 = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        p2 = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        value = float(rng.uniform(-1, 1))
        if rng.random() < 0.5:
            cv2.line(canvas, p1, p2, value, int(rng.integers(1, 4)), cv2.LINE_AA)
        else:
            cv2.circle(canvas, p1, int(rng.integers(2, 15)), value, -1, cv2.LINE_AA)
    grey += 0.5 * canvas
    grey /= max(float(np.abs(grey).max()), 1e-6)
    contrast = rng.uniform(0.05, 0.5)
    tint = rng.uniform(0.4, 1.0, size=3).astype(np.float32)
    colour = base + contrast * grey[:, :, None] * tint
    return np.clip(colour, 0, 1).astype(np.float32)


def _shape_mask(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) float32 mask in {0, 1} of a random ellipse, polygon or rectangle."""
    mask = np.zeros((height, width), np.float32)
    cx, cy = rng.uniform(0, width), rng.uniform(0, height)
    size = rng.uniform(0.1, 0.45) * min(height, width) * np.array([rng.uniform(1, 2.5), 1])
    kind = rng.integers(3)
    if kind == 0:
        cv2.ellipse(mask, (int(cx), int(cy)), (int(size[0]), int(size[1])),
                    float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    elif kind == 1:
        n = int(rng.integers(3, 8))
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        radii = rng.uniform(0.5, 1.0, n)
        pts = np.stack([cx + size[0] * radii * np.cos(angles),
                        cy + size[1] * radii * np.sin(angles)], axis=1)
        cv2.fillPoly(mask, [pts.astype(np.int32)], 1.0)
    else:
        x0, y0 = int(cx - size[0]), int(cy - size[1])
        cv2.rectangle(mask, (x0, y0), (int(cx + size[0]), int(cy + size[1])), 1.0, -1)
    return mask


def _plane(rng: np.random.Generator, d_center: float, cx: float, cy: float,
           slant: float) -> tuple[float, float, float]:
    """Plane coefficients (a, b, c) of d = a + b x + c y with d(cx, cy) = d_center."""
    b, c = rng.uniform(-slant, slant, size=2)
    return d_center - b * cx - c * cy, float(b), float(c)


def _photometric(rng: np.random.Generator, left: np.ndarray, right: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Shared exposure change, small per-view differences and sensor noise; to uint8."""
    gain, bias, gamma = rng.uniform(0.7, 1.3), rng.uniform(-0.08, 0.08), rng.uniform(0.7, 1.4)
    noise = rng.uniform(0, 0.012)
    out = []
    for image in (left, right):
        view_gain, view_bias = rng.uniform(0.96, 1.04), rng.uniform(-0.015, 0.015)
        x = np.clip(image * (gain * view_gain) + (bias + view_bias), 0, 1) ** gamma
        x = x + rng.normal(0, noise, x.shape)
        out.append(np.clip(np.rint(x * 255.0), 0, 255).astype(np.uint8))
    return out[0], out[1]


def random_stereo_pair(seed: int | np.random.Generator, *, height: int = 96, width: int = 224,
                       max_disparity_px: float = 96.0) -> StereoSample:
    """Render a random textured stereo pair with exact disparity.

    Parameters
    ----------
    seed : int or numpy.random.Generator
        Seed (the same seed gives the same pair).
    height, width : int
        Image size in pixels.
    max_disparity_px : float
        Upper bound of the disparity in the pair.

    Returns
    -------
    StereoSample

    Examples
    --------
    >>> sample = random_stereo_pair(0, height=32, width=64, max_disparity_px=16)
    >>> sample.left.shape, sample.disparity_px.dtype
    ((32, 64, 3), dtype('float32'))
    >>> bool(sample.disparity_px.max() <= 16)
    True
    """
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    # Disparity range of this pair: favour small and mid disparities, like real scenes.
    d_low = rng.uniform(0.0, 0.35) * max_disparity_px
    d_high = d_low + rng.uniform(0.1, 1.0) * (max_disparity_px - d_low)
    slant = _MAX_SLANT * rng.random()

    layers = []  # (a, b, c, mask or None, texture)
    bg_center = rng.uniform(d_low, d_low + 0.5 * (d_high - d_low))
    layers.append((*_plane(rng, bg_center, width / 2, height / 2, min(slant, 0.1)), None,
                   _texture(rng, height, width)))
    for _ in range(rng.integers(0, _MAX_FOREGROUND_LAYERS + 1)):
        mask = _shape_mask(rng, height, width)
        fg_center = rng.uniform(bg_center, d_high)
        my, mx = np.argwhere(mask > 0).mean(axis=0) if mask.any() else (height / 2, width / 2)
        layers.append((*_plane(rng, fg_center, mx, my, slant), mask,
                       _texture(rng, height, width)))

    def render(map_x: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        best_d = np.full((height, width), -np.inf, np.float32)
        image = np.zeros((height, width, 3), np.float32)
        for a, b, c, mask, texture in layers:
            if map_x is None:  # left view: the layer's own coordinates
                x_l, tex, inside = xs, texture, (mask > 0.5) if mask is not None else True
            else:
                # right view: x_r = x_l - (a + b x_l + c y)  =>  x_l = (x_r + a + c y) / (1 - b)
                x_l = ((xs + a + c * ys) / (1.0 - b)).astype(np.float32)
                tex = cv2.remap(texture, x_l, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
                inside = True
                if mask is not None:
                    inside = cv2.remap(mask, x_l, ys, cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0.5
            d = np.clip(a + b * x_l + c * ys, 0.0, max_disparity_px).astype(np.float32)
            closer = inside & (d > best_d)
            best_d = np.where(closer, d, best_d)
            image = np.where(closer[:, :, None], tex, image)
        return image, best_d

    left, disparity = render(None)
    right, _ = render(xs)
    left_u8, right_u8 = _photometric(rng, left, right)
    return StereoSample(left_u8, right_u8, disparity.astype(np.float32))


def random_stereo_batch(seed: int, count: int, **kwargs: float) -> list[StereoSample]:
    """``count`` pairs from consecutive seeds derived from ``seed``."""
    seeds = np.random.SeedSequence(seed).spawn(count)
    return [random_stereo_pair(np.random.default_rng(s), **kwargs) for s in seeds]
