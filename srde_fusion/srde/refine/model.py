"""The lobe model: the highlight a glossy plane would show, as a function of 9 parameters.

See :mod:`~srde_fusion.srde.refine.plane` for the shading model. ``theta = (tilt_1,
tilt_2, offset_m, log_width, tail, foreshortening, specular, diffuse, level)``; the plane
parameters move the reflection geometry of every sample, the shape parameters the lobe,
and the intensities enter linearly and are solved in closed form at every evaluation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...geometry import CameraRig, Plane
from .layout import I_DIFF, I_FORE, I_LEVEL, I_SPEC, I_TAIL, I_WIDTH, N_PARAMS, N_PLANE
from .reflection import PlaneReflection, ShadingGeometry
from .samples import HighlightSamples
from .solver import solve_normal

__all__ = [
    "LOBES",
    "DEFAULT_LOBE",
    "LobeFit",
]

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


#: Fresnel reflectance at normal incidence assumed for the Schlick term (dielectrics).
DEFAULT_F0 = 0.04


# --- optimisation ---------------------------------------------------------------------
# Start: lobe widths scanned with a GGX tail, then other tails around the best width.
WIDTH_GRID = np.geomspace(0.002, 0.4, 11)
_TAIL_GRID = (0.5, 0.25, 0.0)
_WIDTH_REFINE_FACTORS = (0.85, 1.0, 1.2)


# A start whose lobe stays below this (relative to its peak) on every unsaturated sample
# is invisible: skipped.
_MIN_LOBE_ON_UNCLIPPED = 1e-3


# Bounds keep the shape parameters where the model is meaningful. Tails heavier than
# 0.75 let a hugely clipped needle lobe mimic a broad one.
_WIDTH_BOUNDS = (1e-3, 1.0)
_TAIL_BOUNDS = (-0.25, 0.75)
FORESHORTENING_BOUNDS = (-4.0, 5.0)


# Fitted foreshortening exponent starts here, halfway between the conventions.
_FORESHORTENING_START = 0.5


# |tail| below this is the Gaussian limit exp(-z) of the "gtr" lobe.
_ZERO_TAIL = 1e-9


# |t z| below this takes the lobe's derivative by its tail from a series (no cancellation).
_SMALL_TAIL_Z = 1e-3


# Passes of the active-set solve for the intensities (saturated samples in or out).
_ACTIVE_SET_PASSES = 4


@dataclass(frozen=True)
class LobeFit:
    """Photometric parameters of a fit (what the plane's refinement could not know).

    Parameters
    ----------
    width : float
        Lobe width ``w`` (see :data:`LOBES`; the GGX roughness alpha for ``"ggx"`` and for
        ``"gtr"`` at ``tail = 0.5``), dimensionless.
    tail : float
        Tail parameter ``t`` of ``"gtr"`` (0.5 for ``"ggx"``; 0 for ``"blinn_phong"``,
        whose shape is fixed).
    foreshortening : float
        Exponent ``k`` of ``(cos(theta_i) cos(theta_o))^k`` in the specular term
        (0: microfacet BRDF, 1: Phong-style).
    specular : float
        Peak specular luminance at the initial highlight's geometry, linear units.
    diffuse : float
        Diffuse luminance near the highlight, linear units.
    ambient : float
        Constant luminance (ambient light times albedo, flare), linear units.
    """

    width: float
    tail: float
    foreshortening: float
    specular: float
    diffuse: float
    ambient: float


class LobeModel:
    """The highlight rendering of :func:`refine_plane` as a function of 9 parameters.

    ``theta = (tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular,
    diffuse, level)``: the normal is ``normalise(n0 + tilt_1 e1 + tilt_2 e2)`` with
    ``e1, e2`` orthonormal to the initial normal ``n0``; the offset is ``c0 + offset_m``.
    The last three (intensities) are linear and solved at every evaluation; the fit
    moves the others (``free_*`` lists which).
    """

    def __init__(self, samples: HighlightSamples, rig: CameraRig, box, light: np.ndarray,
                 plane0: Plane, lobe: str, f0: float, foreshortening: float | None) -> None:
        self.lobe = lobe
        self.reflection = PlaneReflection(samples, rig, box, light, plane0, f0)
        self.valid = self.reflection.valid
        self.foreshortening0 = (_FORESHORTENING_START if foreshortening is None
                                else float(foreshortening))
        self.y = samples.luminance
        self.censored = samples.saturated
        self.n_unclipped = int(np.count_nonzero(~samples.saturated))  # they come first
        self._lobe_key: bytes | None = None
        self._lobe_value = None
        self._specular_key = None
        self._specular_value = self._specular_geometry = None
        self._terms_geometry = self._terms = None
        self._sum_unclipped_y = float(self.y[:self.n_unclipped].sum())
        # Reused across steps: arrays this large would cost page faults on every call.
        self._ones = np.ones(self.y.shape)
        self._basis_buffer = np.empty((3, len(self.y)))
        self._basis_partner = np.empty((3, len(self.y)))
        self.initial_cost = math.inf  # cost of the start found by initial_guess
        shape = [I_WIDTH] + ([I_TAIL] if lobe == "gtr" else [])
        shape += [I_FORE] if foreshortening is None else []
        self.free_photometric = np.array(shape)
        self.free_all = np.array(list(range(N_PLANE)) + shape)
        self._jacobian_buffer = np.empty((len(self.free_all), len(self.y)))
        self._jacobian_partner = np.empty_like(self._jacobian_buffer)

    def plane(self, theta: np.ndarray) -> Plane:
        """Return the plane of ``theta``."""
        return self.reflection.plane(theta)

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the stereo disparity at the probe pixels between two thetas."""
        return self.reflection.disparity_change_px(before, after)

    def start_theta(self) -> np.ndarray:
        theta = np.zeros(N_PARAMS)
        theta[I_WIDTH] = math.log(0.1)
        theta[I_TAIL] = 0.5 if self.lobe != "blinn_phong" else 0.0
        theta[I_FORE] = self.foreshortening0
        return theta

    # ------------------------------------------------------------------ geometry
    def _lobe(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        """Specular term ``S(n . h) g_s`` with the peak-normalised lobe ``S``, ``(P,)``."""
        return self._shape(g, theta) * self._specular_term(g, theta[I_FORE])

    def _shape(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        """Return the peak-normalised lobe ``S(n . h)``, ``(P,)``."""
        alpha2 = math.exp(2.0 * theta[I_WIDTH])
        if self.lobe == "ggx":
            ratio = alpha2 / (alpha2 + g.sin2_h * (1.0 - alpha2))
            return ratio * ratio
        if self.lobe == "gtr":
            tail = theta[I_TAIL]
            z = g.sin2_h * (2.0 * (1.0 - alpha2) / alpha2)
            if abs(tail) < _ZERO_TAIL:
                return np.exp(-z)
            # (1 + t z)^(-1/t); where a light tail (t < 0) ends, the lobe is 0.
            return np.exp(np.log(np.maximum(1.0 + tail * z, 1e-300)) * (-1.0 / tail))
        with np.errstate(divide="ignore"):
            return np.exp((2.0 / alpha2 - 2.0) * np.log(np.maximum(g.cos_h, 0.0)))

    def _shape_slopes(self, g: ShadingGeometry, theta: np.ndarray, shape: np.ndarray):
        """Return derivatives of :meth:`_shape` ``(P,)`` by the geometry and the shape.

        Returns ``(by, along, by_log_width, by_tail)``: the lobe's derivative is
        ``by * d(along)`` for ``along`` one of ``g.sin2_h`` or ``g.cos_h``; ``by_tail`` is
        None unless the lobe is ``"gtr"``. Where a lobe is exactly 0 (a light tail's end,
        or beyond 90 degrees) all are 0.
        """
        alpha2 = math.exp(2.0 * theta[I_WIDTH])
        if self.lobe == "ggx":
            # S = (a2 / D)^2 with D = a2 + s (1 - a2)
            inv_den = 1.0 / (alpha2 + g.sin2_h * (1.0 - alpha2))
            return (-2.0 * (1.0 - alpha2)) * shape * inv_den, g.sin2_h, \
                4.0 * shape * g.sin2_h * inv_den, None
        if self.lobe == "blinn_phong":
            # S = cos_h^e with e = 2 / a2 - 2
            positive = np.maximum(g.cos_h, 1e-300)
            by_cos = (2.0 / alpha2 - 2.0) * shape / positive
            return by_cos, g.cos_h, (-4.0 / alpha2) * shape * np.log(positive), None
        # gtr: S = (1 + t z)^(-1/t) with z = s f, f = 2 (1 - a2) / a2
        tail = theta[I_TAIL]
        factor = 2.0 * (1.0 - alpha2) / alpha2
        z = g.sin2_h * factor
        if abs(tail) < _ZERO_TAIL:  # S = exp(-z)
            return -factor * shape, g.sin2_h, (4.0 / alpha2) * shape * g.sin2_h, \
                0.5 * shape * z * z
        u = tail * z
        base = np.maximum(1.0 + u, 1e-300)
        by_z = shape / base  # dS/dz = -S / (1 + t z)
        by_log_width = (4.0 / alpha2) * by_z * g.sin2_h
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
        return -factor * by_z, g.sin2_h, by_log_width, by_tail

    def _specular_term(self, g: ShadingGeometry, foreshortening: float) -> np.ndarray:
        """``g_s (cos_i cos_o)^k`` of a geometry, ``(P,)``; the last one is kept."""
        if self._specular_key != (id(g), foreshortening):
            term = g.specular
            if foreshortening != 0.0:
                term = np.exp(foreshortening * g.log_foreshortening)
                term *= g.specular
            self._specular_key, self._specular_value = (id(g), foreshortening), term
            self._specular_geometry = g  # keeps id(g) from being reused while cached
        return self._specular_value

    def _model(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        return theta[I_SPEC] * self._lobe(g, theta) + theta[I_DIFF] * g.diffuse + theta[I_LEVEL]

    # ------------------------------------------------------------------ residuals
    def _residual(self, model: np.ndarray) -> np.ndarray:
        """Return model minus observation, ``(P,)``.

        Saturated samples are lower bounds: for them only a model below the observation
        is an error.
        """
        r = model - self.y
        np.minimum(r[self.n_unclipped:], 0.0, out=r[self.n_unclipped:])  # saturated come last
        return r

    def _intensity_terms(self, g: ShadingGeometry):
        """Return the sums over unsaturated samples that do not depend on the lobe (cached).

        ``(d . d, sum d)`` of the diffuse term ``d`` and ``d . y`` with the observations.
        """
        if self._terms_geometry is not g:
            d = g.diffuse[:self.n_unclipped]
            self._terms = float(d @ d), float(d.sum()), float(d @ self.y[:self.n_unclipped])
            self._terms_geometry = g
        return self._terms

    def _intensities(self, g: ShadingGeometry, lobe: np.ndarray):
        """Specular, diffuse and level ``(3,)`` for a lobe ``(P,)``, by least squares.

        The basis is ``(lobe, g_d - 1, 1)``. Saturated samples count only where the
        model falls below them, which depends on the solution: a few active-set passes
        settle it. Returns the coefficients and the model ``(P,)``.
        """
        k = self.n_unclipped
        dd, d1, dy = self._intensity_terms(g)
        head, y_head = lobe[:k], self.y[:k]
        ld = float(head @ g.diffuse[:k])
        l1 = float(head.sum())
        normal0 = np.array([[float(head @ head), ld, l1], [ld, dd, d1], [l1, d1, float(k)]])
        rhs0 = np.array([float(head @ y_head), dy, self._sum_unclipped_y])
        coef = solve_normal(normal0, rhs0)
        if k < len(lobe):
            clipped = np.stack([lobe[k:], g.diffuse[k:], self._ones[k:]])  # (3, P - k)
            clipped_y = self.y[k:]
            active = np.zeros(len(clipped_y), dtype=bool)
            for _ in range(_ACTIVE_SET_PASSES - 1):
                now_active = coef @ clipped < clipped_y
                if not np.any(now_active ^ active):
                    break
                active = now_active
                cols = clipped[:, active]
                coef = solve_normal(normal0 + cols @ cols.T, rhs0 + cols @ clipped_y[active])
        model = lobe * coef[0]
        model += coef[1] * g.diffuse
        model += coef[2]
        return coef, model

    def _lobe_at(self, theta: np.ndarray):
        """Return the geometry, lobe and shape ``(P,)`` of ``theta`` (Nones if invalid).

        The last one is kept: a step's Jacobian is taken where it was evaluated.
        """
        key = theta[:I_SPEC].tobytes()
        if self._lobe_key != key:
            g = self.reflection.at(theta)
            if g is None:
                self._lobe_value = (None, None, None)
            else:
                shape = self._shape(g, theta)
                self._lobe_value = (g, shape * self._specular_term(g, theta[I_FORE]), shape)
            self._lobe_key = key
        return self._lobe_value

    def evaluate(self, theta: np.ndarray):
        """Residual at ``theta``'s plane and lobe shape with the best intensities.

        Returns the residual ``(P,)`` and ``theta`` with those intensities filled in.
        """
        g, lobe, _ = self._lobe_at(theta)
        if g is None:
            return np.full(self.y.shape, np.inf), theta.copy()
        coef, model = self._intensities(g, lobe)
        out = theta.copy()
        out[I_SPEC:] = coef
        return self._residual(model), out

    def jacobian(self, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Transposed Jacobian ``(len(free), P)`` of :meth:`evaluate`'s residual.

        Variable projection with Kaufman's approximation: the model's derivative at fixed
        intensities (:meth:`model_slopes`), with its component in the span of the
        intensity basis removed. The array is a buffer of the model's, overwritten by
        the next call.
        """
        g, lobe, _ = self._lobe_at(theta)
        jac = self.model_slopes(theta, free, out=self._jacobian_buffer[:len(free)])
        basis = self._basis_buffer
        basis[0] = lobe
        basis[1] = g.diffuse
        basis[2] = 1.0
        model = theta[I_SPEC:] @ basis
        # A saturated sample above its lower bound contributes nothing, nor does its slope.
        ignored = self.censored & (model >= self.y)
        if ignored.any():
            jac[:, ignored] = 0.0
            basis[:, ignored] = 0.0
        partner = self._basis_partner  # (see gram)
        np.copyto(partner, basis)
        coef = solve_normal(basis @ partner.T, basis @ jac.T)  # (3, K)
        jac -= coef.T @ basis
        return jac

    def gram(self, jac: np.ndarray) -> np.ndarray:
        """Return ``jac @ jac.T`` ``(K, K)`` for a Jacobian from :meth:`jacobian`.

        numpy computes ``A @ A.T`` by a rank-k update, several times slower here than a
        product with a copy of ``A``.
        """
        partner = self._jacobian_partner[:len(jac)]
        np.copyto(partner, jac)
        return jac @ partner.T

    def model_slopes(self, theta: np.ndarray, free: np.ndarray, *,
                     out: np.ndarray | None = None) -> np.ndarray:
        """Return the model's derivatives ``(len(free), P)`` by ``theta[free]`` (intensities held).

        Analytic, by the chain rule through the ray-plane algebra of :meth:`_geometry`
        (see :meth:`_plane_slope_terms`) and the lobe shapes. ``theta``'s plane must be
        valid.
        """
        g, lobe, shape = self._lobe_at(theta)
        out = np.empty((len(free), len(lobe))) if out is None else out
        specular, fore = theta[I_SPEC], theta[I_FORE]
        by, along, by_log_width, by_tail = self._shape_slopes(g, theta, shape)
        spec_term = specular * self._specular_term(g, fore)  # S's factor in the model
        planes = [(row, index) for row, index in enumerate(free) if index < N_PLANE]
        if planes:
            on_nk, on_cam, on_lh = self._plane_slope_terms(g, theta, by, along, shape, spec_term)
            directions = self.reflection.directions(theta)
        for row, index in planes:
            # slope = (n . L - c)' on_lh + (c - n . C)' on_cam + (n . k)' on_nk
            dn, dc = directions[index]
            slope = out[row]
            slope[:] = dc * (on_cam - on_lh)
            if dn.any():
                slope += float(dn @ self.reflection.light) * on_lh
                slope -= on_cam * (dn @ self.reflection.camera_t)
                slope += on_nk * (dn @ self.reflection.ray_t)
        for row, index in enumerate(free):
            if index == I_WIDTH:
                np.multiply(by_log_width, spec_term, out=out[row])
            elif index == I_TAIL:
                np.multiply(by_tail, spec_term, out=out[row])
            elif index == I_FORE:  # the exponent multiplies log(cos_i cos_o)
                np.multiply(lobe, g.log_foreshortening, out=out[row])
                out[row] *= specular
        return out

    def _plane_slope_terms(self, g: ShadingGeometry, theta: np.ndarray, by: np.ndarray,
                           along: np.ndarray, shape: np.ndarray, spec_term: np.ndarray):
        """Return the model's derivatives ``(P,)`` by ``n . k``, ``c - n . C``, ``n . L - c``.

        Every shading term depends on the plane through these three per-sample scalars
        (``k`` the ray, ``C`` the camera centre, ``L`` the light), and linearly so to
        first order: collecting the chain rule's coefficients once makes each plane
        parameter's slope three products.
        """
        fore = theta[I_FORE]
        inv_r, inv_half = 1.0 / g.r, 1.0 / g.half_norm
        rho = g.tq_b * inv_r  # dr = rho dt (r^2 = a - 2 t b + t^2 q)
        kappa = g.cos_io * rho  # d cos_io = kappa dt (cos_io = (t q - b) / (sqrt(q) r))
        np.subtract(self.reflection.sqrt_q, kappa, out=kappa)
        kappa *= inv_r
        # d grazing = kappa ((1 - grazing) / half_norm - 1) / half_norm dt
        grazing_t = (1.0 - g.grazing) * inv_half
        grazing_t -= 1.0
        grazing_t *= kappa
        grazing_t *= inv_half
        # d log F = 5 (1 - f0) x^4 / F dx, x = grazing (Schlick)
        fresnel_slope = g.grazing * g.grazing
        fresnel_slope *= fresnel_slope
        fresnel_slope *= 5.0 * (1.0 - self.reflection.f0) / g.fresnel
        # The model's slope on d cos_h, on the specular factor's relative change and on
        # the diffuse factor's relative change.
        on_cos_h = by * spec_term
        if along is g.sin2_h:  # d sin^2 = -2 cos_h d cos_h
            on_cos_h *= -2.0 * g.cos_h
        on_spec = shape * spec_term
        on_diffuse = theta[I_DIFF] * (g.diffuse + 1.0)
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
        # cos_i = (n . L - c) / r: d cos_i = (d(n . L - c) - cos_i rho dt) / r
        on_lh = on_cos_i * inv_r
        term = on_lh * g.cos_i
        term *= rho
        on_t -= term
        # t = (c - n . C) / (n . k): dt = (d(c - n . C) - t d(n . k)) / (n . k)
        on_cam = on_t / g.nk
        # cos_o = -(n . k) / sqrt(q)
        on_nk = on_cos_o / self.reflection.sqrt_q
        np.negative(on_nk, out=on_nk)
        on_nk -= on_cam * g.t
        return on_nk, on_cam, on_lh

    # ------------------------------------------------------------------ start and report
    def initial_guess(self) -> np.ndarray | None:
        """Parameters at the initial plane: the best lobe shape on a grid.

        Intensities are fitted for every candidate; None if no lobe gives a positive
        specular term.
        """
        g = self.reflection.at(self.start_theta())
        best_cost, best = math.inf, None

        def consider(width: float, tail: float) -> None:
            nonlocal best_cost, best
            theta = self.start_theta()
            theta[I_WIDTH], theta[I_TAIL] = math.log(width), tail
            lobe = self._lobe(g, theta)
            if not lobe[:self.n_unclipped].max(initial=0.0) > _MIN_LOBE_ON_UNCLIPPED:
                return  # so narrow that no unsaturated sample sees it
            coef, model = self._intensities(g, lobe)
            if not coef[0] > 0.0:
                return
            residual = self._residual(model)
            cost = float(residual @ residual) / len(residual)
            if cost < best_cost:
                best_cost, best = cost, theta
                best[I_SPEC:] = coef

        # Widths first with the default tail, then other tails around the best width.
        for width in WIDTH_GRID:
            consider(width, self.start_theta()[I_TAIL])
        if best is not None and I_TAIL in self.free_all:
            best_width = math.exp(best[I_WIDTH])
            for factor in _WIDTH_REFINE_FACTORS:
                for tail in _TAIL_GRID[1:]:
                    consider(best_width * factor, tail)
        self.initial_cost = best_cost
        return best

    def _bounds(self):
        return {I_WIDTH: np.log(_WIDTH_BOUNDS), I_TAIL: _TAIL_BOUNDS,
                I_FORE: FORESHORTENING_BOUNDS}

    def clamp(self, theta: np.ndarray) -> np.ndarray:
        for index, (low, high) in self._bounds().items():
            theta[index] = min(max(theta[index], low), high)
        return theta

    def parameters_at_bounds(self, theta: np.ndarray) -> str:
        """Name and value of fitted shape parameters stuck at a bound ("" if none)."""
        names = {I_WIDTH: "width", I_TAIL: "tail", I_FORE: "foreshortening"}
        stuck = []
        for index, (low, high) in self._bounds().items():
            if index in self.free_all and min(theta[index] - low, high - theta[index]) < 1e-9:
                value = math.exp(theta[index]) if index == I_WIDTH else theta[index]
                stuck.append(f"{names[index]} {value:.4g}")
        return ", ".join(stuck)

    def lobe_fit(self, theta: np.ndarray) -> LobeFit:
        return LobeFit(width=float(np.exp(theta[I_WIDTH])), tail=float(theta[I_TAIL]),
                       foreshortening=float(theta[I_FORE]), specular=float(theta[I_SPEC]),
                       diffuse=float(theta[I_DIFF]),
                       ambient=float(theta[I_LEVEL] - theta[I_DIFF]))
