"""Faceted objects: two or three flat glossy faces that share edges, each with its highlight.

A faceted object is a row of :class:`~srde_fusion.synthetic.scene.PlanarObject` faces,
neighbours sharing an edge in 3-D: a ridge (convex, the edge nearer the cameras than the
faces beside it, like a box seen on an edge) or a valley (concave). Each face is a
scene object of its own, so the renderer needs nothing new: the object's mask is the
union of its faces' instance masks, and each face's ground truth is its own plane and
instance region.

Each face gets a light of its own, placed so that its highlight lies on that face, away
from the face's outline, in the reference view and in at least ``min_views`` views;
further lights (``extra_lights``) land wherever geometry puts them. A face's normal
differs from its neighbour's by ``dihedral_deg``, so a highlight seen on one face is
rarely seen on the other: the mirror direction turns by twice that angle.
Deterministic from a seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import SceneError
from ..geometry import CameraRig
from ..imaging import REC709_LUMA
from .random_scenes import light_visible
from .render import cast_rays, highlights_on_objects, shade_points
from .scene import Light, Material, PlanarObject, Scene, check_range, check_rig
from .surfaces import object_surface

__all__ = [
    "FacetedScene",
    "faceted_scene",
]


@dataclass(frozen=True)
class FacetedScene:
    """A scene whose objects are the faces of one faceted object.

    Attributes
    ----------
    scene : Scene
        ``scene.objects`` are the faces in order along the object (neighbours share an
        edge); ``scene.lights[k]`` is face k's own light for k < the number of faces,
        then the extra lights.
    convex : bool
        Ridge (True) or valley (False).
    dihedral_deg : tuple of float
        Angle between the normals of each pair of neighbouring faces, degrees.
    """

    scene: Scene
    convex: bool
    dihedral_deg: tuple[float, ...]

    @property
    def n_faces(self) -> int:
        """Number of faces."""
        return len(self.scene.objects)


def _rotate(v: np.ndarray, axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotate ``v`` about the unit ``axis`` (Rodrigues)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return v * c + np.cross(axis, v) * s + axis * float(axis @ v) * (1.0 - c)


def _face(points_m: np.ndarray, normal: np.ndarray, material: Material) -> PlanarObject:
    """Build a polygon face through the 3-D points ``(K, 3)`` (a convex polygon in its plane)."""
    center = points_m.mean(axis=0)
    probe = PlanarObject("rectangle", tuple(center), tuple(normal), (1.0, 1.0))
    local = probe.local_coords(points_m)
    size = tuple(float(s) for s in np.ptp(local, axis=0))
    return PlanarObject("polygon", tuple(center), tuple(normal), size, 0.0,
                        tuple(map(tuple, local)), material)


def _mirror_inside(face: PlanarObject, light_m: np.ndarray, rig: CameraRig,
                   margin_m: float) -> np.ndarray:
    """Return whether each view's mirror point of the light lies on the face, ``(N,)`` bool."""
    plane = face.plane
    if float(plane.signed_distance(light_m)) <= 0.0:
        return np.zeros(rig.n_cameras, dtype=bool)
    virtual = plane.mirror(light_m)
    toward = virtual - rig.centers_m
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (plane.offset_m - rig.centers_m @ plane.n) / (toward @ plane.n)
    crossing = rig.centers_m + s[:, None] * toward
    inside = face.inner_distance_m(face.local_coords(crossing)) >= margin_m
    return np.isfinite(s) & (s > 0.0) & (s < 1.0) & inside


