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
no point spacing wider than the lobe on most lights and lobes met in practice: against
a fine numerical average, the largest error is below 1 % of the peak while the disc's
radius is at most 1.2 lobe half-widths, about 4 % at 2 (the point model: 50 % at 1),
and below 1.5 % for an ellipse one lobe unit wide seen at ``theta_d`` up to 45 degrees
(tests). An ellipse whose long axis spans more than about three lobe widths falls
between the points. Block means smooth that ripple; samples of one pixel show it, and
are rendered with :data:`PIXEL_DISC_RINGS` rings (61 points) instead. A disc well inside
the lobe (a rough coating) is read as closely by fewer points, and the points multiply
the cost of every evaluation: the refinement takes the fewest rings whose reach
(:data:`RINGS_REACH_UNITS`) covers the disc at the lobe's starting width
(:func:`disc_rings`).

The slopes follow ``s`` and ``b`` (the plane's tilt and the distance to the light)
and the ellipse's stretch and turn (through the three cosines), all analytic.

At ``b = 0`` every point is the centre and the lobe is the point model's; the
refinement keeps the point model's own code for a point light.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DISC_RINGS", "PIXEL_DISC_RINGS", "DiscGeometry", "disc_geometry", "disc_points",
           "disc_rings", "lobe_unit", "max_disc_rings"]

#: Rings of the hexagonal pattern of points over the light's disc (see the module notes).
DISC_RINGS = 2


#: Rings of the pattern when the samples are single pixels. A block's mean smooths the
#: pattern's ripple on a disc several lobe widths wide, a pixel shows it: on six stereo
#: scenes under a 15 mm lamp (1.7-5.4 lobe widths), read pixel by pixel, 2 / 3 / 4 rings
#: left the plane 0.031 / 0.010 / 0.007 px off on average (``mismatched_physics.py``'s
#: wide lights; block means with 2 rings 0.020 px).
PIXEL_DISC_RINGS = 4


#: The largest disc, in lobe units (:func:`lobe_unit`), that a pattern of 1, 2 and 3
#: rings reads within about 1 % of the lobe's peak (against a fine average over a round
#: disc: 0.65 / 0.83 / 0.87 % for GGX at these radii, 0.56 / 0.94 / 1.29 % for the
#: light tail -0.2). Larger discs take the most rings the samples need.
RINGS_REACH_UNITS = (0.75, 1.0, 1.25)


def max_disc_rings(block_px: int) -> int:
    """Rings of the pattern on the widest disc, for samples of ``block_px`` pixels."""
    return PIXEL_DISC_RINGS if block_px == 1 else DISC_RINGS


def lobe_unit(lobe: str, width: float) -> float:
    """``sin(theta_h)`` at which ``lobe`` of width ``w`` falls to ``1/e`` (GTR's Gaussian limit).

    ``w / sqrt(2 (1 - w^2))``; ``w / sqrt(1 - w^2)`` for ``"blinn_phong"``; infinite at
    ``w = 1`` (the bound of the fitted width: a lobe flat over every angle).
    """
    spread = (1.0 if lobe == "blinn_phong" else 2.0) * (1.0 - width * width)
    return width / math.sqrt(spread) if spread > 0.0 else math.inf


def disc_rings(reach: float, lobe: str, width: float, block_px: int) -> int:
    """Fewest rings that read a disc of half-vector ``reach`` under a lobe of ``width``.

    ``reach`` is the half-vector ellipse's longest semi-axis over the samples
    (:attr:`DiscGeometry.reach`, radians); past :data:`RINGS_REACH_UNITS` lobe units
    the most the samples need (:func:`max_disc_rings`).
    """
    units = reach / lobe_unit(lobe, width)
    cap = max_disc_rings(block_px)
    for rings, limit in enumerate(RINGS_REACH_UNITS, start=1):
        if units <= limit:
            return min(rings, cap)
    return cap


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


