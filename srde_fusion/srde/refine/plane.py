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

The shading model and its parameters are described in
:mod:`~srde_fusion.srde.refine.model`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..._checks import check_mask, check_point3, check_views
from ...errors import ImageError, LightError, SRDEError
from ...geometry import CameraRig, Plane, plane_from_lights
from ...geometry.rig import MAX_LIGHT_RADIUS_M
from .disc import DISC_RINGS, disc_rings
from .joint import JointLobeModel
from .layout import I_FORE, I_SPEC, I_WIDTH, N_PLANE
from .lobes import DEFAULT_LOBE, LOBES
from .model import (
    DEFAULT_F0,
    FORESHORTENING_BOUNDS,
    FRESNEL_TERMS,
    SUPPORT_POINTS,
    WIDTH_GRID,
    LobeFit,
    LobeModel,
)
from .samples import (
    MASK_MARGIN_PX,
    HighlightSamples,
    low_quantile_of,
    mask_bbox,
    sample_windows,
    warp_change_px,
)
from .solver import Minimum, levenberg_marquardt

__all__ = [
    "PlaneRefinement",
    "disparity_sigma_px",
    "refine_plane",
]

#: A fit rerun with the foreshortening exponent held (its free value ran to a bound) is
#: kept only when its plane's disparity standard error is at most this, px.
HELD_EXPONENT_MAX_SIGMA_PX = 0.1

#: A fit whose RMS residual exceeds this fraction of the highlight's contrast does not
#: explain the image (texture, a second light, a curved surface): the plane is kept.
MAX_RELATIVE_RESIDUAL = 0.05


#: The refined highlight may move at most this fraction of the window half-size.
MAX_SHIFT_FRACTION = 0.5


# The joint fit also ends when a step lowers the cost by less than _COST_RTOL (relative;
# see levenberg_marquardt for the plane's own rule). Fits that only seed or compare stop
# at _PHOTOMETRIC_COST_RTOL.
_COST_RTOL = 1e-7
_PHOTOMETRIC_COST_RTOL = 1e-4


# Restart shifts (px) of the virtual light's image in the farthest camera, tried when a
# fit from the initial plane fails.
_RESTART_SHIFTS_PX = (-16.0, -8.0, -4.0, -2.0, 2.0, 4.0, 8.0, 16.0)


