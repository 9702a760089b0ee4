"""Analytic derivatives of the lobe model's luminance by its plane and shape parameters.

The chain rule runs through the lobe families (:func:`~.lobes.lobe_shape_slopes`) and
the ray-plane algebra of :class:`~.reflection.PlaneReflection`: every shading term
depends on the plane through three scalars per sample (``n . k``, ``c - n . C`` and
``n . L - c``), so each plane parameter's slope is three products.
"""

from __future__ import annotations

import numpy as np

from .layout import I_DIFF, I_FORE, I_SPEC, I_TAIL, I_WIDTH, N_PLANE
from .lobes import lobe_shape_slopes
from .reflection import PlaneReflection, ShadingGeometry

__all__ = ["model_slopes"]


def model_slopes(reflection: PlaneReflection, lobe: str, g: ShadingGeometry, theta: np.ndarray,
                 free: np.ndarray, *, lobe_term: np.ndarray, shape: np.ndarray,
                 specular_factor: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Return the model's derivatives ``(len(free), P)`` by ``theta[free]`` (intensities held).

    Parameters
    ----------
    reflection : PlaneReflection
        The samples' reflection geometry; ``g`` is its geometry at ``theta``'s plane.
    lobe : str
        The lobe family.
    g : ShadingGeometry
    theta : numpy.ndarray, (9,)
        The parameters (see ``layout``).
    free : numpy.ndarray, (K,), int
        Indices of the parameters to differentiate by.
    lobe_term : numpy.ndarray, (P,)
        The specular term ``S g_s (cos_i cos_o)^k``.
    shape : numpy.ndarray, (P,)
        The peak-normalised lobe ``S``.
    specular_factor : numpy.ndarray, (P,)
        ``g_s (cos_i cos_o)^k``.
    out : numpy.ndarray, (K, P)
        Where the derivatives go (returned).
    """
    specular, fore = theta[I_SPEC], theta[I_FORE]
    by, along, by_log_width, by_tail, by_r, by_cosines = lobe_shape_slopes(
        lobe, g, theta[I_WIDTH], theta[I_TAIL], shape)
    spec_term = specular * specular_factor  # S's factor in the model
    planes = [(row, index) for row, index in enumerate(free) if index < N_PLANE]
    if planes:
        on_nk, on_cam, on_lh = _plane_slope_terms(reflection, g, fore, theta[I_DIFF], by, along,
                                                  shape, spec_term, by_r, by_cosines)
        directions = reflection.directions(theta)
    for row, index in planes:
        # slope = (n . L - c)' on_lh + (c - n . C)' on_cam + (n . k)' on_nk
        dn, dc = directions[index]
        slope = out[row]
        slope[:] = dc * (on_cam - on_lh)
        if dn.any():
            slope += float(dn @ reflection.light) * on_lh
            slope -= on_cam * (dn @ reflection.camera_t)
            slope += on_nk * (dn @ reflection.ray_t)
    for row, index in enumerate(free):
        if index == I_WIDTH:
            np.multiply(by_log_width, spec_term, out=out[row])
        elif index == I_TAIL:
            np.multiply(by_tail, spec_term, out=out[row])
        elif index == I_FORE:  # the exponent multiplies log(cos_i cos_o)
            np.multiply(lobe_term, g.log_foreshortening, out=out[row])
            out[row] *= specular
    return out


def _plane_slope_terms(reflection: PlaneReflection, g: ShadingGeometry, fore, diffuse,
                       by: np.ndarray, along: np.ndarray, shape: np.ndarray,
                       spec_term: np.ndarray, by_r: np.ndarray | None = None,
                       by_cosines: np.ndarray | None = None):
    """Return the model's derivatives ``(P,)`` by ``n . k``, ``c - n . C``, ``n . L - c``.

    Every shading term depends on the plane through these three per-sample scalars
    (``k`` the ray, ``C`` the camera centre, ``L`` the light), and linearly so to
    first order: collecting the chain rule's coefficients once makes each plane
    parameter's slope three products. ``fore`` and ``diffuse`` are the foreshortening
    exponent and the diffuse intensity; ``by`` and ``along`` the lobe's slope (see
    :class:`~.lobes.LobeSlopes`), ``by_r`` its slope by the distance to the light
    (under a light's disc; None for a point light) and ``by_cosines`` its slopes by
    ``cos_i``, ``cos_o`` and ``cos_io`` (under the disc's ellipse; None otherwise).
    """
    inv_r, inv_half = 1.0 / g.r, 1.0 / g.half_norm
    rho = g.tq_b * inv_r  # dr = rho dt (r^2 = a - 2 t b + t^2 q)
    kappa = g.cos_io * rho  # d cos_io = kappa dt (cos_io = (t q - b) / (sqrt(q) r))
    np.subtract(reflection.sqrt_q, kappa, out=kappa)
    kappa *= inv_r
    # d grazing = kappa ((1 - grazing) / half_norm - 1) / half_norm dt
    grazing_t = (1.0 - g.grazing) * inv_half
    grazing_t -= 1.0
    grazing_t *= kappa
    grazing_t *= inv_half
    # d log F / dx with x = grazing = 1 - cos: -F'(cos) / F
    fresnel_slope = g.fresnel_slope / g.fresnel
    np.negative(fresnel_slope, out=fresnel_slope)
    # The model's slope on d cos_h, on the specular factor's relative change and on
    # the diffuse factor's relative change.
    on_cos_h = by * spec_term
    if along is g.sin2_h:  # d sin^2 = -2 cos_h d cos_h
        on_cos_h *= -2.0 * g.cos_h
    on_spec = shape * spec_term
    on_diffuse = diffuse * (g.diffuse + 1.0)
    # cos_h = (cos_i + cos_o) / half_norm, half_norm = sqrt(2 + 2 cos_io)
    through_h = on_cos_h * inv_half
    # specular factor F (cos_i cos_o)^k / (cos_o r^2), diffuse factor cos_i / r^2
    on_cos_i = fore * on_spec
    on_cos_i += on_diffuse
    on_cos_i /= g.cos_i
    on_cos_i += through_h
    on_cos_o = (fore - 1.0) * on_spec
    on_cos_o /= g.cos_o
    on_cos_o += through_h
    if by_cosines is not None:  # the ellipse's stretch and turn
        on_cos_i += by_cosines[0] * spec_term
        on_cos_o += by_cosines[1] * spec_term
    # everything that moves with the ray parameter t directly
    on_t = fresnel_slope * grazing_t
    on_t *= on_spec
    term = through_h * g.cos_h
    term *= kappa
    term *= inv_half
    on_t -= term
    term = on_spec + on_diffuse
    term *= rho
    term *= 2.0 * inv_r  # d log r^2 = 2 rho / r dt
    on_t -= term
    if by_r is not None:  # the light's disc: its size moves with r, and dr = rho dt
        term = by_r * spec_term
        term *= rho
        on_t += term
    if by_cosines is not None:  # and its ellipse with cos_io: d cos_io = kappa dt
        term = by_cosines[2] * spec_term
        term *= kappa
        on_t += term
    # cos_i = (n . L - c) / r: d cos_i = (d(n . L - c) - cos_i rho dt) / r
    on_lh = on_cos_i * inv_r
    term = on_lh * g.cos_i
    term *= rho
    on_t -= term
    # t = (c - n . C) / (n . k): dt = (d(c - n . C) - t d(n . k)) / (n . k)
    on_cam = on_t / g.nk
    # cos_o = -(n . k) / sqrt(q)
    on_nk = on_cos_o / reflection.sqrt_q
    np.negative(on_nk, out=on_nk)
    on_nk -= on_cam * g.t
    return on_nk, on_cam, on_lh
