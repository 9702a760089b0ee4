"""Photometric refinement of an SRDE plane: fit a specular lobe to the highlight in every view.

A centroid of the highlight (the paper's edge ring, or an intensity-weighted blob) is not
the image of the virtual light. Irradiance on the plane falls off with distance and angle
from the light, the lobe widens with roughness and clipping flattens its top, so the
blob's mass drifts towards the part of the plane nearest the light. The drift is nearly
the same in every view, so the triangulated virtual light moves while the reprojection
residual stays small: on rough surfaces the plane comes out tilted or shifted by tenths of
a pixel of disparity although every view agrees.

:func:`refine_plane` removes that bias by analysis by synthesis. It renders the highlight
of a glossy plane lit by the known point light and seen from the known camera centres, and
adjusts the plane (3 DoF around the initial plane) together with what it cannot know —
lobe width and tail, a foreshortening exponent, specular and diffuse intensity, ambient
level — until the rendering explains the linear luminance around the highlight in all
views at once. Saturated pixels only say "at least this bright" and enter as one-sided
residuals. The fit is a short Levenberg-Marquardt run on a few thousand block-averaged
samples near the highlights, with the intensities solved in closed form at every step
(variable projection); its own cost decides whether the refined plane replaces the
initial one.

The shading model, for a sample whose ray meets the plane at X (array frame, metres)::

    Y = level + diffuse * (g_d - 1) + specular * S(n . h) * g_s

    g_d = cos(theta_i) / r^2
    g_s = F(omega_i . h) * (cos(theta_i) cos(theta_o))^k / (cos(theta_o) r^2)

``g_d`` and ``g_s`` are normalised to a median of 1 over the samples at the initial plane,
so ``specular`` and ``diffuse`` read as luminances at the highlight and
``level = ambient + diffuse``. ``r`` is the distance from X to the light, ``h`` the half
vector between the directions to the light and to the camera, ``F`` Schlick's Fresnel
term and ``S`` the lobe scaled to a peak of 1. The foreshortening exponent ``k`` spans the
conventions in use: ``k = 0`` is the Cook-Torrance microfacet BRDF
``D F G / (4 cos(theta_i) cos(theta_o))`` (its radiance under a point light is
``I D F G / (4 cos(theta_o) r^2)``; ``G ~ 1`` near the mirror direction), ``k = 1`` a
Phong-style BRDF without the ``1 / (4 cos cos)`` factor. Near the mirror direction the
factor tilts the lobe across the image, which shifts its peak, so it must be modelled
(or fitted) rather than ignored.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..._checks import check_mask, check_point3, check_views
from ...errors import ImageError, SRDEError
from ...geometry import CameraRig, Plane, plane_from_lights
from ...imaging import REC709_LUMA, luminance, saturation_mask, srgb_to_linear

__all__ = [
    "LOBES",
    "DEFAULT_LOBE",
    "LobeFit",
    "PlaneRefinement",
    "refine_plane",
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

# --- fitting window -------------------------------------------------------------------
#: The window's half-size is at most this fraction of the smaller image side.
MAX_WINDOW_FRACTION = 0.2
#: Smallest half-size of the window, pixels.
MIN_WINDOW_HALF_PX = 8
#: The window reaches this many half-maximum radii of the highlight blob from its centre.
WINDOW_PER_BLOB_RADIUS = 3.0
#: Block samples per window side at most; larger windows average larger blocks.
SAMPLES_PER_SIDE = 30
#: Pixels closer than this to the object's outline are not fitted (mask warping slack).
MASK_MARGIN_PX = 2
#: Fewer samples than this, all views together, are too few to fit the model.
MIN_SAMPLES = 60
#: Fewer unsaturated samples than this above the background cannot show the lobe's flanks.
MIN_FLANK_SAMPLES = 12
#: Peak-over-background contrast (linear luminance) below which there is no highlight.
MIN_HIGHLIGHT_CONTRAST = 0.02
#: A fit whose RMS residual exceeds this fraction of the highlight's contrast does not
#: explain the image (texture, a second light, a curved surface): the plane is kept.
MAX_RELATIVE_RESIDUAL = 0.05
#: The refined highlight may move at most this fraction of the window half-size.
MAX_SHIFT_FRACTION = 0.5

# Coarse grid step (pixels) and number of views used to size the window.
_SIZING_STRIDE_PX = 4
_SIZING_VIEWS = 3
# Quantile of the luminance taken as the object's background level near the highlight.
_BACKGROUND_QUANTILE = 0.2

# --- optimisation ---------------------------------------------------------------------
# Start: lobe widths scanned with a GGX tail, then other tails around the best width.
_WIDTH_GRID = np.geomspace(0.002, 0.4, 11)
_TAIL_GRID = (0.5, 0.25, 0.0)
_WIDTH_REFINE_FACTORS = (0.85, 1.0, 1.2)
# A start whose lobe stays below this (relative to its peak) on every unsaturated sample
# is invisible: skipped.
_MIN_LOBE_ON_UNCLIPPED = 1e-3
# Bounds keep the shape parameters where the model is meaningful. Tails heavier than
# 0.75 let a hugely clipped needle lobe mimic a broad one.
_WIDTH_BOUNDS = (1e-3, 1.0)
_TAIL_BOUNDS = (-0.25, 0.75)
_FORESHORTENING_BOUNDS = (-4.0, 5.0)
# Fitted foreshortening exponent starts here, halfway between the conventions.
_FORESHORTENING_START = 0.5
# |tail| below this is the Gaussian limit exp(-z) of the "gtr" lobe.
_ZERO_TAIL = 1e-9
# |t z| below this takes the lobe's derivative by its tail from a series (no cancellation).
_SMALL_TAIL_Z = 1e-3
# Levenberg-Marquardt: start and largest damping, and stopping rules. A joint step ends
# the fit when it moves the disparity at the object's corners by less than
# _DISPARITY_STEP_TOL_PX and lowers the cost by less than _PLANE_COST_RTOL (relative), or
# lowers it by less than _COST_RTOL. Photometric-only fits only seed or compare, and stop
# at _PHOTOMETRIC_COST_RTOL.
_LAMBDA0 = 1e-3
_LAMBDA_MAX = 1e8
_COST_RTOL = 1e-7
_DISPARITY_STEP_TOL_PX = 1e-4
_PLANE_COST_RTOL = 1e-4
_PHOTOMETRIC_COST_RTOL = 1e-4
# Restart shifts (px) of the virtual light's image in the farthest camera, tried when a
# fit from the initial plane fails.
_RESTART_SHIFTS_PX = (-16.0, -8.0, -4.0, -2.0, 2.0, 4.0, 8.0, 16.0)
# Below this determinant the Jacobi-scaled 3x3 normal equations count as singular.
_MIN_SCALED_DETERMINANT = 1e-12
# The first stage only has to bring the plane near; the joint stage finishes.
_START_ITERATIONS = 6
# Passes of the active-set solve for the intensities (saturated samples in or out).
_ACTIVE_SET_PASSES = 4

# uint8 code -> linear intensity, per image encoding
_DECODE_LUT = {
    "srgb": srgb_to_linear(np.arange(256, dtype=np.float32) / 255.0),
    "linear": np.arange(256, dtype=np.float32) / 255.0,
}

# Layout of the parameter vector theta.
_N_PLANE = 3
_I_WIDTH, _I_TAIL, _I_FORE = 3, 4, 5
_I_SPEC, _I_DIFF, _I_LEVEL = 6, 7, 8
_N_PARAMS = 9


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


@dataclass(frozen=True)
class PlaneRefinement:
    """Outcome of :func:`refine_plane`.

    Parameters
    ----------
    plane : Plane
        The refined plane, or the initial one when ``status == "kept_initial"``.
    initial_plane : Plane
        The plane the refinement started from.
    status : {"refined", "kept_initial"}
    reason : str
        Why the initial plane was kept, naming the step and the numbers ("" if refined).
    converged : bool
        The joint Levenberg-Marquardt fit met a stopping rule before ``max_iterations``.
    iterations : int
        Steps (accepted or rejected) of the joint fit.
    cost_initial : float
        Mean squared residual (linear luminance squared) with the plane held at the
        initial plane and only the photometric parameters fitted; NaN if not reached.
    cost_final : float
        Mean squared residual of the joint fit; NaN if not reached.
    residual : float
        RMS residual of the returned plane's fit, linear luminance; NaN if no fit ran.
    params : LobeFit or None
        Photometric parameters belonging to the returned plane; None if no fit ran.
    n_samples : int
        Block samples fitted, all views together.
    lobe : str
        Lobe model fitted.
    time_s : float
        Wall time, seconds.
    """

    plane: Plane
    initial_plane: Plane
    status: str
    reason: str
    converged: bool
    iterations: int
    cost_initial: float
    cost_final: float
    residual: float
    params: LobeFit | None
    n_samples: int
    lobe: str
    time_s: float

    @property
    def ok(self) -> bool:
        """True when the refined plane replaced the initial one."""
        return self.status == "refined"

    def __bool__(self) -> bool:
        return self.ok


# ======================================================================================
# Public entry point
# ======================================================================================


def refine_plane(
    views: Sequence[np.ndarray],
    rig: CameraRig,
    light_m,
    mask: np.ndarray,
    initial_plane: Plane,
    *,
    centers_uv=None,
    lobe: str = DEFAULT_LOBE,
    foreshortening: float | None = None,
    f0: float = DEFAULT_F0,
    max_iterations: int = 20,
) -> PlaneRefinement:
    """Refine a plane so that a specular lobe model explains the highlight in every view.

    Parameters
    ----------
    views : sequence of numpy.ndarray, N x (H, W, 3) or (H, W), uint8 or float in [0, 1]
        One image per rig camera, in the rig's order, encoded as ``rig.image_encoding``.
    rig : CameraRig
        The rectified array; planes and points are in its array frame.
    light_m : array_like, (3,), metres
        Position of the point light in the array frame.
    mask : numpy.ndarray, (H, W), bool
        The object's pixels in the reference view. Other views use it through the
        homography of the initial plane.
    initial_plane : Plane
        Starting plane, e.g. SRDE's geometric plane.
    centers_uv : array_like, (N, 2), pixels, optional
        Highlight centre per view, where the fitting windows go; a row of NaN leaves
        that view out. By default the initial plane's virtual light projected into
        every view.
    lobe : {"gtr", "ggx", "blinn_phong"}
        Lobe shape fitted (see :data:`LOBES`); ``"gtr"`` fits its tail too.
    foreshortening : float, optional
        Exponent ``k`` of the specular term's ``(cos(theta_i) cos(theta_o))^k``; fitted
        if None (default), else held (0 for a microfacet BRDF, 1 for Phong-style).
    f0 : float
        Fresnel reflectance at normal incidence of the Schlick term, in (0, 1].
    max_iterations : int
        Cap on the steps of each Levenberg-Marquardt stage.

    Returns
    -------
    PlaneRefinement
        ``status == "refined"`` with the new plane, or ``"kept_initial"`` with the
        initial plane and a ``reason``: implausible initial plane, no usable highlight
        samples, fit failed, did not lower its own cost, does not explain the image, or
        moved the highlight out of its window.

    Raises
    ------
    SRDEError
        Invalid arguments (``rig``, ``initial_plane``, options); ``ImageError``,
        ``MaskError``, ``LightError`` for views, mask and light.

    Notes
    -----
    Cost: mean over the samples of the squared difference between modelled and observed
    linear luminance; for saturated samples only a model *below* the observation counts.
    A fit starts from the best lobe shape on a grid at the initial plane and runs in two
    Levenberg-Marquardt stages: plane and lobe shape with the foreshortening exponent
    held (it could otherwise absorb part of the plane's error), then everything. Its
    reference is the initial plane with every photometric parameter fitted on the same
    samples. The plane is kept unless the fit lowers that cost, keeps its shape
    parameters inside their ranges, explains the samples (RMS residual at most
    :data:`MAX_RELATIVE_RESIDUAL` of the highlight's contrast) and keeps the highlight
    inside its window. A failed fit is retried once from the virtual-light depth whose
    start explains the samples best (a wrong centre in one view puts the initial plane's
    virtual light at the wrong depth); a plane that moved by more than the mask margin in
    some view is fitted again on samples placed for it.

    Examples
    --------
    >>> import numpy as np
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=60.0, image_size=(64, 48))
    >>> plane = Plane.from_point_normal([0, 0, 1.0], [0, 0, -1.0])
    >>> dark = [np.zeros((48, 64, 3), np.uint8)] * 9
    >>> out = refine_plane(dark, rig, [0.1, -0.3, 0.2], np.ones((48, 64), bool), plane)
    >>> out.status, out.plane == plane
    ('kept_initial', True)
    >>> out.reason
    'samples: no view shows a highlight brighter than the object by 0.02 (linear) inside the mask'
    """
    start = time.perf_counter()
    if not isinstance(rig, CameraRig):
        raise SRDEError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    views = check_views(views, rig.n_cameras, rig.image_size)
    mask = np.ascontiguousarray(check_mask(mask, (rig.height, rig.width)))
    light = check_point3(light_m, "light_m")
    if not isinstance(initial_plane, Plane):
        raise SRDEError(f"initial_plane: expected a Plane, got {type(initial_plane).__name__}")
    centers = _check_centers(centers_uv, rig.n_cameras)
    if lobe not in LOBES:
        raise SRDEError(f"lobe: expected one of {list(LOBES)}, got {lobe!r}")
    if foreshortening is not None and not _is_number_in(foreshortening, *_FORESHORTENING_BOUNDS):
        raise SRDEError(f"foreshortening: expected None or a number in "
                        f"{list(_FORESHORTENING_BOUNDS)}, got {foreshortening!r}")
    if not _is_number_in(f0, 0.0, 1.0) or f0 == 0.0:
        raise SRDEError(f"f0: expected a number in (0, 1], got {f0!r}")
    if (isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer))
            or max_iterations < 1):
        raise SRDEError(f"max_iterations: expected a positive integer, got {max_iterations!r}")

    def kept(reason: str, **fields) -> PlaneRefinement:
        values = dict(converged=False, iterations=0, cost_initial=math.nan, cost_final=math.nan,
                      residual=math.nan, params=None, n_samples=0)
        values.update(fields)
        return PlaneRefinement(initial_plane, initial_plane, "kept_initial", reason, lobe=lobe,
                               time_s=time.perf_counter() - start, **values)

    problem = _initial_plane_problem(initial_plane, rig, light)
    if problem:
        return kept(problem)
    if centers is None:
        virtual = initial_plane.mirror(light)
        centers = np.stack([rig.project(virtual, i) for i in range(rig.n_cameras)])
    setup = _Setup(views, rig, mask, _box(mask), light, initial_plane, centers, lobe, f0,
                   foreshortening, max_iterations)
    attempt = _attempt(setup, initial_plane)
    if isinstance(attempt, str):
        return kept(attempt)
    if attempt.problem:
        # A start far from the truth (a wrong centre in one view puts the virtual light
        # at the wrong depth) can end in a wrong basin: retry once from the best depth.
        plane = _restart_plane(setup, attempt.samples)
        retry = _attempt(setup, plane) if plane is not None else None
        if isinstance(retry, _Attempt):
            if retry.problem:
                retry = _resampled(setup, retry, keep_photometry=False) or retry
            if not retry.problem:
                attempt = retry
    if not attempt.problem:
        attempt = _resampled(setup, attempt, keep_photometry=True) or attempt

    fit, model = attempt.fit, attempt.model
    common = dict(converged=fit.converged, iterations=fit.iterations,
                  cost_initial=attempt.cost_initial, cost_final=fit.cost,
                  n_samples=attempt.samples.n_samples)
    if attempt.problem:
        return kept(attempt.problem, residual=math.sqrt(attempt.cost_initial),
                    params=attempt.params_initial, **common)
    return PlaneRefinement(model.plane(fit.theta), initial_plane, "refined", "", lobe=lobe,
                           residual=math.sqrt(fit.cost), params=model.lobe_fit(fit.theta),
                           time_s=time.perf_counter() - start, **common)


@dataclass(frozen=True)
class _Setup:
    """The validated arguments of one :func:`refine_plane` call."""

    views: list
    rig: CameraRig
    mask: np.ndarray
    box: tuple[int, int, int, int]  # the mask's bounding box (x, y, width, height)
    light: np.ndarray
    initial_plane: Plane
    centers: np.ndarray
    lobe: str
    f0: float
    foreshortening: float | None
    max_iterations: int

    def model(self, samples: _Samples, plane: Plane) -> _LobeModel:
        return _LobeModel(samples, self.rig, self.box, self.light, plane, self.lobe, self.f0,
                          self.foreshortening)


@dataclass(frozen=True)
class _Fit:
    theta: np.ndarray
    cost: float
    iterations: int
    converged: bool


@dataclass(frozen=True)
class _Attempt:
    """One fit, on samples placed for ``sample_plane``, and its verdict."""

    sample_plane: Plane
    samples: _Samples
    model: _LobeModel
    fit: _Fit
    cost_initial: float  # the initial plane's best cost on the same samples
    params_initial: LobeFit | None
    problem: str  # why the fit's plane must not be used ("" if it may)


def _attempt(setup: _Setup, sample_plane: Plane, photometry: np.ndarray | None = None
             ) -> _Attempt | str:
    """Sample for ``sample_plane``, fit from it, and judge against the initial plane.

    Returns why no fit could run (a string) when the samples or the start fail.
    ``photometry``: parameters whose lobe shape to start from instead of a grid search.
    """
    samples = _sample_windows(setup.views, setup.rig, setup.mask, sample_plane, setup.centers,
                              box=setup.box)
    if isinstance(samples, str):
        return samples
    model = setup.model(samples, sample_plane)
    if not model.valid:
        return ("initial plane: some fitted samples see it from behind or lie where the "
                "light is behind it")
    if photometry is None:
        theta0 = model.initial_guess()
        if theta0 is None:
            return (f"fit: no lobe width in [{_WIDTH_GRID[0]:g}, {_WIDTH_GRID[-1]:g}] gives a "
                    f"positive specular term over the {samples.n_samples} samples")
    else:
        theta0 = photometry.copy()
        theta0[:_N_PLANE] = 0.0
    fit = _fit(model, theta0, setup.max_iterations)
    # The fair reference: the initial plane with every photometric parameter fitted,
    # starting from the joint solution's, on the same samples.
    reference = model if sample_plane is setup.initial_plane else setup.model(
        samples, setup.initial_plane)
    if reference.valid:
        theta_ref, cost_ref = _profile_at_start(reference, fit.theta, setup.max_iterations)
        params_ref = reference.lobe_fit(theta_ref)
    else:  # the initial plane cannot even be evaluated on these samples
        cost_ref, params_ref = math.inf, None
    problem = _judge(fit, cost_ref, model, samples, setup.rig, setup.light, setup.initial_plane)
    return _Attempt(sample_plane, samples, model, fit, cost_ref, params_ref, problem)


def _resampled(setup: _Setup, attempt: _Attempt, *, keep_photometry: bool) -> _Attempt | None:
    """Fit again on samples placed for the plane an attempt found, if it moved far.

    Samples are placed (the object's region in the other views) for the plane a fit
    starts from; a plane that moves by more than the mask margin there leaves some of
    them off the object. Returns the new attempt if it passes, else None.
    """
    plane = attempt.model.plane(attempt.fit.theta)
    if not _warp_change_px(setup.rig, attempt.sample_plane, plane, setup.box) > MASK_MARGIN_PX:
        return None
    again = _attempt(setup, plane, photometry=attempt.fit.theta if keep_photometry else None)
    return again if isinstance(again, _Attempt) and not again.problem else None


def _warp_change_px(rig: CameraRig, before: Plane, after: Plane, box) -> float:
    """Largest move (px) of the object box's corners, mapped into any other camera.

    Compares where the mappings that two planes induce send the reference mask's box
    ``(x, y, width, height)``.
    """
    x, y, w, h = box
    corners = np.array([[x, x + w - 1, x, x + w - 1], [y, y, y + h - 1, y + h - 1],
                        [1.0, 1.0, 1.0, 1.0]])
    moved = (_views_from_reference(rig, after) - _views_from_reference(rig, before)) @ corners
    return float(np.max(np.abs(moved)))  # (the reference view's rows are 0)


def _fit(model: _LobeModel, theta0: np.ndarray, max_iterations: int) -> _Fit:
    """Fit plane and photometry from ``theta0`` (parameters of ``model``)."""
    # Stage 1: plane and lobe shape with the foreshortening exponent held, since it
    # could otherwise absorb part of the initial plane's error.
    free_start = model.free_all[model.free_all != _I_FORE]
    theta_start, _, _, _ = _levenberg_marquardt(model, theta0, free_start,
                                                min(max_iterations, _START_ITERATIONS),
                                                cost_rtol=_PHOTOMETRIC_COST_RTOL)
    # Stage 2: everything.
    theta, cost, iterations, converged = _levenberg_marquardt(
        model, theta_start, model.free_all, max_iterations, cost_rtol=_COST_RTOL)
    return _Fit(theta, cost, iterations, converged)


def _profile_at_start(model: _LobeModel, photometry_from: np.ndarray, max_iterations: int):
    """Best photometric parameters and cost with ``model``'s own starting plane."""
    theta = photometry_from.copy()
    theta[:_N_PLANE] = 0.0
    theta, cost, _, _ = _levenberg_marquardt(model, theta, model.free_photometric,
                                             max_iterations, cost_rtol=_PHOTOMETRIC_COST_RTOL)
    return theta, cost


def _judge(fit: _Fit, cost_initial: float, model: _LobeModel, samples: _Samples,
           rig: CameraRig, light: np.ndarray, initial_plane: Plane) -> str:
    """Why a fit's plane must not replace the initial plane ("" if it may)."""
    theta, cost = fit.theta, fit.cost
    if not (np.all(np.isfinite(theta)) and math.isfinite(cost)):
        return "fit: non-finite parameters or cost"
    if not cost < cost_initial:
        return f"fit: cost {cost:.4g} does not improve on the initial plane's {cost_initial:.4g}"
    if not theta[_I_SPEC] > 0.0:
        return f"fit: specular intensity {theta[_I_SPEC]:.3g} is not positive"
    at_bound = model.parameters_at_bounds(theta)
    if at_bound:
        return (f"fit: {at_bound} at the bound of its range; the lobe model does not "
                "describe this highlight")
    contrast = float(samples.luminance.max() - _low_quantile(samples.luminance))
    if math.sqrt(cost) > MAX_RELATIVE_RESIDUAL * contrast:
        return (f"fit: RMS residual {math.sqrt(cost):.4g} is more than "
                f"{MAX_RELATIVE_RESIDUAL:.0%} of the highlight's contrast {contrast:.4g}; "
                "the model does not explain the image")
    shift_px = _highlight_shift_px(rig, light, initial_plane, model.plane(theta),
                                   samples.view_indices)
    if not shift_px <= MAX_SHIFT_FRACTION * samples.half_window_px:
        return (f"fit: the highlight moved {shift_px:.1f} px, more than {MAX_SHIFT_FRACTION:g} "
                f"x the {samples.half_window_px} px window half-size")
    return ""


def _restart_plane(setup: _Setup, samples: _Samples) -> Plane | None:
    """Find the virtual-light depth whose start explains the images best; return its plane.

    The virtual light slides along the reference camera's ray through it, so that its
    image in the farthest used camera moves by each of ``_RESTART_SHIFTS_PX``. The cost
    of each candidate plane's best lobe start, all on the same samples so that the costs
    compare, ranks them. None if no candidate starts better than the initial plane.
    """
    rig, light = setup.rig, setup.light
    virtual = setup.initial_plane.mirror(light)
    ref = rig.reference_center_m
    inverse_depth = 1.0 / (virtual[2] - ref[2])
    # Disparity of the virtual light across the farthest camera, per unit inverse depth.
    span_px = rig.intrinsics.fx * float(np.max(np.linalg.norm(
        (rig.centers_m - ref)[list(samples.view_indices)], axis=1)))
    if span_px <= 0.0:  # only the reference view is sampled: no depth moves V's image there
        return None
    best_cost, best_plane = math.inf, None
    for shift in (0.0, *_RESTART_SHIFTS_PX):
        w = inverse_depth + shift / span_px
        if w <= 0.0:
            continue
        plane = plane_from_lights(light, ref + (virtual - ref) * (inverse_depth / w), ref)
        if _initial_plane_problem(plane, rig, light):
            continue
        candidate = setup.model(samples, plane)
        if candidate.valid and candidate.initial_guess() is not None \
                and candidate.initial_cost < best_cost:
            best_cost, best_plane = candidate.initial_cost, (plane if shift else None)
    return best_plane


# ======================================================================================
# Input checks and geometric sanity
# ======================================================================================


def _is_number_in(value, low: float, high: float) -> bool:
    return (not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
            and low <= float(value) <= high)


def _check_centers(centers_uv, n_views: int) -> np.ndarray | None:
    if centers_uv is None:
        return None
    try:
        centers = np.asarray(centers_uv, dtype=np.float64)
    except (TypeError, ValueError):
        raise ImageError(f"centers_uv: expected an array ({n_views}, 2) of pixels, "
                         f"got {type(centers_uv).__name__}") from None
    if centers.shape != (n_views, 2):
        raise ImageError(f"centers_uv: expected shape ({n_views}, 2), got {centers.shape}")
    if np.any(np.isinf(centers)):
        raise ImageError("centers_uv: expected finite pixels (a NaN row skips a view), got inf")
    return centers


def _initial_plane_problem(plane: Plane, rig: CameraRig, light: np.ndarray) -> str:
    """Why the initial plane cannot seed a fit, or an empty string."""
    n = plane.n
    if not (np.all(np.isfinite(n)) and math.isfinite(plane.offset_m)
            and abs(np.linalg.norm(n) - 1.0) < 1e-6):
        return f"initial plane: normal {plane.normal} is not a finite unit vector"
    behind = [i for i in range(rig.n_cameras) if plane.signed_distance(rig.centers_m[i]) <= 0.0]
    if behind:
        return (f"initial plane: camera(s) {behind} lie behind it (the normal must point "
                "towards the cameras)")
    if n[2] >= 0.0:
        return f"initial plane: seen edge-on or from behind (normal z = {n[2]:.3g} >= 0)"
    light_distance = float(plane.signed_distance(light))
    if light_distance <= 0.0:
        return f"initial plane: the light is behind it (signed distance {light_distance:.3g} m)"
    return ""


def _highlight_shift_px(rig: CameraRig, light, before: Plane, after: Plane, views) -> float:
    """Largest displacement of the virtual light's image between two planes, pixels."""
    old, new = before.mirror(light), after.mirror(light)
    # The rig is rectified: seen from camera j, a point X is X - (C_j - C_ref) seen from
    # the reference camera.
    offsets_m = rig.centers_m[list(views)] - rig.reference_center_m
    moved = rig.project(new - offsets_m) - rig.project(old - offsets_m)
    return float(np.max(np.linalg.norm(moved, axis=1)))


# ======================================================================================
# Sampling the highlight windows
# ======================================================================================


@dataclass(frozen=True)
class _Samples:
    """Samples fitted, all views stacked, unsaturated first; arrays ``(P,)`` or ``(P, 3)``.

    A sample is the mean linear luminance of a ``block x block`` pixel square, placed at
    the square's centre: averaging costs far less than fitting every pixel and keeps
    nearly all their information (the window spans about six half-maximum radii of the
    lobe, so a block is a small fraction of the lobe's width).
    """

    camera_m: np.ndarray  # (P, 3) centre of the sample's camera
    ray: np.ndarray  # (P, 3) unnormalised ray ((u - cx) / fx, (v - cy) / fy, 1)
    luminance: np.ndarray  # (P,) linear luminance
    saturated: np.ndarray  # (P,) bool: some pixel clipped, the mean is a lower bound
    view_indices: tuple[int, ...]
    half_window_px: int
    block_px: int

    @property
    def n_samples(self) -> int:
        return int(self.luminance.shape[0])


def _sample_windows(views, rig: CameraRig, mask: np.ndarray, plane: Plane, centers: np.ndarray,
                    *, box=None) -> _Samples | str:
    """Block samples around each view's highlight on the object, or why there are none.

    ``box``: the mask's bounding box, if known.
    """
    box = _box(mask) if box is None else box
    eroded = _erode(mask, MASK_MARGIN_PX, box)
    w, h = rig.image_size
    max_half = max(MIN_WINDOW_HALF_PX, int(MAX_WINDOW_FRACTION * min(w, h)))
    usable = [i for i in range(rig.n_cameras)
              if np.all(np.isfinite(centers[i]))
              and -max_half <= centers[i, 0] <= w + max_half
              and -max_half <= centers[i, 1] <= h + max_half]
    if not usable:
        return "samples: no view has a highlight centre inside or near the image"
    maps = _references_from_views(rig, plane)
    to_ref = {i: None if i == rig.reference else maps[i] for i in usable}

    # Size the window from the blob's half-maximum radius, seen on a coarse grid in a few
    # views (the reference first).
    stride = _SIZING_STRIDE_PX
    offsets = np.arange(-max_half, max_half + 1, stride)
    radii = []
    for i in sorted(usable, key=lambda j: j != rig.reference):
        if len(radii) == _SIZING_VIEWS:
            break
        uu = np.tile(offsets + int(np.rint(centers[i, 0])), len(offsets))
        vv = np.repeat(offsets + int(np.rint(centers[i, 1])), len(offsets))
        keep = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        uu, vv = uu[keep], vv[keep]
        inside = _object_lookup(eroded, to_ref[i], uu, vv)
        if inside.sum() < MIN_SAMPLES:
            continue
        y = luminance(views[i][vv[inside], uu[inside]][None], rig.image_encoding)[0]
        background, peak = _low_quantile(y), float(y.max())
        if peak - background < MIN_HIGHLIGHT_CONTRAST:
            continue
        area_px = np.count_nonzero(y > 0.5 * (background + peak)) * stride**2
        radii.append(math.sqrt(area_px / math.pi))
    if not radii:
        return (f"samples: no view shows a highlight brighter than the object by "
                f"{MIN_HIGHLIGHT_CONTRAST:g} (linear) inside the mask")
    half = math.ceil(WINDOW_PER_BLOB_RADIUS * float(np.median(radii))) + 2
    half = min(max(half, MIN_WINDOW_HALF_PX), max_half)
    block = max(1, math.ceil((2 * half + 1) / SAMPLES_PER_SIDE))

    block_mask = _erode(mask, MASK_MARGIN_PX + block // 2, box)
    uvs, lum, sat, used, counts = [], [], [], [], []
    for i in usable:
        window = _block_window(views[i], rig, block_mask, to_ref[i], centers[i], half, block)
        if window is None or not window[3].any():
            continue
        uv, y, clipped, inside = window
        uvs.append(uv[inside])
        lum.append(y[inside])
        sat.append(clipped[inside])
        used.append(i)
        counts.append(len(lum[-1]))
    if not used:
        return "samples: no object pixels in any highlight window"
    luminance_all = np.concatenate(lum)
    saturated_all = np.concatenate(sat)
    if len(luminance_all) < MIN_SAMPLES:
        return (f"samples: only {len(luminance_all)} object samples near the highlights "
                f"(< {MIN_SAMPLES})")
    unsaturated = luminance_all[~saturated_all]
    background = _low_quantile(unsaturated) if unsaturated.size else 1.0
    flank = int(np.count_nonzero(unsaturated > background + MIN_HIGHLIGHT_CONTRAST))
    if flank < MIN_FLANK_SAMPLES:
        return (f"samples: only {flank} unsaturated samples on the highlight's flanks "
                f"(< {MIN_FLANK_SAMPLES}; {int(saturated_all.sum())} of "
                f"{len(saturated_all)} saturated); the lobe cannot be fitted")
    # Unsaturated samples first: the intensity solve then slices instead of copying.
    order = np.argsort(saturated_all, kind="stable")
    cameras_m = np.repeat(rig.centers_m[used], counts, axis=0)
    return _Samples(cameras_m[order], rig.rays(np.concatenate(uvs)[order]),
                    luminance_all[order], saturated_all[order], tuple(used), half, block)


def _low_quantile(values: np.ndarray) -> float:
    """Return the background level near the highlight: a low quantile, by partition."""
    k = int(_BACKGROUND_QUANTILE * (len(values) - 1))
    return float(np.partition(values, k)[k])


@dataclass(frozen=True)
class _Eroded:
    """A shrunk reference mask, kept only over the object's box (the rest is outside)."""

    inside: np.ndarray  # (h, w) bool, the box's pixels
    origin: tuple[int, int]  # reference pixel (x, y) of inside[0, 0]


def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box ``(x, y, width, height)`` of a bool mask's pixels, in pixels."""
    # (a bool array viewed as bytes: no copy of a full-size mask)
    return tuple(int(v) for v in cv2.boundingRect(mask.view(np.uint8)))


def _erode(mask: np.ndarray, radius_px: int, box) -> _Eroded:
    """Shrink the mask by ``radius_px`` in the chessboard metric.

    Only the object's bounding box ``box`` (see :func:`_box`), padded by the radius, is
    eroded: nothing outside it survives, and the padding keeps the box's edge eroded as
    in the full image.
    """
    x, y, w, h = box
    height, width = mask.shape
    x0, y0 = max(x - radius_px, 0), max(y - radius_px, 0)
    x1, y1 = min(x + w + radius_px, width), min(y + h + radius_px, height)
    side = 2 * radius_px + 1
    pixels = np.ascontiguousarray(mask[y0:y1, x0:x1]).view(np.uint8)
    return _Eroded(cv2.erode(pixels, np.ones((side, side), np.uint8)).view(bool), (x0, y0))


def _views_from_reference(rig: CameraRig, plane: Plane) -> np.ndarray:
    """Affine maps ``(N, 2, 3)`` from reference pixels to each camera's pixels on the plane.

    In a rectified rig a point at depth z moves by ``-f (C_j - C_ref) / z`` between the
    reference view and camera j, and on a plane ``1 / z`` is affine in the pixel: the
    homography the plane induces is affine.
    """
    k = rig.intrinsics
    n = plane.n
    base = plane.offset_m - float(n @ rig.reference_center_m)
    # 1 / z = g . (u, v, 1) at reference pixels (u, v)
    g = np.array([n[0] / k.fx, n[1] / k.fy, n[2] - n[0] * k.cx / k.fx - n[1] * k.cy / k.fy]) / base
    d = rig.centers_m - rig.reference_center_m
    # camera pixel = A (u, v) + t with A = I - s g[:2]^T, t = -s g[2], s = f * dXY
    s = d[:, :2] * np.array([k.fx, k.fy])  # (N, 2)
    maps = np.empty((len(d), 2, 3))
    maps[:, :, :2] = np.eye(2) - s[:, :, None] * g[:2]
    maps[:, :, 2] = -g[2] * s
    return maps


def _references_from_views(rig: CameraRig, plane: Plane) -> np.ndarray:
    """Affine maps ``(N, 2, 3)`` from each camera's pixels to the reference pixels."""
    forward = _views_from_reference(rig, plane)
    a, t = forward[:, :, :2], forward[:, :, 2]
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    inverse = np.empty_like(forward)
    inverse[:, 0, 0], inverse[:, 1, 1] = a[:, 1, 1] / det, a[:, 0, 0] / det
    inverse[:, 0, 1], inverse[:, 1, 0] = -a[:, 0, 1] / det, -a[:, 1, 0] / det
    inverse[:, :, 2] = -np.einsum("nij,nj->ni", inverse[:, :, :2], t)
    return inverse


def _object_lookup(eroded_ref: _Eroded, to_ref: np.ndarray | None, uu: np.ndarray,
                   vv: np.ndarray) -> np.ndarray:
    """Whether camera pixels ``uu, vv`` (any shape) land on the eroded reference mask."""
    if to_ref is not None:
        uu, vv = (to_ref[0, 0] * uu + to_ref[0, 1] * vv + to_ref[0, 2],
                  to_ref[1, 0] * uu + to_ref[1, 1] * vv + to_ref[1, 2])
    x0, y0 = eroded_ref.origin
    ru, rv = np.rint(uu).astype(np.intp) - x0, np.rint(vv).astype(np.intp) - y0
    h, w = eroded_ref.inside.shape
    ok = (ru >= 0) & (ru < w) & (rv >= 0) & (rv < h)
    inside = np.zeros(ok.shape, dtype=bool)
    inside[ok] = eroded_ref.inside[rv[ok], ru[ok]]
    return inside


def _block_window(view: np.ndarray, rig: CameraRig, block_mask: np.ndarray, to_ref, center_uv,
                  half: int, block: int):
    """Block samples of the window around ``center_uv``, or None if it misses the image.

    Returns block centres ``(M, 2)`` (pixels), mean linear luminance, saturation (a pixel
    of the block clipped) and object membership ``(M,)``; ``block_mask`` is the
    reference mask eroded so that a block centred on it lies wholly on the object.
    """
    w, h = rig.image_size
    n_side = (2 * half + 1) // block
    start = np.rint(np.asarray(center_uv)).astype(int) - (n_side * block) // 2
    # Keep whole blocks inside the image.
    lo = np.maximum(0, np.ceil(-start / block)).astype(int)
    hi = np.minimum(n_side, np.floor((np.array([w, h]) - start) / block)).astype(int)
    if np.any(hi <= lo):
        return None
    u0, v0 = start + lo * block
    nu, nv = (int(x) for x in hi - lo)
    crop = view[v0:v0 + nv * block, u0:u0 + nu * block]
    lum = _decode(crop, rig.image_encoding)
    if lum.ndim == 3:
        lum = cv2.transform(lum, REC709_LUMA.reshape(1, 3))
    clipped = saturation_mask(crop)
    if block > 1:
        # INTER_AREA with an integer factor is the exact block mean.
        lum = cv2.resize(lum, (nu, nv), interpolation=cv2.INTER_AREA)
        # any() over block rows, then over block columns (single-axis reductions are fast)
        clipped = clipped.reshape(nv, block, nu * block).any(axis=1)
        clipped = clipped.reshape(nv, nu, block).any(axis=2)
    cu = u0 + block * np.arange(nu) + (block - 1) / 2.0
    cv = v0 + block * np.arange(nv) + (block - 1) / 2.0
    uu, vv = np.tile(cu, nv), np.repeat(cv, nu)  # row-major, like the blocks
    inside = _object_lookup(block_mask, to_ref, uu, vv)
    return (np.stack([uu, vv], axis=1), lum.ravel().astype(np.float64), clipped.ravel(),
            inside)


def _decode(image: np.ndarray, encoding: str) -> np.ndarray:
    """Linear intensity ``(H, W[, 3])`` float32 of a crop (a table for uint8 images)."""
    if image.dtype == np.uint8:
        return cv2.LUT(image, _DECODE_LUT[encoding])
    if encoding == "srgb":
        return srgb_to_linear(image)
    return image.astype(np.float32)


# ======================================================================================
# Shading model
# ======================================================================================


@dataclass(frozen=True)
class _Geometry:
    """Shading geometry of the samples for one plane, arrays ``(P,)``.

    Besides the shading terms it keeps the intermediates of their derivatives with
    respect to the plane (see :meth:`_LobeModel.jacobian`).
    """

    cos_h: np.ndarray  # cosine of the half-vector angle
    sin2_h: np.ndarray
    log_foreshortening: np.ndarray  # log(cos_i cos_o)
    diffuse: np.ndarray  # g_d - 1
    specular: np.ndarray  # F / (cos_o r^2), normalised
    normal: np.ndarray  # (3,) unit normal n
    t: np.ndarray  # ray parameter of X = C + t k
    nk: np.ndarray  # n . k
    tq_b: np.ndarray  # t q - b, half the derivative of r^2 along t
    r: np.ndarray  # distance from X to the light
    cos_i: np.ndarray
    cos_o: np.ndarray
    cos_io: np.ndarray  # omega_i . omega_o
    half_norm: np.ndarray  # |omega_i + omega_o|
    grazing: np.ndarray  # 1 - omega_i . h
    fresnel: np.ndarray


class _LobeModel:
    """The highlight rendering of :func:`refine_plane` as a function of 9 parameters.

    ``theta = (tilt_1, tilt_2, offset_m, log_width, tail, foreshortening, specular,
    diffuse, level)``: the normal is ``normalise(n0 + tilt_1 e1 + tilt_2 e2)`` with
    ``e1, e2`` orthonormal to the initial normal ``n0``; the offset is ``c0 + offset_m``.
    The last three (intensities) are linear and solved at every evaluation; the fit
    moves the others (``free_*`` lists which).
    """

    def __init__(self, samples: _Samples, rig: CameraRig, box, light: np.ndarray,
                 plane0: Plane, lobe: str, f0: float, foreshortening: float | None) -> None:
        self.lobe = lobe
        self.f0 = f0
        self.light = light
        self.n0 = plane0.n
        self.c0 = plane0.offset_m
        self.foreshortening0 = (_FORESHORTENING_START if foreshortening is None
                                else float(foreshortening))
        helper = np.eye(3)[int(np.argmin(np.abs(self.n0)))]
        e1 = np.cross(self.n0, helper)
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.n0, self.e1)
        # Convergence is judged by the disparity at the corners of the object's box.
        x, y, w, h = box
        corners = np.array([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]],
                           dtype=np.float64)
        self.probe_rays = rig.rays(corners)
        self.reference_center_m = rig.reference_center_m
        self.disparity_scale = rig.intrinsics.fx * rig.baseline_m
        # Per-sample constants of the ray-plane algebra (see _geometry).
        k, c = samples.ray, samples.camera_m
        self.ray_t = np.ascontiguousarray(k.T)
        self.camera_t = np.ascontiguousarray(c.T)
        self.q = np.einsum("pi,pi->p", k, k)
        self.sqrt_q = np.sqrt(self.q)
        to_light = light - c
        self.a = np.einsum("pi,pi->p", to_light, to_light)
        self.b = np.einsum("pi,pi->p", to_light, k)
        self.y = samples.luminance
        self.censored = samples.saturated
        self.n_unclipped = int(np.count_nonzero(~samples.saturated))  # they come first
        self._cache_key: bytes | None = None
        self._cache: _Geometry | None = None
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
        shape = [_I_WIDTH] + ([_I_TAIL] if lobe == "gtr" else [])
        shape += [_I_FORE] if foreshortening is None else []
        self.free_photometric = np.array(shape)
        self.free_all = np.array(list(range(_N_PLANE)) + shape)
        self._jacobian_buffer = np.empty((len(self.free_all), len(self.y)))
        self._jacobian_partner = np.empty_like(self._jacobian_buffer)
        # Normalise the geometric factors at the initial plane so the intensities read
        # as luminances at the highlight and the parameters are well scaled.
        self.diffuse_scale = self.spec_scale = 1.0
        geometry = self._geometry(np.zeros(_N_PLANE))
        self.valid = geometry is not None
        if not self.valid:
            return
        self.diffuse_scale = 1.0 / float(np.median(geometry.diffuse + 1.0))
        self.spec_scale = 1.0 / float(np.median(geometry.specular))
        # the same geometry with the scales applied is the start's
        diffuse = geometry.diffuse + 1.0
        diffuse *= self.diffuse_scale
        diffuse -= 1.0
        self._cache = dataclasses.replace(geometry, diffuse=diffuse,
                                          specular=geometry.specular * self.spec_scale)
        self._cache_key = np.zeros(_N_PLANE).tobytes()

    def start_theta(self) -> np.ndarray:
        theta = np.zeros(_N_PARAMS)
        theta[_I_WIDTH] = math.log(0.1)
        theta[_I_TAIL] = 0.5 if self.lobe != "blinn_phong" else 0.0
        theta[_I_FORE] = self.foreshortening0
        return theta

    # ------------------------------------------------------------------ geometry
    def _planes(self, p: np.ndarray):
        """Return normals ``(B, 3)`` and offsets ``(B,)`` of plane parameters ``(B, 3)``."""
        m = self.n0 + p[:, :1] * self.e1 + p[:, 1:2] * self.e2
        return m / np.linalg.norm(m, axis=1, keepdims=True), self.c0 + p[:, 2]

    def plane(self, theta: np.ndarray) -> Plane:
        n, c = self._planes(theta[None, :_N_PLANE])
        return Plane(tuple(float(v) + 0.0 for v in n[0]), float(c[0]))

    def _geometry(self, plane_params: np.ndarray) -> _Geometry | None:
        """Shading geometry of the samples for plane parameters ``(3,)``.

        Everything reduces to scalars per sample: with ``X = C + t k`` on the plane,
        ``|L - X|^2 = a - 2 t b + t^2 q`` and ``n . X = c``. None if the plane is invalid
        for some sample: seen from behind, behind a camera, or with the light behind it.
        """
        n, c = self._planes(plane_params[None])
        n, c = n[0], float(c[0])
        nk = n @ self.ray_t
        light_height = float(n @ self.light) - c
        if not (nk.max() < 0.0 and light_height > 0.0):
            return None  # some samples see the plane from behind, or the light is behind it
        t = (c - n @ self.camera_t) / nk
        if not t.min() > 0.0:
            return None
        cos_o = np.divide(nk, self.sqrt_q)
        np.negative(cos_o, out=cos_o)
        tq_b = t * self.q
        tq_b -= self.b
        r2 = tq_b - self.b  # |L - X|^2 = t (t q - 2 b) + a
        r2 *= t
        r2 += self.a
        r = np.sqrt(r2)
        cos_i = light_height / r
        cos_io = tq_b / self.sqrt_q  # omega_i . omega_o = (t q - b) / (sqrt(q) r)
        cos_io /= r
        half_norm = cos_io * 2.0  # |omega_i + omega_o|
        half_norm += 2.0
        np.sqrt(half_norm, out=half_norm)
        cos_h = cos_i + cos_o
        cos_h /= half_norm
        np.minimum(cos_h, 1.0, out=cos_h)
        grazing = cos_io + 1.0  # 1 - omega_i . h
        grazing /= half_norm
        np.subtract(1.0, grazing, out=grazing)
        # Schlick; powers by multiplication (numpy's ** 5 is a slow generic pow)
        fresnel = grazing * grazing
        fresnel *= fresnel
        fresnel *= grazing
        fresnel *= 1.0 - self.f0
        fresnel += self.f0
        sin2_h = cos_h * cos_h
        np.subtract(1.0, sin2_h, out=sin2_h)
        log_foreshortening = cos_i * cos_o
        np.log(log_foreshortening, out=log_foreshortening)
        diffuse = cos_i / r2
        diffuse *= self.diffuse_scale
        diffuse -= 1.0
        specular = np.multiply(cos_o, r2, out=r2)
        np.divide(fresnel, specular, out=specular)
        specular *= self.spec_scale
        return _Geometry(cos_h=cos_h, sin2_h=sin2_h, log_foreshortening=log_foreshortening,
                         diffuse=diffuse, specular=specular, normal=n, t=t, nk=nk, tq_b=tq_b,
                         r=r, cos_i=cos_i, cos_o=cos_o, cos_io=cos_io, half_norm=half_norm,
                         grazing=grazing, fresnel=fresnel)

    def _base_geometry(self, theta: np.ndarray) -> _Geometry | None:
        """Geometry of ``theta``'s plane, reused while only the photometry changes."""
        key = theta[:_N_PLANE].tobytes()
        if self._cache_key != key:
            self._cache = self._geometry(theta[:_N_PLANE])
            self._cache_key = key
        return self._cache

    def _lobe(self, g: _Geometry, theta: np.ndarray) -> np.ndarray:
        """Specular term ``S(n . h) g_s`` with the peak-normalised lobe ``S``, ``(P,)``."""
        return self._shape(g, theta) * self._specular_term(g, theta[_I_FORE])

    def _shape(self, g: _Geometry, theta: np.ndarray) -> np.ndarray:
        """Return the peak-normalised lobe ``S(n . h)``, ``(P,)``."""
        alpha2 = math.exp(2.0 * theta[_I_WIDTH])
        if self.lobe == "ggx":
            ratio = alpha2 / (alpha2 + g.sin2_h * (1.0 - alpha2))
            return ratio * ratio
        if self.lobe == "gtr":
            tail = theta[_I_TAIL]
            z = g.sin2_h * (2.0 * (1.0 - alpha2) / alpha2)
            if abs(tail) < _ZERO_TAIL:
                return np.exp(-z)
            # (1 + t z)^(-1/t); where a light tail (t < 0) ends, the lobe is 0.
            return np.exp(np.log(np.maximum(1.0 + tail * z, 1e-300)) * (-1.0 / tail))
        with np.errstate(divide="ignore"):
            return np.exp((2.0 / alpha2 - 2.0) * np.log(np.maximum(g.cos_h, 0.0)))

    def _shape_slopes(self, g: _Geometry, theta: np.ndarray, shape: np.ndarray):
        """Return derivatives of :meth:`_shape` ``(P,)`` by the geometry and the shape.

        Returns ``(by, along, by_log_width, by_tail)``: the lobe's derivative is
        ``by * d(along)`` for ``along`` one of ``g.sin2_h`` or ``g.cos_h``; ``by_tail`` is
        None unless the lobe is ``"gtr"``. Where a lobe is exactly 0 (a light tail's end,
        or beyond 90 degrees) all are 0.
        """
        alpha2 = math.exp(2.0 * theta[_I_WIDTH])
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
        tail = theta[_I_TAIL]
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

    def _specular_term(self, g: _Geometry, foreshortening: float) -> np.ndarray:
        """``g_s (cos_i cos_o)^k`` of a geometry, ``(P,)``; the last one is kept."""
        if self._specular_key != (id(g), foreshortening):
            term = g.specular
            if foreshortening != 0.0:
                term = np.exp(foreshortening * g.log_foreshortening)
                term *= g.specular
            self._specular_key, self._specular_value = (id(g), foreshortening), term
            self._specular_geometry = g  # keeps id(g) from being reused while cached
        return self._specular_value

    def _model(self, g: _Geometry, theta: np.ndarray) -> np.ndarray:
        return theta[_I_SPEC] * self._lobe(g, theta) + theta[_I_DIFF] * g.diffuse + theta[_I_LEVEL]

    # ------------------------------------------------------------------ residuals
    def _residual(self, model: np.ndarray) -> np.ndarray:
        """Return model minus observation, ``(P,)``.

        Saturated samples are lower bounds: for them only a model below the observation
        is an error.
        """
        r = model - self.y
        np.minimum(r[self.n_unclipped:], 0.0, out=r[self.n_unclipped:])  # saturated come last
        return r

    def _intensity_terms(self, g: _Geometry):
        """Return the sums over unsaturated samples that do not depend on the lobe (cached).

        ``(d . d, sum d)`` of the diffuse term ``d`` and ``d . y`` with the observations.
        """
        if self._terms_geometry is not g:
            d = g.diffuse[:self.n_unclipped]
            self._terms = float(d @ d), float(d.sum()), float(d @ self.y[:self.n_unclipped])
            self._terms_geometry = g
        return self._terms

    def _intensities(self, g: _Geometry, lobe: np.ndarray):
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
        coef = _solve_normal(normal0, rhs0)
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
                coef = _solve_normal(normal0 + cols @ cols.T, rhs0 + cols @ clipped_y[active])
        model = lobe * coef[0]
        model += coef[1] * g.diffuse
        model += coef[2]
        return coef, model

    def _lobe_at(self, theta: np.ndarray):
        """Return the geometry, lobe and shape ``(P,)`` of ``theta`` (Nones if invalid).

        The last one is kept: a step's Jacobian is taken where it was evaluated.
        """
        key = theta[:_I_SPEC].tobytes()
        if self._lobe_key != key:
            g = self._base_geometry(theta)
            if g is None:
                self._lobe_value = (None, None, None)
            else:
                shape = self._shape(g, theta)
                self._lobe_value = (g, shape * self._specular_term(g, theta[_I_FORE]), shape)
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
        out[_I_SPEC:] = coef
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
        model = theta[_I_SPEC:] @ basis
        # A saturated sample above its lower bound contributes nothing, nor does its slope.
        ignored = self.censored & (model >= self.y)
        if ignored.any():
            jac[:, ignored] = 0.0
            basis[:, ignored] = 0.0
        partner = self._basis_partner  # (see gram)
        np.copyto(partner, basis)
        coef = _solve_normal(basis @ partner.T, basis @ jac.T)  # (3, K)
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
        specular, fore = theta[_I_SPEC], theta[_I_FORE]
        by, along, by_log_width, by_tail = self._shape_slopes(g, theta, shape)
        spec_term = specular * self._specular_term(g, fore)  # S's factor in the model
        planes = [(row, index) for row, index in enumerate(free) if index < _N_PLANE]
        if planes:
            on_nk, on_cam, on_lh = self._plane_slope_terms(g, theta, by, along, shape, spec_term)
            directions = self._plane_directions(theta)
        for row, index in planes:
            # slope = (n . L - c)' on_lh + (c - n . C)' on_cam + (n . k)' on_nk
            dn, dc = directions[index]
            slope = out[row]
            slope[:] = dc * (on_cam - on_lh)
            if dn.any():
                slope += float(dn @ self.light) * on_lh
                slope -= on_cam * (dn @ self.camera_t)
                slope += on_nk * (dn @ self.ray_t)
        for row, index in enumerate(free):
            if index == _I_WIDTH:
                np.multiply(by_log_width, spec_term, out=out[row])
            elif index == _I_TAIL:
                np.multiply(by_tail, spec_term, out=out[row])
            elif index == _I_FORE:  # the exponent multiplies log(cos_i cos_o)
                np.multiply(lobe, g.log_foreshortening, out=out[row])
                out[row] *= specular
        return out

    def _plane_slope_terms(self, g: _Geometry, theta: np.ndarray, by: np.ndarray,
                           along: np.ndarray, shape: np.ndarray, spec_term: np.ndarray):
        """Return the model's derivatives ``(P,)`` by ``n . k``, ``c - n . C``, ``n . L - c``.

        Every shading term depends on the plane through these three per-sample scalars
        (``k`` the ray, ``C`` the camera centre, ``L`` the light), and linearly so to
        first order: collecting the chain rule's coefficients once makes each plane
        parameter's slope three products.
        """
        fore = theta[_I_FORE]
        inv_r, inv_half = 1.0 / g.r, 1.0 / g.half_norm
        rho = g.tq_b * inv_r  # dr = rho dt (r^2 = a - 2 t b + t^2 q)
        kappa = g.cos_io * rho  # d cos_io = kappa dt (cos_io = (t q - b) / (sqrt(q) r))
        np.subtract(self.sqrt_q, kappa, out=kappa)
        kappa *= inv_r
        # d grazing = kappa ((1 - grazing) / half_norm - 1) / half_norm dt
        grazing_t = (1.0 - g.grazing) * inv_half
        grazing_t -= 1.0
        grazing_t *= kappa
        grazing_t *= inv_half
        # d log F = 5 (1 - f0) x^4 / F dx, x = grazing (Schlick)
        fresnel_slope = g.grazing * g.grazing
        fresnel_slope *= fresnel_slope
        fresnel_slope *= 5.0 * (1.0 - self.f0) / g.fresnel
        # The model's slope on d cos_h, on the specular factor's relative change and on
        # the diffuse factor's relative change.
        on_cos_h = by * spec_term
        if along is g.sin2_h:  # d sin^2 = -2 cos_h d cos_h
            on_cos_h *= -2.0 * g.cos_h
        on_spec = shape * spec_term
        on_diffuse = theta[_I_DIFF] * (g.diffuse + 1.0)
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
        on_nk = on_cos_o / self.sqrt_q
        np.negative(on_nk, out=on_nk)
        on_nk -= on_cam * g.t
        return on_nk, on_cam, on_lh

    def _plane_directions(self, theta: np.ndarray):
        """Return the derivatives ``(dn (3,), dc)`` of normal and offset by each plane parameter."""
        m = self.n0 + theta[0] * self.e1 + theta[1] * self.e2
        norm = float(np.linalg.norm(m))
        n = m / norm
        # n = m / |m|: dn = (e - n (n . e)) / |m|
        return ((self.e1 - n * float(n @ self.e1)) / norm, 0.0), \
            ((self.e2 - n * float(n @ self.e2)) / norm, 0.0), (np.zeros(3), 1.0)

    # ------------------------------------------------------------------ start and report
    def initial_guess(self) -> np.ndarray | None:
        """Parameters at the initial plane: the best lobe shape on a grid.

        Intensities are fitted for every candidate; None if no lobe gives a positive
        specular term.
        """
        g = self._base_geometry(self.start_theta())
        best_cost, best = math.inf, None

        def consider(width: float, tail: float) -> None:
            nonlocal best_cost, best
            theta = self.start_theta()
            theta[_I_WIDTH], theta[_I_TAIL] = math.log(width), tail
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
                best[_I_SPEC:] = coef

        # Widths first with the default tail, then other tails around the best width.
        for width in _WIDTH_GRID:
            consider(width, self.start_theta()[_I_TAIL])
        if best is not None and _I_TAIL in self.free_all:
            best_width = math.exp(best[_I_WIDTH])
            for factor in _WIDTH_REFINE_FACTORS:
                for tail in _TAIL_GRID[1:]:
                    consider(best_width * factor, tail)
        self.initial_cost = best_cost
        return best

    def _bounds(self):
        return {_I_WIDTH: np.log(_WIDTH_BOUNDS), _I_TAIL: _TAIL_BOUNDS,
                _I_FORE: _FORESHORTENING_BOUNDS}

    def clamp(self, theta: np.ndarray) -> np.ndarray:
        for index, (low, high) in self._bounds().items():
            theta[index] = min(max(theta[index], low), high)
        return theta

    def parameters_at_bounds(self, theta: np.ndarray) -> str:
        """Name and value of fitted shape parameters stuck at a bound ("" if none)."""
        names = {_I_WIDTH: "width", _I_TAIL: "tail", _I_FORE: "foreshortening"}
        stuck = []
        for index, (low, high) in self._bounds().items():
            if index in self.free_all and min(theta[index] - low, high - theta[index]) < 1e-9:
                value = math.exp(theta[index]) if index == _I_WIDTH else theta[index]
                stuck.append(f"{names[index]} {value:.4g}")
        return ", ".join(stuck)

    def disparity_change_px(self, before: np.ndarray, after: np.ndarray) -> float:
        """Largest change of the stereo disparity at the probe pixels between two planes."""
        n, c = self._planes(np.stack([before[:_N_PLANE], after[:_N_PLANE]]))
        # d = fx B / z with 1 / z = (n . k) / (c - n . C_ref) along reference rays k
        disparity = self.disparity_scale * (n @ self.probe_rays.T) / (
            c - n @ self.reference_center_m)[:, None]
        return float(np.max(np.abs(disparity[1] - disparity[0])))

    def lobe_fit(self, theta: np.ndarray) -> LobeFit:
        return LobeFit(width=float(np.exp(theta[_I_WIDTH])), tail=float(theta[_I_TAIL]),
                       foreshortening=float(theta[_I_FORE]), specular=float(theta[_I_SPEC]),
                       diffuse=float(theta[_I_DIFF]),
                       ambient=float(theta[_I_LEVEL] - theta[_I_DIFF]))


# ======================================================================================
# Levenberg-Marquardt
# ======================================================================================


def _solve_normal(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
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


def _levenberg_marquardt(model: _LobeModel, theta0: np.ndarray, free: np.ndarray,
                         max_iterations: int, *, cost_rtol: float):
    """Minimise the mean squared residual over ``theta[free]`` (intensities follow).

    Stops when an accepted step lowers the cost by less than ``cost_rtol`` (relative),
    or moves the plane's disparity by less than ``_DISPARITY_STEP_TOL_PX`` while
    lowering the cost by less than ``_PLANE_COST_RTOL``, or when no step lowers it.
    Returns the parameters, their cost, the number of steps tried (accepted or not) and
    whether a stopping rule was met.
    """
    residual, theta = model.evaluate(theta0)
    cost = float(np.mean(residual**2))
    lam = _LAMBDA0
    converged = False
    steps = 0
    moves_plane = bool(np.any(free < _N_PLANE))
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
    return theta, cost, steps, converged