def faceted_scene(seed: int, rig: CameraRig, *, n_faces: int = 2, convex: bool = True,
                  dihedral_deg=(15.0, 60.0), extra_lights: int = 0,
                  distance_m=(0.7, 1.2), edge_length_m=(0.16, 0.28),
                  face_width_m=(0.08, 0.14), max_tilt_deg: float = 20.0,
                  roughness=(0.005, 0.03), light_distance_m=(0.5, 1.4),
                  highlight_margin_m: float = 0.02, min_views: int = 3,
                  clip_ratio=(1.5, 4.0), diffuse_level=(0.03, 0.12),
                  noise_std: float = 0.002, max_attempts: int = 2000) -> FacetedScene:
    """Sample a faceted object and its lights, deterministically from ``seed``.

    Parameters
    ----------
    seed : int
    rig : CameraRig
    n_faces : {2, 3}
        Faces in a row; three faces have two parallel edges.
    convex : bool
        Ridge (True) or valley (False) at every edge.
    dihedral_deg : float or (float, float)
        Angle between neighbouring faces' normals, degrees, fixed or uniform in a range.
    extra_lights : int
        Lights beyond one per face, 0.1-0.4 m from a face's light, unseen by the cameras.
    distance_m : (float, float)
        Depth range of the (middle) edge's midpoint, metres.
    edge_length_m, face_width_m : (float, float)
        Length of the shared edges and width of each face across them, metres.
    max_tilt_deg : float
        Largest angle between the unfolded object's normal and the direction to the
        reference camera.
    roughness, clip_ratio, diffuse_level : float or (float, float)
        As :class:`~srde_fusion.synthetic.RandomSceneConfig` (one material for every
        face; each face's specular scale puts its own highlight at ``clip_ratio``).
    light_distance_m : (float, float)
        Distance from a face's highlight point to its light, metres.
    highlight_margin_m : float
        Smallest distance from a face's own highlight point to the face's outline.
    min_views : int
        Views (the reference among them) in which each face's own highlight must lie on it.
    noise_std : float
    max_attempts : int

    Returns
    -------
    FacetedScene

    Raises
    ------
    SceneError
        Invalid options, or no valid object found in ``max_attempts`` tries.
    """
    rig = check_rig(rig)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError(f"seed: expected a non-negative integer, got {seed!r}")
    if n_faces not in (2, 3) or isinstance(n_faces, bool):
        raise SceneError(f"n_faces: expected 2 or 3, got {n_faces!r}")
    if not isinstance(convex, bool):
        raise SceneError(f"convex: expected a bool, got {convex!r}")
    if isinstance(extra_lights, bool) or not isinstance(extra_lights, (int, np.integer)) \
            or not 0 <= extra_lights <= 4:
        raise SceneError(f"extra_lights: expected an integer in [0, 4], got {extra_lights!r}")
    if isinstance(min_views, bool) or not isinstance(min_views, (int, np.integer)) \
            or not 1 <= min_views <= rig.n_cameras:
        raise SceneError(f"min_views: expected an integer in [1, {rig.n_cameras}], got "
                         f"{min_views!r}")
    dihedral = check_range(dihedral_deg, "dihedral_deg", low=0.0, high=90.0)
    dist = check_range(distance_m, "distance_m", low=0.0)
    edge_len = check_range(edge_length_m, "edge_length_m", low=0.0)
    width = check_range(face_width_m, "face_width_m", low=0.0)
    rough = check_range(roughness, "roughness", low=0.0, high=1.0)
    light_dist = check_range(light_distance_m, "light_distance_m", low=0.0)
    clip = check_range(clip_ratio, "clip_ratio", low=0.0)
    level = check_range(diffuse_level, "diffuse_level", low=0.0, high=1.0)
    rng = np.random.default_rng([int(seed), 17])
    k = rig.intrinsics
    w_px, h_px = rig.image_size
    xs = (np.arange(w_px) - k.cx) / k.fx
    ys = (np.arange(h_px) - k.cy) / k.fy
    for _ in range(max_attempts):
        built = _sample_faces(rng, rig, n_faces, convex, dihedral, dist, edge_len, width,
                              max_tilt_deg, rough)
        if built is None:
            continue
        faces, angles = built
        if not _in_view(faces, rig):
            continue
        surfaces = [object_surface(f, i + 1) for i, f in enumerate(faces)]
        _, index = cast_rays(surfaces, rig, rig.reference, xs, ys)
        # Every face shows a fair part of itself in the reference view.
        if any(np.count_nonzero(index == i) < 400 for i in range(n_faces)):
            continue
        lights = []
        for face in faces:
            light = _own_light(rng, face, rig, light_dist, highlight_margin_m, min_views)
            if light is None:
                break
            lights.append(light)
        if len(lights) < n_faces:
            continue
        extra = _extra_lights(rng, rig, lights, extra_lights)
        if extra is None:
            continue
        lights += extra
        scene = Scene(tuple(faces), lights=tuple(lights), ambient=0.02, noise_std=noise_std)
        seen = highlights_on_objects(scene, rig)
        if any(not seen[f, f, rig.reference] or seen[f, f].sum() < min_views
               for f in range(n_faces)):
            continue  # a face hides another's highlight
        return FacetedScene(_exposed(rng, scene, rig, level, clip), convex, angles)
    raise SceneError(f"faceted_scene: expected a valid object in {max_attempts} attempts, got "
                     "none; widen face_width_m or dihedral_deg, or lower highlight_margin_m")


