"""Several lights in one fit: a lobe per light, one plane, one surface.

Two lights close to each other put their highlights close together; on a rough coating
the two merge into one blob whose centre belongs to neither light, so no centroid
measures either virtual light. The image still holds the answer: the blob is the sum of
two lobes of the *same* surface (one roughness, one Fresnel term, one foreshortening),
each lit by its own known light and mirrored by the *same* plane. :class:`JointLobeModel`
renders that sum, one :class:`~.model.LobeModel` per light sharing the plane and shape
parameters, each light with its own specular intensity. Every further known light also sheds
diffuse light on the samples, each with an intensity of its own (:mod:`~.diffuse`):
the windows of different views lie on different parts of the surface, where another
lamp's diffuse light is not one constant level. The same model with one part and only
further lights' diffuse terms serves a light whose neighbours' highlights are out of
its windows.

``theta`` is the single light's layout (see ``layout``) followed by the specular
intensity of each further modelled light, then the diffuse intensity of each further
light: ``(tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular_0,
diffuse, level, specular_1, ..., specular_{K-1}, diffuse_1, ..., diffuse_M)``. All
intensities enter linearly and are solved in closed form at every evaluation, as for one
light; saturated samples are one-sided as there.
"""

from __future__ import annotations

import math

import numpy as np

from .diffuse import DiffuseLights
from .intensities import with_saturated
from .layout import I_DIFF, I_LEVEL, I_SPEC, I_TAIL, I_WIDTH, N_PARAMS
from .model import WIDTH_GRID, LobeFit, LobeModel

__all__ = ["JointLobeModel"]

# A further light whose lobe is this small (its squared norm over the samples, relative
# to the first light's) is not in the windows: its intensity is not fitted (held at 0).
_NEGLIGIBLE_LOBE = 1e-6


# Start: widths scanned with the families' default tail, then these around the best.
_TAILS = (0.25, 0.0)
_WIDTH_FACTORS = (0.85, 1.0, 1.2)


