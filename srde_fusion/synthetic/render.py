"""Rendering synthetic scenes with exact ground truth.

The renderer casts the pixel rays of every camera of a :class:`~srde_fusion.geometry.CameraRig`
analytically against planar objects, vectorised over the image; objects occlude each
other and the background, the nearest hit wins. Shading is physically based in linear
light: Lambertian diffuse with inverse-square and cosine falloff, a white ambient term,
and a specular lobe from :mod:`srde_fusion.synthetic.shading` (GGX microfacet or
normalised Blinn-Phong); nothing casts shadows and there are no inter-reflections.
Linear radiance is scaled by the exposure, gets sensor noise, is sRGB-encoded and clipped
to 8 bits, so highlights saturate as in a real camera.

By default the physics is the refinement's own model: Schlick's Fresnel and a spherical
light folded into a wider lobe (:func:`srde_fusion.synthetic.shading.widened_roughness`).
A :class:`~srde_fusion.synthetic.physics.Physics` switches on, one by one, what that
model does not assume: exact Fresnel, the light integrated over its area,
height-correlated masking, diffuse transmittance and a photon-counting sensor; with
``supersample`` the pixel's area is integrated too.

Ground truth is for the reference camera at pixel centres: depth, stereo-pair disparity
(``fx * B / z``; 0 where the background is at infinity), the instance mask, the object
planes, each object's virtual light (the light mirrored across its plane) and where that
virtual light projects in every view -- the centre of the highlight.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import SceneError
from ..geometry import CameraRig, Plane
from ..imaging import linear_to_srgb
from .physics import Physics
from .scene import Light, Material, Rendering, Scene, check_rig, inside_outline
from .shading import disc_samples, fresnel_exact, ior_from_f0, specular_brdf, widened_roughness
from .surfaces import SKY_ALBEDO, TexturedSurface, background_surfaces, object_surface

__all__ = [
    "render",
]

#: Entries of the linear -> 8-bit sRGB table (linear steps of 1.5e-5).
_ENCODE_LUT_SIZE = 1 << 16


#: Width of the point blocks handed to cv2.remap for texture lookups.
_REMAP_COLS = 1024


#: Largest supersampling factor accepted (k x k samples per pixel).
MAX_SUPERSAMPLE = 8


#: A sampled light is integrated where the widened-lobe estimate of the specular term is
#: above this fraction of its largest value on the surface; below it the two differ by a
#: small part of a value already under 1e-4 of the peak.
_SAMPLED_LIGHT_MIN = 1e-4


#: Shading points per block of the sampled light integration (bounds its memory).
_SAMPLED_BLOCK = 2048


#: The default physics: the refinement's own model.
_MODEL_PHYSICS = Physics()


# ---------------------------------------------------------------------------------- casting
def _pixel_box(surface: TexturedSurface, rig: CameraRig, camera: int
               ) -> tuple[int, int, int, int] | None:
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


def cast_rays(
    surfaces: Sequence[TexturedSurface], rig: CameraRig, camera: int, xs: np.ndarray, ys: np.ndarray
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
    surf: TexturedSurface, center_m: np.ndarray, num: float, x: np.ndarray, y: np.ndarray
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
    return front, t, inside_outline(surf.shape, lx, ly)


def _covers(
    surf: TexturedSurface, center_m: np.ndarray, num: float, x: np.ndarray, y: np.ndarray
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


def _mip(surf: TexturedSurface, level: int) -> np.ndarray:
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


def _albedo(surf: TexturedSurface, local: np.ndarray, footprint_m: float) -> np.ndarray:
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


def _ior(mat: Material) -> float:
    """Return the refractive index of the exact Fresnel equations: given, or from ``f0``."""
    return mat.ior if mat.ior is not None else ior_from_f0(mat.f0)


def _fresnel(mat: Material, cos_i: np.ndarray, physics: Physics) -> np.ndarray | None:
    """Exact Fresnel reflectance at ``cos_i`` (float32), or None for Schlick's term."""
    if physics.fresnel != "exact":
        return None
    return fresnel_exact(cos_i, _ior(mat), mat.extinction).astype(np.float32, copy=False)


@functools.lru_cache(maxsize=16)
def _hemispherical_fresnel(ior: float, extinction: float) -> float:
    """Cosine-weighted mean of the Fresnel reflectance over the hemisphere, ``2 int F c dc``."""
    c = (np.arange(512) + 0.5) / 512
    return float(2.0 * np.mean(fresnel_exact(c, ior, extinction) * c))


