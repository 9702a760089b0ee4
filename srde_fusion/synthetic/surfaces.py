"""Textured surfaces the renderer casts rays against: objects and the background room.

Textures come from scikit-image's sample images or procedural noise; each surface keeps
a mip pyramid so that texture is filtered to the pixel footprint.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import skimage.data

from ..geometry import CameraRig
from ..imaging import REC709_LUMA
from .scene import Material, PlanarObject, Scene

__all__ = [
]

#: Linear radiance of the background at infinity, as a fraction of the ambient term.
SKY_ALBEDO = 0.02


# ---------------------------------------------------------------------------------- surfaces
@dataclass(frozen=True, eq=False)
class TexturedSurface:
    """A plane patch ready for ray casting and shading (objects and background alike)."""

    shape: PlanarObject
    normal: np.ndarray  # (3,) unit, facing the cameras
    offset_m: float  # n . X = offset on the plane
    center_m: np.ndarray  # (3,)
    e1: np.ndarray  # (3,)
    e2: np.ndarray  # (3,)
    corners_m: np.ndarray  # (K, 3) convex hull bound, for the pixel bounding box
    label: int  # k for objects[k - 1], 0 for background
    tile_m: float = 0.0  # > 0: texture tiled (mirrored) with this texel size, metres
    mips: dict = field(default_factory=dict)  # level -> texture shrunk 2**level times


def object_surface(obj: PlanarObject, label: int, tile_m: float = 0.0) -> TexturedSurface:
    e1, e2 = obj.axes
    n = np.asarray(obj.normal)
    center = np.asarray(obj.center_m)
    return TexturedSurface(
        obj, n, float(n @ center), center, e1, e2, obj.bounding_corners_m(), label, tile_m
    )


@functools.lru_cache(maxsize=8)
def _skimage_texture(name: str) -> np.ndarray:

    image = getattr(skimage.data, name)().astype(np.float32) / 255.0
    if image.ndim == 3:
        image = image @ REC709_LUMA
    lo, hi = np.percentile(image, [1, 99])
    image = np.clip((image - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    image.setflags(write=False)
    return image


#: Grey textures bundled with scikit-image that tile reasonably.
_SKIMAGE_TEXTURES = ("brick", "gravel", "grass")


def _noise_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Tileable colour noise with a 1/f amplitude spectrum, (size, size, 3) float32 in [0, 1]."""
    freq = np.fft.fftfreq(size)
    radius = np.hypot(freq[:, None], freq[None, :])
    radius[0, 0] = 1.0  # the mean is removed below; avoid dividing by zero
    amplitude = radius ** -rng.uniform(0.9, 1.4)
    amplitude[0, 0] = 0.0
    # One shared grey pattern plus weaker per-channel patterns: textured, mildly coloured.
    spectra = np.fft.fft2(rng.standard_normal((4, size, size))) * amplitude
    fields = np.fft.ifft2(spectra).real
    out = fields[0][:, :, None] + 0.5 * np.moveaxis(fields[1:], 0, -1)
    lo, hi = np.percentile(out, [1, 99])
    return np.clip((out - lo) / max(hi - lo, 1e-12), 0.0, 1.0).astype(np.float32)


def _random_texture(rng: np.random.Generator) -> np.ndarray:
    """Draw a colour texture (h, w, 3) float32 albedo: a tinted bundled image or noise."""
    choice = rng.integers(0, len(_SKIMAGE_TEXTURES) + 1)
    if choice == len(_SKIMAGE_TEXTURES):
        tex = _noise_texture(rng)
    else:
        grey = _skimage_texture(_SKIMAGE_TEXTURES[choice])
        tint = rng.uniform(0.5, 1.0, size=3).astype(np.float32)
        tex = grey[:, :, None] * tint
    return (0.1 + 0.8 * tex).astype(np.float32)


def background_surfaces(
    scene: Scene, rig: CameraRig, *, with_textures: bool = True
) -> list[TexturedSurface]:
    """Textured back wall, floor and panels around the objects, from ``background_seed``.

    The wall and the panels lie behind the farthest object corner and the floor below
    the lowest one, so nothing of the background ever hides an object. Textures are
    anchored to each plane's local coordinates, so all views agree. Layout and textures
    come from separate random streams: ``with_textures=False`` gives the same layout,
    untextured, without the cost of making textures.
    """
    layout = np.random.default_rng([scene.background_seed, 7])
    texturing = np.random.default_rng([scene.background_seed, 8])
    k = rig.intrinsics
    w_px, h_px = rig.image_size
    corners = np.concatenate([o.bounding_corners_m() for o in scene.objects])
    z_far = float(corners[:, 2].max())
    lowest = float(corners[:, 1].max())
    spread = float(np.max(np.abs(rig.centers_m[:, :2] - rig.reference_center_m[:2])))
    z_wall = z_far + layout.uniform(0.4, 1.2)
    # Half extents of every camera's frustum at the wall depth, doubled for the tilt.
    half_w = (max(k.cx, w_px - k.cx) / k.fx * z_wall + spread) * 2.0
    half_h = (max(k.cy, h_px - k.cy) / k.fy * z_wall + spread) * 2.0
    material = Material(diffuse_rgb=(1.0, 1.0, 1.0), specular=0.0)
    surfaces = []

    def add(z_texel_m: float, **shape_kw: Any) -> PlanarObject:
        texture = _random_texture(texturing) if with_textures else None
        # Texels 1.5-3 px wide at their depth: detail to match, without aliasing.
        texel_m = texturing.uniform(1.5, 3.0) * z_texel_m / k.fx
        obj = PlanarObject(material=material, texture=texture, **shape_kw)
        surfaces.append(object_surface(obj, 0, texel_m))
        return obj

    tilt = np.radians(layout.uniform(-12, 12, size=2))
    add(
        z_wall,
        shape="rectangle",
        center_m=(0.0, 0.0, z_wall),
        normal=(math.sin(tilt[0]), math.sin(tilt[1]), -1.0),
        size_m=(2 * half_w, 2 * half_h),
    )
    floor_y = lowest + layout.uniform(0.05, 0.3)
    if layout.random() < 0.7:
        add(
            0.5 * (z_far + z_wall),
            shape="rectangle",
            center_m=(0.0, floor_y, z_wall),
            normal=(0.0, -1.0, 0.0),
            size_m=(2 * half_w, 2 * z_wall),
        )
    for _ in range(layout.integers(1, 4)):
        z = layout.uniform(z_far + 0.1, z_wall - 0.1) if z_wall - z_far > 0.25 else z_wall - 0.05
        size = layout.uniform(0.2, 0.7, size=2)
        # Panels towards the image sides; the objects are mostly near the middle.
        u = (layout.uniform(0.0, 0.3) + layout.integers(0, 2) * 0.7) * w_px
        v = layout.uniform(0.1, 0.9) * h_px
        center = rig.backproject([u, v], z)
        normal = (layout.uniform(-0.3, 0.3), layout.uniform(-0.3, 0.3), -1.0)
        rotation = layout.uniform(-0.3, 0.3)
        probe = PlanarObject("rectangle", tuple(center), normal, tuple(size), rotation)
        if probe.bounding_corners_m()[:, 2].min() > z_far + 0.02:
            add(
                z,
                shape="rectangle",
                center_m=tuple(center),
                normal=normal,
                size_m=tuple(size),
                rotation_rad=rotation,
            )
    return surfaces
