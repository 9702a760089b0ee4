"""A spherical light of known radius: the lobe averaged over the light's disc.

Seen from a point of the surface, a sphere of radius ``R`` at distance ``r`` is a disc of
angular radius ``asin(R / r)``. The radiance it sends to the camera is the point
light's with the BRDF averaged over the disc's directions::

    Y = I cos(theta_i) / r^2 * mean over the disc of f(omega_i)

The lobe ``S`` is a function of the half vector, and a disc of light directions spreads
the half vector over a disc of angular radius ``b = asin(R / r) / 2`` around the light
centre's (in the plane of incidence; across it the disc is longer by ``1 / cos`` of
half the angle between light and eye, at most a few per cent here, which the model
leaves out). So under a sphere the model's lobe is ``S`` averaged over a disc of radius
``b``: flat-topped over the light's mirror image when the disc is wider than the lobe,
a slightly wider lobe when it is narrower. Neither is a member of the fitted lobe
family, whose width would otherwise absorb the light's extent.

The average is taken in the tangent plane of the half vector, where a small disc is
flat: with ``s = sin(theta_h)`` the light centre's half-vector offset from the normal
and ``b xi`` a point of the disc (``xi`` in the unit disc), the lobe's argument is
``sin^2 = (s - b xi_x)^2 + (b xi_y)^2``. The points ``xi`` are a fixed hexagonal
pattern of :data:`DISC_RINGS` rings (1 + 6 + 12 = 19 points, at equal-area radii, scaled
so that their mean ``|xi|^2`` is the disc's, 1/2), of which only the 12 with
``xi_y >= 0`` are evaluated: the pattern is symmetric about the ``x`` axis, along
which the offset ``s`` lies. This needs one lobe evaluation per point, not a
reflection geometry per point (sub-lights would), and no point spacing wider than the
lobe on the lights and lobes met in practice: against a fine numerical average, the
largest error is below 1 % of the peak while the disc's radius is at most 1.2 lobe
half-widths, about 4 % at 2 (the point model: 50 % at 1).

At ``b = 0`` every point is the centre and the lobe is the point model's; the
refinement keeps the point model's own code for a point light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DISC_RINGS", "DiscGeometry", "disc_geometry", "disc_points"]

#: Rings of the hexagonal pattern of points over the light's disc (see the module notes).
DISC_RINGS = 2


# s = sin(theta_h) is kept above this: the slopes divide by it (see disc_geometry).
_MIN_SIN_H = 1e-9


def disc_points(rings: int = DISC_RINGS) -> tuple[np.ndarray, np.ndarray]:
    """Return points of the unit disc with ``y >= 0`` ``(K, 2)`` and their weights ``(K,)``.

    The hexagonal pattern of ``rings`` rings (ring ``k`` holds ``6 k`` points) at radii
    that split the disc into equal areas, scaled so that the mean of ``|xi|^2`` is 1/2
    (the disc's); points below the ``x`` axis are folded onto their mirror images,
    whose weight doubles. The weights sum to 1.
    """
    counts = [1] + [6 * k for k in range(1, rings + 1)]
    n = sum(counts)
    xy, weight = [np.zeros(2)], [1.0]
    first = 1
    for k in range(1, rings + 1):
        # the ring sits at the radius halving the area between its neighbours' edges
        radius = math.sqrt((first + 0.5 * counts[k]) / n)
        first += counts[k]
        for j in range(3 * k + 1):  # angles 0 .. pi of the 6 k points
            angle = math.pi * j / (3 * k)
            xy.append(radius * np.array([math.cos(angle), math.sin(angle)]))
            weight.append(1.0 if j in (0, 3 * k) else 2.0)
    points, weights = np.array(xy), np.array(weight) / n
    mean_r2 = float(weights @ np.sum(points ** 2, axis=1))
    return points * math.sqrt(0.5 / mean_r2), weights


@dataclass(frozen=True)
class DiscGeometry:
    """The lobe's arguments at the disc's points, for one plane.

    ``sin2`` ``(K, P)`` is ``sin^2`` of the half-vector angle at each point of the
    disc (``K`` points, ``P`` samples) and ``weights`` ``(K, 1)`` their quadrature
    weights; ``sin2_by_cos_h`` and ``sin2_by_r`` its derivatives by the light centre's
    ``cos(theta_h)`` and by the distance ``r`` to the light (metres). ``shapes`` keeps
    the last lobe evaluated at the points (its key and ``(K, P)`` values): a step's
    slopes are taken where the step was evaluated.
    """

    sin2: np.ndarray
    weights: np.ndarray
    sin2_by_cos_h: np.ndarray
    sin2_by_r: np.ndarray
    shapes: dict = field(default_factory=dict, compare=False, repr=False)


def disc_geometry(cos_h: np.ndarray, sin2_h: np.ndarray, r: np.ndarray,
                  radius_m: float) -> DiscGeometry:
    """Return the disc's geometry for the light centre's half vectors ``(P,)``.

    Parameters
    ----------
    cos_h, sin2_h : numpy.ndarray, (P,)
        ``cos`` and ``sin^2`` of the angle between the normal and the half vector of the
        light's centre.
    r : numpy.ndarray, (P,)
        Distance from each surface point to the light's centre, metres.
    radius_m : float
        The light's radius, metres, > 0.
    """
    points, weights = disc_points(DISC_RINGS)
    xi_x, xi_y = points[:, :1], points[:, 1:]  # (K, 1)
    s = np.maximum(np.sqrt(sin2_h), _MIN_SIN_H)
    ratio = np.minimum(radius_m / r, 1.0)
    b = 0.5 * np.arcsin(ratio)
    # db/dr = -(R / r^2) / (2 sqrt(1 - (R / r)^2)); inside the sphere (ratio 1) it is flat
    b_by_r = np.zeros_like(r)
    outside = ratio < 1.0
    b_by_r[outside] = (-0.5 * ratio[outside] / r[outside]
                       / np.sqrt(1.0 - ratio[outside] ** 2))
    along = s - b * xi_x  # (K, P)
    across = b * xi_y
    sin2 = along * along + across * across
    # ds / d cos_h = -cos_h / s: the pattern is symmetric in xi_x, so the weighted sum of
    # these slopes stays finite as s -> 0
    sin2_by_cos_h = along * (-2.0 * cos_h / s)
    sin2_by_b = across * xi_y
    sin2_by_b -= along * xi_x
    sin2_by_b *= 2.0
    return DiscGeometry(sin2, weights[:, None], sin2_by_cos_h, sin2_by_b * b_by_r)
