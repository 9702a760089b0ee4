"""Fresnel reflectance: how much light a surface reflects at a given angle of incidence.

Shared by the renderer (:mod:`srde_fusion.synthetic`) and the photometric refinement
(:mod:`srde_fusion.srde.refine`): the exact Fresnel equations for dielectrics and
conductors, and Schlick's approximation of them.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "fresnel_dielectric",
    "fresnel_exact",
    "fresnel_exact_slope",
    "ior_from_f0",
    "schlick_fresnel",
]


def schlick_fresnel(cos_vh: np.ndarray, f0: float) -> np.ndarray:
    """Schlick's Fresnel reflectance ``f0 + (1 - f0) (1 - v.h)^5``."""
    return f0 + (1.0 - f0) * np.power(np.clip(1.0 - cos_vh, 0.0, 1.0), 5)


def ior_from_f0(f0: float) -> float:
    """Refractive index of the dielectric whose normal-incidence reflectance is ``f0``.

    Inverts ``f0 = ((n - 1) / (n + 1))^2``; ``f0 = 0.04`` gives ``n = 1.5``.
    """
    root = math.sqrt(min(max(f0, 0.0), 0.999999))
    return (1.0 + root) / (1.0 - root)


def fresnel_exact(cos_i: np.ndarray, ior: float, extinction: float = 0.0) -> np.ndarray:
    """Unpolarised Fresnel reflectance from air onto a medium of index ``ior + i extinction``.

    The mean of the s- and p-polarised reflectances of the Fresnel equations, written
    for a complex index so that one formula covers dielectrics (``extinction = 0``) and
    conductors (metals: ``extinction > 0``).

    Parameters
    ----------
    cos_i : numpy.ndarray, (...)
        Cosine of the angle of incidence on the (micro)surface, in [0, 1] (``v . h``
        for a microfacet).
    ior : float
        Real part ``n`` of the refractive index, > 0 (1.49 for acrylic, 1.5 for glass).
    extinction : float
        Imaginary part ``k`` >= 0 (0 for dielectrics; about 1.0-7 for metals).

    Returns
    -------
    numpy.ndarray, (...)
        Reflectance in [0, 1]: ``((n - 1)^2 + k^2) / ((n + 1)^2 + k^2)`` at normal
        incidence, 1 at grazing incidence.

    Examples
    --------
    >>> round(float(fresnel_exact(np.array(1.0), 1.5)), 4)
    0.04
    >>> round(float(fresnel_exact(np.array(0.0), 1.5)), 4)
    1.0
    """
    c = np.clip(cos_i, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    n2, k2 = ior * ior, extinction * extinction
    # |eta^2 - sin^2|, written as a^2 + b^2 with a = Re(sqrt(eta^2 - sin^2)).
    t = n2 - k2 - s2
    modulus = np.sqrt(t * t + 4.0 * n2 * k2)
    a = np.sqrt(np.maximum(0.5 * (modulus + t), 0.0))
    two_ac = 2.0 * a * c
    r_s = (modulus - two_ac + c2) / np.maximum(modulus + two_ac + c2, 1e-30)
    # p-polarised relative to s: (c^2 |..| - 2 a c s^2 + s^4) / (c^2 |..| + 2 a c s^2 + s^4).
    num = c2 * modulus - two_ac * s2 + s2 * s2
    den = np.maximum(c2 * modulus + two_ac * s2 + s2 * s2, 1e-30)
    return 0.5 * (r_s + r_s * num / den)


def fresnel_exact_slope(cos_i: np.ndarray, ior: float, extinction: float = 0.0,
                        step: float = 1e-6) -> np.ndarray:
    """Return the derivative of :func:`fresnel_exact` by ``cos_i`` (central differences).

    The reflectance is smooth in ``cos_i`` on ``(0, 1)``; a step of 1e-6 keeps the
    truncation error near 1e-12 and the rounding error near 1e-10, far below what a
    Jacobian needs. At the ends the difference is one-sided (inside ``[0, 1]``).
    """
    c = np.asarray(cos_i, dtype=np.float64)
    lo = np.clip(c - step, 0.0, 1.0)
    hi = np.clip(c + step, 0.0, 1.0)
    return (fresnel_exact(hi, ior, extinction) - fresnel_exact(lo, ior, extinction)) / (hi - lo)


def fresnel_dielectric(cos_i: np.ndarray, ior: float, *, slope: bool = False):
    """:func:`fresnel_exact` of a dielectric seen from air (``ior > 1``), and its slope.

    The same reflectance as ``fresnel_exact(cos_i, ior)``, in the real form a dielectric
    allows: with ``g = sqrt(ior^2 - 1 + c^2)``, ``A = (g - c) / (g + c)`` and
    ``B = (c (g + c) - 1) / (c (g - c) + 1)``, ``F = A^2 (1 + B^2) / 2``. About a third of
    the general formula's operations, and the derivative is analytic, so the photometric
    refinement (which evaluates it at every sample on every step) uses this one.

    Parameters
    ----------
    cos_i : numpy.ndarray, (...)
        Cosine of the angle of incidence, clipped to [0, 1].
    ior : float
        Refractive index, > 1 (from air: no total internal reflection).
    slope : bool
        Also return ``dF / d cos_i``.

    Returns
    -------
    numpy.ndarray, (...), or a tuple of two
        Reflectance, and its derivative by ``cos_i`` if ``slope``.

    Examples
    --------
    >>> c = np.linspace(0.0, 1.0, 5)
    >>> bool(np.allclose(fresnel_dielectric(c, 1.49), fresnel_exact(c, 1.49)))
    True
    """
    # The refinement calls this at every sample of every plane it tries, so the arithmetic
    # runs in place where it can (each new array this size costs page faults), in the
    # formulas' order: the values are those of the formulas written out, to the bit.
    c = np.clip(cos_i, 0.0, 1.0)
    g = c * c
    g += ior * ior - 1.0
    np.sqrt(g, out=g)
    g_plus = g + c
    g_minus = g - c
    a = g_minus / g_plus
    b_num = c * g_plus
    b_num -= 1.0
    b_den = np.multiply(c, g_minus, out=g_minus)  # (g - c is not needed after A)
    b_den += 1.0
    b = b_num / b_den
    a2 = a * a
    one_b2 = b * b
    one_b2 += 1.0
    reflectance = a2 * 0.5
    reflectance *= one_b2
    if not slope:
        return reflectance
    # dg/dc = c / g (g >= sqrt(ior^2 - 1) > 0 for ior > 1; at ior = 1, g = c: taken as 1)
    dg = c / g if ior > 1.0 else np.divide(c, g, out=np.ones_like(g), where=g > 0.0)
    cdg = np.multiply(c, dg, out=dg)
    # dA/dc = 2 (c g' - g) / (g + c)^2
    da = cdg - g
    da *= 2.0
    g_plus *= g_plus
    da /= g_plus
    # dB/dc = ((g + c g' + 2c) b_den - b_num (g + c g' - 2c)) / b_den^2
    two_c = c * 2.0
    db = g + cdg
    db_minus = db - two_c
    db_minus *= b_num
    db += two_c
    db *= b_den
    db -= db_minus
    b_den *= b_den
    db /= b_den
    # dF/dc = A A' (1 + B^2) + A^2 B B'
    out = a * da
    out *= one_b2
    a2 *= b
    a2 *= db
    out += a2
    return reflectance, out
