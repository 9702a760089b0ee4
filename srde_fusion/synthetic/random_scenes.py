"""Random scenes under the paper's conditions (Methods, synthetic data).

Textureless objects of random shape, colour, size and pose; one light (or several) of
random size, colour and intensity that no camera sees directly; every object's highlight
of the first light inside the object in every view (optionally every light's).
Deterministic from a seed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import ndimage

from ..errors import SceneError
from ..geometry import MAX_LIGHTS, CameraRig
from ..imaging import REC709_LUMA
from .render import cast_rays, shade_points
from .scene import (
    BACKGROUNDS,
    SHAPES,
    Light,
    Material,
    PlanarObject,
    Scene,
    check_finite,
    check_range,
    check_rig,
)
from .shading import LOBES
from .surfaces import background_surfaces, object_surface

__all__ = [
    "RandomSceneConfig",
    "random_scene",
]

# ---------------------------------------------------------------------------------- sampling
def light_visible(
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
    black = replace(obj.material, diffuse_rgb=(0.0, 0.0, 0.0))
    surf = object_surface(replace(obj, material=black), 1)
    radiance = shade_points(
        surf,
        np.array([rel[0] / rel[2]]),
        np.array([rel[1] / rel[2]]),
        np.array([rel[2]]),
        eye,
        Scene((obj,), light, ambient=0.0),
    )
    return float(radiance[0] @ REC709_LUMA)


@dataclass(frozen=True)
class RandomSceneConfig:
    """How :func:`random_scene` samples scenes; validated on construction.

    Ranges are stored as ``(low, high)`` tuples (a single number ``x`` becomes ``(x, x)``).

    Parameters
    ----------
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
    n_lights : int or (int, int)
        Number of lights, fixed or drawn uniformly from ``[min, max]`` (at most
        :data:`~srde_fusion.geometry.MAX_LIGHTS`). The first light places the objects as
        above; the others are drawn around it.
    light_spacing_m : (float, float)
        Range of the distance from each further light to the first, metres; lights are
        never closer to each other than its minimum.
    all_highlights_on_objects : bool
        Require every light's highlight inside every object (with the margin, unhidden)
        in every view; otherwise only the first light's is guaranteed and the others
        land wherever geometry puts them (``Rendering.highlight_on_object`` says where).

    Raises
    ------
    SceneError
        An option out of range; the message names it.
    """

    n_objects: int = 1
    background: str = "none"
    lobe: str = "ggx"
    roughness: tuple[float, float] | float = (0.005, 0.03)
    light_radius_m: tuple[float, float] | float = (0.002, 0.01)
    distance_m: tuple[float, float] = (0.6, 1.4)
    max_tilt_deg: float = 30.0
    size_m: tuple[float, float] = (0.15, 0.4)
    shapes: Sequence[str] = SHAPES
    highlight_margin_m: float = 0.02
    light_offset_m: tuple[float, float] = (0.1, 0.6)
    clip_ratio: tuple[float, float] | float = (1.5, 4.0)
    diffuse_level: tuple[float, float] | float = (0.03, 0.12)
    noise_std: float = 0.002
    max_attempts: int = 2000
    n_lights: tuple[int, int] | int = 1
    light_spacing_m: tuple[float, float] = (0.1, 0.4)
    all_highlights_on_objects: bool = False

    def __post_init__(self) -> None:
        n_objects, max_attempts = self.n_objects, self.max_attempts
        if (isinstance(n_objects, bool) or not isinstance(n_objects, (int, np.integer))
                or n_objects < 1):
            raise SceneError(f"n_objects: expected a positive integer, got {n_objects!r}")
        if self.background not in BACKGROUNDS:
            raise SceneError(f"background: expected one of {list(BACKGROUNDS)}, got "
                             f"{self.background!r}")
        if self.lobe not in LOBES:
            raise SceneError(f"lobe: expected one of {list(LOBES)}, got {self.lobe!r}")
        normalised = {
            "roughness": check_range(self.roughness, "roughness", low=0.0, high=1.0),
            "light_radius_m": check_range(self.light_radius_m, "light_radius_m", low=0.0,
                                          low_open=False),
            "distance_m": check_range(self.distance_m, "distance_m", low=0.0),
            "size_m": check_range(self.size_m, "size_m", low=0.0),
            "light_offset_m": check_range(self.light_offset_m, "light_offset_m", low=0.0,
                                          low_open=False),
            "clip_ratio": check_range(self.clip_ratio, "clip_ratio", low=0.0),
            "diffuse_level": check_range(self.diffuse_level, "diffuse_level", low=0.0,
                                         high=1.0),
            "max_tilt_deg": check_finite(self.max_tilt_deg, "max_tilt_deg", low=0.0,
                                         low_open=True, high=89.0),
            "highlight_margin_m": check_finite(self.highlight_margin_m, "highlight_margin_m",
                                               low=0.0),
            "noise_std": check_finite(self.noise_std, "noise_std", low=0.0),
        }
        shapes = tuple(self.shapes) if not isinstance(self.shapes, str) else (self.shapes,)
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
        lights = self.n_lights
        lights = tuple(lights) if isinstance(lights, (tuple, list)) else (lights, lights)
        if len(lights) != 2 or not all(
            isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= MAX_LIGHTS
            for n in lights
        ) or lights[1] < lights[0]:
            raise SceneError(f"n_lights: expected an integer in [1, {MAX_LIGHTS}] or (min, max) "
                             f"of them, got {self.n_lights!r}")
        if not isinstance(self.all_highlights_on_objects, bool):
            raise SceneError(f"all_highlights_on_objects: expected a bool, got "
                             f"{self.all_highlights_on_objects!r}")
        normalised.update(
            shapes=shapes, n_objects=int(n_objects), max_attempts=int(max_attempts),
            n_lights=(int(lights[0]), int(lights[1])),
            light_spacing_m=check_range(self.light_spacing_m, "light_spacing_m", low=0.0),
        )
        for name, value in normalised.items():
            object.__setattr__(self, name, value)


def random_scene(seed: int, rig: CameraRig, *, config: RandomSceneConfig | None = None,
                 **options: Any) -> Scene:
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
    config : RandomSceneConfig, optional
        The sampling options; the defaults when None.
    **options
        Any :class:`RandomSceneConfig` field, overriding ``config``'s (``n_objects=2``,
        ``background="textured"``, ``roughness=(0.01, 0.08)``, ...).

    Returns
    -------
    Scene
        Build the rig that knows the lights with ``rig.with_lights(rig_lights(scene))``
        (``rig.with_light(scene.light.position_m)`` for the first alone).

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
    rig = check_rig(rig)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError(f"seed: expected a non-negative integer, got {seed!r}")
    known = [f.name for f in dataclasses.fields(RandomSceneConfig)]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise SceneError(f"{unknown[0]}: expected one of the RandomSceneConfig options {known}, "
                         f"got an unknown option")
    if config is None:
        config = RandomSceneConfig(**options)
    elif not isinstance(config, RandomSceneConfig):
        raise SceneError(f"config: expected a RandomSceneConfig, got {type(config).__name__}")
    elif options:
        config = dataclasses.replace(config, **options)
    n_objects, background, lobe = config.n_objects, config.background, config.lobe
    rough, radius, dist = config.roughness, config.light_radius_m, config.distance_m
    sizes, offsets, clip = config.size_m, config.light_offset_m, config.clip_ratio
    level, max_tilt = config.diffuse_level, config.max_tilt_deg
    margin, noise, shapes = config.highlight_margin_m, config.noise_std, config.shapes
    max_attempts = config.max_attempts

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
            light_visible(pos, r, rig)
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
        surf = object_surface(obj, 1)
        _, index = cast_rays([surf], rig, ref, xs, ys)
        mask = index == 0
        if not mask.any():
            return None

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

    extra = _further_lights(rng, config, rig, light, placed)
    lights = (light, *extra)
    ambient = 0.02
    base = Scene(
        tuple(placed),
        light,
        lights=lights,
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
        [_diffuse_unit_all(o, p, lights) for o, p in zip(placed, mirror_points, strict=True)],
        axis=0,
    )
    if background == "textured":
        # Solve exposure and ambient so that objects sit at `target` and the textured
        # background around 1.5-3x brighter: a stereo network needs to see its texture.
        wall = background_surfaces(base, rig, with_textures=False)[0]
        wall_obj = replace(wall.shape, material=Material(diffuse_rgb=(0.5, 0.5, 0.5), specular=0.0))
        direct_b, amb_b = _diffuse_unit_all(wall_obj, wall.center_m, lights)
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


def _diffuse_unit_all(obj: PlanarObject, point_m: np.ndarray, lights: Sequence[Light]
                      ) -> tuple[float, float]:
    """:func:`_diffuse_unit` with the direct light of every light added up."""
    direct, ambient = _diffuse_unit(obj, point_m, lights[0], 1.0)
    for light in lights[1:]:
        direct = direct + _diffuse_unit(obj, point_m, light, 1.0)[0]
    return direct, ambient


def _further_lights(rng: np.random.Generator, config: RandomSceneConfig, rig: CameraRig,
                    first: Light, placed: list[PlanarObject]) -> tuple[Light, ...]:
    """Draw the lights after the first: around it, unseen, apart from each other.

    With ``all_highlights_on_objects`` each must also put its highlight inside every
    object (with the margin) in every view, unhidden by the other objects.
    """
    low, high = config.n_lights
    if high == 1:
        return ()  # one light: no draws, so single-light scenes stay what they were
    count = int(rng.integers(low, high + 1)) - 1
    spacing = config.light_spacing_m
    first_m = np.asarray(first.position_m)
    positions = [first_m]
    extra: list[Light] = []
    for _ in range(count):
        for _ in range(config.max_attempts):
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            pos = first_m + rng.uniform(*spacing) * direction
            r = rng.uniform(*config.light_radius_m)
            if (
                min(np.linalg.norm(p - pos) for p in positions) < spacing[0]
                or light_visible(pos, r, rig)
                or np.min(np.linalg.norm(rig.centers_m - pos, axis=1)) < 0.05
            ):
                continue
            if config.all_highlights_on_objects and not _highlights_inside(
                    pos, placed, rig, config.highlight_margin_m):
                continue
            tint = rng.uniform(0.75, 1.0, size=3)
            extra.append(Light(tuple(pos), r, tuple(tint / tint.max()), rng.uniform(0.5, 2.0)))
            positions.append(pos)
            break
        else:
            raise SceneError(
                f"random_scene: expected to place light {len(extra) + 2} of {count + 1} in "
                f"{config.max_attempts} attempts, got none; widen light_spacing_m or, with "
                f"all_highlights_on_objects, lower highlight_margin_m or enlarge size_m")
    return tuple(extra)


def _highlights_inside(light_m: np.ndarray, objects: Sequence[PlanarObject], rig: CameraRig,
                       margin_m: float) -> bool:
    """Whether a light's highlight lies inside every object, with the margin, unhidden."""
    mirrors = []
    for obj in objects:
        local = _mirror_points_local(obj, light_m, rig)
        if local is None or obj.inner_distance_m(local).min() < margin_m:
            return False
        mirrors.append(obj.to_world(local))
    for a, mirror in zip(objects, mirrors, strict=True):
        if any(_occludes(b, rig.centers_m, mirror) for b in objects if b is not a):
            return False
    return True


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