@functools.lru_cache(maxsize=4)
def _pattern_basis(rings: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the pattern's five functions ``(K, 5)`` and its weights ``(K, 1)``.

    See :class:`DiscGeometry`. Made once per ring count, read-only: every evaluation of
    the model reads them.
    """
    points, weights = disc_points(rings)
    xi_1, xi_2 = points[:, 0], points[:, 1]  # in and across the plane of incidence
    basis = np.stack([np.ones_like(xi_1), xi_1 ** 2, xi_2 ** 2, xi_2, xi_1], axis=1)
    weights = weights[:, None]
    basis.flags.writeable = weights.flags.writeable = False
    return basis, weights


@dataclass(frozen=True)
class DiscGeometry:
    """The lobe's arguments at the disc's points, for one plane.

    ``sin2`` ``(K, P)`` is ``sin^2`` of the half-vector angle at each point of the
    disc (``K`` points, ``P`` samples) and ``weights`` ``(K, 1)`` their quadrature
    weights. ``sin^2`` is linear in five functions of the points, ``basis`` ``(K, 5)``
    (``1, xi_1^2, xi_2^2, xi_2, xi_1``), with per-sample coefficients: ``sin2 = basis @
    coef``. The coefficients' derivatives ``(5, P)`` by the offset ``s``, the disc's
    radius ``b``, the ellipse's stretch ``k`` and turn ``T`` (None for a round disc) and
    the chain factors ``(P,)`` from the model's variables to those give every slope of
    the averaged lobe from one product of the lobe's point slopes with the basis
    (:meth:`slopes`). ``reach`` is the ellipse's longest semi-axis over the samples
    (radians of the half vector). ``shapes`` keeps the last lobe evaluated at the points (its key
    and ``(K, P)`` values): a step's slopes are taken where the step was evaluated.
    """

    sin2: np.ndarray
    weights: np.ndarray
    basis: np.ndarray
    coef_by_s: np.ndarray
    coef_by_b: np.ndarray
    s_by_cos_h: np.ndarray
    b_by_r: np.ndarray
    reach: float = 0.0
    coef_by_k: np.ndarray | None = None
    coef_by_t: np.ndarray | None = None
    k_by_cos_io: np.ndarray | None = None
    t_by: np.ndarray | None = None  # (4, P): by cos_i, cos_o, cos_io, cos_h
    shapes: dict = field(default_factory=dict, compare=False, repr=False)

    def slopes(self, by_sin2: np.ndarray):
        """Averaged lobe's slopes from its slopes by ``sin^2`` at the points ``(K, P)``.

        Returns ``(by_cos_h, by_r, by_cosines)``: by the light centre's ``cos(theta_h)``,
        by the distance ``r`` to the light, and ``(3, P)`` by ``cos_i``, ``cos_o`` and
        ``cos_io`` through the ellipse (each with the others and ``cos_h`` held; None
        for a round disc).
        """
        # mean_k w_k by_k,p (basis @ c)_k,p = sum_j c_j,p (w basis)^T by_sin2 _j,p
        moments = (self.basis * self.weights).T @ by_sin2  # (5, P)

        def through(coef_by: np.ndarray) -> np.ndarray:
            return np.einsum("jp,jp->p", coef_by, moments)

        by_cos_h = through(self.coef_by_s) * self.s_by_cos_h
        by_r = through(self.coef_by_b) * self.b_by_r
        if self.coef_by_t is None:
            return by_cos_h, by_r, None
        by_t = through(self.coef_by_t)
        by_k = through(self.coef_by_k)
        by_cos_h += by_t * self.t_by[3]
        by_cosines = by_t * self.t_by[:3]
        by_cosines[2] += by_k * self.k_by_cos_io
        return by_cos_h, by_r, by_cosines


def disc_geometry(cos_h: np.ndarray, sin2_h: np.ndarray, r: np.ndarray, radius_m: float,
                  *, cos_i: np.ndarray | None = None, cos_o: np.ndarray | None = None,
                  cos_io: np.ndarray | None = None, rings: int = DISC_RINGS) -> DiscGeometry:
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
    rings : int
        Rings of the pattern of points over the disc (:func:`disc_points`).
    """
    basis, weights = _pattern_basis(rings)
    s = np.maximum(np.sqrt(sin2_h), _MIN_SIN_H)
    ratio = np.minimum(radius_m / r, 1.0)
    b = 0.5 * np.arcsin(ratio)
    # db/dr = -(R / r^2) / (2 sqrt(1 - (R / r)^2)); inside the sphere (ratio 1) it is flat
    b_by_r = np.zeros_like(r)
    outside = ratio < 1.0
    b_by_r[outside] = (-0.5 * ratio[outside] / r[outside]
                       / np.sqrt(1.0 - ratio[outside] ** 2))
    # A point b z of the ellipse, z = (xi_2 k sqrt(T) - xi_1 sqrt(1 - T), xi_2 k sqrt(1 - T)
    # + xi_1 sqrt(T)) (the unit disc stretched by k across the plane of incidence and
    # turned so that the across axis makes an angle of cosine sqrt(T) with the offset):
    # sin^2 = (s - b z_x)^2 + (b z_y)^2 = s^2 + b^2 xi_1^2 + b^2 k^2 xi_2^2
    #         - 2 s b k sqrt(T) xi_2 + 2 s b sqrt(1 - T) xi_1.
    # A round disc is k = 1, T = 0.
    stretch = turn = None
    if cos_io is not None:
        # k = 1 / cos(theta_d), cos(theta_d)^2 = (1 + l . v) / 2
        stretch = 1.0 / np.sqrt(np.maximum(0.5 * (1.0 + cos_io), 1e-300))
        capped = stretch > MAX_ELONGATION
        stretch = np.minimum(stretch, MAX_ELONGATION)
        # T: the normal's squared component across the plane of incidence (the Gram
        # determinant of normal, light and eye over |l x v|^2), over s^2
        gram = 1.0 + 2.0 * cos_i * cos_o * cos_io - cos_i ** 2 - cos_o ** 2 - cos_io ** 2
        spread = 1.0 - cos_io ** 2
        s2 = s * s
        turn = np.clip(np.maximum(gram, 0.0) / np.maximum(spread * s2, 1e-300), 0.0, 1.0)
        k, root_t, root_1t = stretch, np.sqrt(turn), np.sqrt(1.0 - turn)
    else:
        k, root_t, root_1t = np.ones_like(s), np.zeros_like(s), np.ones_like(s)
    b2, sb = b * b, s * b
    coef = np.stack([s * s, b2, b2 * k * k, -2.0 * sb * k * root_t, 2.0 * sb * root_1t])
    zeros = np.zeros_like(s)
    coef_by_s = np.stack([2.0 * s, zeros, zeros, -2.0 * b * k * root_t, 2.0 * b * root_1t])
    coef_by_b = np.stack([zeros, 2.0 * b, 2.0 * b * k * k, -2.0 * s * k * root_t,
                          2.0 * s * root_1t])
    geometry = dict(sin2=basis @ coef, weights=weights, basis=basis,
                    coef_by_s=coef_by_s, coef_by_b=coef_by_b,
                    s_by_cos_h=-cos_h / s, b_by_r=b_by_r,
                    reach=float(np.max(b * k)) if len(b) else 0.0)
    if stretch is not None:
        # The 1 / sqrt terms at T = 0 or 1 cancel over the symmetric pattern; kept finite.
        coef_by_k = np.stack([zeros, zeros, 2.0 * b2 * k, -2.0 * sb * root_t, zeros])
        coef_by_t = np.stack([zeros, zeros, zeros, -sb * k / np.maximum(root_t, 1e-6),
                              -sb / np.maximum(root_1t, 1e-6)])
        # T = G / (|l x v|^2 s^2) with s^2 = 1 - cos_h^2; k = (2 / (1 + cos_io))^(1/2)
        defined = (spread > 1e-12) & (s > 1e-6)
        inv = np.where(defined, 1.0 / np.maximum(spread * s2, 1e-300), 0.0)
        t_by = np.stack([2.0 * (cos_o * cos_io - cos_i) * inv,  # by cos_i
                         2.0 * (cos_i * cos_io - cos_o) * inv,  # by cos_o
                         2.0 * (cos_i * cos_o - cos_io + cos_io * turn * s2) * inv,  # cos_io
                         np.where(defined, 2.0 * turn * cos_h / np.maximum(s2, 1e-300), 0.0)])
        geometry.update(coef_by_k=coef_by_k, coef_by_t=coef_by_t,
                        k_by_cos_io=np.where(capped, 0.0, -0.25 * stretch ** 3), t_by=t_by)
    return DiscGeometry(**geometry)
