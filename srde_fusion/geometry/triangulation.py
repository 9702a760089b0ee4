"""Triangulating the virtual light from its image centres in a rectified array.

In a rectified array every camera j sees a point whose reference-view image is
``(u_ref, v_ref)`` at

    u_j = u_ref - fx * dX_j * w,    v_j = v_ref - fy * dY_j * w,

where ``(dX_j, dY_j)`` is camera j's centre minus the reference's (metres) and
``w = 1 / z`` is the inverse depth of the point (1/metres, z from the cameras' plane).
The model is *linear* in ``(u_ref, v_ref, w)`` and its residuals are exactly the
reprojection errors in pixels, so ordinary least squares is the maximum-likelihood
triangulation under isotropic pixel noise, with no iteration and no conditioning trouble
(the ``w`` column is scaled to pixels of shift). Two cameras with distinct centres are
enough; more average the detection noise down.

:func:`robust_triangulate` adds outlier rejection: every pair of views proposes a point,
the proposal that the most views agree with (reprojection residual within a bound) wins,
and the point is refitted on those views. :func:`pairwise_virtual_lights` is the paper's
per-pair solve, kept as the baseline.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

__all__ = [
    "Triangulation",
    "triangulate_rectified",
    "robust_triangulate",
    "adjacent_pairs",
    "pairwise_virtual_lights",
    "max_shift_px",
]

# Two camera centres closer than this (metres) cannot triangulate anything.
_MIN_BASELINE_M = 1e-9
# Relative slack when comparing camera distances for adjacency.
_ADJACENCY_TOL = 1e-6
# Refit rounds of the robust solve before it settles on an inlier set.
_MAX_REFITS = 10
# Fewest views from which a residual scale is estimated.
_MIN_VIEWS_FOR_SCALE = 5
# The adaptive outlier bound, in robust standard deviations of the residuals.
_OUTLIER_SIGMAS = 4.0


@dataclass(frozen=True)
class Triangulation:
    """A point triangulated from image centres of a rectified rig.

    Parameters
    ----------
    point_m : (3,) float64
        The point in the array frame, metres; NaN if ``w`` is 0 (at infinity) or the
        views could not constrain it. A negative ``w`` puts it behind the cameras.
    inverse_depth_per_m : float
        ``w = 1 / z``, with ``z`` the point's depth in front of the cameras' plane.
    reference_uv : (2,) float64
        The point's image in the reference camera, pixels.
    residuals_px : (N,) float64
        Reprojection residual (Euclidean, pixels) of every view with a centre, NaN for
        views without one. Views outside ``used`` keep theirs, which says why they were
        dropped.
    used : (N,) bool
        Views the point was fitted to.
    rms_px : float
        RMS of ``residuals_px`` over ``used``.
    """

    point_m: np.ndarray
    inverse_depth_per_m: float
    reference_uv: np.ndarray
    residuals_px: np.ndarray
    used: np.ndarray
    rms_px: float


def _offsets(rig) -> np.ndarray:
    """Camera centres minus the reference's, ``(N, 2)`` (x, y), metres."""
    return rig.centers_m[:, :2] - rig.reference_center_m[:2]


def max_shift_px(rig, inverse_depth_per_m: float, used) -> float:
    """Largest image shift of a point at inverse depth ``w`` between used views, pixels."""
    k = rig.intrinsics
    off = _offsets(rig)[np.asarray(used, dtype=bool)]
    span = np.array([np.ptp(off[:, 0]) * k.fx, np.ptp(off[:, 1]) * k.fy])
    return float(np.hypot(*span) * abs(inverse_depth_per_m))


def _solve(rig, centers_uv: np.ndarray, use: np.ndarray):
    """Least-squares ``(u_ref, v_ref, w)`` from the views in ``use``; None if degenerate."""
    k = rig.intrinsics
    off = _offsets(rig)[use]
    if np.ptp(off[:, 0]) < _MIN_BASELINE_M and np.ptp(off[:, 1]) < _MIN_BASELINE_M:
        return None
    uv = centers_uv[use]
    n = off.shape[0]
    # Rows [1, 0, -fx dX] and [0, 1, -fy dY]; the w column scaled to pixels of shift so
    # all three columns are of similar size.
    scale = max(k.fx, k.fy) * float(np.abs(off).max())
    design = np.zeros((2 * n, 3))
    design[:n, 0] = 1.0
    design[n:, 1] = 1.0
    design[:n, 2] = -k.fx * off[:, 0] / scale
    design[n:, 2] = -k.fy * off[:, 1] / scale
    rhs = np.concatenate([uv[:, 0], uv[:, 1]])
    sol, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return sol[0], sol[1], sol[2] / scale


