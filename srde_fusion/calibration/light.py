"""Light calibration: locate the point light from its highlight on an ArUco plate.

SRDE needs the light position ``L`` in the array frame. A flat glossy plate with ArUco
markers (:class:`~srde_fusion.calibration.board.Board`) is held in front of the array; its pose
comes from the markers of all views (:func:`~srde_fusion.calibration.board.estimate_plate_pose`).
In each view the highlight centre on the plate defines a ray ``k_i`` from the camera
centre ``C_i``; it hits the plate at ``H_i`` and, by the law of reflection, came from
the light along ``r_i = k_i - 2 (k_i · n_p) n_p``. The light is the point closest to all
reflected rays, ``L = argmin sum_i |(L - H_i) x r_i / |r_i||^2``, a 3x3 linear solve
(paper §V-C-1). Rays from several plate poses enter the same solve; poses that tilt the
plate differently make the rays cross at wider angles and pin the light down along
the rays, which a single pose seen by a small array does poorly.

The markers of a small plate fix its normal to a few tenths of a milliradian, and each
pose's error turns its whole bundle of rays; bundles turned differently meet away from
the light. So the intersection is followed by a joint refinement: light and plate poses
together, reproducing the marker corners and the highlight centres (the images of the
light mirrored across each plate) in pixels. The benchmark
``benchmarks/light_calibration.py`` compares both.

Everything that would make the light silently wrong is an error: too few views with
markers, no usable highlight (absent, under a marker, clipped by the plate edge), a
plate seen nearly edge-on, rays that do not meet, a light behind the plate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import least_squares

from ..errors import LightError
from ..geometry import CameraRig, project_points, rotation_from_vector, rotation_to_vector
from .plate_pose import PlatePose

if TYPE_CHECKING:
    from .photometric import PhotometricLight

__all__ = [
    "DEFAULT_MAX_INCIDENCE_DEG",
    "DEFAULT_MAX_RESIDUAL_M",
    "DEFAULT_MIN_VIEWS",
    "HIGHLIGHT_ACCURACY_PX",
    "CORNER_ACCURACY_PX",
    "LightEstimate",
    "closest_point_to_rays",
    "reflect_highlights",
    "light_from_reflections",
]

#: Largest angle (degrees) between the plate normal and a camera's line of sight to the
#: plate centre. Beyond it the pose and the reflected rays are too sensitive to errors.
DEFAULT_MAX_INCIDENCE_DEG = 70.0


#: Largest mean distance (metres) of the light to the reflected rays.
DEFAULT_MAX_RESIDUAL_M = 0.01


#: Views per capture that must show a usable highlight.
DEFAULT_MIN_VIEWS = 2


# Rays whose directions span less than this (smallest eigenvalue of sum(I - d d^T) per
# ray) do not fix a point: they are parallel to within about a milliradian.
_MIN_RAY_SPREAD = 1e-6


# Joint refinement: residual kinds are weighted by their RMS, re-estimated this many
# times, and never taken below this (exact synthetic centres would get infinite weight).
_REWEIGHT_ROUNDS = 2
_MIN_SIGMA_PX = 0.01


#: Smallest one-sigma error (pixels) the uncertainty assumes for a detected highlight
#: centre and for a marker corner, whatever the residuals say. Residuals cannot show
#: errors the model absorbs: on rendered captures the detected centres are off by
#: 0.01-0.05 px in a pattern that varies smoothly across the array, which the fit takes
#: for a slightly different virtual-light depth, leaving residuals of 0.003 px and a
#: light about 1 mm off. That error is shared by the captures, so the highlight floor
#: counts once, not once per capture. ``benchmarks/light_calibration.py`` measures how
#: often the true light falls within 1, 2 and 3 sigma.
HIGHLIGHT_ACCURACY_PX = 0.02
CORNER_ACCURACY_PX = 0.05


# ---------------------------------------------------------------------- the solve
def check_positive(value: Any, name: str) -> float:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not math.isfinite(value)
        or value <= 0
    ):
        raise LightError(f"{name}: expected a positive number, got {value!r}")
    return float(value)


def closest_point_to_rays(origins_m: Any, directions: Any) -> tuple[np.ndarray, np.ndarray]:
    """Find the point with the least sum of squared distances to a set of 3D lines.

    Solves ``sum_i (I - d_i d_i^T) X = sum_i (I - d_i d_i^T) O_i`` with unit ``d_i``,
    the normal equations of ``min_X sum_i |(X - O_i) x d_i|^2``.

    Parameters
    ----------
    origins_m : array_like, (R, 3)
        A point of each line, metres.
    directions : array_like, (R, 3)
        Direction of each line (any non-zero length).

    Returns
    -------
    point_m : numpy.ndarray, (3,)
    distances_m : numpy.ndarray, (R,)
        Distance of the point to each line.

    Raises
    ------
    LightError
        Fewer than two lines, or lines (nearly) parallel, which meet nowhere in
        particular.

    Examples
    --------
    >>> p, d = closest_point_to_rays([[0, 0, 0], [1, 0, 0]], [[0, 0, 1], [-1, 0, 1]])
    >>> np.round(p, 6).tolist(), np.round(d, 6).tolist()
    ([0.0, 0.0, 1.0], [0.0, 0.0])
    """
    o = np.asarray(origins_m, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape or o.shape[0] < 2:
        raise LightError(
            f"rays: expected at least 2 rays with one origin and one direction each, "
            f"got {o.shape[0]} origins and {d.shape[0]} directions"
        )
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    # (R, 3, 3) projectors onto the plane orthogonal to each ray.
    proj = np.eye(3) - d[:, :, None] * d[:, None, :]
    a = proj.sum(axis=0)
    b = np.einsum("rij,rj->i", proj, o)
    spread = float(np.linalg.eigvalsh(a)[0]) / o.shape[0]
    if spread < _MIN_RAY_SPREAD:
        raise LightError(
            f"rays: expected rays that cross at some angle, got {o.shape[0]} nearly "
            f"parallel rays (spread {spread:.2g}); use more views or plate poses"
        )
    point = np.linalg.solve(a, b)
    distances = np.linalg.norm(np.cross(point - o, d), axis=1)
    return point, distances


def reflect_highlights(
    pose: PlatePose, centers_px: Any, rig: CameraRig
) -> tuple[np.ndarray, np.ndarray]:
    """Reflect the viewing rays of highlight centres on the plate.

    Parameters
    ----------
    pose : PlatePose
        The plate in the array frame.
    centers_px : array_like, (N, 2)
        Highlight centre ``(u, v)`` in each rig view; NaN rows are skipped.
    rig : CameraRig

    Returns
    -------
    hits_m : numpy.ndarray, (R, 3)
        Where the viewing rays hit the plate, ``H_i``, for the R finite centres.
    directions : numpy.ndarray, (R, 3)
        Unit reflected directions ``r_i``, pointing from ``H_i`` towards the light.

    Raises
    ------
    LightError
        A viewing ray that meets the plate behind its camera or from the back.
    """
    centers = np.asarray(centers_px, dtype=np.float64).reshape(-1, 2)
    views = np.flatnonzero(np.all(np.isfinite(centers), axis=1))
    n = pose.plane.n
    c = pose.plane.offset_m
    k = rig.rays(centers[views])
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    origins = rig.centers_m[views]
    cos_in = k @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (c - origins @ n) / cos_in
    bad = ~(np.isfinite(t) & (t > 0) & (cos_in < 0))
    if np.any(bad):
        names = [rig.camera_names[i] for i in views[bad]]
        raise LightError(
            f"highlight rays: expected viewing rays that meet the front of the plate, "
            f"got rays of {names} missing it or meeting it from behind"
        )
    hits = origins + t[:, None] * k
    directions = k - 2.0 * cos_in[:, None] * n
    return hits, directions / np.linalg.norm(directions, axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class LightEstimate:
    """The light position found from highlights on a plate, with everything behind it.

    Parameters
    ----------
    position_m : numpy.ndarray, (3,), float64
        The light ``L`` in the array frame, metres.
    residual_m : float
        Mean distance of ``L`` to the reflected rays, metres.
    highlight_residual_px : float
        RMS distance between the highlight centres and the projections of the virtual
        lights (``L`` mirrored across each plate), pixels.
    position_std_m : numpy.ndarray, (3,), float64
        One-sigma uncertainty of ``L`` per axis, metres: the square root of the diagonal
        of ``position_cov_m2``.
    closed_form_position_m : numpy.ndarray, (3,), float64
        The least-squares intersection of the reflected rays from the marker-only plate
        poses (the paper's estimate), before any joint refinement.
    refined : bool
        Whether the light and the plate poses were refined jointly.
    ray_origins_m : numpy.ndarray, (R, 3)
        Hit points ``H_i`` of the viewing rays on the plate.
    ray_directions : numpy.ndarray, (R, 3)
        Unit reflected directions ``r_i`` (towards the light).
    ray_distances_m : numpy.ndarray, (R,)
        Distance of ``L`` to each ray.
    ray_captures, ray_views : numpy.ndarray, (R,), int
        Capture index and view (camera) index of each ray.
    highlight_centers_px : tuple of numpy.ndarray, each (N, 2)
        Per capture, the highlight centre in each view; NaN where a view was not used.
    view_reasons : tuple of tuple of str
        Per capture and view, why the view gave no ray (``""`` when it did).
    plate_poses : tuple of PlatePose
        The plate pose of each capture (after the joint refinement, if any).
    position_cov_m2 : numpy.ndarray, (3, 3), float64
        Covariance of ``L``, square metres: the residual-scaled covariance of the solve
        (each residual kind taken at its RMS, but never below
        :data:`HIGHLIGHT_ACCURACY_PX` / :data:`CORNER_ACCURACY_PX`, so an exact-looking
        fit does not claim sub-millimetre certainty), plus, with three captures or more,
        the leave-one-capture-out (jackknife) covariance, which shows captures that
        disagree; when the highlights' images moved the light, plus the covariance of
        their mean from the captures' scatter (generous for that light, about three times
        nearer than the rays'). Systematic errors of the board print or the camera model
        still do not show.
    uncertainty : str
        How ``position_cov_m2`` was formed, in words.
    geometric_position_m : numpy.ndarray, (3,), float64, or None
        When the highlights' images moved the light (:mod:`.photometric`), the light of
        the ray solve (joint refinement) before that; None otherwise. The residuals and
        ray distances above are always those of ``position_m``.
    photometric : PhotometricLight or None
        The light each capture's highlight images show, and why a capture gave none;
        None when not asked for.
    capture_indices : tuple of int or None
        Index of each capture above in the list the calibration was given (some may have
        been left out); None: the captures as given.
    skipped_captures : tuple of str
        Why each capture left out was (``"capture 3 (...): ..."``).
    """

    position_m: np.ndarray
    residual_m: float
    highlight_residual_px: float
    position_std_m: np.ndarray
    closed_form_position_m: np.ndarray
    refined: bool
    ray_origins_m: np.ndarray
    ray_directions: np.ndarray
    ray_distances_m: np.ndarray
    ray_captures: np.ndarray
    ray_views: np.ndarray
    highlight_centers_px: tuple[np.ndarray, ...]
    view_reasons: tuple[tuple[str, ...], ...]
    plate_poses: tuple[PlatePose, ...]
    position_cov_m2: np.ndarray
    uncertainty: str
    geometric_position_m: np.ndarray | None = None
    photometric: PhotometricLight | None = None
    capture_indices: tuple[int, ...] | None = None
    skipped_captures: tuple[str, ...] = ()

    @property
    def n_rays(self) -> int:
        """Number of reflected rays in the solve."""
        return int(self.ray_origins_m.shape[0])

    @property
    def n_captures(self) -> int:
        """Number of plate poses combined."""
        return len(self.plate_poses)

    @property
    def ray_solve_position_m(self) -> np.ndarray:
        """The ray solve's light, ``(3,)`` metres: before the images moved it, if they did."""
        return self.position_m if self.geometric_position_m is None else self.geometric_position_m

    def capture_index(self, c: int) -> int:
        """Index in the list the calibration was given of the estimate's capture ``c``."""
        return c if self.capture_indices is None else self.capture_indices[c]

    @property
    def views_used(self) -> tuple[tuple[int, ...], ...]:
        """Per capture, the views whose highlight gave a ray."""
        return tuple(
            tuple(int(v) for v in self.ray_views[self.ray_captures == c])
            for c in range(self.n_captures)
        )

    def sigma_distance(self, point_m: Any) -> float:
        """Mahalanobis distance of a point from the estimate, in sigmas (3D).

        Returns
        -------
        float
            ``sqrt((p - L)^T C^-1 (p - L))`` with ``C = position_cov_m2``; a point on the
            one-sigma ellipsoid gives 1.
        """
        e = np.asarray(point_m, dtype=np.float64).reshape(3) - self.position_m
        return float(np.sqrt(e @ np.linalg.pinv(self.position_cov_m2) @ e))

    @property
    def reprojection_errors_px(self) -> tuple[float, ...]:
        """RMS marker reprojection error of each capture's plate pose, pixels."""
        return tuple(p.reprojection_error_px for p in self.plate_poses)

    def summary(self) -> str:
        """Describe the estimate in a few lines: position, residuals, per-capture details."""
        x, y, z = self.position_m
        sx, sy, sz = self.position_std_m * 1000.0
        how = "joint refinement of light and plate poses" if self.refined else "ray intersection"
        if self.geometric_position_m is not None:
            how = "the highlights' images, after the " + how
        lines = [
            f"light position: ({x:+.4f}, {y:+.4f}, {z:+.4f}) m, "
            f"± ({sx:.1f}, {sy:.1f}, {sz:.1f}) mm (1 sigma, {how})",
            f"uncertainty: {self.uncertainty}",
            f"residual: {self.residual_m * 1000:.2f} mm mean distance to {self.n_rays} rays, "
            f"{self.highlight_residual_px:.2f} px RMS at the highlights, "
            f"{self.n_captures} plate pose(s)",
        ]
        fit = self.photometric
        if fit is not None and self.geometric_position_m is not None:
            moved = np.linalg.norm(self.position_m - self.geometric_position_m) * 1000.0
            lines.append(f"from the highlights' images of {fit.n_used} of {self.n_captures} "
                         f"capture(s): {moved:.2f} mm from the ray solve's light")
        elif fit is not None:
            lines.append("from the ray solve only: no capture's highlight images gave a light")
        for c, pose in enumerate(self.plate_poses):
            names = len(self.views_used[c])
            lines.append(
                f"  capture {self.capture_index(c)}: {names} highlight rays, plate at "
                f"{np.linalg.norm(pose.center_m):.3f} m, marker reprojection "
                f"{pose.reprojection_error_px:.2f} px RMS"
            )
            lines += [f"    skipped {r}" for r in self.view_reasons[c] if r]
            if fit is not None and fit.reasons[c]:
                lines.append(f"    images not used: {fit.reasons[c]}")
        lines += [f"  left out: {why}" for why in self.skipped_captures]
        return "\n".join(lines)


def incidence_check(
    pose: PlatePose, rig: CameraRig, views: Sequence[int], max_incidence_deg: float, where: str
) -> None:
    sight = pose.center_m - rig.centers_m[list(views)]
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.clip(-(sight @ pose.plane.n), -1.0, 1.0)))
    worst = int(np.argmax(angles))
    if angles[worst] > max_incidence_deg:
        raise LightError(
            f"{where}: expected a plate facing the cameras (angle between plate normal and "
            f"line of sight <= {max_incidence_deg:g} deg), got {angles[worst]:.1f} deg for "
            f"{rig.camera_names[views[worst]]}: the plate is nearly edge-on"
        )


