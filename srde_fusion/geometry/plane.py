"""Plane geometry of SRDE: mirror images, planes from light pairs, ray casting.

All points are in the array frame (DESIGN §2), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SRDEError

__all__ = [
    "Plane",
    "mirror_point",
    "plane_from_lights",
    "plane_depth",
    "plane_disparity",
    "incidence_angle_deg",
]


@dataclass(frozen=True)
class Plane:
    """A plane ``n · X = c`` with unit normal ``n`` oriented towards the cameras.

    Parameters
    ----------
    normal : (3,) float64
        Unit normal, oriented so that ``n · (C_ref - X) > 0`` for points X on the plane.
    offset_m : float
        ``c`` in ``n · X = c``, metres.
    """

    normal: tuple[float, float, float]
    offset_m: float

    @classmethod
    def from_point_normal(cls, point_m, normal, towards_m=(0.0, 0.0, 0.0)) -> Plane:
        """Build the plane through ``point_m`` with normal ``normal``, facing ``towards_m``.

        Examples
        --------
        >>> p = Plane.from_point_normal([0, 0, 2.0], [0, 0, 1.0])
        >>> p.normal, p.offset_m
        ((0.0, 0.0, -1.0), -2.0)
        """
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        x = np.asarray(point_m, dtype=np.float64)
        if np.dot(n, np.asarray(towards_m, dtype=np.float64) - x) < 0:
            n = -n
        # "+ 0.0" turns -0.0 into 0.0 so printed normals read cleanly.
        return cls(tuple(float(v) + 0.0 for v in n), float(np.dot(n, x)))

    @property
    def n(self) -> np.ndarray:
        """The unit normal as an array ``(3,)``."""
        return np.asarray(self.normal, dtype=np.float64)

    def signed_distance(self, points_m) -> np.ndarray:
        """Signed distance ``n · X - c`` (positive on the cameras' side), metres."""
        return np.asarray(points_m, dtype=np.float64) @ self.n - self.offset_m

    def mirror(self, points_m) -> np.ndarray:
        """Mirror image of points across the plane."""
        p = np.asarray(points_m, dtype=np.float64)
        return p - 2.0 * self.signed_distance(p)[..., None] * self.n

    def angle_to(self, other: Plane) -> float:
        """Angle between the two normals (ignoring orientation), degrees."""
        # atan2 of sine and cosine stays accurate for tiny angles, where arccos does not.
        sine = float(np.linalg.norm(np.cross(self.n, other.n)))
        return float(np.degrees(np.arctan2(sine, abs(float(np.dot(self.n, other.n))))))


def mirror_point(point_m, plane: Plane) -> np.ndarray:
    """Mirror image of a point across a plane (the virtual light of a light)."""
    return plane.mirror(point_m)


def plane_from_lights(light_m, virtual_light_m, towards_m=(0.0, 0.0, 0.0)) -> Plane:
    """Return the mirror plane between a light and its virtual image.

    The normal is along ``V - L`` and the plane passes through ``(V + L) / 2``
    (paper, Methods: plane from real and virtual light).
    """
    light_m = np.asarray(light_m, dtype=np.float64)
    virtual_light_m = np.asarray(virtual_light_m, dtype=np.float64)
    return Plane.from_point_normal((light_m + virtual_light_m) / 2.0, virtual_light_m - light_m,
                                   towards_m)


def _grid_rays(rig, window) -> tuple[np.ndarray, np.ndarray]:
    """Normalised ray coordinates ``x (W',)`` and ``y (H',)`` of a pixel window's grid.

    The rays of a grid are separable, ``k = (x[u], y[v], 1)``: working on the two axes
    and broadcasting costs far less than a ray per pixel.
    """
    k = rig.intrinsics
    w, h = rig.image_size
    u0, v0, u1, v1 = (0, 0, w, h) if window is None else window
    x = (np.arange(u0, u1, dtype=np.float64) - k.cx) / k.fx
    y = (np.arange(v0, v1, dtype=np.float64) - k.cy) / k.fy
    return x, y


def _check_window(uv, window) -> None:
    if window is not None and uv is not None:
        raise SRDEError("window: expected either uv or window, got both")


def plane_depth(plane: Plane, rig, uv=None, *, window=None) -> np.ndarray:
    """Depth (z, metres, from the reference camera) where pixel rays hit the plane.

    ``z = n · (s - C_ref) / (n · k)`` with ``k = ((u - cx)/fx, (v - cy)/fy, 1)``
    (paper eq. for ray-plane intersection). Rays parallel to the plane or hitting it
    behind the camera give NaN.

    Parameters
    ----------
    plane : Plane
    rig : CameraRig
    uv : array_like (..., 2), optional
        Pixels; the full reference image grid ``(H, W)`` by default.
    window : (int, int, int, int), optional
        ``(u0, v0, u1, v1)``, inclusive-exclusive: the grid of this pixel window
        instead, ``(v1 - v0, u1 - u0)`` (e.g. an object's bounding box). Not with ``uv``.
    """
    _check_window(uv, window)
    n = plane.n
    num = plane.offset_m - float(np.dot(n, rig.reference_center_m))
    if uv is None:
        u, v = _grid_rays(rig, window)
        denom = n[0] * u[None, :] + n[1] * v[:, None] + n[2]
    else:
        denom = rig.rays(uv) @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = num / denom
    return np.where(np.isfinite(z) & (z > 0), z, np.nan)


def plane_disparity(plane: Plane, rig, uv=None, *, window=None) -> np.ndarray:
    """Stereo-pair disparity (pixels) of the plane at the reference pixels, ``fx B / z``.

    ``uv`` and ``window`` as in :func:`plane_depth`.
    """
    return rig.depth_to_disparity(plane_depth(plane, rig, uv, window=window))


def incidence_angle_deg(plane: Plane, rig, uv=None, *, window=None) -> np.ndarray:
    """Angle between reference-camera pixel rays and the plane's normal, degrees.

    Measured against the normal flipped to face the ray, so 0 is a ray hitting the plane
    head-on, 90 a ray parallel to it (grazing), and above 90 a ray that meets the plane
    only behind the camera. Near 90 the depth ``z = n · (s - C_ref) / (n · k)`` is
    ill-conditioned: a small error in the normal moves the intersection far along the ray.

    Parameters
    ----------
    plane : Plane
        Oriented towards the cameras (as every Plane of this library is).
    rig : CameraRig
    uv : array_like (..., 2), optional
        Pixels; the full reference image grid ``(H, W)`` by default.
    window : (int, int, int, int), optional
        ``(u0, v0, u1, v1)``: the grid of this pixel window instead (see
        :func:`plane_depth`).

    Returns
    -------
    numpy.ndarray, (...), (H, W) or (v1 - v0, u1 - u0), float64
        Angles in [0, 180].

    Examples
    --------
    >>> from srde_fusion.geometry.rig import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=500.0, image_size=(64, 48))
    >>> plane = Plane.from_point_normal([0, 0, 1.0], [0, 0, 1.0])
    >>> float(incidence_angle_deg(plane, rig, [[rig.intrinsics.cx, rig.intrinsics.cy]])[0])
    0.0
    """
    _check_window(uv, window)
    n = plane.n
    if uv is None:
        x, y = _grid_rays(rig, window)
        dot = n[0] * x[None, :] + n[1] * y[:, None] + n[2]
        length = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1.0)
    else:
        rays = rig.rays(uv)
        dot, length = rays @ n, np.linalg.norm(rays, axis=-1)
    # The normal faces the cameras, so a ray that meets the plane in front has k · n < 0.
    cos = -dot / length
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