def _sampled_specular(
    mat: Material, light: Light, physics: Physics, point_m: tuple[np.ndarray, ...],
    normal: np.ndarray, view: tuple[np.ndarray, ...], cos_v: np.ndarray,
) -> np.ndarray:
    """Specular radiance ``(M,)`` of a spherical light integrated over its disc.

    Seen from a surface point, a sphere of uniform radiance is a disc of the same radius
    facing the point (to first order in ``R / d``); the disc is covered by
    ``physics.light_samples`` stratified points, each carrying its share of the light's
    intensity, and the BRDF is evaluated towards every one.

    ``point_m`` and ``view`` are the points and unit directions to the eye, as ``(x, y,
    z)`` component arrays ``(M,)``.
    """
    f32 = np.float32
    centre = np.asarray(light.position_m, dtype=f32)
    offsets = disc_samples(physics.light_samples) * f32(light.radius_m)  # (S, 2)
    px, py, pz = point_m
    wx, wy, wz = centre[0] - px, centre[1] - py, centre[2] - pz
    inv = f32(1.0) / np.sqrt(wx * wx + wy * wy + wz * wz)
    wx, wy, wz = wx * inv, wy * inv, wz * inv
    # A basis (a, b) of the disc, orthogonal to w: a = normalise(w x e) with e the axis w
    # is least aligned with (here y or x; the light is never straight along both).
    use_x = np.abs(wy) > f32(0.9)
    ax = np.where(use_x, f32(0.0), -wz)
    ay = np.where(use_x, wz, f32(0.0))
    az = np.where(use_x, -wy, wx)
    inv = f32(1.0) / np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax * inv, ay * inv, az * inv
    bx, by, bz = wy * az - wz * ay, wz * ax - wx * az, wx * ay - wy * ax
    # Sample positions relative to the points, (M, S) per component.
    u, v = offsets[None, :, 0], offsets[None, :, 1]
    lx = (centre[0] - px)[:, None] + u * ax[:, None] + v * bx[:, None]
    ly = (centre[1] - py)[:, None] + u * ay[:, None] + v * by[:, None]
    lz = (centre[2] - pz)[:, None] + u * az[:, None] + v * bz[:, None]
    dist2 = lx * lx + ly * ly + lz * lz
    dist = np.sqrt(dist2)
    lx, ly, lz = lx / dist, ly / dist, lz / dist
    n = normal.astype(f32)
    cos_l = n[0] * lx + n[1] * ly + n[2] * lz
    vx, vy, vz = (c[:, None] for c in view)
    hx, hy, hz = lx + vx, ly + vy, lz + vz
    half_len = np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), f32(1e-6))
    cos_h = (n[0] * hx + n[1] * hy + n[2] * hz) / half_len
    cos_vh = (vx * hx + vy * hy + vz * hz) / half_len
    above = cos_l > f32(1e-6)
    cos_l_safe = np.where(above, cos_l, f32(1.0))
    cos_v2 = np.broadcast_to(cos_v[:, None], cos_l.shape)
    brdf = specular_brdf(cos_l_safe, cos_v2, cos_h, cos_vh, f32(mat.roughness),
                         lobe=mat.lobe, f0=mat.f0, fresnel=_fresnel(mat, cos_vh, physics),
                         masking=physics.masking)
    irradiance = np.where(above, cos_l_safe / dist2, f32(0.0))
    share = f32(light.intensity / physics.light_samples)
    return share * np.sum(brdf * irradiance, axis=1, dtype=f32)


@dataclass(frozen=True)
class _LightAtPoints:
    """One light as seen from a batch of surface points (all arrays ``(M,)`` float32)."""

    light: Light
    to_light_m: tuple[np.ndarray, np.ndarray, np.ndarray]  # light centre minus the point
    dist_m: np.ndarray
    irradiance: np.ndarray  # intensity * cos_l / d^2 (0 where unlit)
    height_m: float  # the light's height above the plane, n . L - c
    lit: bool  # light and eye both in front of the plane


