"""Levenberg-Marquardt with bounds on the free parameters, and 3x3 normal equations.

:func:`levenberg_marquardt` works on any :class:`LeastSquaresModel`: the model supplies
residuals, a Jacobian of the free parameters and its bounds; the solver adds damping to
the normal equations, keeps steps inside the bounds and stops when the cost or the
disparity stops moving. :func:`solve_normal` is the small solve the lobe model's
intensities use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .layout import N_PLANE

__all__ = ["LeastSquaresModel", "Minimum", "levenberg_marquardt", "solve_normal"]

# Levenberg-Marquardt: start and largest damping, and the plane's stopping rule: a step
# that moves the disparity at the object's corners by less than _DISPARITY_STEP_TOL_PX
# and lowers the cost by less than _PLANE_COST_RTOL (relative) ends the fit.
_LAMBDA0 = 1e-3
_LAMBDA_MAX = 1e8
_DISPARITY_STEP_TOL_PX = 1e-4
_PLANE_COST_RTOL = 1e-4


# Below this determinant the Jacobi-scaled 3x3 normal equations count as singular.
_MIN_SCALED_DETERMINANT = 1e-12


def solve_normal(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve 3x3 normal equations ``normal x = rhs`` (``rhs`` ``(3,)`` or ``(3, K)``).

    Jacobi scaling keeps the nearly collinear diffuse and level columns solvable. The
    inverse is written out (cofactors): this runs hundreds of times per fit, where
    ``numpy.linalg.solve``'s call overhead would dominate. A singular system (a lobe
    invisible everywhere) falls back to the pseudo-inverse.
    """
    rows = normal.tolist()
    scale = [1.0 / math.sqrt(max(rows[j][j], 1e-300)) for j in range(3)]
    (a, b, c), (d, e, f), (g, h, i) = [[rows[j][k] * scale[j] * scale[k] for k in range(3)]
                                       for j in range(3)]
    cofactors = [[e * i - f * h, c * h - b * i, b * f - c * e],
                 [f * g - d * i, a * i - c * g, c * d - a * f],
                 [d * h - e * g, b * g - a * h, a * e - b * d]]
    det = a * cofactors[0][0] + b * cofactors[1][0] + c * cofactors[2][0]
    if rhs.ndim == 1 and abs(det) > _MIN_SCALED_DETERMINANT:
        # (plain floats: three numbers do not repay numpy's call overhead)
        y = [r * sj for r, sj in zip(rhs.tolist(), scale, strict=True)]
        return np.array([scale[j] * (cofactors[j][0] * y[0] + cofactors[j][1] * y[1]
                                     + cofactors[j][2] * y[2]) / det for j in range(3)])
    scale_v = np.array(scale)
    if abs(det) > _MIN_SCALED_DETERMINANT:
        inverse = np.array(cofactors) / det
    else:
        inverse = np.linalg.pinv(normal * scale_v[:, None] * scale_v[None, :])
    x = inverse @ (scale_v[:, None] * rhs.reshape(3, -1))
    return (scale_v[:, None] * x).reshape(rhs.shape)


class LeastSquaresModel(Protocol):
    """What :func:`levenberg_marquardt` needs of a model of parameters ``theta``.

    Parameters ``0 .. N_PLANE - 1`` of ``theta`` are the plane's (see ``layout``).
    """

    def evaluate(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residual ``(P,)`` at ``theta``, and ``theta`` with its dependent parameters set."""

    def jacobian(self, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
        """Transposed Jacobian ``(len(free), P)`` of the residual by ``theta[free]``."""

    def gram(self, jac: np.ndarray) -> np.ndarray:
        """``jac @ jac.T``, ``(len(free), len(free))``."""

    def clamp(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` with its bounded parameters moved inside their bounds (in place)."""

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the disparity between the planes of two ``theta``, pixels."""


@dataclass(frozen=True)
class Minimum:
    """Where :func:`levenberg_marquardt` stopped.

    Parameters
    ----------
    theta : numpy.ndarray
        The parameters (dependent ones set).
    cost : float
        Mean squared residual at ``theta``.
    iterations : int
        Steps tried, accepted or not.
    converged : bool
        A stopping rule was met before ``max_iterations``.
    residual : numpy.ndarray, (P,)
        The residual at ``theta``.
    jacobian : numpy.ndarray, (len(free), P) or None
        The Jacobian of the last linearisation (at ``theta``, or one accepted step before
        it when the fit stopped on a step too small to go on); None if none was taken.
    """

    theta: np.ndarray
    cost: float
    iterations: int
    converged: bool
    residual: np.ndarray
    jacobian: np.ndarray | None


def levenberg_marquardt(model: LeastSquaresModel, theta0: np.ndarray, free: np.ndarray,
                         max_iterations: int, *, cost_rtol: float) -> Minimum:
    """Minimise the mean squared residual over ``theta[free]`` (intensities follow).

    Stops when an accepted step lowers the cost by less than ``cost_rtol`` (relative),
    or moves the plane's disparity by less than ``_DISPARITY_STEP_TOL_PX`` while
    lowering the cost by less than ``_PLANE_COST_RTOL``, or when no step lowers it.
    """
    residual, theta = model.evaluate(theta0)
    cost = float(np.mean(residual**2))
    lam = _LAMBDA0
    converged = False
    steps = 0
    moves_plane = bool(np.any(free < N_PLANE))
    jac = None
    while steps < max_iterations and not converged:
        jac = model.jacobian(theta, free)  # (K, P)
        normal = model.gram(jac)
        gradient = jac @ residual
        # Marquardt's scaling: damping proportional to each parameter's curvature.
        damping = np.diag(np.maximum(normal.diagonal(), 1e-12 * max(1.0, float(normal.max()))))
        improved = False
        while steps < max_iterations:
            steps += 1
            try:
                delta = np.linalg.solve(normal + lam * damping, -gradient)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            trial = theta.copy()
            trial[free] += delta
            trial_residual, trial = model.evaluate(model.clamp(trial))
            trial_cost = float(np.mean(trial_residual**2))
            if math.isfinite(trial_cost) and trial_cost < cost:
                decrease = (cost - trial_cost) / max(cost, 1e-300)
                plane_step_px = model.disparity_change_px(theta, trial) if moves_plane else 0.0
                theta, cost, residual = trial, trial_cost, trial_residual
                lam = max(lam / 3.0, 1e-9)
                improved = True
                converged = decrease < cost_rtol or (
                    plane_step_px < _DISPARITY_STEP_TOL_PX and decrease < _PLANE_COST_RTOL)
                break
            lam *= 4.0
            if lam > _LAMBDA_MAX:
                converged = True  # no step lowers the cost: a local minimum
                break
        if not improved:
            break
    # (the model's Jacobian is a buffer its next call overwrites)
    return Minimum(theta, cost, steps, converged, residual,
                   None if jac is None else np.array(jac))
