"""The lobe families: the peak-normalised specular lobe ``S`` and its derivatives.

A lobe is a function of the half-vector angle ``theta_h`` (through ``sin^2(theta_h)`` or
``cos(theta_h)`` of a :class:`~.reflection.ShadingGeometry`) with a width ``w``, fitted as
``log_width = log(w)``, and for ``"gtr"`` a tail ``t``. Each family is scaled to a peak
of 1 at ``theta_h = 0``.

Under a light of known radius (a geometry with a ``disc``, see :mod:`~.disc`) the lobe is
averaged over the points of the light's disc; its derivatives by the geometry are then
taken by the light centre's ``cos(theta_h)`` and by the distance to the light.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .reflection import ShadingGeometry

__all__ = ["LOBES", "DEFAULT_LOBE", "LobeSlopes", "lobe_shape", "lobe_shape_slopes", "start_tail"]

#: Lobe shapes :func:`refine_plane` can fit, as functions of the half-vector angle:
#:
#: ``"gtr"``
#:     Generalised Trowbridge-Reitz with a free tail: ``(1 + t z)^(-1 / t)`` with
#:     ``z = 2 (1 - w^2) sin^2(theta_h) / w^2``. ``t = 1/2`` is GGX of roughness ``w``,
#:     ``t -> 0`` a Gaussian in ``sin(theta_h)`` (Beckmann-like), ``t < 0`` lighter tails
#:     (Blinn-Phong of exponent ``e`` is close to ``t = -1 / e``). Flexible enough to fit
#:     materials that follow neither GGX nor Blinn-Phong.
#: ``"ggx"``
#:     Trowbridge-Reitz, ``(w^2 / (w^2 + (1 - w^2) sin^2(theta_h)))^2``.
#: ``"blinn_phong"``
#:     ``cos(theta_h)^e`` with ``e = 2 / w^2 - 2``.
LOBES = ("gtr", "ggx", "blinn_phong")
DEFAULT_LOBE = "gtr"


# |tail| below this is the Gaussian limit exp(-z) of the "gtr" lobe.
_ZERO_TAIL = 1e-9


# |t z| below this takes the lobe's derivative by its tail from a series (no cancellation).
_SMALL_TAIL_Z = 1e-3


def start_tail(lobe: str) -> float:
    """Tail a fit of ``lobe`` starts from: GGX's for the Trowbridge-Reitz families."""
    return 0.5 if lobe != "blinn_phong" else 0.0


def lobe_shape(lobe: str, g: ShadingGeometry, log_width, tail) -> np.ndarray:
    """Return the peak-normalised lobe ``S(n . h)``, ``(P,)``.

    Parameters
    ----------
    lobe : {"gtr", "ggx", "blinn_phong"}
    g : ShadingGeometry
        The samples' geometry for one plane.
    log_width : float
        ``log(w)``.
    tail : float
        ``t`` of ``"gtr"`` (the other families ignore it).
    """
    disc = getattr(g, "disc", None)
    if disc is None:
        return _point_shape(lobe, g.sin2_h, g.cos_h, log_width, tail)
    return _disc_mean(disc, _disc_shapes(lobe, disc, log_width, tail))


def _disc_shapes(lobe: str, disc, log_width, tail) -> np.ndarray:
    """Return the lobe at every point of the disc, ``(K, P)``; the last one is kept."""
    key = (lobe, float(log_width), float(tail))
    if disc.shapes.get("key") != key:
        disc.shapes["values"] = _point_shape(lobe, disc.sin2, _disc_cos(lobe, disc),
                                             log_width, tail)
        disc.shapes["key"] = key
    return disc.shapes["values"]


def _disc_cos(lobe: str, disc) -> np.ndarray | None:
    """``cos`` of the half-vector angles at the disc's points, if the lobe reads it."""
    return np.sqrt(np.maximum(1.0 - disc.sin2, 0.0)) if lobe == "blinn_phong" else None


def _disc_mean(disc, values: np.ndarray) -> np.ndarray:
    """Quadrature over the disc's points: ``(K, P)`` -> ``(P,)``."""
    return np.einsum("kp,k->p", values, disc.weights[:, 0])


def _point_shape(lobe: str, sin2_h: np.ndarray, cos_h: np.ndarray | None, log_width, tail
                 ) -> np.ndarray:
    """Return the lobe at half-vector angles given by ``sin^2`` and ``cos`` (same shape)."""
    alpha2 = math.exp(2.0 * log_width)
    if lobe == "ggx":
        ratio = alpha2 / (alpha2 + sin2_h * (1.0 - alpha2))
        return ratio * ratio
    if lobe == "gtr":
        z = sin2_h * (2.0 * (1.0 - alpha2) / alpha2)
        if abs(tail) < _ZERO_TAIL:
            return np.exp(-z)
        # (1 + t z)^(-1/t); where a light tail (t < 0) ends, the lobe is 0. (In place:
        # the disc's lobes are (K, P) arrays.)
        z *= tail
        z += 1.0
        np.maximum(z, 1e-300, out=z)
        np.log(z, out=z)
        z *= -1.0 / tail
        return np.exp(z, out=z)
    with np.errstate(divide="ignore"):
        return np.exp((2.0 / alpha2 - 2.0) * np.log(np.maximum(cos_h, 0.0)))