def _light_at_points(light: Light, surf: TexturedSurface, x: np.ndarray, y: np.ndarray,
                     t: np.ndarray, eye_m: np.ndarray, height_v: float) -> _LightAtPoints:
    """Distances and irradiance of one light at the points ``eye + t (x, y, 1)``."""
    f32 = np.float32
    lpos = np.asarray(light.position_m)
    # Surface point relative to the light's centre, and distance to it: (M,) each.
    to_lx = f32(lpos[0] - eye_m[0]) - t * x
    to_ly = f32(lpos[1] - eye_m[1]) - t * y
    to_lz = f32(lpos[2] - eye_m[2]) - t
    dist2 = to_lx * to_lx + to_ly * to_ly + to_lz * to_lz
    dist = np.sqrt(dist2)
    # n . (L - P) = n . L - c on the plane: the light's height above it.
    height_l = float(surf.normal @ lpos) - surf.offset_m
    if height_l <= 0.0 or height_v <= 0.0:
        irradiance = np.zeros_like(t)
    else:
        irradiance = f32(light.intensity * height_l) / (dist2 * dist)
    return _LightAtPoints(light, (to_lx, to_ly, to_lz), dist, irradiance, height_l,
                          height_l > 0.0 and height_v > 0.0)


def shade_points(
    surf: TexturedSurface,
    ray_x: np.ndarray,
    ray_y: np.ndarray,
    depth_m: np.ndarray,
    eye_m: np.ndarray,
    scene: Scene,
    sample_angle_rad: float = 0.0,
    physics: Physics = _MODEL_PHYSICS,
) -> np.ndarray:
    """Linear radiance ``(M, 3)`` float32 of surface points seen along camera rays.

    The points are ``eye + depth * (ray_x, ray_y, 1)`` (all ``(M,)``). Components are
    kept as separate arrays and the plane's constants folded in (``n . P = c`` on the
    plane), which keeps the per-pixel work to a few dozen element-wise float32 passes.
    Every light of the scene adds its diffuse and specular terms; the ambient term is
    counted once. ``sample_angle_rad`` is the angular spacing of the image samples
    (texture filtering); ``physics`` says which effects are simulated (:class:`Physics`).
    """
    f32 = np.float32
    n = surf.normal
    x = ray_x.astype(f32, copy=False)
    y = ray_y.astype(f32, copy=False)
    t = depth_m.astype(f32, copy=False)
    height_v = float(n @ eye_m) - surf.offset_m
    seen = [_light_at_points(light, surf, x, y, t, eye_m, height_v) for light in scene.lights]
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
    mat = surf.shape.material
    ambient = f32(scene.ambient)
    any_lit = any(s.lit for s in seen)
    if any_lit and (mat.specular > 0.0 or physics.diffuse_transmittance):
        ray_len = np.sqrt(x * x + y * y + f32(1.0))
        cos_v = f32(height_v) / (t * ray_len)
    if physics.diffuse_transmittance and any_lit:
        # A coating lets (1 - F) of the light in and (1 - F) of the scattered light out;
        # ambient light comes from everywhere, so it enters with the hemispherical mean.
        ior = _ior(mat)
        out = f32(1.0) - fresnel_exact(cos_v, ior, mat.extinction).astype(f32)
        ambient = (ambient * f32(1.0 - _hemispherical_fresnel(ior, mat.extinction))) * out[:, None]
    direct = None
    for s in seen:
        color = np.asarray(s.light.color_rgb, dtype=f32)
        term = s.irradiance[:, None] * (color / f32(np.pi))
        if physics.diffuse_transmittance and s.lit:
            into = f32(1.0) - fresnel_exact(f32(s.height_m) / s.dist_m, ior,
                                            mat.extinction).astype(f32)
            term = term * (into * out)[:, None]
        direct = term if direct is None else direct + term
    radiance = albedo * (direct + ambient)
    if mat.specular > 0.0:
        for s in seen:
            if s.lit:
                specular = _specular(surf, s, x, y, t, eye_m, ray_len, cos_v, physics)
                color = np.asarray(s.light.color_rgb, dtype=f32)
                radiance += (f32(mat.specular) * specular)[:, None] * color
    return radiance.astype(f32, copy=False)