def _residuals(rig, centers_uv, u_ref, v_ref, w) -> np.ndarray:
    k = rig.intrinsics
    off = _offsets(rig)
    pred = np.stack([u_ref - k.fx * off[:, 0] * w, v_ref - k.fy * off[:, 1] * w], axis=1)
    return np.linalg.norm(centers_uv - pred, axis=1)


def _pair_residuals(rig, centers_uv: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Residuals of every view for the point proposed by each pair of candidate views.

    For two views the least-squares solve has a closed form: eliminating ``u_ref`` and
    ``v_ref`` leaves ``min_w (du + dax w)^2 + (dv + day w)^2`` with ``du = u_i - u_j``,
    ``dax = fx (dX_i - dX_j)`` (and the same in v). Pairs without a baseline are skipped.

    Returns
    -------
    numpy.ndarray, (P, N) float64
        One row per usable pair.
    """
    k = rig.intrinsics
    off = _offsets(rig)
    ax, ay = k.fx * off[:, 0], k.fy * off[:, 1]
    pairs = np.array(list(combinations(candidates, 2)), dtype=np.intp).reshape(-1, 2)
    i, j = pairs[:, 0], pairs[:, 1]
    dax, day = ax[i] - ax[j], ay[i] - ay[j]
    norm = dax * dax + day * day
    spans = norm > (max(k.fx, k.fy) * _MIN_BASELINE_M) ** 2
    i, j, dax, day, norm = i[spans], j[spans], dax[spans], day[spans], norm[spans]
    du = centers_uv[i, 0] - centers_uv[j, 0]
    dv = centers_uv[i, 1] - centers_uv[j, 1]
    w = -(du * dax + dv * day) / norm                                   # (P,)
    u_ref = 0.5 * (centers_uv[i, 0] + ax[i] * w + centers_uv[j, 0] + ax[j] * w)
    v_ref = 0.5 * (centers_uv[i, 1] + ay[i] * w + centers_uv[j, 1] + ay[j] * w)
    pred_u = u_ref[:, None] - ax[None, :] * w[:, None]                  # (P, N)
    pred_v = v_ref[:, None] - ay[None, :] * w[:, None]
    return np.hypot(centers_uv[None, :, 0] - pred_u, centers_uv[None, :, 1] - pred_v)


def _result(rig, centers_uv, use, solution) -> Triangulation:
    n = rig.n_cameras
    if solution is None:
        nan3 = np.full(3, np.nan)
        return Triangulation(nan3, float("nan"), np.full(2, np.nan), np.full(n, np.nan),
                             use.copy(), float("nan"))
    u_ref, v_ref, w = solution
    residuals = _residuals(rig, centers_uv, u_ref, v_ref, w)  # NaN where no centre
    if w == 0.0:
        point = np.full(3, np.nan)
    else:
        point = rig.reference_center_m + rig.rays(np.array([u_ref, v_ref])) / w
    rms = float(np.sqrt(np.mean(residuals[use] ** 2)))
    return Triangulation(point, float(w), np.array([u_ref, v_ref]), residuals, use.copy(), rms)


def triangulate_rectified(rig, centers_uv, use=None) -> Triangulation:
    """Least-squares triangulation of one point from its image centres in all views.

    Parameters
    ----------
    rig : CameraRig
        A rectified rig (all cameras share orientation and intrinsics).
    centers_uv : array_like, (N, 2) float
        The point's image in every camera, pixels; rows with NaN are ignored.
    use : array_like, (N,) bool, optional
        Views to fit to (default: every view with a finite centre).

    Returns
    -------
    Triangulation
        NaN-filled when the used views do not span a baseline (fewer than two distinct
        camera centres).

    Examples
    --------
    >>> from srde_fusion.geometry.rig import CameraRig
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(640, 480))
    >>> point = [0.1, -0.05, 1.5]
    >>> centers = np.stack([rig.project(point, j) for j in range(rig.n_cameras)])
    >>> np.round(triangulate_rectified(rig, centers).point_m, 9).tolist()
    [0.1, -0.05, 1.5]
    """
    centers_uv = np.asarray(centers_uv, dtype=np.float64)
    finite = np.all(np.isfinite(centers_uv), axis=1)
    use = finite if use is None else np.asarray(use, dtype=bool) & finite
    if use.sum() < 2:
        return _result(rig, centers_uv, use, None)
    return _result(rig, centers_uv, use, _solve(rig, centers_uv, use))


def robust_triangulate(rig, centers_uv, *, max_residual_px: float,
                       min_residual_px: float | None = None) -> Triangulation:
    """Triangulate from the largest set of views that agree on one point.

    Every pair of views with a centre and distinct camera centres proposes a point; the
    proposal with the most views within ``max_residual_px`` (ties: smallest squared
    residual over them) wins; the point is refitted on those views and the inlier set
    recomputed until it no longer changes.

    With ``min_residual_px`` and at least five views, the bound then adapts to the data:
    it becomes ``4 sigma``, with sigma from the least median of the residuals over all
    pair proposals (a scale up to half the views cannot inflate), kept within
    ``[min_residual_px, max_residual_px]``; the views within it of the least-median
    proposal are refitted as before. A view whose highlight is cut by an object edge
    misses by a fraction of a pixel, far more than clean views disagree among
    themselves, but not always more than a fixed bound loose enough for real
    calibration errors.

    Parameters
    ----------
    rig : CameraRig
    centers_uv : array_like, (N, 2) float
        Image centres, NaN where a view has none.
    max_residual_px : float
        Reprojection residual above which a view is always an outlier, pixels.
    min_residual_px : float, optional
        Floor of the adaptive bound, pixels; None keeps the bound fixed.

    Returns
    -------
    Triangulation
        ``used`` marks the agreeing views; NaN-filled if no pair of views can
        triangulate or no two views agree.
    """
    centers_uv = np.asarray(centers_uv, dtype=np.float64)
    finite = np.all(np.isfinite(centers_uv), axis=1)
    res = _pair_residuals(rig, centers_uv, np.flatnonzero(finite))   # (P, N), NaN: no centre
    if res.shape[0] == 0:
        return _result(rig, centers_uv, finite & False, None)
    inliers = finite & (np.nan_to_num(res, nan=np.inf) <= max_residual_px)
    count = inliers.sum(axis=1)
    sse = np.where(inliers, np.nan_to_num(res), 0.0) ** 2
    # Most inliers first, then the smallest squared residual over them.
    order = np.lexsort((sse.sum(axis=1), -count))
    if count[order[0]] < 2:
        return _result(rig, centers_uv, finite & False, None)
    best_use = inliers[order[0]]
    refitted = None
    if min_residual_px is not None and finite.sum() >= _MIN_VIEWS_FOR_SCALE:
        medians = np.median(res[:, finite], axis=1)
        least = int(np.argmin(medians))
        least_median, median_residuals = float(medians[least]), res[least]
        # Least median of squares over the pair proposals: a residual scale that up to
        # half the views being off cannot inflate. Residual norms of isotropic 2D noise
        # are Rayleigh distributed, with median sigma * sqrt(2 ln 2).
        sigma = least_median / np.sqrt(2.0 * np.log(2.0))
        bound = float(np.clip(_OUTLIER_SIGMAS * sigma, min_residual_px, max_residual_px))
        # Start from the least-median proposal's inliers: a fit that already includes the
        # outliers would pull towards them and hide them.
        start = finite & (np.nan_to_num(median_residuals, nan=np.inf) <= bound)
        if start.sum() >= 2:
            refitted = _refit(rig, centers_uv, finite, start, bound)
    if refitted is None:  # the fixed bound, from the proposal with the most inliers
        refitted = _refit(rig, centers_uv, finite, best_use, max_residual_px)
    use, solution = refitted
    if solution is None:
        solution = _solve(rig, centers_uv, use)
    return _result(rig, centers_uv, use, solution)


def _refit(rig, centers_uv, finite, use, bound):
    """Refit and re-select the views within ``bound`` until the selection settles.

    Returns the selection and its solution, or None in place of the solution when the
    last selection was not solved (``_solve`` of it then gives it).
    """
    solution = None
    for _ in range(_MAX_REFITS):
        solution = _solve(rig, centers_uv, use)
        if solution is None:
            break
        res = _residuals(rig, centers_uv, *solution)
        refit = finite & (np.nan_to_num(res, nan=np.inf) <= bound)
        if refit.sum() < 2 or np.array_equal(refit, use):
            break
        use = refit
        solution = None
    return use, solution


def adjacent_pairs(rig) -> list[tuple[int, int]]:
    """Pairs of neighbouring cameras: horizontal, vertical and diagonal neighbours.

    Two cameras are neighbours when no third camera lies on the segment between them
    and their distance is at most ``sqrt(2)`` times the larger of their nearest-neighbour
    distances. On a grid that gives the horizontal, vertical and both diagonal
    neighbours (20 pairs on 3 x 3), on a stereo rig its one pair.

    Returns
    -------
    list of (int, int)
        ``(i, j)`` with ``i < j``, in lexicographic order.

    Examples
    --------
    >>> from srde_fusion.geometry.rig import CameraRig
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(640, 480))
    >>> len(adjacent_pairs(rig)), adjacent_pairs(rig)[:4]
    (20, [(0, 1), (0, 3), (0, 4), (1, 2)])
    """
    centers = rig.centers_m
    n = len(centers)
    dist = np.linalg.norm(centers[:, None, :] - centers[None, :, :], axis=2)
    off_diag = dist + np.diag(np.full(n, np.inf))
    nearest = off_diag.min(axis=1)
    pairs = []
    for i, j in combinations(range(n), 2):
        d = dist[i, j]
        reach = np.sqrt(2.0) * max(nearest[i], nearest[j]) * (1 + _ADJACENCY_TOL)
        if d < _MIN_BASELINE_M or d > reach:
            continue
        others = [m for m in range(n) if m not in (i, j)]
        # A camera m on the segment has dist(i, m) + dist(m, j) == dist(i, j).
        if any(dist[i, m] + dist[m, j] <= d * (1 + _ADJACENCY_TOL) for m in others):
            continue
        pairs.append((i, j))
    return pairs


def pairwise_virtual_lights(rig, centers_uv, pairs) -> np.ndarray:
    """Triangulate the virtual light per camera pair, as the paper does.

    For a pair (i, j) the centre displacement along the pair's baseline gives the depth
    ``z = fx B_ij / delta_ij``; ``X = z (u_i - cx) / fx``, ``Y = z (v_i - cy) / fy`` relative
    to camera i, moved into the array frame by adding ``C_i``. With ``fx != fy`` the
    displacement is taken in normalised image coordinates, which is the same formula.

    Parameters
    ----------
    rig : CameraRig
    centers_uv : array_like, (N, 2) float
        Image centres, NaN where a view has none.
    pairs : sequence of (int, int)

    Returns
    -------
    numpy.ndarray, (P, 3) float64
        One point per pair, metres; NaN rows for pairs with a missing centre or no
        displacement along the baseline. A negative depth (displacement the wrong way)
        is returned as computed: behind the cameras.

    References
    ----------
    Kossira et al., SRDE, Methods: "Disparity Estimation" (eqs. 6-7).
    """
    centers_uv = np.asarray(centers_uv, dtype=np.float64)
    k = rig.intrinsics
    idx = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    i, j = idx[:, 0], idx[:, 1]
    baseline = rig.centers_m[j, :2] - rig.centers_m[i, :2]  # (P, 2) metres
    # Normalised displacement c_i - c_j equals baseline / z in a rectified array.
    shift = np.stack([(centers_uv[i, 0] - centers_uv[j, 0]) / k.fx,
                      (centers_uv[i, 1] - centers_uv[j, 1]) / k.fy], axis=1)
    along = np.sum(shift * baseline, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.sum(baseline * baseline, axis=1) / along
    z = np.where(np.isfinite(z), z, np.nan)
    points = rig.centers_m[i] + rig.rays(centers_uv[i]) * z[:, None]
    return points
