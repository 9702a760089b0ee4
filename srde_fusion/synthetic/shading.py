"""Reflectance models of the synthetic renderer: Lambertian diffuse plus a specular lobe.

Two specular lobes are available, because a step that fits a lobe model should be
tested on images rendered with a different one:

``"ggx"``
    Cook-Torrance microfacet BRDF ``D G F / (4 cos_l cos_v)`` with the GGX
    (Trowbridge-Reitz) normal distribution ``D``, the separable Smith masking term ``G``
    for GGX and Schlick's Fresnel approximation ``F`` (Walter et al., "Microfacet Models
    for Refraction through Rough Surfaces", EGSR 2007).
``"blinn_phong"``
    Energy-normalised Blinn-Phong, ``F (e + 8) / (8 pi) cos^e(theta_h)`` with exponent
    ``e = 2 / alpha^2 - 2`` (the exponent whose lobe matches a Beckmann lobe of slope
    ``alpha`` near its peak). Narrower tails than GGX.

Beside these, the renderer can switch on physics the refinement's model does not share
(see :class:`srde_fusion.synthetic.physics.Physics`): the exact Fresnel equations for
dielectrics and conductors (:func:`fresnel_exact`), height-correlated Smith
masking-shadowing (:func:`smith_g2_height_correlated`), and a spherical light integrated
over its visible disc (:func:`disc_samples`) instead of the widened lobe below.

Both lobes take the same roughness ``alpha`` and have nearly the same peak at normal
incidence, ``1 / (4 pi alpha^2)``; they differ in shape away from the peak.

A spherical light of radius ``R`` at distance ``d`` subtends a disc of angular radius
``R / d``, which the mirror half-vector sees as a disc of radius ``R / (2 d)``. Instead of
sampling the sphere, the renderer folds that disc into the lobe: the disc's per-axis
slope variance ``(R / (2 d))^2 / 4`` is added to the lobe's (``alpha^2 / 2`` for a
Beckmann-like lobe), giving ``alpha_eff = sqrt(alpha^2 + R^2 / (8 d^2))``. This widens the
highlight and lowers its peak while keeping its energy, and is exact in the limit of a
point light.
"""

from __future__ import annotations

import math

import numpy as np

from ..optics import fresnel_exact, ior_from_f0, schlick_fresnel

__all__ = [
    "LOBES",
    "ggx_ndf",
    "smith_g1_ggx",
    "schlick_fresnel",
    "fresnel_exact",
    "ior_from_f0",
    "smith_g2_height_correlated",
    "disc_samples",
    "blinn_phong_exponent",
    "widened_roughness",
    "specular_brdf",
]

#: Names of the specular lobes :func:`specular_brdf` implements.
LOBES = ("ggx", "blinn_phong")


