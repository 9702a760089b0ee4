"""Procedural stereo pairs with exact disparity, for training and testing the stand-in.

A pair is a stack of textured planar layers seen by a rectified stereo rig: a slanted
background plane and a few occluding foreground layers (ellipses, polygons, rectangles,
thin bars and rings), each with its own plane ``d(x, y) = a + b x + c y`` in left-image
pixels. The left image and its ground truth come from a z-buffer over the layers (larger
disparity is closer); the right image samples every layer where it lands in the right
view, ``x_r = x_l - d(x_l, y)``, which is solved in closed form for a plane, and
z-buffers again. Occlusions are therefore exact, including slanted surfaces.

Textures come in kinds, each at a random scale: band-limited noise over several octaves
with strokes, 1/f^beta noise (the power spectrum of natural photographs), "dead leaves"
(overlapping discs and polygons with sizes spread over two decades, close to the
statistics of natural images), oriented stripes, and nearly flat colour where matching
is ambiguous. Some layers are glossy: a specular highlight that
does not move with the surface (its disparity differs from the plane's) and a faint
mirrored texture seen at a larger depth. The views differ photometrically: shared
exposure and gamma, per-view gain, bias and colour balance, occasional blur of one view,
and sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["StereoSample", "random_stereo_pair", "random_stereo_batch"]

_MAX_SLANT = 0.35  # |dd/dx| and |dd/dy| of the planes; |dd/dx| < 1 keeps x_r monotonic
_TEXTURELESS_PROB = 0.1
_MAX_FOREGROUND_LAYERS = 6
_GLOSSY_PROB = 0.2  # a layer gets a highlight and a faint mirror image
_BLUR_PROB = 0.2  # one view slightly out of focus


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


def _noise_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) float32 multi-octave noise with strokes, roughly in [-1, 1]."""
    grey = np.zeros((height, width), np.float32)
    for cell_px in (1, 2, 4, 8, 16, 32, 64):
        if rng.random() < 0.6:
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
    return grey + 0.5 * canvas


def _dead_leaves(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W, 3) float32 dead-leaves texture: occluding shapes, radii ~ r^-3 density."""
    image = np.empty((height, width, 3), np.float32)
    image[:] = rng.uniform(0, 1, 3)
    r_min, r_max = 2.5, max(height, width) / 3.0
    # enough shapes to cover the canvas several times at these radii
    for _ in range(int(rng.integers(200, 700))):
        # inverse CDF of a density proportional to r^-3 on [r_min, r_max]
        u = rng.random()
        r = (r_min**-2 - u * (r_min**-2 - r_max**-2)) ** -0.5
        centre = (int(rng.integers(-5, width + 5)), int(rng.integers(-5, height + 5)))
        colour = tuple(float(v) for v in rng.uniform(0, 1, 3))
        if rng.random() < 0.6:
            cv2.circle(image, centre, max(int(r), 1), colour, -1, cv2.LINE_AA)
        else:
            angles = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 6))))
            pts = np.stack([centre[0] + r * np.cos(angles), centre[1] + r * np.sin(angles)], 1)
            cv2.fillPoly(image, [pts.astype(np.int32)], colour, cv2.LINE_AA)
    return image


def _power_law_noise(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) float32 noise with a 1/f^beta amplitude spectrum (beta 0.8..1.6), std 1.

    Photographs have amplitude spectra close to 1/f: detail at every scale, most contrast
    in the coarse scales. Random phases, so no edges; the dead leaves give those.
    """
    fy = np.fft.fftfreq(height)[:, None]
    fx = np.fft.rfftfreq(width)[None, :]
    radius = np.sqrt(fx**2 + fy**2)
    radius[0, 0] = 1.0
    amplitude = radius ** -rng.uniform(0.8, 1.6)
    amplitude[0, 0] = 0.0
    phase = rng.uniform(0, 2 * np.pi, amplitude.shape)
    grey = np.fft.irfft2(amplitude * np.exp(1j * phase), s=(height, width))
    return (grey / max(float(grey.std()), 1e-9)).astype(np.float32)


def _stripes(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) float32 oriented stripes (repetitive texture) with a little noise."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    angle = rng.uniform(0, np.pi)
    period = rng.uniform(3.0, 40.0)
    phase = (xs * np.cos(angle) + ys * np.sin(angle)) * (2 * np.pi / period)
    wave = np.sin(phase) if rng.random() < 0.5 else np.sign(np.sin(phase))
    return wave.astype(np.float32) + 0.3 * rng.standard_normal((height, width)).astype(np.float32)


