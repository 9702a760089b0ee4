"""Synthetic scenes: flat glossy objects lit by one small light, with exact ground truth.

The renderer casts the pixel rays of every camera of a :class:`~srde_fusion.geometry.rig.CameraRig`
analytically against planar objects (rectangles, ellipses, convex polygons), vectorised
over the image. Objects are single-sided (they show the side their normal points to) and
occlude each other and the background; the nearest hit wins. Shading is physically based
in linear light: Lambertian diffuse with inverse-square and cosine falloff, a white
ambient term, and a specular lobe from :mod:`srde_fusion.synthetic.shading` (GGX microfacet or
normalised Blinn-Phong). The spherical light widens the lobe (see
:func:`srde_fusion.synthetic.shading.widened_roughness`); nothing casts shadows and there are no
inter-reflections. Linear radiance is scaled by the exposure, gets Gaussian sensor
noise, is sRGB-encoded and clipped to 8 bits, so highlights saturate as in a real camera.

Ground truth is for the reference camera at pixel centres: depth, stereo-pair disparity
(``fx * B / z``; 0 where the background is at infinity), the instance mask, the object
planes, each object's virtual light (the light mirrored across its plane) and where that
virtual light projects in every view — the centre of the highlight.

:func:`random_scene` samples scenes under the paper's conditions (Methods, synthetic
data): textureless objects of random shape, colour, size and pose; one light of random
size, colour and intensity that no camera sees directly; every object's highlight inside
the object in every view.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import LightError, RigError, SceneError, SRDEError
from ..geometry import CameraRig, Plane
from ..imaging import REC709_LUMA, linear_to_srgb
from .shading import LOBES, specular_brdf, widened_roughness

__all__ = [
    "SceneError",
    "Material",
    "PlanarObject",
    "Light",
    "Scene",
    "Rendering",
    "render",
    "random_scene",
    "default_rig",
    "render_dataset",
    "scene_to_dict",
    "scene_from_dict",
    "SHAPES",
    "BACKGROUNDS",
]

#: Object outlines the renderer knows.
SHAPES = ("rectangle", "ellipse", "triangle", "polygon")
#: Background kinds: at infinity, or textured planes at finite depth.
BACKGROUNDS = ("none", "textured")

#: Linear radiance of the background at infinity, as a fraction of the ambient term.
_SKY_ALBEDO = 0.02
#: Sides of the polygon that stands in for an ellipse in margin checks (inscribed).
_ELLIPSE_SIDES = 96
#: Entries of the linear -> 8-bit sRGB table (linear steps of 1.5e-5).
_ENCODE_LUT_SIZE = 1 << 16
#: Width of the point blocks handed to cv2.remap for texture lookups.
_REMAP_COLS = 1024
#: Largest supersampling factor accepted (k x k samples per pixel).
MAX_SUPERSAMPLE = 8


# ---------------------------------------------------------------------------------- checks
def _finite(
    value: Any,
    name: str,
    error: type[SRDEError] = SceneError,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{name}: expected a number, got {type(value).__name__} {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise error(f"{name}: expected a finite number, got {value}")
    if low is not None and (value < low or (low_open and value == low)):
        bound = f"> {low:g}" if low_open else f">= {low:g}"
        raise error(f"{name}: expected a number {bound}, got {value:g}")
    if high is not None and value > high:
        raise error(f"{name}: expected a number <= {high:g}, got {value:g}")
    return value


def _vec(
    value: Any,
    name: str,
    n: int = 3,
    error: type[SRDEError] = SceneError,
    *,
    low: float | None = None,
    high: float | None = None,
) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (tuple, list)) or len(value) != n:
        raise error(f"{name}: expected {n} numbers, got {value!r}")
    return tuple(_finite(v, f"{name}[{i}]", error, low=low, high=high) for i, v in enumerate(value))


def _range(
    value: Any, name: str, *, low: float, low_open: bool = True, high: float | None = None
) -> tuple[float, float]:
    """Return a sampling range given as one number or ``(min, max)``."""
    if isinstance(value, (tuple, list, np.ndarray)):
        if len(value) != 2:
            raise SceneError(f"{name}: expected a number or (min, max), got {value!r}")
        lo = _finite(value[0], f"{name}[0]", low=low, low_open=low_open, high=high)
        hi = _finite(value[1], f"{name}[1]", low=low, low_open=low_open, high=high)
        if hi < lo:
            raise SceneError(f"{name}: expected min <= max, got ({lo:g}, {hi:g})")
        return lo, hi
    v = _finite(value, name, low=low, low_open=low_open, high=high)
    return v, v


# ---------------------------------------------------------------------------------- model
@dataclass(frozen=True)
class Material:
    """Reflectance of an object: Lambertian diffuse plus one specular lobe.

    Parameters
    ----------
    diffuse_rgb : (float, float, float)
        Diffuse albedo per channel, in [0, 1].
    specular : float
        Scale of the specular lobe (1 = physically plausible dielectric).
    roughness : float
        Lobe width ``alpha`` in (0, 1] (GGX slope width; Blinn-Phong exponent
        ``2 / alpha^2 - 2``).
    lobe : {"ggx", "blinn_phong"}
        Specular lobe model (:mod:`srde_fusion.synthetic.shading`).
    f0 : float
        Fresnel reflectance at normal incidence, in [0, 1].
    """

    diffuse_rgb: tuple[float, float, float] = (0.3, 0.3, 0.3)
    specular: float = 1.0
    roughness: float = 0.02
    lobe: str = "ggx"
    f0: float = 0.04

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "diffuse_rgb", _vec(self.diffuse_rgb, "material.diffuse_rgb", low=0.0, high=1.0)
        )
        object.__setattr__(self, "specular", _finite(self.specular, "material.specular", low=0.0))
        object.__setattr__(
            self,
            "roughness",
            _finite(self.roughness, "material.roughness", low=0.0, low_open=True, high=1.0),
        )
        if self.lobe not in LOBES:
            raise SceneError(f"material.lobe: expected one of {list(LOBES)}, got {self.lobe!r}")
        object.__setattr__(self, "f0", _finite(self.f0, "material.f0", low=0.0, high=1.0))


def _check_texture(texture: Any) -> np.ndarray | None:
    if texture is None:
        return None
    if not isinstance(texture, np.ndarray):
        raise SceneError(
            f"texture: expected a numpy array (h, w) or (h, w, 3), got {type(texture).__name__}"
        )
    if not (texture.ndim == 2 or (texture.ndim == 3 and texture.shape[2] == 3)):
        raise SceneError(f"texture: expected shape (h, w) or (h, w, 3), got {texture.shape}")
    if texture.shape[0] < 1 or texture.shape[1] < 1:
        raise SceneError(f"texture: expected at least 1x1 texels, got {texture.shape[:2]}")
    if texture.dtype == np.uint8:
        tex = texture.astype(np.float32) / 255.0
    elif np.issubdtype(texture.dtype, np.floating):
        tex = texture.astype(np.float32)
        if not np.all(np.isfinite(tex)) or tex.min() < 0.0 or tex.max() > 1.0:
            raise SceneError("texture: expected finite albedo values in [0, 1], got values outside")
    else:
        raise SceneError(f"texture: expected dtype uint8 or float in [0, 1], got {texture.dtype}")
    if tex.ndim == 2:
        tex = np.repeat(tex[:, :, None], 3, axis=2)
    tex.setflags(write=False)
    return tex


def _edge_lines(vertices: np.ndarray) -> np.ndarray:
    """Edge lines ``(K, 3)`` of a convex CCW polygon: ``a x + b y + c`` = inward distance."""
    nxt = np.roll(vertices, -1, axis=0)
    edge = nxt - vertices
    length = np.linalg.norm(edge, axis=1)
    inward = np.stack([-edge[:, 1], edge[:, 0]], axis=1) / length[:, None]
    return np.column_stack([inward, -np.sum(inward * vertices, axis=1)])


def _convex_ccw(vertices: Any, name: str) -> np.ndarray:
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{name}: expected (K, 2) numbers, got {vertices!r}") from None
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
        raise SceneError(f"{name}: expected (K, 2) finite numbers with K >= 3, got shape {v.shape}")
    edge = np.roll(v, -1, axis=0) - v
    cross = (
        edge[:, 0] * np.roll(edge, -1, axis=0)[:, 1] - edge[:, 1] * np.roll(edge, -1, axis=0)[:, 0]
    )
    scale = float(np.max(np.abs(v))) ** 2
    if np.all(cross < -1e-12 * scale):
        v = v[::-1].copy()
    elif not np.all(cross > 1e-12 * scale):
        raise SceneError(
            f"{name}: expected the vertices of a convex polygon in order, got {v.tolist()}"
        )
    return v


@dataclass(frozen=True)
class PlanarObject:
    """A flat object: an outline in a plane, with a material and an optional texture.

    The in-plane axes ``(e1, e2)`` start from the array x axis projected onto the plane
    (``e2 = e1 x n``, so a fronto-parallel object has ``e1`` = right and ``e2`` = down, as
    seen by the cameras) and are rotated in the plane by ``rotation_rad``.

    Parameters
    ----------
    shape : {"rectangle", "ellipse", "triangle", "polygon"}
    center_m : (float, float, float)
        Origin of the local coordinates, array frame, metres.
    normal : (float, float, float)
        Plane normal; normalised and flipped to face the array origin (the reference
        camera) if needed. Only that side is visible.
    size_m : (float, float)
        Extent along ``e1`` and ``e2``: the rectangle's sides, the ellipse's axes, and the
        box a texture covers.
    rotation_rad : float
        In-plane rotation of the local axes.
    vertices_m : (K, 2) sequence, optional
        Local vertices of a convex "triangle" (K = 3) or "polygon"; a triangle without
        vertices is the isosceles one spanning the ``size_m`` box, apex up.
    material : Material
    texture : numpy.ndarray, (h, w) or (h, w, 3), optional
        Albedo in [0, 1] (uint8 accepted) over the local box ``[-w/2, w/2] x [-h/2, h/2]``
        (row 0 at ``-h/2``); multiplies the diffuse albedo.
    """

    shape: str
    center_m: tuple[float, float, float]
    normal: tuple[float, float, float]
    size_m: tuple[float, float]
    rotation_rad: float = 0.0
    vertices_m: tuple | None = None
    material: Material = Material()
    texture: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise SceneError(f"shape: expected one of {list(SHAPES)}, got {self.shape!r}")
        center = _vec(self.center_m, "center_m")
        normal = np.array(_vec(self.normal, "normal"))
        length = float(np.linalg.norm(normal))
        if length < 1e-12:
            raise SceneError(f"normal: expected a non-zero vector, got {self.normal!r}")
        if abs(length - 1.0) > 1e-15:  # unit normals stay bit-exact (round trips compare equal)
            normal /= length
        if np.dot(normal, -np.asarray(center)) < 0:
            normal = -normal
        object.__setattr__(self, "center_m", center)
        object.__setattr__(self, "normal", tuple(float(v) + 0.0 for v in normal))
        size = _vec(self.size_m, "size_m", 2, low=0.0)
        if min(size) <= 0:
            raise SceneError(
                f"size_m: expected two positive extents in metres, got {self.size_m!r}"
            )
        object.__setattr__(self, "size_m", size)
        object.__setattr__(self, "rotation_rad", _finite(self.rotation_rad, "rotation_rad"))
        if not isinstance(self.material, Material):
            raise SceneError(f"material: expected a Material, got {type(self.material).__name__}")
        vertices = self.vertices_m
        if self.shape == "triangle" and vertices is None:
            w, h = size
            vertices = ((0.0, -h / 2), (w / 2, h / 2), (-w / 2, h / 2))
        if self.shape in ("triangle", "polygon"):
            if vertices is None:
                raise SceneError(
                    "vertices_m: expected (K, 2) local vertices for a polygon, got None"
                )
            v = _convex_ccw(vertices, "vertices_m")
            if self.shape == "triangle" and len(v) != 3:
                raise SceneError(f"vertices_m: expected 3 vertices for a triangle, got {len(v)}")
            object.__setattr__(self, "vertices_m", tuple(tuple(float(c) for c in p) for p in v))
        elif vertices is not None:
            raise SceneError(f"vertices_m: expected None for a {self.shape}, got {vertices!r}")
        object.__setattr__(self, "texture", _check_texture(self.texture))

    # ------------------------------------------------------------------ geometry
    @property
    def plane(self) -> Plane:
        """The object's plane, normal towards the array origin."""
        return Plane.from_point_normal(self.center_m, self.normal)

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit in-plane axes ``(e1, e2)``, each ``(3,)`` float64 in the array frame."""
        n = np.asarray(self.normal)
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = ref - np.dot(ref, n) * n
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(e1, n)
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return c * e1 + s * e2, -s * e1 + c * e2

    def local_coords(self, points_m: Any) -> np.ndarray:
        """In-plane coordinates ``(..., 2)`` in metres of points ``(..., 3)`` (projected)."""
        e1, e2 = self.axes
        rel = np.asarray(points_m, dtype=np.float64) - np.asarray(self.center_m)
        return np.stack([rel @ e1, rel @ e2], axis=-1)

    def to_world(self, local_m: Any) -> np.ndarray:
        """Array-frame points ``(..., 3)`` of local coordinates ``(..., 2)``."""
        e1, e2 = self.axes
        loc = np.asarray(local_m, dtype=np.float64)
        return np.asarray(self.center_m) + loc[..., :1] * e1 + loc[..., 1:2] * e2

    def contains_local(self, local_m: Any) -> np.ndarray:
        """Whether local coordinates ``(..., 2)`` lie inside the outline, ``(...)`` bool."""
        loc = np.asarray(local_m, dtype=np.float64)
        x, y = loc[..., 0], loc[..., 1]
        return _inside(self, x, y)

    def contains(self, points_m: Any) -> np.ndarray:
        """Whether points ``(..., 3)``, projected onto the plane, lie inside the outline."""
        return self.contains_local(self.local_coords(points_m))

    def outline_local(self) -> np.ndarray:
        """Return a convex polygon ``(K, 2)`` inscribed in the outline (exact but for ellipses).

        Vertices run counter-clockwise for x right, y up.
        """
        w, h = self.size_m
        if self.shape == "rectangle":
            return np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
        if self.shape == "ellipse":
            phi = np.linspace(0.0, 2 * np.pi, _ELLIPSE_SIDES, endpoint=False)
            return np.column_stack([w / 2 * np.cos(phi), h / 2 * np.sin(phi)])
        return np.asarray(self.vertices_m, dtype=np.float64)

    def bounding_corners_m(self) -> np.ndarray:
        """Array-frame points ``(K, 3)`` whose convex hull contains the object."""
        w, h = self.size_m
        if self.shape in ("rectangle", "ellipse"):
            local = np.array([[-w / 2, -h / 2], [-w / 2, h / 2], [w / 2, h / 2], [w / 2, -h / 2]])
        else:
            local = np.asarray(self.vertices_m, dtype=np.float64)
        return self.to_world(local)

    def inner_distance_m(self, local_m: Any) -> np.ndarray:
        """Distance ``(...)`` in metres from local points to the outline, negative outside.

        Exact inside rectangles and polygons; for ellipses measured to the inscribed
        polygon of :meth:`outline_local`, so it errs on the safe side.
        """
        loc = np.asarray(local_m, dtype=np.float64)
        lines = _edge_lines(self.outline_local())
        return np.min(loc @ lines[:, :2].T + lines[:, 2], axis=-1)


def _inside(obj: PlanarObject, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    w, h = obj.size_m
    if obj.shape == "rectangle":
        return (np.abs(x) <= w / 2) & (np.abs(y) <= h / 2)
    if obj.shape == "ellipse":
        return np.square(x / (w / 2)) + np.square(y / (h / 2)) <= 1.0
    inside = np.ones(np.shape(x), dtype=bool)
    for a, b, c in _edge_lines(np.asarray(obj.vertices_m)):
        inside &= a * x + b * y + c >= 0.0
    return inside


@dataclass(frozen=True)
class Light:
    """A small spherical light.

    Parameters
    ----------
    position_m : (float, float, float)
        Centre in the array frame, metres.
    radius_m : float
        Sphere radius (0 = point light); it widens the highlight.
    color_rgb : (float, float, float)
        Linear colour, each channel >= 0.
    intensity : float
        Radiant intensity scale: irradiance at distance r is ``intensity * cos / r^2``.
    """

    position_m: tuple[float, float, float]
    radius_m: float = 0.005
    color_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "position_m", _vec(self.position_m, "light.position_m", error=LightError)
        )
        object.__setattr__(
            self, "radius_m", _finite(self.radius_m, "light.radius_m", LightError, low=0.0)
        )
        object.__setattr__(
            self, "color_rgb", _vec(self.color_rgb, "light.color_rgb", error=LightError, low=0.0)
        )
        object.__setattr__(
            self,
            "intensity",
            _finite(self.intensity, "light.intensity", LightError, low=0.0, low_open=True),
        )


@dataclass(frozen=True)
class Scene:
    """Objects, one light, and how the cameras expose them.

    Parameters
    ----------
    objects : tuple of PlanarObject
        At least one; ``instance_mask`` value k means ``objects[k - 1]``.
    light : Light
    ambient : float
        White ambient radiance per unit albedo (linear, before exposure).
    background : {"none", "textured"}
        "none": nothing behind the objects (at infinity, nearly black, disparity 0).
        "textured": a textured back wall and panels behind the objects and often a floor
        below them, at finite depth, generated from ``background_seed``; they never
        hide an object.
    background_seed : int
        Seed of the textured background (and of the default sensor noise).
    exposure : float
        Linear scale applied before noise, sRGB encoding and 8-bit clipping.
    noise_std : float
        Standard deviation of Gaussian sensor noise in linear [0, 1] units.
    """

    objects: tuple[PlanarObject, ...]
    light: Light
    ambient: float = 0.02
    background: str = "none"
    background_seed: int = 0
    exposure: float = 1.0
    noise_std: float = 0.0

    def __post_init__(self) -> None:
        objects = self.objects
        if isinstance(objects, PlanarObject):
            objects = (objects,)
        if not isinstance(objects, (tuple, list)) or not objects:
            raise SceneError(
                f"objects: expected a non-empty sequence of PlanarObject, got {objects!r}"
            )
        for i, obj in enumerate(objects):
            if not isinstance(obj, PlanarObject):
                raise SceneError(f"objects[{i}]: expected a PlanarObject, got {type(obj).__name__}")
        object.__setattr__(self, "objects", tuple(objects))
        if not isinstance(self.light, Light):
            raise LightError(f"light: expected a Light, got {type(self.light).__name__}")
        object.__setattr__(self, "ambient", _finite(self.ambient, "ambient", low=0.0))
        if self.background not in BACKGROUNDS:
            raise SceneError(
                f"background: expected one of {list(BACKGROUNDS)}, got {self.background!r}"
            )
        seed = self.background_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise SceneError(f"background_seed: expected a non-negative integer, got {seed!r}")
        object.__setattr__(self, "background_seed", int(seed))
        object.__setattr__(
            self, "exposure", _finite(self.exposure, "exposure", low=0.0, low_open=True)
        )
        object.__setattr__(self, "noise_std", _finite(self.noise_std, "noise_std", low=0.0))


@dataclass(frozen=True, eq=False)
class Rendering:
    """Views of a scene and the reference camera's ground truth.

    Attributes
    ----------
    views : tuple of numpy.ndarray, (H, W, 3) uint8
        sRGB images in the rig's camera order; highlights clip at 255.
    disparity_px : numpy.ndarray, (H, W) float32
        Stereo-pair disparity ``fx * B / z`` at the reference pixel centres; 0 where
        the background is at infinity.
    depth_m : numpy.ndarray, (H, W) float32
        Depth ``z`` from the reference camera, metres; inf at infinity.
    instance_mask : numpy.ndarray, (H, W) int32
        0 = background, k = ``objects[k - 1]`` (the nearest surface wins).
    planes : tuple of Plane
        One per object, normal towards the reference camera.
    virtual_lights_m : numpy.ndarray, (K, 3) float64
        The light mirrored across each object's plane.
    highlight_uv : numpy.ndarray, (K, N, 2) float64
        Projection of each virtual light into each view: the highlight centre where the
        mirror point lies on the object (NaN where the virtual light is behind a camera).
    """

    views: tuple[np.ndarray, ...]
    disparity_px: np.ndarray
    depth_m: np.ndarray
    instance_mask: np.ndarray
    planes: tuple[Plane, ...]
    virtual_lights_m: np.ndarray
    highlight_uv: np.ndarray

    @property
    def object_masks(self) -> list[np.ndarray]:
        """One ``(H, W)`` bool mask per object, in scene order."""
        return [self.instance_mask == k for k in range(1, len(self.planes) + 1)]


# ---------------------------------------------------------------------------------- surfaces
@dataclass(frozen=True, eq=False)
class _Surface:
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


def _surface(obj: PlanarObject, label: int, tile_m: float = 0.0) -> _Surface:
    e1, e2 = obj.axes
    n = np.asarray(obj.normal)
    center = np.asarray(obj.center_m)
    return _Surface(
        obj, n, float(n @ center), center, e1, e2, obj.bounding_corners_m(), label, tile_m
    )


@functools.lru_cache(maxsize=8)
def _skimage_texture(name: str) -> np.ndarray:
    import skimage.data

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


def _background_surfaces(
    scene: Scene, rig: CameraRig, *, with_textures: bool = True
) -> list[_Surface]:
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
        surfaces.append(_surface(obj, 0, texel_m))
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


# ---------------------------------------------------------------------------------- casting
def _pixel_box(surface: _Surface, rig: CameraRig, camera: int) -> tuple[int, int, int, int] | None:
    """Rows/cols ``(r0, r1, c0, c1)`` the surface can cover in a camera (None = nowhere)."""
    w, h = rig.image_size
    rel = surface.corners_m - rig.centers_m[camera]
    if np.any(rel[:, 2] <= 1e-9):
        return 0, h, 0, w
    k = rig.intrinsics
    u = k.fx * rel[:, 0] / rel[:, 2] + k.cx
    v = k.fy * rel[:, 1] / rel[:, 2] + k.cy
    c0, c1 = max(0, math.floor(u.min()) - 1), min(w, math.ceil(u.max()) + 2)
    r0, r1 = max(0, math.floor(v.min()) - 1), min(h, math.ceil(v.max()) + 2)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1


def _cast(
    surfaces: Sequence[_Surface], rig: CameraRig, camera: int, xs: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit per pixel: depth ``(H, W)`` (inf = none) and surface index (-1 = none).

    ``xs (W,)`` and ``ys (H,)`` are the normalised ray coordinates ``(u - cx) / fx`` and
    ``(v - cy) / fy`` of the sample positions; rays are ``(x, y, 1)``, so the ray
    parameter of a hit is its depth.
    """
    h, w = len(ys), len(xs)
    depth = np.full((h, w), np.inf)
    index = np.full((h, w), -1, dtype=np.int32)
    center = rig.centers_m[camera]
    for s, surf in enumerate(surfaces):
        num = surf.offset_m - float(surf.normal @ center)
        if num >= 0.0:
            continue  # the camera is behind the plane: single-sided surfaces are invisible
        box = _pixel_box(surf, rig, camera)
        if box is None:
            continue
        r0, r1, c0, c1 = box
        x, y = xs[None, c0:c1], ys[r0:r1, None]
        corner_x = np.array([[xs[c0], xs[c1 - 1]]])
        corner_y = np.array([[ys[r0]], [ys[r1 - 1]]])
        depth_box = depth[r0:r1, c0:c1]
        if _covers(surf, center, num, corner_x, corner_y).all():
            # Outlines are convex and the rays' footprint on the plane is a convex
            # quadrilateral: if its corners are inside, every ray of the box hits.
            t = num / (surf.normal[0] * x + surf.normal[1] * y + surf.normal[2])
            hit = t < depth_box
        else:
            front, t, inside = _hits(surf, center, num, x, y)
            hit = front & (t < depth_box) & inside
        depth_box[hit] = t[hit]
        index[r0:r1, c0:c1][hit] = s
    return depth, index