def ggx_ndf(cos_h: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """GGX normal distribution ``D(h) = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)``.

    Parameters
    ----------
    cos_h : numpy.ndarray, (...), float
        Cosine between the surface normal and the half vector.
    alpha : float or numpy.ndarray broadcastable to ``cos_h``
        GGX roughness (slope width), > 0.

    Returns
    -------
    numpy.ndarray, (...), float
        Microfacet density per steradian; it integrates to 1 against ``cos_h``.

    Examples
    --------
    >>> round(float(ggx_ndf(np.array(1.0), 0.1)), 3)  # peak 1 / (pi alpha^2)
    31.831
    """
    a2 = np.square(alpha)
    c2 = np.square(cos_h)
    return a2 / (np.pi * np.square(c2 * (a2 - 1.0) + 1.0))


def smith_g1_ggx(cos_theta: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Smith masking of one direction for GGX, ``2 c / (c + sqrt(alpha^2 + (1 - alpha^2) c^2))``.

    ``cos_theta`` must be positive (directions above the surface).
    """
    a2 = np.square(alpha)
    c2 = np.square(cos_theta)
    return 2.0 * cos_theta / (cos_theta + np.sqrt(a2 + (1.0 - a2) * c2))


def smith_g2_height_correlated(
    cos_l: np.ndarray, cos_v: np.ndarray, alpha: np.ndarray | float
) -> np.ndarray:
    """Height-correlated Smith masking-shadowing for GGX, ``1 / (1 + Lambda_l + Lambda_v)``.

    ``Lambda(c) = (sqrt(1 + alpha^2 (1 / c^2 - 1)) - 1) / 2``. It accounts for the light
    and view being masked by the same microfacets, which the separable product
    ``G1(l) G1(v)`` counts twice; the difference grows at grazing angles.
    """
    a2 = np.square(alpha)

    def lam(c: np.ndarray) -> np.ndarray:
        c2 = np.square(c)
        return 0.5 * (np.sqrt(1.0 + a2 * (1.0 - c2) / c2) - 1.0)

    return 1.0 / (1.0 + lam(cos_l) + lam(cos_v))


def disc_samples(n: int) -> np.ndarray:
    """``n`` points spread evenly over the unit disc, ``(n, 2)`` float32; ``n`` a multiple of 4.

    The renderer's pattern for integrating a spherical light over the disc it presents to
    a surface point. A golden-angle spiral of ``n / 4`` points (equal area per point),
    turned by 0, 90, 180 and 270 degrees: the points' mean is the disc's centre and
    their second moment the disc's, ``I / 4``, exactly. A spiral alone is off in both by
    about 1 % at 64 points (its mean 0.9 % of the radius from the centre), the same in
    every pixel of a scene: a lamp moved by that much, which moved two-light planes by
    0.002-0.005 px.

    Raises
    ------
    ValueError
        ``n`` not a positive multiple of 4.
    """
    if n < 4 or n % 4:
        raise ValueError(f"disc_samples: expected a positive multiple of 4, got {n}")
    m = n // 4
    i = np.arange(m) + 0.5
    radius = np.sqrt(i / m)
    angle = i * math.pi * (3.0 - math.sqrt(5.0))
    u, v = radius * np.cos(angle), radius * np.sin(angle)
    quarter_turns = [(u, v), (-v, u), (-u, -v), (v, -u)]
    return np.concatenate([np.stack(p, axis=1) for p in quarter_turns]).astype(np.float32)


def blinn_phong_exponent(alpha: np.ndarray | float) -> np.ndarray:
    """Blinn-Phong exponent ``2 / alpha^2 - 2`` equivalent to a lobe of roughness ``alpha``."""
    return 2.0 / np.square(alpha) - 2.0


def widened_roughness(
    alpha: float, light_radius_m: float, light_distance_m: np.ndarray
) -> np.ndarray:
    """Roughness of a lobe lit by a sphere: ``sqrt(alpha^2 + R^2 / (8 d^2))``.

    Parameters
    ----------
    alpha : float
        Roughness of the surface.
    light_radius_m : float
        Radius ``R`` of the spherical light (0 = point light).
    light_distance_m : numpy.ndarray, (...)
        Distance ``d`` from each surface point to the light centre.

    Returns
    -------
    numpy.ndarray, (...)
        Effective roughness (see the module notes for the derivation).
    """
    return np.sqrt(alpha * alpha + np.square(light_radius_m / light_distance_m) / 8.0)


def specular_brdf(
    cos_l: np.ndarray,
    cos_v: np.ndarray,
    cos_h: np.ndarray,
    cos_vh: np.ndarray,
    alpha: np.ndarray | float,
    *,
    lobe: str,
    f0: float,
    fresnel: np.ndarray | None = None,
    masking: str = "separable",
) -> np.ndarray:
    """Specular BRDF value (per steradian) for unit normal, light, view and half vectors.

    Parameters
    ----------
    cos_l, cos_v : numpy.ndarray, (...)
        ``n.l`` and ``n.v``; both must be positive where the result is used.
    cos_h : numpy.ndarray, (...)
        ``n.h`` with ``h = (l + v) / |l + v|``.
    cos_vh : numpy.ndarray, (...)
        ``v.h`` (enters the Fresnel term).
    alpha : float or numpy.ndarray, (...)
        Roughness (possibly widened by :func:`widened_roughness`).
    lobe : {"ggx", "blinn_phong"}
    f0 : float
        Fresnel reflectance at normal incidence (Schlick's term).
    fresnel : numpy.ndarray, (...), optional
        The Fresnel reflectance at ``cos_vh``, precomputed (exact Fresnel); Schlick's
        approximation with ``f0`` when None.
    masking : {"separable", "height_correlated"}
        Smith masking-shadowing of the GGX lobe: ``G1(l) G1(v)`` or
        :func:`smith_g2_height_correlated`.

    Returns
    -------
    numpy.ndarray, (...)
        The BRDF; multiply by the irradiance ``I cos_l / r^2`` for the outgoing radiance.
    """
    if fresnel is None:
        fresnel = schlick_fresnel(cos_vh, f0)
    if lobe == "ggx":
        if masking == "height_correlated":
            geometry = smith_g2_height_correlated(cos_l, cos_v, alpha)
        else:
            geometry = smith_g1_ggx(cos_l, alpha) * smith_g1_ggx(cos_v, alpha)
        return ggx_ndf(cos_h, alpha) * geometry * fresnel / (4.0 * cos_l * cos_v)
    exponent = blinn_phong_exponent(alpha)
    # exp(e log c) instead of c**e: e reaches 1e5 for mirror-like surfaces.
    with np.errstate(divide="ignore"):
        lobe_value = np.exp(exponent * np.log(np.clip(cos_h, 0.0, 1.0)))
    return fresnel * (exponent + 8.0) / (8.0 * np.pi) * lobe_value
