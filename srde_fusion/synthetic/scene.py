"""What a synthetic scene is: planar glossy objects, their materials, one or more lights.

Objects are planar (rectangles, ellipses, convex polygons) and single-sided: they show
the side their normal points to. Every value is validated once, here, with "expected X,
got Y" messages; the renderer and the sampler take these types as they are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import LightError, RigError, SceneError, SRDEError
from ..geometry import MAX_LIGHTS, CameraRig, Plane, RigLight
from .shading import LOBES

__all__ = [
    "Material",
    "PlanarObject",
    "Light",
    "Scene",
    "Rendering",
    "SHAPES",
    "BACKGROUNDS",
]

#: Object outlines the renderer knows.
SHAPES = ("rectangle", "ellipse", "triangle", "polygon")


#: Background kinds: at infinity, or textured planes at finite depth.
BACKGROUNDS = ("none", "textured")


#: Sides of the polygon that stands in for an ellipse in margin checks (inscribed).
_ELLIPSE_SIDES = 96


# ---------------------------------------------------------------------------------- checks
def check_finite(
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
    return tuple(check_finite(v, f"{name}[{i}]", error, low=low, high=high)
                 for i, v in enumerate(value))


def check_range(
    value: Any, name: str, *, low: float, low_open: bool = True, high: float | None = None
) -> tuple[float, float]:
    """Return a sampling range given as one number or ``(min, max)``."""
    if isinstance(value, (tuple, list, np.ndarray)):
        if len(value) != 2:
            raise SceneError(f"{name}: expected a number or (min, max), got {value!r}")
        lo = check_finite(value[0], f"{name}[0]", low=low, low_open=low_open, high=high)
        hi = check_finite(value[1], f"{name}[1]", low=low, low_open=low_open, high=high)
        if hi < lo:
            raise SceneError(f"{name}: expected min <= max, got ({lo:g}, {hi:g})")
        return lo, hi
    v = check_finite(value, name, low=low, low_open=low_open, high=high)
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
        Fresnel reflectance at normal incidence, in [0, 1] (Schlick's term).
    ior : float, optional
        Refractive index used by the exact Fresnel equations (``Physics(fresnel="exact")``);
        None: the dielectric whose normal-incidence reflectance is ``f0``.
    extinction : float
        Imaginary part of the refractive index (> 0 for metals), exact Fresnel only.
    """

    diffuse_rgb: tuple[float, float, float] = (0.3, 0.3, 0.3)
    specular: float = 1.0
    roughness: float = 0.02
    lobe: str = "ggx"
    f0: float = 0.04
    ior: float | None = None
    extinction: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "diffuse_rgb", _vec(self.diffuse_rgb, "material.diffuse_rgb", low=0.0, high=1.0)
        )
        object.__setattr__(self, "specular",
                           check_finite(self.specular, "material.specular", low=0.0))
        object.__setattr__(
            self,
            "roughness",
            check_finite(self.roughness, "material.roughness", low=0.0, low_open=True, high=1.0),
        )
        if self.lobe not in LOBES:
            raise SceneError(f"material.lobe: expected one of {list(LOBES)}, got {self.lobe!r}")
        object.__setattr__(self, "f0", check_finite(self.f0, "material.f0", low=0.0, high=1.0))
        if self.ior is not None:
            object.__setattr__(self, "ior", check_finite(self.ior, "material.ior", low=0.0,
                                                         low_open=True, high=100.0))
        object.__setattr__(self, "extinction",
                           check_finite(self.extinction, "material.extinction", low=0.0,
                                        high=100.0))


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
        object.__setattr__(self, "rotation_rad", check_finite(self.rotation_rad, "rotation_rad"))
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
        return inside_outline(self, x, y)

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


def inside_outline(obj: PlanarObject, x: np.ndarray, y: np.ndarray) -> np.ndarray:
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
            self, "radius_m", check_finite(self.radius_m, "light.radius_m", LightError, low=0.0)
        )
        object.__setattr__(
            self, "color_rgb", _vec(self.color_rgb, "light.color_rgb", error=LightError, low=0.0)
        )
        object.__setattr__(
            self,
            "intensity",
            check_finite(self.intensity, "light.intensity", LightError, low=0.0, low_open=True),
        )