def _texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W, 3) float32 texture in [0, 1] of a random kind, drawn at a random scale."""
    base = rng.uniform(0.1, 0.9, size=3).astype(np.float32)
    if rng.random() < _TEXTURELESS_PROB:
        return np.clip(base + rng.normal(0, 0.004, (height, width, 3)), 0, 1).astype(np.float32)
    # coarser scales: draw smaller and enlarge (smooth, large-scale structure)
    scale = float(np.exp(rng.uniform(0.0, np.log(4.0)))) if rng.random() < 0.4 else 1.0
    h, w = max(int(height / scale), 4), max(int(width / scale), 4)
    kind = rng.random()
    if kind < 0.35:
        colour = _dead_leaves(rng, h, w)
        contrast = rng.uniform(0.2, 1.0)
        colour = base + contrast * (colour - colour.mean(axis=(0, 1)))
    else:
        if kind < 0.65:
            grey = _noise_texture(rng, h, w)
        elif kind < 0.88:
            grey = _power_law_noise(rng, h, w)
        else:
            grey = _stripes(rng, h, w)
        grey /= max(float(np.abs(grey).max()), 1e-6)
        contrast = rng.uniform(0.03, 0.7)
        tint = rng.uniform(0.4, 1.0, size=3).astype(np.float32)
        colour = base + contrast * grey[:, :, None] * tint
    if scale != 1.0:
        colour = cv2.resize(colour, (width, height), interpolation=cv2.INTER_LINEAR)
    return np.clip(colour, 0, 1).astype(np.float32)


def _shape_mask(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) float32 mask in {0, 1}: ellipse, polygon, rectangle, thin bars or a ring."""
    mask = np.zeros((height, width), np.float32)
    cx, cy = rng.uniform(0, width), rng.uniform(0, height)
    size = rng.uniform(0.05, 0.45) * min(height, width) * np.array([rng.uniform(1, 2.5), 1])
    kind = rng.integers(5)
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
    elif kind == 2:
        x0, y0 = int(cx - size[0]), int(cy - size[1])
        cv2.rectangle(mask, (x0, y0), (int(cx + size[0]), int(cy + size[1])), 1.0, -1)
    elif kind == 3:  # thin structures (poles, spokes, cables): a few bars
        for _ in range(int(rng.integers(1, 4))):
            angle = rng.uniform(0, np.pi)
            length = rng.uniform(0.3, 1.2) * max(height, width)
            dx, dy = 0.5 * length * np.cos(angle), 0.5 * length * np.sin(angle)
            x, y = cx + rng.normal(0, 10), cy + rng.normal(0, 10)
            cv2.line(mask, (int(x - dx), int(y - dy)), (int(x + dx), int(y + dy)), 1.0,
                     int(rng.integers(2, 9)))
    else:  # a ring (a hole shows the layers behind)
        outer = int(max(size[1], 6))
        cv2.circle(mask, (int(cx), int(cy)), outer, 1.0, -1)
        cv2.circle(mask, (int(cx), int(cy)), int(outer * rng.uniform(0.3, 0.8)), 0.0, -1)
    return mask


def _plane(rng: np.random.Generator, d_center: float, cx: float, cy: float,
           slant: float) -> tuple[float, float, float]:
    """Plane coefficients (a, b, c) of d = a + b x + c y with d(cx, cy) = d_center."""
    b, c = rng.uniform(-slant, slant, size=2)
    return d_center - b * cx - c * cy, float(b), float(c)


@dataclass(frozen=True)
class _Gloss:
    """View-dependent appearance of a glossy layer, in image coordinates.

    A highlight (an image of a light behind the surface) and a faint mirror image of
    another texture, both at disparities of their own rather than the surface's.
    """

    highlight_xy: tuple[float, float]
    highlight_sigma_px: tuple[float, float]
    highlight_gain: float
    highlight_disparity_px: float
    mirror: np.ndarray  # (H, W, 3) float32
    mirror_alpha: float
    mirror_disparity_px: float

    def apply(self, tex: np.ndarray, xs: np.ndarray, ys: np.ndarray, *,
              right_view: bool) -> np.ndarray:
        hx, hy = self.highlight_xy
        mirror = self.mirror
        if right_view:  # both move by their own disparity between the views
            hx -= self.highlight_disparity_px
            mirror = cv2.remap(mirror, xs + self.mirror_disparity_px, ys, cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)
        sx, sy = self.highlight_sigma_px
        spot = np.exp(-0.5 * (((xs - hx) / sx) ** 2 + ((ys - hy) / sy) ** 2))
        out = (1.0 - self.mirror_alpha) * tex + self.mirror_alpha * mirror
        return out + self.highlight_gain * spot[:, :, None]


