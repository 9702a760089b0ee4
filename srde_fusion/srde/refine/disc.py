"""A spherical light of known radius: the lobe averaged over the light's disc.

Seen from a point of the surface, a sphere of radius ``R`` at distance ``r`` is a disc of
angular radius ``asin(R / r)``. The radiance it sends to the camera is the point
light's with the BRDF averaged over the disc's directions::

    Y = I cos(theta_i) / r^2 * mean over the disc of f(omega_i)

The lobe ``S`` is a function of the half vector ``h = (l + v) / |l + v|``, and a disc of
light directions ``l`` spreads the half vector over an ellipse around the light
centre's: a tilt ``dl`` moves ``h`` by ``dl / 2`` within the plane of incidence (the
plane of ``l`` and ``v``) and by ``dl / (2 cos(theta_d))`` across it, ``theta_d`` being
half the angle between light and eye. So under a sphere the model's lobe is ``S``
averaged over an ellipse of semi-axes ``b = asin(R / r) / 2`` in the plane of incidence
and ``b / cos(theta_d)`` across it: flat-topped over the light's mirror image when the
ellipse is wider than the lobe, a slightly wider and longer lobe when it is narrower.
Neither is a member of the fitted lobe family, whose width would otherwise absorb the
light's extent. (The elongation matters: with a light off to the side, ``theta_d`` is
30-45 degrees, the ellipse 15-40 % longer across, and in a different direction in each
camera; a round disc left a stereo plane 0.1 px off where the lobe's own width is 2.5
times the disc's.)

The average is taken in the tangent plane of the half vector, where a small ellipse is
flat: with ``s = sin(theta_h)`` the light centre's half-vector offset from the normal
(along ``x``) and ``b z`` a point of the ellipse (``z`` in the unit ellipse: the unit
disc stretched by ``1 / cos(theta_d)`` across the plane of incidence, turned by that
plane's angle to ``x``), the lobe's argument is ``sin^2 = (s - b z_x)^2 + (b z_y)^2``.
The points are a fixed hexagonal pattern over the unit disc of :data:`DISC_RINGS`
rings (1 + 6 + 12 = 19 points, at equal-area radii, scaled so that their mean
``|xi|^2`` is the disc's, 1/2), stretched and turned per sample. The angle needs no
vector per sample: the normal's component across the plane of incidence follows from
the three cosines between normal, light and eye (the Gram determinant). This needs one
lobe evaluation per point, not a reflection geometry per point (sub-lights would), and
no point spacing wider than the lobe on the lights and lobes met in practice: against a
fine numerical average, the largest error is below 1 % of the peak while the disc's
radius is at most 1.2 lobe half-widths, about 4 % at 2 (the point model: 50 % at 1).

The slopes follow ``s`` and ``b`` (the plane's tilt and the distance to the light)
and the ellipse's stretch and turn (through the three cosines), all analytic.

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
    """Return points of the unit disc ``(K, 2)`` and their weights ``(K,)``.

    The hexagonal pattern of ``rings`` rings (ring ``k`` holds ``6 k`` points) at radii
    that split the disc into equal areas, scaled so that the mean of ``|xi|^2`` is 1/2
    (the disc's). The pattern is symmetric about both axes; the weights are equal and
    sum to 1.
    """
    counts = [1] + [6 * k for k in range(1, rings + 1)]
    n = sum(counts)
    xy = [np.zeros(2)]
    first = 1
    for k in range(1, rings + 1):
        # the ring sits at the radius halving the area between its neighbours' edges
        radius = math.sqrt((first + 0.5 * counts[k]) / n)
        first += counts[k]
        for j in range(6 * k):
            angle = math.pi * j / (3 * k)
            xy.append(radius * np.array([math.cos(angle), math.sin(angle)]))
    points = np.array(xy)
    mean_r2 = float(np.mean(np.sum(points ** 2, axis=1)))
    return points * math.sqrt(0.5 / mean_r2), np.full(n, 1.0 / n)


#: Largest stretch of the half-vector ellipse across the plane of incidence (``1 /
#: cos(theta_d)``; 10 at 84 degrees, past which light and eye are nearly opposite).
MAX_ELONGATION = 10.0


@dataclass(frozen=True)
class DiscGeometry:
    """The lobe's arguments at the disc's points, for one plane.

    ``sin2`` ``(K, P)`` is ``sin^2`` of the half-vector angle at each point of the
    disc (``K`` points, ``P`` samples) and ``weights`` ``(K, 1)`` their quadrature
    weights; ``sin2_by_cos_h`` and ``sin2_by_r`` its derivatives by the light centre's
    ``cos(theta_h)`` and by the distance ``r`` to the light (metres). Under an ellipse
    (the cosines given), ``sin2_by_cosines`` ``(3, K, P)`` holds its derivatives by
    ``cos_i``, ``cos_o`` and ``cos_io`` through the ellipse's stretch and turn (each
    with the others and ``cos_h`` held); None for a round disc. ``shapes`` keeps the
    last lobe evaluated at the points (its key and ``(K, P)`` values): a step's slopes
    are taken where the step was evaluated.
    """

    sin2: np.ndarray
    weights: np.ndarray
    sin2_by_cos_h: np.ndarray
    sin2_by_r: np.ndarray
    sin2_by_cosines: np.ndarray | None = None
    shapes: dict = field(default_factory=dict, compare=False, repr=False)


def disc_geometry(cos_h: np.ndarray, sin2_h: np.ndarray, r: np.ndarray, radius_m: float,
                  *, cos_i: np.ndarray | None = None, cos_o: np.ndarray | None = None,
                  cos_io: np.ndarray | None = None) -> DiscGeometry:
    """Return the light's geometry for the light centre's half vectors ``(P,)``.

    Parameters
    ----------
    cos_h, sin2_h : numpy.ndarray, (P,)
        ``cos`` and ``sin^2`` of the angle between the normal and the half vector of the
        light's centre.
    r : numpy.ndarray, (P,)
        Distance from each surface point to the light's centre, metres.
    radius_m : float
        The light's radius, metres, > 0.
    cos_i, cos_o, cos_io : numpy.ndarray, (P,), optional
        Cosines between normal and light, normal and eye, light and eye: they stretch
        and turn the half-vector disc into its ellipse (module notes). Without them the
        disc stays round.
    """
    points, weights = disc_points(DISC_RINGS)
    xi_1, xi_2 = points[:, :1], points[:, 1:]  # (K, 1): in and across the plane of incidence
    s = np.maximum(np.sqrt(sin2_h), _MIN_SIN_H)
    ratio = np.minimum(radius_m / r, 1.0)
    b = 0.5 * np.arcsin(ratio)
    # db/dr = -(R / r^2) / (2 sqrt(1 - (R / r)^2)); inside the sphere (ratio 1) it is flat
    b_by_r = np.zeros_like(r)
    outside = ratio < 1.0
    b_by_r[outside] = (-0.5 * ratio[outside] / r[outside]
                       / np.sqrt(1.0 - ratio[outside] ** 2))
    if cos_io is None:
        z_x, z_y = xi_1, xi_2  # a round disc
    else:
        # Stretch across the plane of incidence: 1 / cos(theta_d), with cos(theta_d)^2 =
        # (1 + l . v) / 2.
        half_sum = np.maximum(0.5 * (1.0 + cos_io), 1e-300)
        stretch = 1.0 / np.sqrt(half_sum)
        capped = stretch > MAX_ELONGATION
        stretch = np.minimum(stretch, MAX_ELONGATION)
        # Turn: the squared cosine of the angle between the offset's direction and the
        # across axis is the normal's squared component across the plane of incidence
        # (the Gram determinant of normal, light and eye over |l x v|^2) over s^2.
        gram = 1.0 + 2.0 * cos_i * cos_o * cos_io - cos_i ** 2 - cos_o ** 2 - cos_io ** 2
        spread = 1.0 - cos_io ** 2  # |l x v|^2
        s2 = s * s
        turn = np.clip(np.maximum(gram, 0.0) / np.maximum(spread * s2, 1e-300), 0.0, 1.0)
        cos_turn, sin_turn = np.sqrt(turn), np.sqrt(1.0 - turn)
        # (the pattern's symmetry about both axes makes the turn's signs irrelevant)
        stretched = xi_2 * stretch
        z_x = stretched * cos_turn - xi_1 * sin_turn  # (K, P)
        z_y = stretched * sin_turn + xi_1 * cos_turn
    along = s - b * z_x  # (K, P)
    across = b * z_y
    sin2 = along * along + across * across
    # ds / d cos_h = -cos_h / s: the pattern is symmetric, so the weighted sum of these
    # slopes stays finite as s -> 0
    sin2_by_cos_h = along * (-2.0 * cos_h / s)
    # d sin^2 / d z = 2 b (-along, across)
    sin2_by_b = across * z_y
    sin2_by_b -= along * z_x
    sin2_by_b *= 2.0
    by_cosines = None
    if cos_io is not None:
        # Through the stretch k and the turn T = cos^2: z_x = xi_2 k sqrt(T) - xi_1
        # sqrt(1 - T), z_y = xi_2 k sqrt(1 - T) + xi_1 sqrt(T). The 1 / sqrt terms at
        # T = 0 or 1 cancel over the symmetric pattern; they are kept finite.
        root_t, root_1t = np.maximum(cos_turn, 1e-6), np.maximum(sin_turn, 1e-6)
        zx_by_t = xi_2 * (0.5 * stretch / root_t) + xi_1 * (0.5 / root_1t)
        zy_by_t = xi_1 * (0.5 / root_t) - xi_2 * (0.5 * stretch / root_1t)
        sin2_by_t = (across * zy_by_t - along * zx_by_t) * (2.0 * b)
        sin2_by_k = (across * sin_turn - along * cos_turn) * (2.0 * b) * xi_2
        # T = G / (|l x v|^2 s^2), s^2 = 1 - cos_h^2; k = (2 / (1 + cos_io))^(1/2)
        defined = (spread > 1e-12) & (s > 1e-6)
        inv = np.where(defined, 1.0 / np.maximum(spread * s2, 1e-300), 0.0)
        t_by_i = (2.0 * (cos_o * cos_io - cos_i)) * inv
        t_by_o = (2.0 * (cos_i * cos_io - cos_o)) * inv
        t_by_io = (2.0 * (cos_i * cos_o - cos_io) + 2.0 * cos_io * turn * s2) * inv
        t_by_cos_h = np.where(defined, 2.0 * turn * cos_h / np.maximum(s2, 1e-300), 0.0)
        k_by_io = np.where(capped, 0.0, -0.25 * stretch ** 3)
        sin2_by_cos_h += sin2_by_t * t_by_cos_h
        by_cosines = np.stack([sin2_by_t * t_by_i, sin2_by_t * t_by_o,
                               sin2_by_t * t_by_io + sin2_by_k * k_by_io])
    return DiscGeometry(sin2, weights[:, None], sin2_by_cos_h, sin2_by_b * b_by_r, by_cosines)