def _specular(surf: TexturedSurface, seen: _LightAtPoints, x: np.ndarray, y: np.ndarray,
              t: np.ndarray, eye_m: np.ndarray, ray_len: np.ndarray, cos_v: np.ndarray,
              physics: Physics) -> np.ndarray:
    """Specular radiance ``(M,)`` of one lit light before the material's scale and colour."""
    f32 = np.float32
    mat = surf.shape.material
    light = seen.light
    to_lx, to_ly, to_lz = seen.to_light_m
    dist = seen.dist_m
    cos_l = f32(seen.height_m) / dist
    # l . v with v = -ray / |ray|; then h = (l + v) / |l + v|.
    cos_lv = -(to_lx * x + to_ly * y + to_lz) / (dist * ray_len)
    half_len = np.sqrt(np.maximum(f32(2.0) + f32(2.0) * cos_lv, f32(1e-12)))
    cos_h = (cos_l + cos_v) / half_len
    cos_vh = (cos_lv + f32(1.0)) / half_len
    alpha = widened_roughness(mat.roughness, light.radius_m, dist).astype(f32)
    brdf = specular_brdf(cos_l, cos_v, cos_h, cos_vh, alpha, lobe=mat.lobe, f0=mat.f0,
                         fresnel=_fresnel(mat, cos_vh, physics), masking=physics.masking)
    specular = brdf * seen.irradiance
    if physics.light == "sampled" and light.radius_m > 0.0 and specular.size:
        # The widened lobe says where the highlight is; integrate the light there.
        near = np.flatnonzero(specular > f32(_SAMPLED_LIGHT_MIN) * specular.max())
        view = (-x / ray_len, -y / ray_len, f32(-1.0) / ray_len)
        point = (f32(eye_m[0]) + t * x, f32(eye_m[1]) + t * y, f32(eye_m[2]) + t)
        for start in range(0, near.size, _SAMPLED_BLOCK):
            idx = near[start:start + _SAMPLED_BLOCK]
            specular[idx] = _sampled_specular(
                mat, light, physics, tuple(c[idx] for c in point), surf.normal,
                tuple(c[idx] for c in view), cos_v[idx])
    return specular


def _render_view(
    surfaces: Sequence[TexturedSurface],
    scene: Scene,
    rig: CameraRig,
    camera: int,
    offset_px: tuple[float, float],
    supersample: int = 1,
    physics: Physics = _MODEL_PHYSICS,
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
    depth, index = cast_rays(surfaces, rig, camera, xs, ys)
    sky = scene.ambient * SKY_ALBEDO
    radiance = np.full((h * w, 3), sky, dtype=np.float32)
    eye = rig.centers_m[camera]
    flat_index, flat_depth = index.ravel(), depth.ravel()
    grid_x = np.broadcast_to(xs.astype(np.float32), (h, w)).ravel()
    grid_y = np.repeat(ys.astype(np.float32), w)
    for s, surf in enumerate(surfaces):
        pixels = np.flatnonzero(flat_index == s)
        if pixels.size == 0:
            continue
        radiance[pixels] = shade_points(
            surf, grid_x[pixels], grid_y[pixels], flat_depth[pixels], eye, scene, sample_angle,
            physics)
    return radiance.reshape(h, w, 3), depth, index


@functools.lru_cache(maxsize=1)
def _encode_lut() -> np.ndarray:
    levels = linear_to_srgb(np.linspace(0.0, 1.0, _ENCODE_LUT_SIZE, dtype=np.float32))
    return np.round(levels * 255.0).astype(np.uint8)


def _encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] (values beyond clip) to 8-bit sRGB through a lookup table."""
    idx = (np.clip(linear, 0.0, 1.0) * (_ENCODE_LUT_SIZE - 1) + 0.5).astype(np.int32)
    return _encode_lut()[idx]


def render(
    scene: Scene, rig: CameraRig, *, noise_seed: int | None = None, supersample: int = 1,
    physics: Physics | None = None,
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
    physics : Physics, optional
        Which physical effects to simulate; the default is the refinement's own model
        (:class:`Physics`); ``Physics.faithful()`` switches on everything it does not
        assume.

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
    >>> from srde_fusion.synthetic import Light, PlanarObject
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(64, 48))
    >>> plate = PlanarObject("rectangle", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.3, 0.3))
    >>> out = render(Scene((plate,), Light((0.3, 0.0, 0.0))), rig)
    >>> float(out.disparity_px[24, 32]), int(out.instance_mask[24, 32]), out.views[1].shape
    (10.0, 1, (48, 64, 3))
    """
    if not isinstance(scene, Scene):
        raise SceneError(f"scene: expected a Scene, got {type(scene).__name__}")
    rig = check_rig(rig)
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
    if physics is None:
        physics = _MODEL_PHYSICS
    elif not isinstance(physics, Physics):
        raise SceneError(f"physics: expected a Physics or None, got {type(physics).__name__}")
    surfaces = [object_surface(obj, k + 1) for k, obj in enumerate(scene.objects)]
    if scene.background == "textured":
        surfaces += background_surfaces(scene, rig)
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
            radiance, depth, index = _render_view(surfaces, scene, rig, cam, off, supersample,
                                                  physics)
            total = radiance if total is None else total + radiance
            if cam == rig.reference and supersample == 1:
                ref_depth, ref_index = depth, index
        linear = physics.expose(total * np.float32(scene.exposure / len(offsets)), rng)
        if scene.noise_std > 0:
            linear += np.float32(scene.noise_std) * rng.standard_normal(
                linear.shape, dtype=np.float32
            )
        views.append(_encode(linear))
    if ref_depth is None:
        k = rig.intrinsics
        xs = (np.arange(rig.width) - k.cx) / k.fx
        ys = (np.arange(rig.height) - k.cy) / k.fy
        ref_depth, ref_index = cast_rays(surfaces, rig, rig.reference, xs, ys)
    labels = np.array([s.label for s in surfaces] + [0], dtype=np.int32)
    instance = labels[ref_index]  # index -1 (no hit) picks the trailing 0
    finite = np.isfinite(ref_depth)
    disparity = np.zeros(ref_depth.shape, dtype=np.float32)
    disparity[finite] = rig.intrinsics.fx * rig.baseline_m / ref_depth[finite]
    ref_center = rig.reference_center_m
    planes = tuple(Plane.from_point_normal(o.center_m, o.normal, ref_center) for o in scene.objects)
    virtual = np.array([[p.mirror(np.asarray(light.position_m)) for p in planes]
                        for light in scene.lights])  # (L, K, 3)
    uv = np.stack([rig.project(virtual, camera=i) for i in range(rig.n_cameras)], axis=2)
    return Rendering(
        tuple(views), disparity, ref_depth.astype(np.float32), instance, planes, virtual[0],
        uv[0], virtual, uv, highlights_on_objects(scene, rig),
    )