def _sample_faces(rng, rig: CameraRig, n_faces: int, convex: bool, dihedral, dist, edge_len,
                  width, max_tilt_deg: float, rough):
    """Draw faces in a row sharing edges, or None if the draw is implausible."""
    uv = rng.uniform([0.35 * rig.width, 0.35 * rig.height], [0.65 * rig.width, 0.65 * rig.height])
    middle = rig.backproject(uv, rng.uniform(*dist))
    to_cam = rig.reference_center_m - middle
    to_cam /= np.linalg.norm(to_cam)
    tilt = rng.normal(size=3)
    tilt -= (tilt @ to_cam) * to_cam
    tilt /= np.linalg.norm(tilt)
    n0 = _rotate(to_cam, tilt, math.radians(rng.uniform(0.0, max_tilt_deg)))
    d = rng.normal(size=3)
    d -= (d @ n0) * n0
    d /= np.linalg.norm(d)
    s = np.cross(n0, d)
    length = rng.uniform(*edge_len)
    material = Material(diffuse_rgb=tuple(rng.uniform(0.15, 0.6, size=3)), specular=1.0,
                        roughness=rng.uniform(*rough), f0=rng.uniform(0.03, 0.06))
    widths = rng.uniform(*width, size=n_faces)
    angles = tuple(float(rng.uniform(*dihedral)) for _ in range(n_faces - 1))

    def strip(edge_mid: np.ndarray, out: np.ndarray, w: float) -> np.ndarray:
        # A trapezoid from the shared edge outwards: the far side 70-100 % as long.
        far = length * rng.uniform(0.7, 1.0) / 2.0
        shift = rng.uniform(-0.1, 0.1) * length
        return np.array([edge_mid - length / 2 * d, edge_mid + length / 2 * d,
                         edge_mid + w * out + (far + shift) * d,
                         edge_mid + w * out + (-far + shift) * d])

    def fold_sign(base_n: np.ndarray, out: np.ndarray, angle: float) -> float:
        # The turn about the edge that makes the fold a ridge (the part beyond the edge
        # behind the base face's plane) or a valley.
        turned = _rotate(out, d, math.radians(angle))
        return 1.0 if (float(turned @ base_n) < 0.0) == convex else -1.0

    def turn(v: np.ndarray, angle: float) -> np.ndarray:
        return _rotate(v, d, math.radians(angle))

    if n_faces == 2:
        # Each face turns by half the angle about the edge through the middle point.
        half = angles[0] / 2.0
        sign = fold_sign(n0, s, half)
        n_a, out_a = turn(n0, sign * half), turn(s, sign * half)
        n_b, out_b = turn(n0, -sign * half), turn(-s, -sign * half)
        pieces = [(strip(middle, out_a, widths[0]), n_a), (strip(middle, out_b, widths[1]), n_b)]
    else:
        # The middle face keeps n0; the sides turn about its two edges.
        half_w = widths[1] / 2.0
        edge_a, edge_c = middle + half_w * s, middle - half_w * s
        sign_a, sign_c = fold_sign(n0, s, angles[0]), fold_sign(n0, -s, angles[1])
        middle_face = np.array([edge_a - length / 2 * d, edge_a + length / 2 * d,
                                edge_c + length / 2 * d, edge_c - length / 2 * d])
        pieces = [(strip(edge_a, turn(s, sign_a * angles[0]), widths[0]),
                   turn(n0, sign_a * angles[0])),
                  (middle_face, n0),
                  (strip(edge_c, turn(-s, sign_c * angles[1]), widths[2]),
                   turn(n0, sign_c * angles[1]))]
    faces = []
    for points, normal in pieces:
        # Every camera must see the face's front (objects are single-sided).
        if np.any((rig.centers_m - points.mean(axis=0)) @ normal <= 0.0):
            return None
        cosines = ((rig.centers_m - points.mean(axis=0)) @ normal
                   / np.linalg.norm(rig.centers_m - points.mean(axis=0), axis=1))
        if np.any(cosines < math.cos(math.radians(75.0))):
            return None
        try:
            faces.append(_face(points, normal, material))
        except SceneError:
            return None
    return faces, angles


def _in_view(faces, rig: CameraRig) -> bool:
    """Whether every camera sees every face whole, a little inside the image."""
    k = rig.intrinsics
    for face in faces:
        corners = face.to_world(face.outline_local())
        for cam in range(rig.n_cameras):
            rel = corners - rig.centers_m[cam]
            if rel[:, 2].min() <= 0.05:
                return False
            u = k.fx * rel[:, 0] / rel[:, 2] + k.cx
            v = k.fy * rel[:, 1] / rel[:, 2] + k.cy
            if u.min() < 2 or v.min() < 2 or u.max() > rig.width - 3 or v.max() > rig.height - 3:
                return False
    return True