# The first stage only has to bring the plane near; the joint stage finishes.
_START_ITERATIONS = 6


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
    disparity_sigma_px : float
        Standard error of the refined plane's disparity (the rig's stereo disparity, px):
        the largest over the corners of the object's box, from the fit's own residuals
        (:func:`disparity_sigma_px`); NaN unless refined.
    contrast : float
        The fitted samples' highlight contrast (brightest sample over the background,
        linear luminance), the scale of the residual check; NaN if no samples were cut.
    views : tuple of int
        The views whose windows around the fitted light's highlight were fitted,
        ascending; empty if no samples were cut.
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
    disparity_sigma_px: float = math.nan
    contrast: float = math.nan
    views: tuple[int, ...] = ()

    @property
    def ok(self) -> bool:
        """True when the refined plane replaced the initial one."""
        return self.status == "refined"

    @property
    def explains_images(self) -> bool:
        """Whether the returned plane's fit passes the residual check.

        Its RMS residual is at most :data:`MAX_RELATIVE_RESIDUAL` of the samples'
        contrast, as a refined plane's must be; False when either is unknown. A plane kept
        because its fit did not improve on it may still explain the images so.
        """
        return bool(self.residual <= MAX_RELATIVE_RESIDUAL * self.contrast)

    def __bool__(self) -> bool:
        return self.ok


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
    fresnel: str = "exact",
    max_iterations: int = 20,
    other_lights_m=None,
    modelled_lights_m=None,
    light_radius_m: float | None = None,
    modelled_centers_uv=None,
    pixel_samples: bool | None = None,
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
        Fresnel reflectance at normal incidence, in (0, 1]: 0.04 for plastics and glass
        (refractive index 1.5); ``((n - 1) / (n + 1))^2`` for a known index ``n``.
    fresnel : {"exact", "schlick"}
        The Fresnel equations of the dielectric with that reflectance (default), or
        Schlick's approximation of them (which real surfaces do not follow at grazing
        angles).
    max_iterations : int
        Cap on the steps of each Levenberg-Marquardt stage.
    other_lights_m : array_like, (M, 3), metres, optional
        Further known lights. Their highlights (where each sampled plane puts them) are
        left out of the fitting windows (see ``modelled_lights_m`` for rendering them);
        their diffuse light on the samples is rendered, each with an intensity of its
        own (:mod:`~.diffuse`), as is the modelled lights'.
    modelled_lights_m : array_like, (M, 3), metres, optional
        Further known lights whose highlights are rendered beside ``light_m``'s instead
        (:class:`~.joint.JointLobeModel`: one lobe per light on the same plane and
        surface, each light with its own intensity), for highlights merged into one
        blob. They should not also be in ``other_lights_m``. They are points.
    light_radius_m : float, optional
        Radius of the (spherical) light, metres, if known: the lobe model then sees the
        light's disc (a flat-topped highlight over the light's mirror image, see
        :mod:`~srde_fusion.srde.refine.disc`) instead of a point, whose extent the lobe's
        fitted width would otherwise absorb. None or 0: a point light.
    modelled_centers_uv : array_like, (M, N, 2), pixels, optional
        The modelled lights' highlight centres per view (a NaN row: none there). The
        fitting windows then also go around them, in the views where ``light_m``'s
        highlight has a window: every light's highlight measures the same plane. Without
        them the windows follow ``light_m``'s highlight only.
    pixel_samples : bool, optional
        Fit every pixel of the windows (True) or the means of small blocks of them
        (False). By default every pixel on a rig of two cameras, where each view's
        evidence counts double and the pixels beside a clipped core are the lobe's
        steepest (several times the time), blocks on larger arrays.

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
    if foreshortening is not None and not _is_number_in(foreshortening, *FORESHORTENING_BOUNDS):
        raise SRDEError(f"foreshortening: expected None or a number in "
                        f"{list(FORESHORTENING_BOUNDS)}, got {foreshortening!r}")
    if not _is_number_in(f0, 0.0, 1.0) or f0 == 0.0:
        raise SRDEError(f"f0: expected a number in (0, 1], got {f0!r}")
    if fresnel not in FRESNEL_TERMS:
        raise SRDEError(f"fresnel: expected one of {list(FRESNEL_TERMS)}, got {fresnel!r}")
    if (isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer))
            or max_iterations < 1):
        raise SRDEError(f"max_iterations: expected a positive integer, got {max_iterations!r}")
    if light_radius_m is not None and not _is_number_in(light_radius_m, 0.0, MAX_LIGHT_RADIUS_M):
        raise LightError(f"light_radius_m: expected None or a radius in "
                         f"[0, {MAX_LIGHT_RADIUS_M:g}] m, got {light_radius_m!r}")
    radius_m = float(light_radius_m) if light_radius_m else None  # 0: a point light
    if pixel_samples is not None and not isinstance(pixel_samples, bool):
        raise SRDEError(f"pixel_samples: expected True, False or None, got {pixel_samples!r}")

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
    others = _check_lights(other_lights_m, "other_lights_m")
    modelled = _check_lights(modelled_lights_m, "modelled_lights_m")
    modelled_centers = _check_modelled_centers(modelled_centers_uv, modelled, rig.n_cameras)
    setup = _Setup(views, rig, mask, mask_bbox(mask), light, initial_plane, centers, lobe, f0,
                   fresnel, foreshortening, max_iterations, others, modelled, radius_m,
                   modelled_centers, pixel_samples)
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
    if attempt.problem and attempt.model.at_bound(attempt.fit.theta, I_FORE):
        # The free exponent ran to its bound: it absorbed what the lobe does not model
        # (a rough lobe's clipped flank seen by two views). Held at the microfacet value
        # (0, as real glossy surfaces and Cook-Torrance have it) the fit may still
        # settle: it is judged as any other, and kept only if the images pin its plane
        # down (a fallback's plane must not be a loose one).
        held = replace(setup, foreshortening=0.0)
        retry = _attempt(held, initial_plane)
        if isinstance(retry, _Attempt) and not retry.problem \
                and disparity_sigma_px(retry.model, retry.fit) <= HELD_EXPONENT_MAX_SIGMA_PX:
            attempt, setup = retry, held
    if not attempt.problem:
        attempt = _resampled(setup, attempt, keep_photometry=True) or attempt

    fit, model = attempt.fit, attempt.model
    common = dict(converged=fit.converged, iterations=fit.iterations,
                  cost_initial=attempt.cost_initial, cost_final=fit.cost,
                  n_samples=attempt.samples.n_samples,
                  contrast=attempt.contrast, views=attempt.samples.view_indices)
    if attempt.problem:
        return kept(attempt.problem, residual=math.sqrt(attempt.cost_initial),
                    params=attempt.params_initial, **common)
    sigma_px = disparity_sigma_px(model, fit)
    return PlaneRefinement(model.plane(fit.theta), initial_plane, "refined", "", lobe=lobe,
                           residual=math.sqrt(fit.cost), params=model.lobe_fit(fit.theta),
                           time_s=time.perf_counter() - start, disparity_sigma_px=sigma_px,
                           **common)


