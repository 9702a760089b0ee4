"""The lobe model's intensities, solved in closed form, and its one-sided residual.

The model is linear in its intensities: ``Y = specular * lobe + diffuse * (g_d - 1) +
level``. For a lobe and a geometry the best intensities are a 3x3 least-squares solve
(variable projection), with saturated samples, which only say "at least this bright",
counted where the model falls below them.
"""

from __future__ import annotations

import numpy as np

from .reflection import ShadingGeometry
from .samples import HighlightSamples
from .solver import solve_normal

__all__ = ["IntensitySolver", "with_saturated"]

# Passes of the active-set solve for the intensities (saturated samples in or out).
_ACTIVE_SET_PASSES = 4


def with_saturated(coef: np.ndarray, normal0: np.ndarray, rhs0: np.ndarray,
                   clipped: np.ndarray, clipped_y: np.ndarray, solve) -> np.ndarray:
    """Re-solve linear intensities with the saturated samples the model falls below.

    ``coef`` ``(B,)`` solves the normal equations ``normal0``, ``rhs0`` of the unsaturated
    samples; ``clipped`` ``(B, S)`` is the basis at the saturated samples ``clipped_y``
    ``(S,)``. Which of them count depends on the solution: a few active-set passes settle
    it. ``solve(normal, rhs)`` solves the normal equations.
    """
    active = np.zeros(len(clipped_y), dtype=bool)
    for _ in range(_ACTIVE_SET_PASSES - 1):
        now_active = coef @ clipped < clipped_y
        if not np.any(now_active ^ active):
            break
        active = now_active
        cols = clipped[:, active]
        coef = solve(normal0 + cols @ cols.T, rhs0 + cols @ clipped_y[active])
    return coef


class IntensitySolver:
    """Best intensities and residuals against the samples' luminance.

    Parameters
    ----------
    samples : HighlightSamples
        The observations, unsaturated samples first.

    Attributes
    ----------
    y : numpy.ndarray, (P,)
        Observed linear luminance.
    censored : numpy.ndarray, (P,), bool
        Saturated samples: lower bounds.
    n_unclipped : int
        Unsaturated samples, ``y[:n_unclipped]``.
    """

    def __init__(self, samples: HighlightSamples) -> None:
        self.y = samples.luminance
        self.censored = samples.saturated
        self.n_unclipped = int(np.count_nonzero(~samples.saturated))  # they come first
        self._terms_geometry = self._terms = None
        self._sum_unclipped_y = float(self.y[:self.n_unclipped].sum())
        # Reused across steps: arrays this large would cost page faults on every call.
        self._ones = np.ones(self.y.shape)
        self._basis_buffer = np.empty((3, len(self.y)))
        self._basis_partner = np.empty((3, len(self.y)))

    def residual(self, model: np.ndarray) -> np.ndarray:
        """Return model minus observation, ``(P,)``.

        Saturated samples are lower bounds: for them only a model below the observation
        is an error.
        """
        r = model - self.y
        np.minimum(r[self.n_unclipped:], 0.0, out=r[self.n_unclipped:])  # saturated come last
        return r

    def _diffuse_terms(self, g: ShadingGeometry):
        """Return the sums over unsaturated samples that do not depend on the lobe (cached).

        ``(d . d, sum d)`` of the diffuse term ``d`` and ``d . y`` with the observations.
        """
        if self._terms_geometry is not g:
            d = g.diffuse[:self.n_unclipped]
            self._terms = float(d @ d), float(d.sum()), float(d @ self.y[:self.n_unclipped])
            self._terms_geometry = g
        return self._terms

    def solve(self, g: ShadingGeometry, lobe: np.ndarray):
        """Specular, diffuse and level ``(3,)`` for a lobe ``(P,)``, by least squares.

        The basis is ``(lobe, g_d - 1, 1)``. Saturated samples count only where the
        model falls below them, which depends on the solution: a few active-set passes
        settle it. Returns the coefficients and the model ``(P,)``.
        """
        k = self.n_unclipped
        dd, d1, dy = self._diffuse_terms(g)
        head, y_head = lobe[:k], self.y[:k]
        ld = float(head @ g.diffuse[:k])
        l1 = float(head.sum())
        normal0 = np.array([[float(head @ head), ld, l1], [ld, dd, d1], [l1, d1, float(k)]])
        rhs0 = np.array([float(head @ y_head), dy, self._sum_unclipped_y])
        coef = solve_normal(normal0, rhs0)
        if k < len(lobe):
            clipped = np.stack([lobe[k:], g.diffuse[k:], self._ones[k:]])  # (3, P - k)
            coef = with_saturated(coef, normal0, rhs0, clipped, self.y[k:], solve_normal)
        model = lobe * coef[0]
        model += coef[1] * g.diffuse
        model += coef[2]
        return coef, model

    def project_out(self, slopes: np.ndarray, g: ShadingGeometry, lobe: np.ndarray,
                    coef: np.ndarray) -> np.ndarray:
        """Remove from model slopes ``(K, P)`` their part in the span of the intensity basis.

        Kaufman's approximation to the Jacobian of the variable-projection residual, at
        intensities ``coef`` ``(3,)`` for ``lobe`` ``(P,)``. ``slopes`` is overwritten and
        returned.
        """
        basis = self._basis_buffer
        basis[0] = lobe
        basis[1] = g.diffuse
        basis[2] = 1.0
        model = coef @ basis
        # A saturated sample above its lower bound contributes nothing, nor does its slope.
        ignored = self.censored & (model >= self.y)
        if ignored.any():
            slopes[:, ignored] = 0.0
            basis[:, ignored] = 0.0
        # numpy computes A @ A.T by a rank-k update, several times slower here than a
        # product with a copy of A.
        partner = self._basis_partner
        np.copyto(partner, basis)
        in_span = solve_normal(basis @ partner.T, basis @ slopes.T)  # (3, K)
        slopes -= in_span.T @ basis
        return slopes