class LobeSlopes(NamedTuple):
    """Derivatives of :func:`lobe_shape`, arrays ``(P,)``.

    The lobe's derivative by the geometry is ``by * d(along)``, ``along`` being
    ``g.sin2_h`` or ``g.cos_h`` (the very array, so ``along is g.sin2_h`` tells which),
    plus ``by_r * dr`` under a light's disc (``r`` the distance to the light, metres),
    plus ``by_cosines . d(cos_i, cos_o, cos_io)`` under its ellipse (``(3, P)``).
    """

    by: np.ndarray
    along: np.ndarray
    by_log_width: np.ndarray
    by_tail: np.ndarray | None  # None unless the lobe is "gtr"
    by_r: np.ndarray | None = None  # None for a point light
    by_cosines: np.ndarray | None = None  # None for a point light or a round disc


def lobe_shape_slopes(lobe: str, g: ShadingGeometry, log_width, tail,
                      shape: np.ndarray) -> LobeSlopes:
    """Return the derivatives of :func:`lobe_shape` by the geometry, the width and the tail.

    ``shape`` is :func:`lobe_shape` of the same arguments. Where a lobe is exactly 0 (a
    light tail's end, or beyond 90 degrees) all derivatives are 0.
    """
    disc = getattr(g, "disc", None)
    if disc is None:
        return _point_slopes(lobe, g.sin2_h, g.cos_h, log_width, tail, shape)
    # The slopes at every point of the disc, chained to the light centre's geometry.
    cos = _disc_cos(lobe, disc)
    at_points = _point_slopes(lobe, disc.sin2, cos, log_width, tail,
                              _disc_shapes(lobe, disc, log_width, tail))
    by_sin2 = at_points.by
    if lobe == "blinn_phong":  # d cos = -d sin^2 / (2 cos)
        by_sin2 = by_sin2 * (-0.5 / np.maximum(cos, 1e-300))
    by_cos_h, by_r, by_cosines = disc.slopes(by_sin2)
    return LobeSlopes(by_cos_h, g.cos_h, _disc_mean(disc, at_points.by_log_width),
                      None if at_points.by_tail is None else _disc_mean(disc, at_points.by_tail),
                      by_r, by_cosines)


def _point_slopes(lobe: str, sin2_h: np.ndarray, cos_h: np.ndarray | None, log_width, tail,
                  shape: np.ndarray) -> LobeSlopes:
    """:func:`lobe_shape_slopes` of the lobe at the angles ``sin2_h``, ``cos_h``."""
    alpha2 = math.exp(2.0 * log_width)
    if lobe == "ggx":
        # S = (a2 / D)^2 with D = a2 + s (1 - a2)
        inv_den = 1.0 / (alpha2 + sin2_h * (1.0 - alpha2))
        return LobeSlopes((-2.0 * (1.0 - alpha2)) * shape * inv_den, sin2_h,
                          4.0 * shape * sin2_h * inv_den, None)
    if lobe == "blinn_phong":
        # S = cos_h^e with e = 2 / a2 - 2
        positive = np.maximum(cos_h, 1e-300)
        by_cos = (2.0 / alpha2 - 2.0) * shape / positive
        return LobeSlopes(by_cos, cos_h, (-4.0 / alpha2) * shape * np.log(positive), None)
    # gtr: S = (1 + t z)^(-1/t) with z = s f, f = 2 (1 - a2) / a2
    factor = 2.0 * (1.0 - alpha2) / alpha2
    z = sin2_h * factor
    if abs(tail) < _ZERO_TAIL:  # S = exp(-z)
        return LobeSlopes(-factor * shape, sin2_h, (4.0 / alpha2) * shape * sin2_h,
                          0.5 * shape * z * z)
    u = tail * z
    base = np.maximum(1.0 + u, 1e-300)
    by_z = shape / base  # dS/dz = -S / (1 + t z)
    by_log_width = (4.0 / alpha2) * by_z * sin2_h
    # dS/dt = S (log(1 + u) - u / (1 + u)) / t^2, by its series where u is small
    with np.errstate(over="ignore", invalid="ignore"):
        by_tail = np.log(base)
        by_tail -= u / base
        by_tail *= shape / (tail * tail)
    small = np.abs(u) < _SMALL_TAIL_Z
    if small.any():
        us, zs = u[small], z[small]
        by_tail[small] = shape[small] * zs * zs * (0.5 + us * (-2.0 / 3.0 + 0.75 * us))
    if tail < 0.0:  # past a light tail's end S = 0, and so is its slope
        by_tail[shape == 0.0] = 0.0
    return LobeSlopes(-factor * by_z, sin2_h, by_log_width, by_tail)