def disparity_sigma_px(model: LobeModel | JointLobeModel, fit: Minimum) -> float:
    """Return the standard error of a fitted plane's disparity at the box corners, px.

    The covariance of the fitted parameters is the sandwich estimate
    ``A^-1 (J diag(r^2) J^T) A^-1 P / (P - K)`` with ``A = J J^T``, from the fit's
    Jacobian ``J`` (``K`` parameters, the intensities profiled out; its last
    linearisation) and residuals ``r`` at its ``P`` samples: it takes the noise from the
    residuals, bright samples noisier than dark ones as a sensor's are, and needs no
    noise model. The plane's part of it, carried to the rig's stereo disparity at the
    four corners of the object's box (the model's probe pixels), gives each corner's
    standard error; the largest is returned. It says how far the images' noise moves the
    plane, not how far a wrong model does. NaN when the fit has no Jacobian, no more
    samples than parameters or a singular one.
    """
    jac, residual, theta = fit.jacobian, fit.residual, fit.theta
    if jac is None or jac.shape[0] < N_PLANE or not np.all(np.isfinite(residual)):
        return math.nan
    n_params, n_samples = jac.shape
    if n_samples <= n_params:
        return math.nan
    try:
        bread = np.linalg.inv(jac @ jac.T)
    except np.linalg.LinAlgError:
        return math.nan
    meat = (jac * residual ** 2) @ jac.T
    covariance = bread @ meat @ bread * (n_samples / (n_samples - n_params))
    # The corners' disparity by each plane parameter, by central differences.
    step = 1e-6
    shifted = np.repeat(theta[None, :N_PLANE], 2 * N_PLANE, axis=0)
    shifted[np.arange(N_PLANE), np.arange(N_PLANE)] += step
    shifted[N_PLANE + np.arange(N_PLANE), np.arange(N_PLANE)] -= step
    disparity = model.probe_disparity_px(shifted)                       # (2 N_PLANE, 4)
    slopes = ((disparity[:N_PLANE] - disparity[N_PLANE:]) / (2 * step)).T   # (4, N_PLANE)
    variance = np.einsum("ci,ij,cj->c", slopes, covariance[:N_PLANE, :N_PLANE], slopes)
    return float(np.sqrt(np.max(variance)))