def _virtual_light(light_m: np.ndarray, rotation: np.ndarray, center_m: np.ndarray) -> np.ndarray:
    n = rotation[:, 2]
    return light_m - 2.0 * float((light_m - center_m) @ n) * n


def ray_distances_m(light_m, origins_m: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance of a point to each ray ``origin + t direction`` (unit directions), metres."""
    return np.linalg.norm(np.cross(light_m - origins_m, directions), axis=1)


def highlight_rms_px(light_m, poses, centers, rig) -> float:
    """RMS distance of the highlight centres from the light's mirror images, pixels."""
    residuals = _highlight_residuals(light_m, poses, centers, rig)
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))


def _highlight_residuals(light_m, poses, centers, rig) -> np.ndarray:
    out = []
    for pose, cc in zip(poses, centers, strict=True):
        views = np.flatnonzero(np.all(np.isfinite(cc), axis=1))
        v = _virtual_light(light_m, pose.rotation, pose.translation_m)
        out.append(project_points(rig, np.repeat(v[None], views.size, axis=0), views) - cc[views])
    return np.concatenate(out)


def _refine_jointly(
    light_m: np.ndarray, poses: tuple[PlatePose, ...], centers: list[np.ndarray], rig: CameraRig
) -> tuple[np.ndarray, tuple[PlatePose, ...], np.ndarray]:
    """Refine the light and the plate poses together on marker corners and highlights.

    Every highlight centre is the image of the virtual light, ``L`` mirrored across its
    plate, so with ``L`` shared by all captures the highlights also pull on the plate
    normals, which the corners of small markers fix only to a few tenths of a
    milliradian. Residuals are pixels: marker corners of every view, and highlight
    centres against the projected virtual light, each kind divided by its own RMS
    (re-estimated once after a first fit), so noisy highlight centres do not bend
    well-measured plates. Poses given without corners stay fixed.

    Returns the light, the refined poses and the light's ``(3, 3)`` covariance.
    """
    free = [c for c, p in enumerate(poses) if p.has_corners]
    marker_data = []
    for c in free:
        p = poses[c]
        cams = np.concatenate(
            [np.full(o.shape[0], i) for i, o in zip(p.views_used, p.plate_points_m, strict=True)]
        )
        marker_data.append(
            (cams, np.concatenate(p.plate_points_m), np.concatenate(p.image_points_px))
        )
    views = [np.flatnonzero(np.all(np.isfinite(cc), axis=1)) for cc in centers]

    def unpack(x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        rt = [(p.rotation, p.translation_m) for p in poses]
        for k, c in enumerate(free):
            rt[c] = (rotation_from_vector(x[3 + 6 * k : 6 + 6 * k]), x[6 + 6 * k : 9 + 6 * k])
        return rt

    def parts(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rt = unpack(x)
        corners = [
            (project_points(rig, obj @ rt[c][0].T + rt[c][1], cams) - img).ravel()
            for (cams, obj, img), c in zip(marker_data, free, strict=True)
        ]
        highlights = []
        for (r, t), cc, vv in zip(rt, centers, views, strict=True):
            v = _virtual_light(x[:3], r, t)
            proj = project_points(rig, np.repeat(v[None], vv.size, axis=0), vv)
            highlights.append((proj - cc[vv]).ravel())
        return np.concatenate(corners or [np.zeros(0)]), np.concatenate(highlights)

    def rms(r: np.ndarray) -> float:
        return max(float(np.sqrt(np.mean(r**2))) if r.size else 1.0, _MIN_SIGMA_PX)

    x = np.concatenate(
        [light_m]
        + [np.r_[rotation_to_vector(poses[c].rotation), poses[c].translation_m] for c in free]
    )
    for _ in range(_REWEIGHT_ROUNDS):
        sigma_corner, sigma_highlight = (rms(r) for r in parts(x))

        def residuals(x: np.ndarray, sc=sigma_corner, sh=sigma_highlight) -> np.ndarray:
            corner, highlight = parts(x)
            return np.concatenate([corner / sc, highlight / sh])

        fit = least_squares(residuals, x, method="lm", x_scale="jac")
        x = fit.x
    rt = unpack(x)
    refined = tuple(
        p.moved(r, t, rig) if c in free else p
        for c, (p, (r, t)) in enumerate(zip(poses, rt, strict=True))
    )
    # Covariance of the light block, marginalised over the poses: (J^T W J)^-1 with each
    # residual kind weighted by its RMS, floored at the accuracy a detector can promise.
    n_corner = sum(d[2].size for d in marker_data)
    sigmas = np.r_[
        np.full(n_corner, sigma_corner), np.full(fit.fun.size - n_corner, sigma_highlight)
    ]
    # The centre error of a detector is largely shared by the captures (one lobe shape,
    # one array) and does not average out over them: its floor counts as one capture's.
    n_lit = sum(1 for vv in views if vv.size)
    honest = np.r_[
        np.full(n_corner, max(sigma_corner, CORNER_ACCURACY_PX)),
        np.full(
            fit.fun.size - n_corner,
            max(sigma_highlight, HIGHLIGHT_ACCURACY_PX * math.sqrt(max(n_lit, 1))),
        ),
    ]
    jac = fit.jac * (sigmas / honest)[:, None]
    cov = np.linalg.pinv(jac.T @ jac)[:3, :3]
    return x[:3], refined, 0.5 * (cov + cov.T)


def _ray_covariance(position_m, origins_m, directions, rig: CameraRig) -> np.ndarray:
    """Covariance of the ray intersection, from the distances of the light to the rays.

    Each ray constrains the 2 directions across it: ``C = s^2 A^-1`` with
    ``A = sum(I - d d^T)`` and ``s`` the RMS distance per constrained direction, never
    below what :data:`HIGHLIGHT_ACCURACY_PX` turns into at the ray's length.
    """
    dist = ray_distances_m(position_m, origins_m, directions)
    a = np.einsum("rij->ij", np.eye(3) - directions[:, :, None] * directions[:, None, :])
    var = float(np.sum(dist**2)) / max(2 * origins_m.shape[0] - 3, 1)
    length = float(np.mean(np.linalg.norm(position_m - origins_m, axis=1)))
    floor = HIGHLIGHT_ACCURACY_PX / rig.intrinsics.fx * length
    return np.linalg.inv(a) * max(var, floor**2)


def light_from_reflections(
    plate_poses: Sequence[PlatePose],
    highlight_centers_px: Sequence[Any],
    rig: CameraRig,
    *,
    refine: bool = True,
    view_reasons: Sequence[Sequence[str]] | None = None,
    max_incidence_deg: float = DEFAULT_MAX_INCIDENCE_DEG,
    max_residual_m: float = DEFAULT_MAX_RESIDUAL_M,
    capture_spread: bool = True,
) -> LightEstimate:
    """Solve for the light from plate poses and highlight centres (one joint solve).

    First the paper's estimate: the reflected rays of all views of all captures, and
    the point closest to them (:func:`closest_point_to_rays`). Then, with ``refine``,
    light and plate poses are refined together so that the marker corners and the
    highlight centres (images of the light mirrored across each plate) are reproduced
    in pixels. Combining plate poses needs this step: each pose's normal is off by
    about 0.1 deg from the markers alone, which turns its ray bundle, and bundles turned
    differently meet away from the light.

    Parameters
    ----------
    plate_poses : sequence of PlatePose
        One pose per capture, from :func:`~srde_fusion.calibration.board.estimate_plate_pose`
        (poses built without corners are held fixed by the refinement).
    highlight_centers_px : sequence of array_like, each (N, 2)
        Per capture, the highlight centre ``(u, v)`` in each rig view; NaN rows (views
        without a usable highlight) are skipped.
    rig : CameraRig
    refine : bool
        Refine light and poses jointly after the closed-form solve.
    view_reasons : sequence of sequence of str, optional
        Per capture and view, why a view has no centre (kept in the result).
    max_incidence_deg : float
        Largest angle between plate normal and a camera's line of sight.
    max_residual_m : float
        Largest accepted mean distance of the light to the rays, metres.
    capture_spread : bool
        With three captures or more, add the spread of the solves that each leave one
        capture out to the covariance (one more solve per capture). False keeps the
        joint fit's covariance alone, for a caller that reads the position only.

    Returns
    -------
    LightEstimate

    Raises
    ------
    LightError
        Mismatched inputs, a plate nearly edge-on, fewer than two rays, parallel rays,
        a light behind a plate, or rays that miss the light by more than
        ``max_residual_m`` on average.

    References
    ----------
    Kossira et al., SRDE, §V-C-1 "Light Source Position Estimation" (reflected rays and
    their least-squares intersection).
    """
    poses = tuple(plate_poses)
    if len(poses) == 0 or len(highlight_centers_px) != len(poses):
        raise LightError(
            f"highlight_centers_px: expected one (N, 2) array per plate pose "
            f"({len(poses)}), got {len(highlight_centers_px)}"
        )
    max_incidence_deg = check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = check_positive(max_residual_m, "max_residual_m")
    if not isinstance(capture_spread, bool):
        raise LightError(f"capture_spread: expected True or False, got {capture_spread!r}")
    n_views = rig.n_cameras
    centers_all = []
    for c, (pose, centers) in enumerate(zip(poses, highlight_centers_px, strict=True)):
        if not isinstance(pose, PlatePose):
            raise LightError(f"plate_poses[{c}]: expected a PlatePose, got {type(pose).__name__}")
        centers = np.asarray(centers, dtype=np.float64)
        if centers.shape != (n_views, 2):
            raise LightError(
                f"highlight_centers_px[{c}]: expected shape ({n_views}, 2), one centre per "
                f"rig view, got {centers.shape}"
            )
        used = np.flatnonzero(np.all(np.isfinite(centers), axis=1))
        if used.size:
            incidence_check(pose, rig, used.tolist(), max_incidence_deg, f"capture {c}")
        centers_all.append(centers)
    position, closed_form, refined_poses, cov = _solve(poses, centers_all, rig, refine)
    how = (
        f"residual-scaled covariance (highlight centres >= {HIGHLIGHT_ACCURACY_PX:g} px, "
        f"marker corners >= {CORNER_ACCURACY_PX:g} px, 1 sigma)"
        if refine
        else f"residual-scaled covariance of the ray intersection (highlight centres >= "
        f"{HIGHLIGHT_ACCURACY_PX:g} px, 1 sigma)"
    )
    jackknife = _jackknife(poses, centers_all, rig, refine) if capture_spread else None
    if jackknife is not None:
        cov = cov + jackknife
        how += f" + leave-one-capture-out spread over {len(poses)} captures"
    poses = refined_poses
    o, d, cap, view = _rays(poses, centers_all, rig)
    dist = ray_distances_m(position, o, d)
    # The light shines onto the plate's printed side, from where the rays point.
    along = np.einsum("ri,ri->r", position - o, d)
    if np.any(along <= 0):
        r = int(np.argmin(along))
        raise LightError(
            f"light: expected a light in front of the plate along every reflected ray, got a "
            f"point {-along[r]:.3f} m behind it for capture {cap[r]}, "
            f"{rig.camera_names[view[r]]}; the rays are inconsistent"
        )
    residual = float(dist.mean())
    if not residual <= max_residual_m:
        r = int(np.argmax(dist))
        raise LightError(
            f"rays: expected reflected rays that meet (mean distance to the light <= "
            f"{max_residual_m * 1000:g} mm), got {residual * 1000:.1f} mm (worst: capture "
            f"{cap[r]}, {rig.camera_names[view[r]]}, {dist[r] * 1000:.1f} mm); check the "
            "highlight centres and the board description"
        )
    hl_rms = highlight_rms_px(position, poses, centers_all, rig)
    if view_reasons is None:
        reasons = tuple(
            tuple("" if np.all(np.isfinite(row)) else "no highlight centre given" for row in cc)
            for cc in centers_all
        )
    else:
        reasons = tuple(tuple(str(s) for s in r) for r in view_reasons)
    return LightEstimate(
        position,
        residual,
        hl_rms,
        np.sqrt(np.clip(np.diag(cov), 0.0, None)),
        closed_form,
        bool(refine),
        o,
        d,
        dist,
        cap,
        view,
        tuple(centers_all),
        reasons,
        poses,
        cov,
        how,
    )


def _solve(poses, centers, rig, refine):
    """Solve for the light: ``(position, closed form, poses, covariance)``."""
    o, d, _, _ = _rays(poses, centers, rig)
    closed_form, _ = closest_point_to_rays(o, d)
    if not refine:
        return closed_form, closed_form, tuple(poses), _ray_covariance(closed_form, o, d, rig)
    position, refined, cov = _refine_jointly(closed_form, tuple(poses), centers, rig)
    return position, closed_form, refined, cov


#: Fewest captures for the leave-one-capture-out spread (with two, each half is one capture).
_JACKKNIFE_MIN_CAPTURES = 3


def _jackknife(poses, centers, rig, refine) -> np.ndarray | None:
    """Leave-one-capture-out covariance of the light, or None with too few captures.

    ``(m - 1) / m * sum_c (L_-c - mean)(L_-c - mean)^T`` over the m solves that each
    leave one capture out: captures that disagree (a plate that bent, a pose that is
    off) spread these solves apart, which the residuals of one joint fit can hide.
    """
    m = len(poses)
    if m < _JACKKNIFE_MIN_CAPTURES:
        return None
    points = []
    for c in range(m):
        keep = [i for i in range(m) if i != c]
        try:
            points.append(_solve([poses[i] for i in keep], [centers[i] for i in keep], rig,
                                 refine)[0])
        except LightError:  # the others alone do not fix a point: no spread to measure
            continue
    if len(points) < _JACKKNIFE_MIN_CAPTURES:
        return None
    dev = np.asarray(points) - np.mean(points, axis=0)
    return (len(points) - 1) / len(points) * dev.T @ dev


def _rays(poses, centers, rig):
    origins, directions, caps, views = [], [], [], []
    for c, (pose, cc) in enumerate(zip(poses, centers, strict=True)):
        hits, dirs = reflect_highlights(pose, cc, rig)
        origins.append(hits)
        directions.append(dirs)
        used = np.flatnonzero(np.all(np.isfinite(cc), axis=1))
        caps.append(np.full(used.size, c))
        views.append(used)
    o = np.concatenate(origins)
    if o.shape[0] < 2:
        raise LightError(
            f"highlights: expected at least 2 highlight rays over all captures, got {o.shape[0]}"
        )
    return o, np.concatenate(directions), np.concatenate(caps), np.concatenate(views)