def _hits(
    surf: _Surface, center_m: np.ndarray, num: float, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Front-facing flag, depth and inside-outline flag of rays ``(x, y, 1)`` from a camera.

    ``num = c - n . C`` (< 0: the camera faces the plane's front). Arrays broadcast.
    """
    n = surf.normal
    denom = n[0] * x + n[1] * y + n[2]
    front = denom < 0.0
    t = num / np.where(front, denom, -1.0)
    rel = center_m - surf.center_m
    lx = rel @ surf.e1 + t * (surf.e1[0] * x + surf.e1[1] * y + surf.e1[2])
    ly = rel @ surf.e2 + t * (surf.e2[0] * x + surf.e2[1] * y + surf.e2[2])
    return front, t, _inside(surf.shape, lx, ly)


def _covers(
    surf: _Surface, center_m: np.ndarray, num: float, x: np.ndarray, y: np.ndarray
) -> np.ndarray:
    """Whether rays ``(x, y, 1)`` hit the surface's front inside its outline."""
    front, _, inside = _hits(surf, center_m, num, x, y)
    return front & inside


def _sample_bilinear(
    texture: np.ndarray, tu: np.ndarray, tv: np.ndarray, *, tiled: bool
) -> np.ndarray:
    """Bilinear texture lookup at texel coordinates ``(M,)``; returns ``(M, 3)`` float32.

    Texel centres are at integer coordinates; tiled textures repeat mirrored, others
    clamp to the edge.
    """
    th, tw = texture.shape[:2]
    if tiled:
        # Fold the coordinates into one mirrored period so any distance from the
        # plane's origin maps into the texture: m in [0, 2w) -> w - |m - w|.
        tu = (tw - 0.5) - np.abs(np.mod(tu + 0.5, 2 * tw) - tw)
        tv = (th - 0.5) - np.abs(np.mod(tv + 0.5, 2 * th) - th)
    # cv2.remap gathers the scattered points as an image of _REMAP_COLS columns (it
    # refuses maps of 32767 or more rows or columns): (M,) -> (rows, _REMAP_COLS).
    m = tu.size
    rows = -(-m // _REMAP_COLS)
    maps = np.zeros((2, rows * _REMAP_COLS), dtype=np.float32)
    maps[0, :m], maps[1, :m] = tu, tv
    out = cv2.remap(
        texture,
        maps[0].reshape(rows, _REMAP_COLS),
        maps[1].reshape(rows, _REMAP_COLS),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape(-1, 3)[:m]


def _mip(surf: _Surface, level: int) -> np.ndarray:
    """Return the surface's texture averaged down ``2**level`` times (cached per surface)."""
    tex = surf.shape.texture
    if level == 0:
        return tex
    if level not in surf.mips:
        th, tw = tex.shape[:2]
        size = (max(1, round(tw / 2**level)), max(1, round(th / 2**level)))
        surf.mips[level] = cv2.resize(tex, size, interpolation=cv2.INTER_AREA).reshape(
            size[1], size[0], 3
        )
    return surf.mips[level]


def _albedo(surf: _Surface, local: np.ndarray, footprint_m: float) -> np.ndarray:
    """Diffuse albedo ``(M, 3)`` (or ``(3,)`` if untextured) at local points ``(M, 2)``.

    ``footprint_m`` is the size of one image sample on the surface. Where a texel is
    much smaller, the lookup uses a texture averaged down to about that size (a mip
    level), so fine print such as marker boards does not alias.
    """
    base = np.asarray(surf.shape.material.diffuse_rgb, dtype=np.float32)
    tex = surf.shape.texture
    if tex is None:
        return base
    th, tw = tex.shape[:2]
    if surf.tile_m > 0:
        texel_u = texel_v = surf.tile_m
        tu, tv = local[:, 0] / texel_u, local[:, 1] / texel_v
    else:
        w, h = surf.shape.size_m
        texel_u, texel_v = w / tw, h / th
        tu = local[:, 0] / texel_u + (tw / 2 - 0.5)
        tv = local[:, 1] / texel_v + (th / 2 - 0.5)
    texels_per_sample = footprint_m / min(texel_u, texel_v)
    level = int(math.floor(math.log2(texels_per_sample))) if texels_per_sample >= 2.0 else 0
    level = min(level, int(math.log2(max(tw, th))))
    mip = _mip(surf, level)
    if mip is not tex:
        # Texel centres stay at integer coordinates: (t + 0.5) scales, then - 0.5.
        tu = (tu + 0.5) * (mip.shape[1] / tw) - 0.5
        tv = (tv + 0.5) * (mip.shape[0] / th) - 0.5
    return base * _sample_bilinear(mip, tu, tv, tiled=surf.tile_m > 0)


def _shade_points(
    surf: _Surface,
    ray_x: np.ndarray,
    ray_y: np.ndarray,
    depth_m: np.ndarray,
    eye_m: np.ndarray,
    scene: Scene,
    sample_angle_rad: float = 0.0,
) -> np.ndarray:
    """Linear radiance ``(M, 3)`` float32 of surface points seen along camera rays.

    The points are ``eye + depth * (ray_x, ray_y, 1)`` (all ``(M,)``). Components are
    kept as separate arrays and the plane's constants folded in (``n . P = c`` on the
    plane), which keeps the per-pixel work to a few dozen element-wise float32 passes.
    ``sample_angle_rad`` is the angular spacing of the image samples (texture filtering).
    """
    f32 = np.float32
    light = scene.light
    n = surf.normal
    lpos = np.asarray(light.position_m)
    x = ray_x.astype(f32, copy=False)
    y = ray_y.astype(f32, copy=False)
    t = depth_m.astype(f32, copy=False)
    # Surface point relative to the light's centre, and distance to it: (M,) each.
    to_lx = f32(lpos[0] - eye_m[0]) - t * x
    to_ly = f32(lpos[1] - eye_m[1]) - t * y
    to_lz = f32(lpos[2] - eye_m[2]) - t
    dist2 = to_lx * to_lx + to_ly * to_ly + to_lz * to_lz
    dist = np.sqrt(dist2)
    # n . (L - P) = n . L - c on the plane: the light's height above it.
    height_l = float(n @ lpos) - surf.offset_m
    height_v = float(n @ eye_m) - surf.offset_m
    if height_l <= 0.0 or height_v <= 0.0:
        irradiance = np.zeros_like(t)
    else:
        irradiance = f32(light.intensity * height_l) / (dist2 * dist)
    # Local texture coordinates: e . (P - center) = e . (eye - center) + t e . ray.
    rel = eye_m - surf.center_m
    local = np.stack(
        [
            f32(rel @ surf.e1) + t * (f32(surf.e1[0]) * x + f32(surf.e1[1]) * y + f32(surf.e1[2])),
            f32(rel @ surf.e2) + t * (f32(surf.e2[0]) * x + f32(surf.e2[1]) * y + f32(surf.e2[2])),
        ],
        axis=1,
    )
    footprint_m = 0.0
    if surf.shape.texture is not None and sample_angle_rad > 0 and height_v > 0:
        # Sample footprint on the surface, (distance^2 / height) * angle, at a typical point.
        step = max(1, t.size // 512)
        distance2 = np.square(t[::step]) * (np.square(x[::step]) + np.square(y[::step]) + 1.0)
        footprint_m = float(np.median(distance2)) / height_v * sample_angle_rad
    albedo = _albedo(surf, local, footprint_m)
    color = np.asarray(light.color_rgb, dtype=f32)
    radiance = albedo * (irradiance[:, None] * (color / f32(np.pi)) + f32(scene.ambient))
    mat = surf.shape.material
    if mat.specular > 0.0 and height_l > 0.0 and height_v > 0.0:
        ray_len = np.sqrt(x * x + y * y + f32(1.0))
        cos_l = f32(height_l) / dist
        cos_v = f32(height_v) / (t * ray_len)
        # l . v with v = -ray / |ray|; then h = (l + v) / |l + v|.
        cos_lv = -(to_lx * x + to_ly * y + to_lz) / (dist * ray_len)
        half_len = np.sqrt(np.maximum(f32(2.0) + f32(2.0) * cos_lv, f32(1e-12)))
        cos_h = (cos_l + cos_v) / half_len
        cos_vh = (cos_lv + f32(1.0)) / half_len
        alpha = widened_roughness(mat.roughness, light.radius_m, dist).astype(f32)
        brdf = specular_brdf(cos_l, cos_v, cos_h, cos_vh, alpha, lobe=mat.lobe, f0=mat.f0)
        radiance += (f32(mat.specular) * brdf * irradiance)[:, None] * color
    return radiance.astype(f32, copy=False)


def _render_view(
    surfaces: Sequence[_Surface],
    scene: Scene,
    rig: CameraRig,
    camera: int,
    offset_px: tuple[float, float],
    supersample: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linear radiance ``(H, W, 3)`` float32 of one camera, plus its depth and index.

    ``offset_px`` shifts the samples within the pixel; ``supersample`` says how many
    samples per pixel side are averaged (textures are filtered to the sample spacing).
    """
    k = rig.intrinsics
    w, h = rig.image_size
    sample_angle = 1.0 / (math.sqrt(k.fx * k.fy) * supersample)
    xs = (np.arange(w) + offset_px[0] - k.cx) / k.fx
    ys = (np.arange(h) + offset_px[1] - k.cy) / k.fy
    depth, index = _cast(surfaces, rig, camera, xs, ys)
    sky = scene.ambient * _SKY_ALBEDO
    radiance = np.full((h * w, 3), sky, dtype=np.float32)
    eye = rig.centers_m[camera]
    flat_index, flat_depth = index.ravel(), depth.ravel()
    grid_x = np.broadcast_to(xs.astype(np.float32), (h, w)).ravel()
    grid_y = np.repeat(ys.astype(np.float32), w)
    for s, surf in enumerate(surfaces):
        pixels = np.flatnonzero(flat_index == s)
        if pixels.size == 0:
            continue
        radiance[pixels] = _shade_points(
            surf, grid_x[pixels], grid_y[pixels], flat_depth[pixels], eye, scene, sample_angle
        )
    return radiance.reshape(h, w, 3), depth, index


@functools.lru_cache(maxsize=1)
def _encode_lut() -> np.ndarray:
    levels = linear_to_srgb(np.linspace(0.0, 1.0, _ENCODE_LUT_SIZE, dtype=np.float32))
    return np.round(levels * 255.0).astype(np.uint8)


def _encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] (values beyond clip) to 8-bit sRGB through a lookup table."""
    idx = (np.clip(linear, 0.0, 1.0) * (_ENCODE_LUT_SIZE - 1) + 0.5).astype(np.int32)
    return _encode_lut()[idx]


def _check_rig(rig: Any) -> CameraRig:
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    return rig


def render(
    scene: Scene, rig: CameraRig, *, noise_seed: int | None = None, supersample: int = 1
) -> Rendering:
    """Render every view of a rig and the reference camera's ground truth.

    Parameters
    ----------
    scene : Scene
    rig : CameraRig
        Any rectified rig; views come out in its camera order.
    noise_seed : int, optional
        Seed of the sensor noise (used only if ``scene.noise_std > 0``); by default
        derived from ``scene.background_seed``, so a render is a pure function of its
        arguments.
    supersample : int
        ``k``: average ``k x k`` samples per pixel (anti-aliased edges); ground truth
        stays at pixel centres.

    Returns
    -------
    Rendering

    Raises
    ------
    SceneError
        ``scene`` is not a Scene or ``supersample`` is not in ``[1, 8]``.
    RigError
        ``rig`` is not a CameraRig.

    Examples
    --------
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(64, 48))
    >>> plate = PlanarObject("rectangle", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.3, 0.3))
    >>> out = render(Scene((plate,), Light((0.3, 0.0, 0.0))), rig)
    >>> float(out.disparity_px[24, 32]), int(out.instance_mask[24, 32]), out.views[1].shape
    (10.0, 1, (48, 64, 3))
    """
    if not isinstance(scene, Scene):
        raise SceneError(f"scene: expected a Scene, got {type(scene).__name__}")
    rig = _check_rig(rig)
    if (
        isinstance(supersample, bool)
        or not isinstance(supersample, (int, np.integer))
        or not 1 <= supersample <= MAX_SUPERSAMPLE
    ):
        raise SceneError(
            f"supersample: expected an integer in [1, {MAX_SUPERSAMPLE}], got {supersample!r}"
        )
    if noise_seed is not None and (
        isinstance(noise_seed, bool)
        or not isinstance(noise_seed, (int, np.integer))
        or noise_seed < 0
    ):
        raise SceneError(f"noise_seed: expected a non-negative integer or None, got {noise_seed!r}")
    surfaces = [_surface(obj, k + 1) for k, obj in enumerate(scene.objects)]
    if scene.background == "textured":
        surfaces += _background_surfaces(scene, rig)
    step = 1.0 / supersample
    offsets = [
        ((i + 0.5) * step - 0.5, (j + 0.5) * step - 0.5)
        for j in range(supersample)
        for i in range(supersample)
    ]
    rng = np.random.default_rng([scene.background_seed if noise_seed is None else noise_seed, 11])
    views = []
    ref_depth = ref_index = None
    for cam in range(rig.n_cameras):
        total = None
        for off in offsets:
            radiance, depth, index = _render_view(surfaces, scene, rig, cam, off, supersample)
            total = radiance if total is None else total + radiance
            if cam == rig.reference and supersample == 1:
                ref_depth, ref_index = depth, index
        linear = total * np.float32(scene.exposure / len(offsets))
        if scene.noise_std > 0:
            linear += np.float32(scene.noise_std) * rng.standard_normal(
                linear.shape, dtype=np.float32
            )
        views.append(_encode(linear))
    if ref_depth is None:
        k = rig.intrinsics
        xs = (np.arange(rig.width) - k.cx) / k.fx
        ys = (np.arange(rig.height) - k.cy) / k.fy
        ref_depth, ref_index = _cast(surfaces, rig, rig.reference, xs, ys)
    labels = np.array([s.label for s in surfaces] + [0], dtype=np.int32)
    instance = labels[ref_index]  # index -1 (no hit) picks the trailing 0
    finite = np.isfinite(ref_depth)
    disparity = np.zeros(ref_depth.shape, dtype=np.float32)
    disparity[finite] = rig.intrinsics.fx * rig.baseline_m / ref_depth[finite]
    ref_center = rig.reference_center_m
    planes = tuple(Plane.from_point_normal(o.center_m, o.normal, ref_center) for o in scene.objects)
    light = np.asarray(scene.light.position_m)
    virtual = np.array([p.mirror(light) for p in planes])
    uv = np.stack([rig.project(virtual, camera=i) for i in range(rig.n_cameras)], axis=1)
    return Rendering(
        tuple(views), disparity, ref_depth.astype(np.float32), instance, planes, virtual, uv
    )


# ---------------------------------------------------------------------------------- sampling
def _light_visible(
    position_m: np.ndarray, radius_m: float, rig: CameraRig, *, margin_px: float = 2.0
) -> bool:
    """Whether any camera could image any part of the light sphere directly."""
    k = rig.intrinsics
    w, h = rig.image_size
    for c in rig.centers_m:
        rel = position_m - c
        if rel[2] + radius_m <= 0.0:
            continue  # entirely behind the camera plane
        if rel[2] - radius_m <= 1e-3:
            return True  # straddles the camera plane: inside the frustum for all we know
        u = k.fx * rel[0] / rel[2] + k.cx
        v = k.fy * rel[1] / rel[2] + k.cy
        r_px = max(k.fx, k.fy) * radius_m / (rel[2] - radius_m) + margin_px
        if -r_px - 0.5 < u < w - 0.5 + r_px and -r_px - 0.5 < v < h - 0.5 + r_px:
            return True
    return False


def _mirror_points_local(
    obj: PlanarObject, light_m: np.ndarray, rig: CameraRig
) -> np.ndarray | None:
    """Local coordinates ``(N, 2)`` of the mirror point seen by each camera (None = none)."""
    plane = obj.plane
    virtual = plane.mirror(light_m)
    centers = rig.centers_m
    toward = virtual - centers
    denom = toward @ plane.n
    if np.any(np.abs(denom) < 1e-12):
        return None
    s = (plane.offset_m - centers @ plane.n) / denom
    if np.any((s <= 0) | (s >= 1)):
        return None
    return obj.local_coords(centers + s[:, None] * toward)


def _random_outline(rng: np.random.Generator, shape: str, w: float, h: float) -> tuple | None:
    """Convex local vertices inside the ``w x h`` box for triangles and polygons."""
    if shape == "triangle":
        # Three angles at least 80 degrees apart keep the triangle fat enough to hold
        # a highlight that moves across the array.
        base = rng.uniform(0, 2 * np.pi)
        gaps = rng.dirichlet([4.0, 4.0, 4.0]) * (2 * np.pi - 3 * np.radians(80)) + np.radians(80)
        angles = base + np.concatenate([[0.0], np.cumsum(gaps[:2])])
    elif shape == "polygon":
        count = int(rng.integers(5, 9))
        # Jittered regular angles: convex (points on an ellipse) and never a sliver.
        angles = np.sort(
            np.mod(
                np.linspace(0, 2 * np.pi, count, endpoint=False)
                + rng.uniform(-0.25, 0.25, size=count) * 2 * np.pi / count
                + rng.uniform(0, 2 * np.pi),
                2 * np.pi,
            )
        )
    else:
        return None
    pts = np.column_stack([w / 2 * np.cos(angles), h / 2 * np.sin(angles)])
    return tuple(map(tuple, pts))


def _random_color(rng: np.random.Generator) -> tuple[float, float, float]:
    hue = rng.uniform(0.0, 1.0)
    sat = rng.uniform(0.0, 0.9)
    value = rng.uniform(0.15, 0.7)
    rgb = np.clip(np.abs(np.mod(hue * 6.0 + np.array([0.0, 4.0, 2.0]), 6.0) - 3.0) - 1.0, 0, 1)
    return tuple(float(c) for c in value * (1.0 - sat + sat * rgb))


def _diffuse_unit(
    obj: PlanarObject, point_m: np.ndarray, light: Light, ambient: float
) -> tuple[float, float]:
    """(direct, ambient) luminance of the diffuse term at a point, per unit exposure."""
    to_light = np.asarray(light.position_m) - point_m
    dist2 = float(to_light @ to_light)
    cos_l = max(0.0, float(to_light @ np.asarray(obj.normal)) / math.sqrt(dist2))
    albedo = float(np.dot(obj.material.diffuse_rgb, REC709_LUMA))
    color = float(np.dot(light.color_rgb, REC709_LUMA))
    return albedo / np.pi * light.intensity * cos_l / dist2 * color, ambient * albedo


def _specular_peak(obj: PlanarObject, light: Light, rig: CameraRig) -> float:
    """Luminance of the specular lobe at the reference mirror point, per unit exposure."""
    local = _mirror_points_local(obj, np.asarray(light.position_m), rig)
    eye = rig.reference_center_m
    rel = obj.to_world(local[rig.reference]) - eye
    surf = _surface(replace(obj, material=replace(obj.material, diffuse_rgb=(0.0, 0.0, 0.0))), 1)
    radiance = _shade_points(
        surf,
        np.array([rel[0] / rel[2]]),
        np.array([rel[1] / rel[2]]),
        np.array([rel[2]]),
        eye,
        Scene((obj,), light, ambient=0.0),
    )
    return float(radiance[0] @ REC709_LUMA)


def random_scene(
    seed: int,
    rig: CameraRig,
    *,
    n_objects: int = 1,
    background: str = "none",
    lobe: str = "ggx",
    roughness: tuple[float, float] | float = (0.005, 0.03),
    light_radius_m: tuple[float, float] | float = (0.002, 0.01),
    distance_m: tuple[float, float] = (0.6, 1.4),
    max_tilt_deg: float = 30.0,
    size_m: tuple[float, float] = (0.15, 0.4),
    shapes: Sequence[str] = SHAPES,
    highlight_margin_m: float = 0.02,
    light_offset_m: tuple[float, float] = (0.1, 0.6),
    clip_ratio: tuple[float, float] | float = (1.5, 4.0),
    diffuse_level: tuple[float, float] | float = (0.03, 0.12),
    noise_std: float = 0.002,
    max_attempts: int = 2000,
) -> Scene:
    """Sample a scene under the paper's conditions, deterministically from ``seed``.

    One light is placed beside or behind the array, outside every camera's field of
    view. Each object is then placed so that the light's mirror reflection reaches the
    array: a reference-view point on the object is drawn, the object's normal is the
    bisector of the directions to the reference camera and to the light there, and the
    object is accepted only if its mirror point (where the line from each camera centre
    to the virtual light crosses the plane) lies inside its outline, at least
    ``highlight_margin_m`` from the edge, in every view, unoccluded; if its normal is
    within ``max_tilt_deg`` of the optical axis; if every view sees the whole object; and,
    for several objects, if the objects do not overlap in the reference view.
    The exposure puts the objects' diffuse shading at ``diffuse_level`` (linear) and the
    specular scale makes the highlight core ``clip_ratio`` times the clipping level.

    Parameters
    ----------
    seed : int
        Seed; the same seed and rig give the same scene.
    rig : CameraRig
    n_objects : int
        Number of objects, each with its own highlight.
    background : {"none", "textured"}
    lobe : {"ggx", "blinn_phong"}
        Specular lobe of every object.
    roughness, light_radius_m : float or (float, float)
        Lobe roughness and light radius (metres), fixed or uniform in a range.
    distance_m : (float, float)
        Depth range of the reference mirror point, metres.
    max_tilt_deg : float
        Largest angle between an object's normal and the optical axis.
    size_m : (float, float)
        Range of the larger object extent, metres (the other is 0.6-1 times it).
    shapes : sequence of str
        Shapes to draw from.
    highlight_margin_m : float
        Smallest distance from every view's mirror point to the object's edge.
    light_offset_m : (float, float)
        Range of the light's lateral distance beyond the array's extent, metres.
    clip_ratio : float or (float, float)
        Highlight peak over the clipping level (> 1 clips).
    diffuse_level : float or (float, float)
        Linear level of the objects' diffuse shading (0.03-0.12 is mid-dark in sRGB).
    noise_std : float
        Sensor noise of the scene (linear units).
    max_attempts : int
        Light placements to try before giving up.

    Returns
    -------
    Scene
        Build the rig that knows the light with ``rig.with_light(scene.light.position_m)``.

    Raises
    ------
    SceneError
        Invalid options, or no valid scene found in ``max_attempts`` tries.

    Examples
    --------
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(640, 480))
    >>> scene = random_scene(3, rig)
    >>> len(scene.objects), scene == random_scene(3, rig)
    (1, True)
    """
    rig = _check_rig(rig)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError(f"seed: expected a non-negative integer, got {seed!r}")
    if isinstance(n_objects, bool) or not isinstance(n_objects, (int, np.integer)) or n_objects < 1:
        raise SceneError(f"n_objects: expected a positive integer, got {n_objects!r}")
    if background not in BACKGROUNDS:
        raise SceneError(f"background: expected one of {list(BACKGROUNDS)}, got {background!r}")
    if lobe not in LOBES:
        raise SceneError(f"lobe: expected one of {list(LOBES)}, got {lobe!r}")
    rough = _range(roughness, "roughness", low=0.0, high=1.0)
    radius = _range(light_radius_m, "light_radius_m", low=0.0, low_open=False)
    dist = _range(distance_m, "distance_m", low=0.0)
    sizes = _range(size_m, "size_m", low=0.0)
    offsets = _range(light_offset_m, "light_offset_m", low=0.0, low_open=False)
    clip = _range(clip_ratio, "clip_ratio", low=0.0)
    level = _range(diffuse_level, "diffuse_level", low=0.0, high=1.0)
    max_tilt = _finite(max_tilt_deg, "max_tilt_deg", low=0.0, low_open=True, high=89.0)
    margin = _finite(highlight_margin_m, "highlight_margin_m", low=0.0)
    noise = _finite(noise_std, "noise_std", low=0.0)
    shapes = tuple(shapes) if not isinstance(shapes, str) else (shapes,)
    bad = [s for s in shapes if s not in SHAPES]
    if not shapes or bad:
        raise SceneError(
            f"shapes: expected a non-empty subset of {list(SHAPES)}, got {list(shapes)}"
        )
    if (
        isinstance(max_attempts, bool)
        or not isinstance(max_attempts, (int, np.integer))
        or max_attempts < 1
    ):
        raise SceneError(f"max_attempts: expected a positive integer, got {max_attempts!r}")

    rng = np.random.default_rng(seed)
    k = rig.intrinsics
    w_px, h_px = rig.image_size
    ref = rig.reference
    ref_center = rig.reference_center_m
    array_center = rig.centers_m.mean(axis=0)
    extent = float(np.max(np.linalg.norm(rig.centers_m - array_center, axis=1)))
    xs = (np.arange(w_px) - k.cx) / k.fx
    ys = (np.arange(h_px) - k.cy) / k.fy

    def sample_light() -> Light | None:
        phi = rng.uniform(0, 2 * np.pi)
        lateral = extent + rng.uniform(*offsets)
        pos = array_center + np.array(
            [lateral * math.cos(phi), lateral * math.sin(phi), rng.uniform(-0.3, 0.15)]
        )
        r = rng.uniform(*radius)
        if (
            _light_visible(pos, r, rig)
            or np.min(np.linalg.norm(rig.centers_m - pos, axis=1)) < 0.05
        ):
            return None
        tint = rng.uniform(0.75, 1.0, size=3)
        return Light(tuple(pos), r, tuple(tint / tint.max()), rng.uniform(0.5, 2.0))

    def sample_object(
        light: Light, placed: list[PlanarObject], ref_masks: list[np.ndarray]
    ) -> tuple[PlanarObject, np.ndarray] | None:
        light_m = np.asarray(light.position_m)
        z = rng.uniform(*dist)
        uv = rng.uniform([0.2 * w_px, 0.2 * h_px], [0.8 * w_px, 0.8 * h_px])
        p0 = rig.backproject(uv, z)
        to_cam = ref_center - p0
        to_light = light_m - p0
        normal = to_cam / np.linalg.norm(to_cam) + to_light / np.linalg.norm(to_light)
        normal /= np.linalg.norm(normal)
        if math.degrees(math.acos(min(1.0, -normal[2]))) > max_tilt:
            return None
        shape = shapes[rng.integers(len(shapes))]
        big = rng.uniform(*sizes)
        w, h = (big, big * rng.uniform(0.6, 1.0))[:: 1 if rng.random() < 0.5 else -1]
        mat = Material(
            diffuse_rgb=_random_color(rng),
            specular=1.0,
            roughness=rng.uniform(*rough),
            lobe=lobe,
            f0=rng.uniform(0.03, 0.06),
        )
        probe = PlanarObject(
            shape,
            tuple(p0),
            tuple(normal),
            (w, h),
            rng.uniform(0, 2 * np.pi),
            _random_outline(rng, shape, w, h),
            mat,
        )
        # Put the reference mirror point near the middle of the outline.
        e1, e2 = probe.axes
        shift = rng.uniform(-0.15, 0.15, size=2) * np.array([w, h])
        obj = replace(probe, center_m=tuple(p0 - shift[0] * e1 - shift[1] * e2))
        local = _mirror_points_local(obj, light_m, rig)
        if local is None or obj.inner_distance_m(local).min() < margin:
            return None
        for cam in range(rig.n_cameras):
            rel = obj.to_world(obj.outline_local()) - rig.centers_m[cam]
            if rel[:, 2].min() <= 0.05:
                return None
            u = k.fx * rel[:, 0] / rel[:, 2] + k.cx
            v = k.fy * rel[:, 1] / rel[:, 2] + k.cy
            if u.min() < 2 or v.min() < 2 or u.max() > w_px - 3 or v.max() > h_px - 3:
                return None
        surf = _surface(obj, 1)
        _, index = _cast([surf], rig, ref, xs, ys)
        mask = index == 0
        if not mask.any():
            return None
        from scipy import ndimage

        grown = ndimage.binary_dilation(mask, iterations=3)
        if any((grown & m).any() for m in ref_masks):
            return None
        # No object may hide another's highlight in any view.
        everyone = placed + [obj]
        for a in everyone:
            mirror = a.to_world(_mirror_points_local(a, light_m, rig))
            for b in everyone:
                if b is a:
                    continue
                if _occludes(b, rig.centers_m, mirror):
                    return None
        return obj, mask

    for _ in range(max_attempts):
        light = sample_light()
        if light is None:
            continue
        placed: list[PlanarObject] = []
        masks: list[np.ndarray] = []
        for _ in range(n_objects):
            for _ in range(60):
                found = sample_object(light, placed, masks)
                if found is not None:
                    placed.append(found[0])
                    masks.append(found[1])
                    break
            else:
                break
        if len(placed) == n_objects:
            break
    else:
        raise SceneError(
            f"random_scene: expected to find a valid scene in {max_attempts} attempts, got none; "
            "widen size_m, distance_m or max_tilt_deg, or lower highlight_margin_m"
        )

    ambient = 0.02
    base = Scene(
        tuple(placed),
        light,
        ambient=ambient,
        background=background,
        background_seed=int(rng.integers(0, 2**31 - 1)),
        noise_std=noise,
    )
    target = rng.uniform(*level)
    mirror_points = [
        o.to_world(_mirror_points_local(o, np.asarray(light.position_m), rig)[ref]) for o in placed
    ]
    direct_o, amb_o = np.mean(
        [_diffuse_unit(o, p, light, 1.0) for o, p in zip(placed, mirror_points, strict=True)],
        axis=0,
    )
    if background == "textured":
        # Solve exposure and ambient so that objects sit at `target` and the textured
        # background around 1.5-3x brighter: a stereo network needs to see its texture.
        wall = _background_surfaces(base, rig, with_textures=False)[0]
        wall_obj = replace(wall.shape, material=Material(diffuse_rgb=(0.5, 0.5, 0.5), specular=0.0))
        direct_b, amb_b = _diffuse_unit(wall_obj, wall.center_m, light, 1.0)
        target_b = target * rng.uniform(1.5, 3.0)
        system = np.array([[direct_o, amb_o], [direct_b, amb_b]])
        exposure, exposed_ambient = np.linalg.solve(system, [target, target_b])
        if exposed_ambient < 0 or exposure <= 0:
            exposure, exposed_ambient = target / (direct_o + ambient * amb_o), 0.0
            exposed_ambient = ambient * exposure
        ambient = exposed_ambient / exposure
    else:
        exposure = target / (direct_o + ambient * amb_o)
    scene = replace(base, ambient=float(ambient), exposure=float(exposure))
    # The specular scale sets the highlight core to `ratio` times the clipping level, so
    # clipped highlights have a controlled size whatever the albedo and roughness.
    ratio = rng.uniform(*clip)
    scaled = []
    for obj in placed:
        peak = _specular_peak(obj, light, rig) * exposure
        scaled.append(replace(obj, material=replace(obj.material, specular=float(ratio / peak))))
    return replace(scene, objects=tuple(scaled))


def _occludes(obj: PlanarObject, centers_m: np.ndarray, points_m: np.ndarray) -> bool:
    """Whether ``obj`` cuts any segment from ``centers_m[i]`` to ``points_m[i]``."""
    plane = obj.plane
    toward = points_m - centers_m
    denom = toward @ plane.n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (plane.offset_m - centers_m @ plane.n) / denom
    hit = np.isfinite(s) & (s > 0) & (s < 1)
    if not hit.any():
        return False
    crossing = centers_m[hit] + s[hit, None] * toward[hit]
    return bool(obj.contains(crossing).any())


# ---------------------------------------------------------------------------------- datasets
def default_rig() -> CameraRig:
    """Return the paper's array: 3 x 3 cameras, 85 mm baselines, 640 x 480, fx = fy = 600."""
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, fy=600.0, image_size=(640, 480))


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """Describe a scene as a JSON-serialisable dict (textures are only flagged)."""

    def obj_dict(o: PlanarObject) -> dict[str, Any]:
        return {
            "shape": o.shape,
            "center_m": list(o.center_m),
            "normal": list(o.normal),
            "size_m": list(o.size_m),
            "rotation_rad": o.rotation_rad,
            "vertices_m": None if o.vertices_m is None else [list(v) for v in o.vertices_m],
            "material": {
                "diffuse_rgb": list(o.material.diffuse_rgb),
                "specular": o.material.specular,
                "roughness": o.material.roughness,
                "lobe": o.material.lobe,
                "f0": o.material.f0,
            },
            "textured": o.texture is not None,
        }

    light = scene.light
    return {
        "objects": [obj_dict(o) for o in scene.objects],
        "light": {
            "position_m": list(light.position_m),
            "radius_m": light.radius_m,
            "color_rgb": list(light.color_rgb),
            "intensity": light.intensity,
        },
        "ambient": scene.ambient,
        "background": scene.background,
        "background_seed": scene.background_seed,
        "exposure": scene.exposure,
        "noise_std": scene.noise_std,
    }


def scene_from_dict(data: Any) -> Scene:
    """Rebuild a scene from :func:`scene_to_dict` output (object textures are not stored).

    Raises
    ------
    SceneError
        Missing keys or values of the wrong kind.

    Examples
    --------
    >>> plate = PlanarObject("ellipse", (0.0, 0.0, 1.0), (0.1, 0.0, -1.0), (0.2, 0.1))
    >>> scene = Scene((plate,), Light((0.3, 0.0, 0.0)))
    >>> scene_from_dict(scene_to_dict(scene)) == scene
    True
    """
    try:
        objects = tuple(
            PlanarObject(
                shape=o["shape"],
                center_m=tuple(o["center_m"]),
                normal=tuple(o["normal"]),
                size_m=tuple(o["size_m"]),
                rotation_rad=o["rotation_rad"],
                vertices_m=None if o["vertices_m"] is None else tuple(map(tuple, o["vertices_m"])),
                material=Material(
                    **{**o["material"], "diffuse_rgb": tuple(o["material"]["diffuse_rgb"])}
                ),
            )
            for o in data["objects"]
        )
        light = data["light"]
        return Scene(
            objects,
            Light(
                tuple(light["position_m"]),
                light["radius_m"],
                tuple(light["color_rgb"]),
                light["intensity"],
            ),
            ambient=data["ambient"],
            background=data["background"],
            background_seed=data["background_seed"],
            exposure=data["exposure"],
            noise_std=data["noise_std"],
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise SceneError(
            f"scene: expected a dict as written by scene_to_dict, got one that fails with "
            f"{type(exc).__name__}: {exc}"
        ) from None


def render_dataset(
    out_dir: str | Path,
    *,
    n_scenes: int,
    seed: int = 0,
    rig: CameraRig | None = None,
    background: str = "none",
    n_objects: int = 1,
    supersample: int = 1,
    progress: bool = True,
    **scene_options: Any,
) -> list[Path]:
    """Render ``n_scenes`` random scenes into scene folders ``scene_0000``, ... (DESIGN §5).

    Each folder holds the views, ``rig.json`` with the scene's light, ``mask.png``
    (instance labels), ``gt_disparity.pfm`` and ``scene.json`` (the scene description,
    virtual lights and highlight centres).

    Parameters
    ----------
    out_dir : str or path-like
        Created if needed.
    n_scenes : int
    seed : int
        Dataset seed; scene ``i`` uses a seed derived from ``(seed, i)``.
    rig : CameraRig, optional
        :func:`default_rig` by default; its light is replaced by each scene's.
    background, n_objects, **scene_options
        Passed to :func:`random_scene`.
    supersample : int
        Passed to :func:`render`.
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of pathlib.Path
        The scene folders.
    """
    from tqdm import tqdm

    from ..io import write_scene

    if isinstance(n_scenes, bool) or not isinstance(n_scenes, (int, np.integer)) or n_scenes < 1:
        raise SceneError(f"n_scenes: expected a positive integer, got {n_scenes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError(f"seed: expected a non-negative integer, got {seed!r}")
    rig = default_rig() if rig is None else _check_rig(rig)
    out = Path(out_dir)
    folders = []
    for i in tqdm(range(n_scenes), desc="render", unit="scene", disable=not progress):
        scene_seed = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
        scene = random_scene(
            scene_seed, rig, n_objects=n_objects, background=background, **scene_options
        )
        scene_rig = rig.with_light(scene.light.position_m)
        result = render(scene, scene_rig, supersample=supersample)
        metadata = {
            "generator": "srde_fusion.synthetic.scenes.random_scene",
            "seed": scene_seed,
            "scene": scene_to_dict(scene),
            "virtual_lights_m": result.virtual_lights_m.tolist(),
            "highlight_uv": np.nan_to_num(result.highlight_uv, nan=-1.0).tolist(),
            "planes": [{"normal": list(p.normal), "offset_m": p.offset_m} for p in result.planes],
        }
        folders.append(
            write_scene(
                out / f"scene_{i:04d}",
                result.views,
                scene_rig,
                mask=result.instance_mask,
                gt_disparity=result.disparity_px,
                metadata=metadata,
            )
        )
    return folders