def highlights_on_objects(scene: Scene, rig: CameraRig) -> np.ndarray:
    """Whether each light's highlight on each object is seen in each view, ``(L, K, N)`` bool.

    The highlight of light ``l`` on object ``k`` in camera ``i`` is where the segment from
    the camera centre to the virtual light (the light mirrored across the plane) crosses
    the plane: it is seen when light and camera are both in front of the object (objects
    are single-sided), the crossing lies inside the outline, and no other object cuts the
    segment before it. The renderer casts no shadows, so none are checked.
    """
    centers = rig.centers_m  # (N, 3)
    out = np.zeros((len(scene.lights), len(scene.objects), len(centers)), dtype=bool)
    for l_idx, light in enumerate(scene.lights):
        light_m = np.asarray(light.position_m)
        for k, obj in enumerate(scene.objects):
            plane = obj.plane
            n, c = plane.n, plane.offset_m
            if float(n @ light_m) - c <= 0.0:
                continue
            virtual = light_m - 2.0 * (float(n @ light_m) - c) * n
            toward = virtual - centers  # (N, 3)
            front = centers @ n - c > 0.0
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (c - centers @ n) / (toward @ n)
            crossing = centers + s[:, None] * toward
            seen = front & np.isfinite(s) & (s > 0.0) & (s < 1.0)
            seen &= obj.contains(crossing)
            for j, other in enumerate(scene.objects):
                if j == k or not seen.any():
                    continue
                # Another object cutting the sight line camera -> highlight hides it.
                o_plane = other.plane
                ray = crossing - centers
                with np.errstate(divide="ignore", invalid="ignore"):
                    s_o = (o_plane.offset_m - centers @ o_plane.n) / (ray @ o_plane.n)
                cut = np.isfinite(s_o) & (s_o > 0.0) & (s_o < 1.0)
                hit = centers + np.where(cut, s_o, 0.0)[:, None] * ray
                seen &= ~(cut & other.contains(hit))
            out[l_idx, k] = seen
    return out