def _gloss(rng: np.random.Generator, height: int, width: int,
           disparity_px: float) -> _Gloss | None:
    """Draw a glossy appearance for a layer at about ``disparity_px``, or None (matte)."""
    if rng.random() >= _GLOSSY_PROB:
        return None
    return _Gloss(
        highlight_xy=(float(rng.uniform(0, width)), float(rng.uniform(0, height))),
        highlight_sigma_px=(float(rng.uniform(2, 25)), float(rng.uniform(2, 25))),
        highlight_gain=float(rng.uniform(0.2, 1.0)),
        # virtual images lie behind the surface: smaller disparity
        highlight_disparity_px=float(disparity_px * rng.uniform(0.3, 1.0)),
        mirror=_texture(rng, height, width),
        mirror_alpha=float(rng.uniform(0.0, 0.4)),
        mirror_disparity_px=float(disparity_px * rng.uniform(0.2, 0.9)),
    )


def _photometric(rng: np.random.Generator, left: np.ndarray, right: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Shared exposure, per-view gain, bias, colour balance, blur and noise; to uint8."""
    gain, bias, gamma = rng.uniform(0.6, 1.4), rng.uniform(-0.08, 0.08), rng.uniform(0.7, 1.4)
    noise = rng.uniform(0, 0.02)
    blurred = int(rng.integers(2)) if rng.random() < _BLUR_PROB else -1
    out = []
    for view, image in enumerate((left, right)):
        view_gain, view_bias = rng.uniform(0.85, 1.15), rng.uniform(-0.03, 0.03)
        balance = rng.uniform(0.95, 1.05, size=3).astype(np.float32)
        view_gamma = gamma * rng.uniform(0.95, 1.05)
        x = np.clip(image * balance * (gain * view_gain) + (bias + view_bias), 0, 1) ** view_gamma
        if view == blurred:
            x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.5, 1.2))
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

    layers = []  # (a, b, c, mask or None, texture, gloss or None)
    bg_center = rng.uniform(d_low, d_low + 0.5 * (d_high - d_low))
    bg_plane = _plane(rng, bg_center, width / 2, height / 2, slant)
    layers.append((*bg_plane, None, _texture(rng, height, width),
                   _gloss(rng, height, width, bg_center)))
    for _ in range(rng.integers(0, _MAX_FOREGROUND_LAYERS + 1)):
        mask = _shape_mask(rng, height, width)
        fg_center = rng.uniform(bg_center, d_high)
        my, mx = np.argwhere(mask > 0).mean(axis=0) if mask.any() else (height / 2, width / 2)
        layers.append((*_plane(rng, fg_center, mx, my, slant), mask,
                       _texture(rng, height, width), _gloss(rng, height, width, fg_center)))

    def render(map_x: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        best_d = np.full((height, width), -np.inf, np.float32)
        image = np.zeros((height, width, 3), np.float32)
        for a, b, c, mask, texture, gloss in layers:
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
            if gloss is not None:
                tex = gloss.apply(tex, xs, ys, right_view=map_x is not None)
            d = np.clip(a + b * x_l + c * ys, 0.0, max_disparity_px).astype(np.float32)
            closer = inside & (d > best_d)
            best_d = np.where(closer, d, best_d)
            image = np.where(closer[:, :, None], tex, image)
        return np.clip(image, 0.0, 1.0), best_d

    left, disparity = render(None)
    right, _ = render(xs)
    left_u8, right_u8 = _photometric(rng, left, right)
    return StereoSample(left_u8, right_u8, disparity.astype(np.float32))


def random_stereo_batch(seed: int, count: int, **kwargs: float) -> list[StereoSample]:
    """``count`` pairs from consecutive seeds derived from ``seed``."""
    seeds = np.random.SeedSequence(seed).spawn(count)
    return [random_stereo_pair(np.random.default_rng(s), **kwargs) for s in seeds]
