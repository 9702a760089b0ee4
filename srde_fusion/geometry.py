"""Plane geometry of SRDE: mirror images, planes from light pairs, ray casting.

All points are in the array frame (DESIGN §2), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Plane",
    "mirror_point",
    "plane_from_lights",
    "plane_depth",
    "plane_disparity",
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
        """The plane through ``point_m`` with normal ``normal``, oriented towards ``towards_m``.

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
        """Angle between the two normals, degrees."""
        c = float(np.clip(abs(np.dot(self.n, other.n)), -1.0, 1.0))
        return float(np.degrees(np.arccos(c)))


def mirror_point(point_m, plane: Plane) -> np.ndarray:
    """Mirror image of a point across a plane (the virtual light of a light)."""
    return plane.mirror(point_m)


def plane_from_lights(light_m, virtual_light_m, towards_m=(0.0, 0.0, 0.0)) -> Plane:
    """The mirror plane between a light and its virtual image.

    The normal is along ``V - L`` and the plane passes through ``(V + L) / 2``
    (paper, Methods: plane from real and virtual light).
    """
    light_m = np.asarray(light_m, dtype=np.float64)
    virtual_light_m = np.asarray(virtual_light_m, dtype=np.float64)
    return Plane.from_point_normal((light_m + virtual_light_m) / 2.0, virtual_light_m - light_m,
                                   towards_m)


def plane_depth(plane: Plane, rig, uv=None) -> np.ndarray:
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
    """
    k = rig.intrinsics
    n = plane.n
    num = plane.offset_m - float(np.dot(n, rig.reference_center_m))
    if uv is None:
        w, h = rig.image_size
        u = (np.arange(w, dtype=np.float64) - k.cx) / k.fx
        v = (np.arange(h, dtype=np.float64) - k.cy) / k.fy
        denom = n[0] * u[None, :] + n[1] * v[:, None] + n[2]
    else:
        denom = rig.rays(uv) @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = num / denom
    return np.where(np.isfinite(z) & (z > 0), z, np.nan)


def plane_disparity(plane: Plane, rig, uv=None) -> np.ndarray:
    """Stereo-pair disparity (pixels) of the plane at the reference pixels, ``fx B / z``."""
    return rig.depth_to_disparity(plane_depth(plane, rig, uv))