def compare_planes(views: Sequence[np.ndarray], rig: CameraRig, light_m, mask: np.ndarray,
                   planes: Sequence[Plane], centers_uv, *, lobe: str = DEFAULT_LOBE,
                   f0: float = DEFAULT_F0, other_lights_m=None, modelled_lights_m=None,
                   light_radius_m: float | None = None, max_iterations: int = 20,
                   pixel_samples: bool | None = None) -> np.ndarray:
    """Best photometric cost of each plane on one set of samples, ``(len(planes),)``.

    The samples are placed for ``planes[0]`` around ``centers_uv`` (as
    :func:`refine_plane` would); each plane then gets its best lobe start and its
    photometric parameters fitted with the plane held. Costs of fits on different
    samples do not compare; these do. ``inf`` for a plane that cannot be evaluated there.
    Inputs are those of :func:`refine_plane`, assumed checked.
    """
    centers = np.asarray(centers_uv, dtype=np.float64)
    setup = _Setup(list(views), rig, mask, mask_bbox(mask), np.asarray(light_m, np.float64),
                   planes[0], centers, lobe, f0, "exact", None, max_iterations,
                   _check_lights(other_lights_m, "other_lights_m"),
                   _check_lights(modelled_lights_m, "modelled_lights_m"),
                   float(light_radius_m) if light_radius_m else None)
    samples = sample_windows(setup.views, rig, mask, planes[0], centers, box=setup.box,
                              other_lights_m=setup.other_lights, pixel_samples=pixel_samples)
    costs = np.full(len(planes), math.inf)
    if isinstance(samples, str):
        return costs
    rendered = setup.light[None] if setup.modelled_lights is None else \
        np.vstack([setup.light[None], setup.modelled_lights])
    for i, plane in enumerate(planes):
        # A light behind this plane lights nothing on it (the plane is held): the plane is
        # rendered with the lights in front of it only, the first of them fitted (a face
        # turned from the samples' light is lit there by another, or by none).
        front = rendered[plane.signed_distance(rendered) > 0.0]
        if not len(front):
            continue
        held = replace(setup, light=front[0],
                       modelled_lights=front[1:] if len(front) > 1 else None)
        model = held.model(samples, plane)
        start = model.initial_guess() if model.valid else None
        if start is not None:
            _, costs[i] = _profile_at_start(model, start, max_iterations)
    return costs


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
    fresnel: str
    foreshortening: float | None
    max_iterations: int
    other_lights: np.ndarray | None = None
    modelled_lights: np.ndarray | None = None
    light_radius_m: float | None = None  # None: a point light
    modelled_centers: np.ndarray | None = None  # (M, N, 2) the modelled lights' highlights
    pixel_samples: bool | None = None  # None: by the rig (``sample_windows``)

    def model(self, samples: HighlightSamples, plane: Plane, support: int = SUPPORT_POINTS,
              disc_rings: int | None = None) -> LobeModel | JointLobeModel:
        """Return the lobe model on ``samples`` around ``plane``.

        ``support`` and ``disc_rings`` (the light's disc, if it has a radius): LobeModel's.
        """
        main = LobeModel(samples, self.rig, self.box, self.light, plane, self.lobe, self.f0,
                         self.foreshortening, support=support, fresnel=self.fresnel,
                         light_radius_m=self.light_radius_m, disc_rings=disc_rings)
        further = [m for m in (self.modelled_lights, self.other_lights) if m is not None]
        if not further:
            return main
        # Every further light's diffuse light is rendered; the modelled ones' lobes too.
        return JointLobeModel([main] + [
            LobeModel(samples, self.rig, self.box, light, plane, self.lobe, self.f0,
                      self.foreshortening, support=support, fresnel=self.fresnel)
            for light in (() if self.modelled_lights is None else self.modelled_lights)],
            diffuse_lights_m=np.vstack(further))


@dataclass(frozen=True)
class _Attempt:
    """One fit, on samples placed for ``sample_plane``, and its verdict."""

    sample_plane: Plane
    samples: HighlightSamples
    model: LobeModel
    fit: Minimum
    cost_initial: float  # the initial plane's best cost on the same samples
    params_initial: LobeFit | None
    problem: str  # why the fit's plane must not be used ("" if it may)
    contrast: float  # the samples' highlight contrast (:func:`_samples_contrast`)