class JointLobeModel:
    """The highlights of several lights on one plane, a :class:`~.solver.LeastSquaresModel`.

    Parameters
    ----------
    parts : list of LobeModel
        One model per light whose lobe is rendered, all on the same samples and initial
        plane, the light whose highlight placed the windows first (its specular
        intensity must come out positive).
    diffuse_lights_m : numpy.ndarray, (M, 3), optional
        Further lights whose diffuse light is rendered (every light but the first that
        the rig knows, whether its lobe is rendered or not), array frame, metres.
    """

    def __init__(self, parts: list[LobeModel], diffuse_lights_m: np.ndarray | None = None
                 ) -> None:
        self.parts = parts
        first = parts[0]
        self.valid = first.valid and all(p.valid for p in parts)
        self.diffuse = (DiffuseLights(first.reflection, diffuse_lights_m, first.reduce)
                        if self.valid and diffuse_lights_m is not None
                        and len(diffuse_lights_m) else None)
        self.n_diffuse = 0 if self.diffuse is None else len(self.diffuse)
        self.intensities = first.intensities  # the observations and their clipping
        self.free_all = first.free_all
        self.free_photometric = first.free_photometric
        self.initial_cost = math.inf
        self.n_lights = len(parts)

    # ------------------------------------------------------------------ delegated
    def plane(self, theta: np.ndarray):
        """Return the plane of ``theta``."""
        return self.parts[0].plane(theta)

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the stereo disparity at the probe pixels between two thetas."""
        return self.parts[0].disparity_change_px(before, after)

    def probe_disparity_px(self, thetas: np.ndarray) -> np.ndarray:
        """Return the stereo disparity ``(B, 4)`` of ``thetas``' planes at the box corners."""
        return self.parts[0].probe_disparity_px(thetas)

    def clamp(self, theta: np.ndarray) -> np.ndarray:
        """Move ``theta``'s shape parameters inside their bounds (in place) and return it."""
        self.parts[0].clamp(theta)
        return theta

    def parameters_at_bounds(self, theta: np.ndarray) -> str:
        """Name and value of fitted shape parameters stuck at a bound ("" if none)."""
        return self.parts[0].parameters_at_bounds(theta)

    def at_bound(self, theta: np.ndarray, index: int) -> bool:
        """Whether shape parameter ``index`` is fitted and stuck at a bound of its range."""
        return self.parts[0].at_bound(theta, index)

    def lobe_fit(self, theta: np.ndarray) -> LobeFit:
        """Return the first light's photometric parameters (the surface's, its intensity)."""
        return self.parts[0].lobe_fit(theta[:N_PARAMS])

    def start_theta(self) -> np.ndarray:
        """Parameters at the initial plane with a mid-range lobe, intensities 0."""
        return np.concatenate([self.parts[0].start_theta(),
                               np.zeros(self.n_lights - 1 + self.n_diffuse)])

    def specular(self, theta: np.ndarray) -> np.ndarray:
        """Each rendered lobe's specular intensity ``(K,)``."""
        return np.concatenate([[theta[I_SPEC]], theta[N_PARAMS:N_PARAMS + self.n_lights - 1]])

    def further_diffuse(self, theta: np.ndarray) -> np.ndarray:
        """Each further light's diffuse intensity ``(M,)``."""
        return theta[N_PARAMS + self.n_lights - 1:]

    # ------------------------------------------------------------------ the rendering
    def _lobes(self, theta: np.ndarray):
        """Every part's lobe at the samples ``(K, P)`` and the diffuse terms, or Nones.

        The diffuse terms ``(1 + M, P)``: the first light's, then the further lights'.
        """
        lobes = []
        diffuse = None
        for k, part in enumerate(self.parts):
            g, _, _, part_shading, lobe = part.lobe_at(theta[:N_PARAMS])
            if g is None:
                return None, None
            if k == 0:
                diffuse = part_shading.diffuse[None, :]
            lobes.append(lobe)
        if self.diffuse is not None:
            further = self.diffuse.at(theta)
            if further is None:
                return None, None
            diffuse = np.vstack([diffuse, further])
        return np.stack(lobes), diffuse

    def _solve(self, lobes: np.ndarray, diffuse: np.ndarray):
        """Intensities ``(K + 1 + M + 1,)`` and the model.

        Specular per rendered lobe, diffuse per light, level.
        """
        solver = self.intensities
        y, k = solver.y, solver.n_unclipped
        basis = self._basis(lobes, diffuse)
        norms = np.einsum("bp,bp->b", basis[:, :k], basis[:, :k])
        # A further light whose lobe does not reach the samples has no intensity to fit.
        used = np.ones(len(basis), dtype=bool)
        used[1:self.n_lights] = norms[1:self.n_lights] > _NEGLIGIBLE_LOBE * max(norms[0], 1e-300)
        sub = basis[used]
        head = sub[:, :k]
        normal0 = head @ head.T
        rhs0 = head @ y[:k]
        coef_used = _solve_scaled(normal0, rhs0)
        if k < len(y):
            coef_used = with_saturated(coef_used, normal0, rhs0, sub[:, k:], y[k:],
                                       _solve_scaled)
        coef = np.zeros(len(basis))
        coef[used] = coef_used
        return coef, coef @ basis, basis

    def _basis(self, lobes: np.ndarray, diffuse: np.ndarray) -> np.ndarray:
        """Return the intensities' basis ``(K + 1 + M + 1, P)``: lobes, diffuse terms, 1."""
        return np.vstack([lobes, diffuse, np.ones((1, lobes.shape[1]))])

    def _theta_with(self, theta: np.ndarray, coef: np.ndarray) -> np.ndarray:
        out = theta.copy()
        k = self.n_lights
        out[I_SPEC] = coef[0]
        out[N_PARAMS:N_PARAMS + k - 1] = coef[1:k]
        out[I_DIFF] = coef[k]
        out[N_PARAMS + k - 1:] = coef[k + 1:-1]
        out[I_LEVEL] = coef[-1]
        return out

    def _coefficients(self, theta: np.ndarray) -> np.ndarray:
        """Return the intensities of ``theta`` in the basis' order (undo :meth:`_theta_with`)."""
        return np.concatenate([self.specular(theta), [theta[I_DIFF]],
                               self.further_diffuse(theta), [theta[I_LEVEL]]])

    # ------------------------------------------------------------------ least squares
    def evaluate(self, theta: np.ndarray):
        """Residual at ``theta``'s plane and lobe shape with the best intensities."""
        lobes, diffuse = self._lobes(theta)
        if lobes is None:
            return np.full(self.intensities.y.shape, np.inf), theta.copy()
        coef, model, _ = self._solve(lobes, diffuse)
        return self.intensities.residual(model), self._theta_with(theta, coef)

    def jacobian(self, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Transposed Jacobian ``(len(free), P)`` (variable projection, Kaufman's form)."""
        # ``theta`` comes from :meth:`evaluate`, its intensities already solved there.
        lobes, diffuse = self._lobes(theta)
        basis = self._basis(lobes, diffuse)
        spec = self.specular(theta)
        model = self._coefficients(theta) @ basis
        jac = np.zeros((len(free), len(model)))
        for k, part in enumerate(self.parts):
            if spec[k] == 0.0 and k > 0:
                continue
            # The part's slopes with its own intensity; the diffuse term's slope once.
            theta_k = theta[:N_PARAMS].copy()
            theta_k[I_SPEC] = spec[k]
            if k > 0:
                theta_k[I_DIFF] = 0.0
            jac += part.slopes_at_samples(theta_k, free)
        if self.diffuse is not None:
            self.diffuse.slopes(theta, self.further_diffuse(theta), free, jac)
        # A saturated sample above its lower bound contributes nothing, nor does its slope.
        ignored = self.intensities.censored & (model >= self.intensities.y)
        if ignored.any():
            jac[:, ignored] = 0.0
            basis = basis.copy()
            basis[:, ignored] = 0.0
        keep = np.einsum("bp,bp->b", basis, basis) > 0.0
        basis = basis[keep]
        in_span = _solve_scaled(basis @ basis.T, basis @ jac.T)  # (B, len(free))
        jac -= in_span.T @ basis
        return jac

    def gram(self, jac: np.ndarray) -> np.ndarray:
        """Return ``jac @ jac.T``."""
        return jac @ jac.T

    # ------------------------------------------------------------------ start
    def initial_guess(self) -> np.ndarray | None:
        """Parameters at the initial plane: the best lobe shape on a grid (as one light's).

        None if no shape gives the first light a positive specular intensity.
        """
        best_cost, best = math.inf, None
        base = self.start_theta()

        def consider(width: float, tail: float) -> None:
            nonlocal best_cost, best
            theta = base.copy()
            theta[I_WIDTH], theta[I_TAIL] = math.log(width), tail
            residual, filled = self.evaluate(theta)
            if not filled[I_SPEC] > 0.0:
                return
            cost = float(residual @ residual) / len(residual)
            if cost < best_cost:
                best_cost, best = cost, filled

        for width in WIDTH_GRID:
            consider(float(width), float(base[I_TAIL]))
        if best is not None and I_TAIL in self.free_all:
            best_width = math.exp(best[I_WIDTH])
            for factor in _WIDTH_FACTORS:
                for tail in _TAILS:
                    consider(best_width * factor, tail)
        self.initial_cost = best_cost
        return best


#: A normal-equation diagonal at or below this fraction of the largest is a basis vector
#: that is zero on the samples (:func:`_solve_scaled`).
_NEGLIGIBLE_DIAGONAL = 1e-24


def _solve_scaled(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve small normal equations ``(B, B)`` for ``rhs`` ``(B,)`` or ``(B, F)``.

    Jacobi scaling keeps the nearly collinear diffuse and level columns solvable; a
    singular system falls back to least squares. A basis vector that is zero on the
    samples for all purposes (a lobe that underflows there: its diagonal 1e-24 of the
    largest or less) gets no coefficient: scaled by ``1 / sqrt`` of its diagonal, it
    made the solution overflow.
    """
    diagonal = normal.diagonal()
    negligible = diagonal <= _NEGLIGIBLE_DIAGONAL * max(float(diagonal.max()), 0.0)
    scale = np.where(negligible, 0.0, 1.0 / np.sqrt(np.where(negligible, 1.0, diagonal)))
    scaled = normal * scale[:, None] * scale[None, :]
    column = scale if rhs.ndim == 1 else scale[:, None]
    try:
        x = np.linalg.solve(scaled, rhs * column)
    except np.linalg.LinAlgError:
        x = np.linalg.lstsq(scaled, rhs * column, rcond=None)[0]
    return x * column