def _own_light(rng, face: PlanarObject, rig: CameraRig, light_dist, margin_m: float,
               min_views: int) -> Light | None:
    """Draw a light whose highlight lies on ``face`` in the reference and ``min_views`` views."""
    outline = face.outline_local()
    for _ in range(30):
        # A point well inside the face, seen by the array as a mirror of the light.
        weights = rng.dirichlet(np.ones(len(outline)))
        point = face.to_world(0.4 * (weights @ outline) + 0.6 * outline.mean(axis=0))
        n = np.asarray(face.normal)
        to_array = rig.centers_m.mean(axis=0) - point
        to_array /= np.linalg.norm(to_array)
        mirror = 2.0 * float(to_array @ n) * n - to_array
        position = point + rng.uniform(*light_dist) * mirror
        radius = rng.uniform(0.002, 0.008)
        if light_visible(position, radius, rig) \
                or np.min(np.linalg.norm(rig.centers_m - position, axis=1)) < 0.1:
            continue
        inside = _mirror_inside(face, position, rig, margin_m)
        if inside[rig.reference] and inside.sum() >= min_views:
            tint = rng.uniform(0.8, 1.0, size=3)
            return Light(tuple(position), radius, tuple(tint / tint.max()),
                         rng.uniform(0.7, 1.5))
    return None


def _extra_lights(rng, rig: CameraRig, lights: list[Light], count: int) -> list[Light] | None:
    """Draw further lights near the faces' lights, unseen by the cameras and apart from them."""
    extra: list[Light] = []
    for _ in range(count):
        for _ in range(200):
            base = np.asarray(lights[int(rng.integers(len(lights)))].position_m)
            direction = rng.normal(size=3)
            position = base + rng.uniform(0.1, 0.4) * direction / np.linalg.norm(direction)
            radius = rng.uniform(0.002, 0.008)
            if light_visible(position, radius, rig) \
                    or np.min(np.linalg.norm(rig.centers_m - position, axis=1)) < 0.1 \
                    or min(np.linalg.norm(np.asarray(x.position_m) - position)
                           for x in lights + extra) < 0.1:
                continue
            tint = rng.uniform(0.8, 1.0, size=3)
            extra.append(Light(tuple(position), radius, tuple(tint / tint.max()),
                               rng.uniform(0.7, 1.5)))
            break
        else:
            return None
    return extra


def _exposed(rng, scene: Scene, rig: CameraRig, level, clip) -> Scene:
    """Set the exposure (diffuse at ``level``) and each face's specular scale (``clip``)."""
    eye = rig.reference_center_m
    albedo = float(np.dot(scene.objects[0].material.diffuse_rgb, REC709_LUMA))
    direct = 0.0
    for face in scene.objects:
        point = np.asarray(face.center_m)
        for light in scene.lights:
            to_light = np.asarray(light.position_m) - point
            dist2 = float(to_light @ to_light)
            cos_l = max(0.0, float(to_light @ np.asarray(face.normal)) / math.sqrt(dist2))
            direct += (albedo / math.pi * light.intensity * cos_l / dist2
                       * float(np.dot(light.color_rgb, REC709_LUMA)))
    direct /= len(scene.objects)
    exposure = rng.uniform(*level) / (direct + scene.ambient * albedo)
    ratio = rng.uniform(*clip)
    faces = []
    for i, face in enumerate(scene.objects):
        light = scene.lights[i]
        # The face's own highlight core at `ratio` times the clipping level, in the
        # reference view (the same scale for the other lights it reflects).
        virtual = face.plane.mirror(np.asarray(light.position_m))
        toward = virtual - eye
        t = (face.plane.offset_m - float(eye @ face.plane.n)) / float(toward @ face.plane.n)
        rel = t * toward
        black = replace(face, material=replace(face.material, diffuse_rgb=(0.0, 0.0, 0.0)))
        radiance = shade_points(object_surface(black, 1), np.array([rel[0] / rel[2]]),
                                np.array([rel[1] / rel[2]]), np.array([rel[2]]), eye,
                                Scene((black,), light, ambient=0.0))
        peak = float(radiance[0] @ REC709_LUMA) * exposure
        faces.append(replace(face, material=replace(face.material,
                                                    specular=float(ratio / peak))))
    return replace(scene, objects=tuple(faces), exposure=float(exposure))