def _attempt(setup: _Setup, sample_plane: Plane, photometry: np.ndarray | None = None,
             *, settled: bool = False) -> _Attempt | str:
    """Sample for ``sample_plane``, fit from it, and judge against the initial plane.

    Returns why no fit could run (a string) when the samples or the start fail.
    ``photometry``: parameters whose lobe shape to start from instead of a grid search.
    ``settled``: ``sample_plane`` is a fitted plane (see ``sample_windows``).
    """
    samples = sample_windows(setup.views, setup.rig, setup.mask, sample_plane, setup.centers,
                              box=setup.box, other_lights_m=setup.other_lights,
                              further_centers=setup.modelled_centers, settled=settled,
                              pixel_samples=setup.pixel_samples)
    if isinstance(samples, str):
        return samples
    # The light's disc (if it has a radius) is read through the blocks' pattern until
    # the lobe's width is known, then through as many points as the two need.
    model = setup.model(samples, sample_plane, disc_rings=DISC_RINGS)
    if not model.valid:
        return ("initial plane: some fitted samples see it from behind or lie where the "
                "light is behind it")
    # The grid start and the first stage only have to come near: they run on the model
    # read at block centres, a quarter of the points; the joint stage ends on the model
    # averaged over the blocks, so the minimum it finds is that model's. (A pixel is read
    # at its centre: the two are one.)
    near = _near(setup, samples, sample_plane, model, DISC_RINGS)
    if photometry is None:
        theta0 = near.initial_guess()
        if theta0 is None:
            return (f"fit: no lobe width in [{WIDTH_GRID[0]:g}, {WIDTH_GRID[-1]:g}] gives a "
                    f"positive specular term over the {samples.n_samples} samples")
    else:
        theta0 = photometry.copy()
        theta0[:N_PLANE] = 0.0
    again = _with_rings_for_width(setup, samples, sample_plane, model, theta0)
    if again is not model:
        model, rings = again, _main(again).reflection.disc_rings
        # the first stage reads no more points than the blocks' pattern
        near = near if rings > DISC_RINGS else _near(setup, samples, sample_plane, model,
                                                     rings)
    fit = _fit(model, theta0, setup.max_iterations, near)
    # The fair reference: the initial plane with every photometric parameter fitted,
    # starting from the joint solution's, on the same samples.
    reference = model if sample_plane is setup.initial_plane else setup.model(
        samples, setup.initial_plane, disc_rings=_main(model).reflection.disc_rings)
    if reference.valid:
        theta_ref, cost_ref = _profile_at_start(reference, fit.theta, setup.max_iterations)
        params_ref = reference.lobe_fit(theta_ref)
    else:  # the initial plane cannot even be evaluated on these samples
        cost_ref, params_ref = math.inf, None
    contrast = _samples_contrast(samples)
    problem = _judge(fit, cost_ref, model, samples, contrast, setup.rig, setup.light,
                     setup.initial_plane)
    return _Attempt(sample_plane, samples, model, fit, cost_ref, params_ref, problem, contrast)


def _main(model: LobeModel | JointLobeModel) -> LobeModel:
    """Return the model of the light that placed the samples (the one with a radius)."""
    return model.parts[0] if isinstance(model, JointLobeModel) else model


def _disc_rings_for(model: LobeModel | JointLobeModel, samples: HighlightSamples, lobe: str,
                    theta: np.ndarray) -> int | None:
    """Rings of the light's disc that ``model``'s samples need under the lobe of ``theta``.

    A disc well inside the lobe is read as closely by fewer points than a wide light
    under a sharp lobe needs, and the points multiply the cost of every evaluation
    (:func:`~.disc.disc_rings`). None for a point light.
    """
    reflection = _main(model).reflection
    start = reflection.at(np.zeros(N_PLANE)) if reflection.light_radius_m else None
    if start is None or start.disc is None:
        return None
    return disc_rings(start.disc.reach, lobe, math.exp(theta[I_WIDTH]), samples.block_px)


