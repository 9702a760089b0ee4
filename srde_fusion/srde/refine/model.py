"""The lobe model: the highlight a glossy plane would show, as a function of 9 parameters.

The shading model, for a sample whose ray meets the plane at X (array frame, metres)::

    Y = level + diffuse * (g_d - 1) + specular * S(n . h) * g_s

    g_d = cos(theta_i) / r^2
    g_s = F(omega_i . h) * (cos(theta_i) cos(theta_o))^k / (cos(theta_o) r^2)

``g_d`` and ``g_s`` are normalised to a median of 1 over the samples at the initial plane,
so ``specular`` and ``diffuse`` read as luminances at the highlight and
``level = ambient + diffuse``. ``r`` is the distance from X to the light, ``h`` the half
vector between the directions to the light and to the camera, ``F`` the Fresnel
term and ``S`` the lobe scaled to a peak of 1. The foreshortening exponent ``k`` spans the
conventions in use: ``k = 0`` is the Cook-Torrance microfacet BRDF
``D F G / (4 cos(theta_i) cos(theta_o))`` (its radiance under a point light is
``I D F G / (4 cos(theta_o) r^2)``; ``G ~ 1`` near the mirror direction), ``k = 1`` a
Phong-style BRDF without the ``1 / (4 cos cos)`` factor. Near the mirror direction the
factor tilts the lobe across the image, which shifts its peak, so it must be modelled
(or fitted) rather than ignored.

Each sample is the mean luminance of a square of pixels, so the model is averaged over
the same square (``samples.support_points``): the rendering runs at ``S`` points per
sample and is reduced with their quadrature weights before it meets the data.

``theta = (tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular, diffuse,
level)`` (see ``layout``): the plane parameters move the reflection geometry of every
sample (``reflection``), the shape parameters the lobe (``lobes``), and the intensities
enter linearly and are solved in closed form at every evaluation (``intensities``); the
derivatives are analytic (``slopes``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...geometry import CameraRig, Plane
from .intensities import IntensitySolver
from .layout import I_DIFF, I_FORE, I_LEVEL, I_SPEC, I_TAIL, I_WIDTH, N_PARAMS, N_PLANE
from .lobes import lobe_shape, start_tail
from .reflection import PlaneReflection, ShadingGeometry
from .samples import HighlightSamples, support_points
from .slopes import model_slopes

__all__ = [
    "LobeFit",
    "LobeModel",
]

#: Fresnel reflectance at normal incidence assumed (a dielectric of refractive index 1.5).
DEFAULT_F0 = 0.04


#: The Fresnel terms the model can use (see :class:`~.reflection.PlaneReflection`).
FRESNEL_TERMS = ("exact", "schlick")


#: Gauss-Legendre points per axis over which the model is averaged on each sample's block.
SUPPORT_POINTS = 2


@dataclass(frozen=True, eq=False)
class SampleShading:
    """The part of a geometry the intensity solve reads, reduced to the samples, ``(P,)``."""

    diffuse: np.ndarray


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
#: A shape parameter this close to a bound, as a fraction of its range, is at the bound.
AT_BOUND_FRACTION = 1e-3


# Fitted foreshortening exponent starts here, halfway between the conventions.
_FORESHORTENING_START = 0.5


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
    moves the others (``free_*`` lists which). A :class:`~.solver.LeastSquaresModel`.

    Parameters
    ----------
    samples : HighlightSamples
    rig : CameraRig
    box : (int, int, int, int)
        ``(x, y, w, h)`` of the object in the reference view (see :class:`PlaneReflection`).
    light : numpy.ndarray, (3,)
        The light, array frame, metres.
    plane0 : Plane
        The plane ``theta``'s plane parameters are relative to.
    lobe : {"gtr", "ggx", "blinn_phong"}
    f0 : float
        Normal-incidence reflectance of the surface.
    foreshortening : float or None
        The exponent ``k``, held; fitted if None.
    fresnel : {"exact", "schlick"}
        The Fresnel term (see :class:`PlaneReflection`).
    support : int
        Points per axis at which the model is averaged over each sample's block (1: at
        block centres); an every-pixel sample is read at its centre
        (:data:`~.samples.PIXEL_SUPPORT_POINTS`).
    light_radius_m : float or None
        Radius of the spherical light, metres: the lobe is seen through the light's disc
        (:mod:`~.disc`). None or 0: a point light.
    disc_rings : int or None
        Rings of the pattern of points over the light's disc (:func:`~.disc.disc_points`);
        None: the most the samples need (:class:`PlaneReflection`).
    """

    def __init__(self, samples: HighlightSamples, rig: CameraRig, box, light: np.ndarray,
                 plane0: Plane, lobe: str, f0: float, foreshortening: float | None,
                 support: int = SUPPORT_POINTS, fresnel: str = "exact",
                 light_radius_m: float | None = None, disc_rings: int | None = None) -> None:
        self.lobe = lobe
        points, self.support_weights = support_points(samples, rig, support)
        self.n_support = len(self.support_weights)
        self.reflection = PlaneReflection(points, rig, box, light, plane0, f0, fresnel,
                                          light_radius_m, disc_rings)
        self.valid = self.reflection.valid
        self.foreshortening0 = (_FORESHORTENING_START if foreshortening is None
                                else float(foreshortening))
        self.intensities = IntensitySolver(samples)
        self._lobe_key: bytes | None = None
        self._lobe_value = None
        self._specular_key = None
        self._specular_value = self._specular_geometry = None
        self._shading = self._shading_geometry = None
        self.initial_cost = math.inf  # cost of the start found by initial_guess
        shape = [I_WIDTH] + ([I_TAIL] if lobe == "gtr" else [])
        shape += [I_FORE] if foreshortening is None else []
        self.free_photometric = np.array(shape)
        self.free_all = np.array(list(range(N_PLANE)) + shape)
        # Reused across steps: arrays this large would cost page faults on every call.
        self._jacobian_buffer = np.empty((len(self.free_all), samples.n_samples))
        self._jacobian_partner = np.empty_like(self._jacobian_buffer)
        self._slopes_buffer = (self._jacobian_buffer if self.n_support == 1 else
                               np.empty((len(self.free_all), points.n_samples)))

    def reduce(self, values: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Average model values ``(..., S * P)`` over each sample's support, ``(..., P)``."""
        if self.n_support == 1:
            return values  # the model points are the samples (``out`` is not needed)
        grouped = values.reshape(*values.shape[:-1], self.n_support, -1)
        return np.einsum("...sp,s->...p", grouped, self.support_weights, out=out)

    def _reduced(self, g: ShadingGeometry) -> SampleShading:
        """Return the samples' diffuse term of a geometry of the model points.

        Kept for the last geometry: the plane stays while the lobe's shape moves, and the
        intensity solve caches its diffuse sums on this object's identity.
        """
        if self._shading_geometry is not g:
            self._shading = SampleShading(self.reduce(g.diffuse))
            self._shading_geometry = g
        return self._shading

    def plane(self, theta: np.ndarray) -> Plane:
        """Return the plane of ``theta``."""
        return self.reflection.plane(theta)

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the stereo disparity at the probe pixels between two thetas."""
        return self.reflection.disparity_change_px(before, after)

    def probe_disparity_px(self, thetas: np.ndarray) -> np.ndarray:
        """Return the stereo disparity ``(B, 4)`` of ``thetas``' planes at the box corners."""
        return self.reflection.probe_disparity_px(thetas)

    def start_theta(self) -> np.ndarray:
        """Parameters at the initial plane with a mid-range lobe, intensities 0."""
        theta = np.zeros(N_PARAMS)
        theta[I_WIDTH] = math.log(0.1)
        theta[I_TAIL] = start_tail(self.lobe)
        theta[I_FORE] = self.foreshortening0
        return theta

    # ------------------------------------------------------------------ the rendering
    def _lobe(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        """Specular term ``S(n . h) g_s`` with the peak-normalised lobe ``S``, ``(P,)``."""
        return self._shape(g, theta) * self._specular_term(g, theta[I_FORE])

    def _shape(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        """Return the peak-normalised lobe ``S(n . h)``, ``(P,)``."""
        return lobe_shape(self.lobe, g, theta[I_WIDTH], theta[I_TAIL])

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

    def luminance(self, g: ShadingGeometry, theta: np.ndarray) -> np.ndarray:
        """Modelled luminance of the samples ``(P,)``: ``theta``'s lobe and intensities."""
        point = theta[I_SPEC] * self._lobe(g, theta) + theta[I_DIFF] * g.diffuse + theta[I_LEVEL]
        return self.reduce(point)

    def lobe_at(self, theta: np.ndarray):
        """Return ``theta``'s geometry, lobe, shape, and the samples' shading and lobe.

        Geometry, lobe and shape are at the model points ``(S * P,)``, the shading and
        the lobe reduced to the samples ``(P,)``; Nones if the plane is invalid. The last one
        is kept: a step's Jacobian is taken where it was evaluated.
        """
        key = theta[:I_SPEC].tobytes()
        if self._lobe_key != key:
            g = self.reflection.at(theta)
            if g is None:
                self._lobe_value = (None, None, None, None, None)
            else:
                shape = self._shape(g, theta)
                lobe = shape * self._specular_term(g, theta[I_FORE])
                self._lobe_value = (g, lobe, shape, self._reduced(g), self.reduce(lobe))
            self._lobe_key = key
        return self._lobe_value

    # ------------------------------------------------------------------ least squares
    def evaluate(self, theta: np.ndarray):
        """Residual at ``theta``'s plane and lobe shape with the best intensities.

        Returns the residual ``(P,)`` and ``theta`` with those intensities filled in.
        """
        g, _, _, shading, lobe = self.lobe_at(theta)
        if g is None:
            return np.full(self.intensities.y.shape, np.inf), theta.copy()
        coef, model = self.intensities.solve(shading, lobe)
        out = theta.copy()
        out[I_SPEC:] = coef
        return self.intensities.residual(model), out

    def jacobian(self, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Transposed Jacobian ``(len(free), P)`` of :meth:`evaluate`'s residual.

        Variable projection with Kaufman's approximation: the model's derivative at fixed
        intensities (:meth:`model_slopes`), with its component in the span of the
        intensity basis removed. The array is a buffer of the model's, overwritten by
        the next call.
        """
        _, _, _, shading, lobe = self.lobe_at(theta)
        jac = self.slopes_at_samples(theta, free)
        return self.intensities.project_out(jac, shading, lobe, theta[I_SPEC:])

    def slopes_at_samples(self, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
        """:meth:`model_slopes` reduced to the samples, ``(len(free), P)``.

        A buffer of the model's, overwritten by the next call (as :meth:`jacobian`'s).
        """
        slopes = self.model_slopes(theta, free, out=self._slopes_buffer[:len(free)])
        return self.reduce(slopes, out=self._jacobian_buffer[:len(free)])

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
        """Return the model's derivatives ``(len(free), S * P)`` by ``theta[free]``.

        At the model points, intensities held (:meth:`reduce` gives the samples').
        Analytic (see :mod:`~.slopes`). ``theta``'s plane must be valid.
        """
        g, lobe, shape, _, _ = self.lobe_at(theta)
        out = np.empty((len(free), len(lobe))) if out is None else out
        return model_slopes(self.reflection, self.lobe, g, theta, free, lobe_term=lobe,
                            shape=shape, specular_factor=self._specular_term(g, theta[I_FORE]),
                            out=out)

    # ------------------------------------------------------------------ start and report
    def initial_guess(self) -> np.ndarray | None:
        """Parameters at the initial plane: the best lobe shape on a grid.

        Intensities are fitted for every candidate; None if no lobe gives a positive
        specular term.
        """
        g = self.reflection.at(self.start_theta())
        shading = self._reduced(g)
        n_unclipped = self.intensities.n_unclipped
        best_cost, best = math.inf, None

        def consider(width: float, tail: float) -> None:
            nonlocal best_cost, best
            theta = self.start_theta()
            theta[I_WIDTH], theta[I_TAIL] = math.log(width), tail
            lobe = self.reduce(self._lobe(g, theta))
            if not lobe[:n_unclipped].max(initial=0.0) > _MIN_LOBE_ON_UNCLIPPED:
                return  # so narrow that no unsaturated sample sees it
            coef, model = self.intensities.solve(shading, lobe)
            if not coef[0] > 0.0:
                return
            residual = self.intensities.residual(model)
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
        """Move ``theta``'s shape parameters inside their bounds (in place) and return it."""
        for index, (low, high) in self._bounds().items():
            theta[index] = min(max(theta[index], low), high)
        return theta

    def at_bound(self, theta: np.ndarray, index: int) -> bool:
        """Whether shape parameter ``index`` (I_WIDTH, I_TAIL, I_FORE) is fitted and stuck.

        Stuck means at a bound of its range, within :data:`AT_BOUND_FRACTION` of the range
        (a solver may stop a hair short of the bound it is pushing against, by how much
        depends on the machine's arithmetic); a held parameter never is.
        """
        low, high = self._bounds()[index]
        slack = AT_BOUND_FRACTION * (high - low)
        return index in self.free_all and min(theta[index] - low, high - theta[index]) < slack

    def parameters_at_bounds(self, theta: np.ndarray) -> str:
        """Name and value of fitted shape parameters stuck at a bound ("" if none)."""
        names = {I_WIDTH: "width", I_TAIL: "tail", I_FORE: "foreshortening"}
        return ", ".join(
            f"{names[index]} {math.exp(theta[index]) if index == I_WIDTH else theta[index]:.4g}"
            for index in self._bounds() if self.at_bound(theta, index))

    def lobe_fit(self, theta: np.ndarray) -> LobeFit:
        """Return the photometric parameters of ``theta``."""
        return LobeFit(width=float(np.exp(theta[I_WIDTH])), tail=float(theta[I_TAIL]),
                       foreshortening=float(theta[I_FORE]), specular=float(theta[I_SPEC]),
                       diffuse=float(theta[I_DIFF]),
                       ambient=float(theta[I_LEVEL] - theta[I_DIFF]))