@dataclass(frozen=True)
class Scene:
    """Objects, their lights, and how the cameras expose them.

    Parameters
    ----------
    objects : tuple of PlanarObject
        At least one; ``instance_mask`` value k means ``objects[k - 1]``.
    light : Light, optional
        The (first) light; what single-light code reads. Optional when ``lights`` is given.
    lights : tuple of Light
        Every light (each a point or a sphere, by its radius); by default ``(light,)``.
        Given together with ``light``, its first entry must be ``light``.
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
    light: Light | None = None
    ambient: float = 0.02
    background: str = "none"
    background_seed: int = 0
    exposure: float = 1.0
    noise_std: float = 0.0
    lights: tuple[Light, ...] = ()

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
        lights = self.lights
        if isinstance(lights, Light):
            lights = (lights,)
        if not isinstance(lights, (tuple, list)) or len(lights) > MAX_LIGHTS:
            raise LightError(f"lights: expected a sequence of at most {MAX_LIGHTS} Light, "
                             f"got {lights!r:.80}")
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                raise LightError(f"lights[{i}]: expected a Light, got {type(light).__name__}")
        light = self.light
        if light is None and lights:
            light = lights[0]
        if not isinstance(light, Light):
            raise LightError(f"light: expected a Light, got {type(light).__name__}")
        if not lights:
            lights = (light,)
        elif lights[0] != light:
            raise LightError(f"light: expected the first of lights ({lights[0]}) or None, "
                             f"got {light}")
        object.__setattr__(self, "light", light)
        object.__setattr__(self, "lights", tuple(lights))
        object.__setattr__(self, "ambient", check_finite(self.ambient, "ambient", low=0.0))
        if self.background not in BACKGROUNDS:
            raise SceneError(
                f"background: expected one of {list(BACKGROUNDS)}, got {self.background!r}"
            )
        seed = self.background_seed
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise SceneError(f"background_seed: expected a non-negative integer, got {seed!r}")
        object.__setattr__(self, "background_seed", int(seed))
        object.__setattr__(
            self, "exposure", check_finite(self.exposure, "exposure", low=0.0, low_open=True)
        )
        object.__setattr__(self, "noise_std", check_finite(self.noise_std, "noise_std", low=0.0))


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
        The first light's (``scene.light``).
    virtual_lights_by_light_m : numpy.ndarray, (L, K, 3) float64
        Every light ``l`` of the scene mirrored across each object's plane.
    highlight_uv_by_light : numpy.ndarray, (L, K, N, 2) float64
        Projection of each of those virtual lights into each view.
    highlight_on_object : numpy.ndarray, (L, K, N) bool
        Whether light ``l``'s highlight on object ``k`` is seen in view ``i``: its mirror
        point (where the ray to the virtual light crosses the plane) lies inside the
        object's outline, both light and camera are in front of the plane, and no other
        object hides it. Where True, ``highlight_uv_by_light[l, k, i]`` is that highlight's
        centre, the pixel that belongs to light ``l``.
    """

    views: tuple[np.ndarray, ...]
    disparity_px: np.ndarray
    depth_m: np.ndarray
    instance_mask: np.ndarray
    planes: tuple[Plane, ...]
    virtual_lights_m: np.ndarray
    highlight_uv: np.ndarray
    virtual_lights_by_light_m: np.ndarray | None = None
    highlight_uv_by_light: np.ndarray | None = None
    highlight_on_object: np.ndarray | None = None

    @property
    def n_lights(self) -> int:
        """Number of lights the ground truth covers."""
        return 1 if self.virtual_lights_by_light_m is None else len(self.virtual_lights_by_light_m)

    @property
    def object_masks(self) -> list[np.ndarray]:
        """One ``(H, W)`` bool mask per object, in scene order."""
        return [self.instance_mask == k for k in range(1, len(self.planes) + 1)]


def relit(scene: Scene, by: Scene) -> Scene:
    """Return ``scene``'s objects under ``by``'s lamps and camera exposure.

    A sorting line keeps its lamps and exposure while objects pass: frames of one line
    are objects of many scenes, each relit by the same one.
    """
    return replace(scene, light=None, lights=by.lights, exposure=by.exposure)


def rig_lights(scene: Scene, *, radii: bool = False) -> tuple[RigLight, ...]:
    """Return the scene's lights as a rig knows them: positions, no name.

    ``rig.with_lights(rig_lights(scene))`` is the rig that knows every light.
    ``radii``: the rig also knows each lamp's radius (a ``rig.json`` with the lamps
    measured); by default it does not.
    """
    return tuple(RigLight(light.position_m, radius_m=light.radius_m if radii else None)
                 for light in scene.lights)


def check_rig(rig: Any) -> CameraRig:
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    return rig