def _with_rings_for_width(setup: _Setup, samples: HighlightSamples, plane: Plane,
                          model: LobeModel | JointLobeModel, theta: np.ndarray
                          ) -> LobeModel | JointLobeModel:
    """``model`` with the light's disc read through the rings the lobe of ``theta`` needs.

    (:func:`_disc_rings_for`.) ``model`` itself for a point light, when it reads that
    many rings already, or when the model with that many is not valid.
    """
    rings = _disc_rings_for(model, samples, setup.lobe, theta)
    if rings is None or rings == _main(model).reflection.disc_rings:
        return model
    again = setup.model(samples, plane, disc_rings=rings)
    return again if again.valid else model


def _near(setup: _Setup, samples: HighlightSamples, plane: Plane,
          model: LobeModel | JointLobeModel, rings: int) -> LobeModel | JointLobeModel:
    """``model`` read at block centres, through ``rings`` rings of the light's disc."""
    if _main(model).n_support == 1:
        return model  # read at the samples' centres already (pixels)
    near = setup.model(samples, plane, support=1, disc_rings=rings)
    return near if near.valid else model


def _resampled(setup: _Setup, attempt: _Attempt, *, keep_photometry: bool) -> _Attempt | None:
    """Fit again on samples placed for the plane an attempt found, if it moved far.

    Samples are placed (the object's region in the other views) for the plane a fit
    starts from; a plane that moves by more than the mask margin there leaves some of
    them off the object. Pixel samples placed for a triangulated plane keep away from
    the outline (``sample_windows``); placed for the fitted one they come nearer, and
    are fitted again too. Returns the new attempt if it passes, else None.
    """
    plane = attempt.model.plane(attempt.fit.theta)
    if not (attempt.samples.may_come_nearer or warp_change_px(
            setup.rig, attempt.sample_plane, plane, setup.box) > MASK_MARGIN_PX):
        return None
    again = _attempt(setup, plane, photometry=attempt.fit.theta if keep_photometry else None,
                     settled=True)
    return again if isinstance(again, _Attempt) and not again.problem else None


def _fit(model: LobeModel, theta0: np.ndarray, max_iterations: int, near: LobeModel
         ) -> Minimum:
    """Fit plane and photometry from ``theta0``: stage 1 on ``near``, stage 2 on ``model``.

    ``near`` is the same model on the same samples and plane, read at fewer points (or
    ``model`` itself); their parameters mean the same.
    """
    # Stage 1: plane and lobe shape with the foreshortening exponent held, since it
    # could otherwise absorb part of the initial plane's error.
    free_start = near.free_all[near.free_all != I_FORE]
    theta_start = levenberg_marquardt(near, theta0, free_start,
                                      min(max_iterations, _START_ITERATIONS),
                                      cost_rtol=_PHOTOMETRIC_COST_RTOL).theta
    # Stage 2: everything.
    return levenberg_marquardt(model, theta_start, model.free_all, max_iterations,
                               cost_rtol=_COST_RTOL)


def _profile_at_start(model: LobeModel, photometry_from: np.ndarray, max_iterations: int):
    """Best photometric parameters and cost with ``model``'s own starting plane."""
    theta = photometry_from.copy()
    theta[:N_PLANE] = 0.0
    fit = levenberg_marquardt(model, theta, model.free_photometric, max_iterations,
                              cost_rtol=_PHOTOMETRIC_COST_RTOL)
    return fit.theta, fit.cost


def _samples_contrast(samples: HighlightSamples) -> float:
    """Brightest sample over the background near the highlight, linear luminance."""
    return float(samples.luminance.max() - low_quantile_of(samples.luminance))


def _judge(fit: Minimum, cost_initial: float, model: LobeModel | JointLobeModel,
           samples: HighlightSamples, contrast: float, rig: CameraRig, light: np.ndarray,
           initial_plane: Plane) -> str:
    """Why a fit's plane must not replace the initial plane ("" if it may).

    ``contrast`` is the samples' highlight contrast (:func:`_samples_contrast`).
    """
    theta, cost = fit.theta, fit.cost
    if not (np.all(np.isfinite(theta)) and math.isfinite(cost)):
        return "fit: non-finite parameters or cost"
    if not cost < cost_initial:
        return f"fit: cost {cost:.4g} does not improve on the initial plane's {cost_initial:.4g}"
    if not theta[I_SPEC] > 0.0:
        return f"fit: specular intensity {theta[I_SPEC]:.3g} is not positive"
    if isinstance(model, JointLobeModel):
        # No lamp emits negative light: a further light's lobe subtracted from the image
        # is a fit that explains one light's highlight by another light's shape (a local
        # minimum, as on a merged blob whose plane came out 1.25 px off with such a light).
        # A light whose lobe misses the samples is held at 0, not negative.
        further = model.specular(theta)[1:]
        if np.any(further < 0.0):
            k = int(np.argmin(further))
            return (f"fit: further light {k + 1} of {len(further)} in the joint fit (counted "
                    f"after its main light) has a negative specular intensity "
                    f"({further[k]:.3g}, against the main light's {theta[I_SPEC]:.3g}); no "
                    "lamp emits negative light")
    at_bound = model.parameters_at_bounds(theta)
    if at_bound:
        return (f"fit: {at_bound} at the bound of its range; the lobe model does not "
                "describe this highlight")
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


def _restart_plane(setup: _Setup, samples: HighlightSamples) -> Plane | None:
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
        # Starts are ranked, not fitted: the model at block centres serves.
        candidate = setup.model(samples, plane, support=1, disc_rings=DISC_RINGS)
        if candidate.valid and candidate.initial_guess() is not None \
                and candidate.initial_cost < best_cost:
            best_cost, best_plane = candidate.initial_cost, (plane if shift else None)
    return best_plane


def _is_number_in(value, low: float, high: float) -> bool:
    return (not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
            and low <= float(value) <= high)


def _check_lights(lights_m, name: str) -> np.ndarray | None:
    if lights_m is None:
        return None
    try:
        lights = np.asarray(lights_m, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise SRDEError(f"{name}: expected (M, 3) finite metres, got {lights_m!r:.80}") from None
    if not np.all(np.isfinite(lights)):
        raise SRDEError(f"{name}: expected (M, 3) finite metres, got {lights!r}")
    return lights if len(lights) else None


def _check_centers(centers_uv, n_views: int) -> np.ndarray | None:
    return _check_pixels(centers_uv, (n_views, 2), "centers_uv")


def _check_modelled_centers(centers_uv, modelled: np.ndarray | None,
                            n_views: int) -> np.ndarray | None:
    if centers_uv is None:
        return None
    if modelled is None:
        raise SRDEError("modelled_centers_uv: expected None without modelled_lights_m (they "
                        "are those lights' highlights), got centres")
    return _check_pixels(centers_uv, (len(modelled), n_views, 2), "modelled_centers_uv",
                         " (a row per modelled light and view)")


def _check_pixels(values, expected: tuple[int, ...], name: str,
                  layout: str = "") -> np.ndarray | None:
    """Pixel positions of shape ``expected``, NaN allowed (a skipped view), inf not."""
    if values is None:
        return None
    try:
        pixels = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ImageError(f"{name}: expected an array {expected} of pixels{layout}, "
                         f"got {type(values).__name__}") from None
    if pixels.shape != expected:
        raise ImageError(f"{name}: expected shape {expected}{layout}, got {pixels.shape}")
    if np.any(np.isinf(pixels)):
        raise ImageError(f"{name}: expected finite pixels (a NaN row skips a view), got inf")
    return pixels


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
