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
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._checks import check_point3, check_views
from ..errors import FileFormatError, LightError, RigError
from ..geometry import CameraRig
from .board import (
    DEFAULT_MAX_REPROJECTION_PX,
    Board,
    PlatePose,
    estimate_plate_pose,
    project_points,
    render_board_image,
    rotation_from_vector,
    rotation_to_vector,
)

__all__ = [
    "LightEstimate",
    "closest_point_to_rays",
    "reflect_highlights",
    "light_from_reflections",
    "plate_highlight_region",
    "find_plate_highlights",
    "estimate_light",
    "read_capture",
    "calibrate_light_files",
    "highlight_normal",
    "plate_scene",
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
# The highlight search keeps this far (metres, on the plate) from the plate edge, and
# this fraction of a marker's side away from each marker (the marker's black edges
# would otherwise pass for highlight gradients).
_EDGE_MARGIN_FRACTION = 0.1
_MARKER_MARGIN_FRACTION = 0.15
# ...and this many pixels from both, once projected.
_REGION_EROSION_PX = 2
# Joint refinement: residual kinds are weighted by their RMS, re-estimated this many
# times, and never taken below this (exact synthetic centres would get infinite weight).
_REWEIGHT_ROUNDS = 2
_MIN_SIGMA_PX = 0.01
# A blob closer than this (pixels) to the search region's border beyond its own radius
# is taken to be cut by it.
_CLIP_MARGIN_PX = 1.0


# ---------------------------------------------------------------------- the solve
def _check_positive(value: Any, name: str) -> float:
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
        One-sigma uncertainty of ``L`` per axis, propagated from the residuals (of the
        joint refinement when ``refined``, else of the rays). It is only as good as the
        noise model: systematic errors of the board or the camera do not show.
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

    @property
    def n_rays(self) -> int:
        """Number of reflected rays in the solve."""
        return int(self.ray_origins_m.shape[0])

    @property
    def n_captures(self) -> int:
        """Number of plate poses combined."""
        return len(self.plate_poses)

    @property
    def views_used(self) -> tuple[tuple[int, ...], ...]:
        """Per capture, the views whose highlight gave a ray."""
        return tuple(
            tuple(int(v) for v in self.ray_views[self.ray_captures == c])
            for c in range(self.n_captures)
        )

    @property
    def reprojection_errors_px(self) -> tuple[float, ...]:
        """RMS marker reprojection error of each capture's plate pose, pixels."""
        return tuple(p.reprojection_error_px for p in self.plate_poses)

    def summary(self) -> str:
        """Describe the estimate in a few lines: position, residuals, per-capture details."""
        x, y, z = self.position_m
        sx, sy, sz = self.position_std_m * 1000.0
        how = "joint refinement of light and plate poses" if self.refined else "ray intersection"
        lines = [
            f"light position: ({x:+.4f}, {y:+.4f}, {z:+.4f}) m, "
            f"± ({sx:.1f}, {sy:.1f}, {sz:.1f}) mm (1 sigma, {how})",
            f"residual: {self.residual_m * 1000:.2f} mm mean distance to {self.n_rays} rays, "
            f"{self.highlight_residual_px:.2f} px RMS at the highlights, "
            f"{self.n_captures} plate pose(s)",
        ]
        for c, pose in enumerate(self.plate_poses):
            names = len(self.views_used[c])
            lines.append(
                f"  capture {c}: {names} highlight rays, plate at "
                f"{np.linalg.norm(pose.center_m):.3f} m, marker reprojection "
                f"{pose.reprojection_error_px:.2f} px RMS"
            )
            lines += [f"    skipped {r}" for r in self.view_reasons[c] if r]
        return "\n".join(lines)


def _incidence_check(
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
    # Gauss-Newton covariance s^2 (J^T J)^-1 of the light block.
    dof = max(fit.fun.size - fit.x.size, 1)
    s2 = 2.0 * fit.cost / dof
    cov = np.linalg.pinv(fit.jac.T @ fit.jac)[:3, :3] * s2
    return x[:3], refined, np.sqrt(np.clip(np.diag(cov), 0.0, None))


def light_from_reflections(
    plate_poses: Sequence[PlatePose],
    highlight_centers_px: Sequence[Any],
    rig: CameraRig,
    *,
    refine: bool = True,
    view_reasons: Sequence[Sequence[str]] | None = None,
    max_incidence_deg: float = DEFAULT_MAX_INCIDENCE_DEG,
    max_residual_m: float = DEFAULT_MAX_RESIDUAL_M,
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
    max_incidence_deg = _check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = _check_positive(max_residual_m, "max_residual_m")
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
            _incidence_check(pose, rig, used.tolist(), max_incidence_deg, f"capture {c}")
        centers_all.append(centers)
    o, d, cap, view = _rays(poses, centers_all, rig)
    closed_form, _ = closest_point_to_rays(o, d)
    position = closed_form
    if refine:
        position, poses, std = _refine_jointly(closed_form, poses, centers_all, rig)
        o, d, cap, view = _rays(poses, centers_all, rig)
    dist = np.linalg.norm(np.cross(position - o, d), axis=1)
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
    if not refine:
        a = np.einsum("rij->ij", np.eye(3) - d[:, :, None] * d[:, None, :])
        # Each ray constrains 2 directions of the 3 unknowns: covariance s^2 A^-1.
        var = float(np.sum(dist**2)) / max(2 * o.shape[0] - 3, 1)
        std = np.sqrt(np.clip(np.diag(np.linalg.inv(a)) * var, 0.0, None))
    hl = _highlight_residuals(position, poses, centers_all, rig)
    hl_rms = float(np.sqrt(np.mean(np.sum(hl**2, axis=1))))
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
        std,
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
    )


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


# ---------------------------------------------------------------------- highlights on the plate
def _inset_outline(board: Board) -> np.ndarray:
    w, h = board.plate_size_m
    margin = _EDGE_MARGIN_FRACTION * board.marker_size_m
    return np.array(
        [
            [-w / 2 + margin, -h / 2 + margin, 0.0],
            [w / 2 - margin, -h / 2 + margin, 0.0],
            [w / 2 - margin, h / 2 - margin, 0.0],
            [-w / 2 + margin, h / 2 - margin, 0.0],
        ]
    )


def _grown_markers(board: Board) -> np.ndarray:
    corners = board.marker_corners_m
    centre = corners.mean(axis=1, keepdims=True)
    grow = _MARKER_MARGIN_FRACTION * board.marker_size_m * math.sqrt(2)
    offset = corners - centre
    return centre + offset * (1.0 + grow / np.linalg.norm(offset, axis=2, keepdims=True))


def _fill(polygons_px: np.ndarray, size: tuple[int, int], values: Sequence[int]) -> np.ndarray:
    w, h = size
    out = np.zeros((h, w), np.int32)
    # Sub-pixel polygon vertices through cv2's fixed-point shift.
    shift = 4
    for poly, value in zip(polygons_px, values, strict=True):
        if not np.all(np.isfinite(poly)):
            continue
        pts = np.rint((poly + 0.0) * (1 << shift)).astype(np.int32)
        cv2.fillConvexPoly(out, pts, int(value), lineType=cv2.LINE_8, shift=shift)
    return out


def _plate_maps(
    rig: CameraRig, board: Board, pose: PlatePose, camera: int
) -> tuple[np.ndarray, np.ndarray]:
    """(plate area inside the edge margin, marker labels 1..M with margins) in one view."""
    outline = rig.project(pose.to_array(_inset_outline(board)), camera)
    plate = _fill(outline[None], rig.image_size, [1]) > 0
    markers = rig.project(pose.to_array(_grown_markers(board)), camera)
    labels = _fill(markers, rig.image_size, range(1, len(board.markers) + 1))
    return plate, labels


def plate_highlight_region(
    rig: CameraRig, board: Board, pose: PlatePose, camera: int
) -> np.ndarray:
    """Return where the highlight is searched in one view: the plate minus its markers.

    Parameters
    ----------
    rig : CameraRig
    board : Board
    pose : PlatePose
    camera : int
        View index.

    Returns
    -------
    numpy.ndarray, (H, W), bool
        The plate inside a margin from its edge, without the markers and a margin
        around them, eroded by a few pixels.
    """
    return _free_region(*_plate_maps(rig, board, pose, camera))


def _free_region(plate: np.ndarray, labels: np.ndarray) -> np.ndarray:
    free = (plate & (labels == 0)).astype(np.uint8)
    kernel = np.ones((2 * _REGION_EROSION_PX + 1,) * 2, np.uint8)
    return cv2.erode(free, kernel).astype(bool)


def _clipped_by(center_uv: np.ndarray, area_px: int, blocked: np.ndarray) -> bool:
    """Whether a round blob of this area around ``center_uv`` reaches a blocked pixel."""
    if not blocked.any():
        return False
    dist = cv2.distanceTransform((~blocked).astype(np.uint8), cv2.DIST_L2, 5)
    h, w = blocked.shape
    u = int(np.clip(round(center_uv[0]), 0, w - 1))
    v = int(np.clip(round(center_uv[1]), 0, h - 1))
    return float(dist[v, u]) < math.sqrt(max(area_px, 1) / math.pi) + _CLIP_MARGIN_PX


def _find_one(
    view: np.ndarray,
    rig: CameraRig,
    board: Board,
    pose: PlatePose,
    camera: int,
    detector_options: dict[str, Any],
) -> tuple[np.ndarray | None, str]:
    from ..srde import detect_highlight

    name = rig.camera_names[camera]
    plate, labels = _plate_maps(rig, board, pose, camera)
    region = _free_region(plate, labels)
    det = detect_highlight(view, region, encoding=rig.image_encoding, **detector_options)
    if det.found:
        center = np.asarray(det.center_uv, dtype=np.float64)
        # A blob cut by a marker or by the plate edge has a biased centre: drop the view.
        if _clipped_by(center, det.area_px, labels > 0):
            near = _nearest_marker(center, labels, board)
            return None, f"{name}: highlight partly under marker {near}"
        if _clipped_by(center, det.area_px, ~plate):
            return None, f"{name}: highlight cut by the plate edge"
        return center, ""
    # Nothing in the free area: is the highlight on a marker, or absent?
    det_all = detect_highlight(view, plate, encoding=rig.image_encoding, **detector_options)
    if det_all.found:
        h, w = labels.shape
        u, v = np.clip(np.rint(det_all.center_uv).astype(int), 0, (w - 1, h - 1))
        # Only a centre on a marker counts: glow of a highlight beside the plate also
        # brightens the plate near its edge, next to the corner markers.
        if labels[v, u] > 0:
            return None, f"{name}: highlight under marker {board.markers[labels[v, u] - 1].id}"
    return None, f"{name}: no highlight on the plate ({det.reason})"


def _nearest_marker(center_uv: np.ndarray, labels: np.ndarray, board: Board) -> int:
    v, u = np.nonzero(labels)
    k = int(np.argmin((u - center_uv[0]) ** 2 + (v - center_uv[1]) ** 2))
    return int(board.markers[labels[v[k], u[k]] - 1].id)


def find_plate_highlights(
    views: Sequence[np.ndarray],
    rig: CameraRig,
    board: Board,
    pose: PlatePose,
    *,
    method: str = "blob",
    **detector_options: Any,
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Find the highlight centre on the plate in each view.

    Each view is searched inside :func:`plate_highlight_region`. A highlight that
    reaches a marker or the plate edge is not used (its centre would be biased); one
    found only on a marker is reported as hidden under it.

    Parameters
    ----------
    views : sequence of numpy.ndarray, (H, W, 3) or (H, W)
        One image per rig camera.
    rig : CameraRig
    board : Board
    pose : PlatePose
    method : {"blob", "paper"}
        Highlight detector (:func:`srde_fusion.srde.highlight.detect_highlight`).
    **detector_options
        Further keyword options of the detector.

    Returns
    -------
    centers_px : numpy.ndarray, (N, 2), float64
        ``(u, v)`` per view; NaN where the view has no usable highlight.
    reasons : tuple of str
        Per view, ``""`` or why there is no centre.
    """
    views = check_views(views, rig.n_cameras, rig.image_size)
    options = {"method": method, **detector_options}
    centers = np.full((rig.n_cameras, 2), np.nan)
    reasons = []
    for i, view in enumerate(views):
        center, reason = _find_one(view, rig, board, pose, i, options)
        if center is not None:
            centers[i] = center
        reasons.append(reason)
    return centers, tuple(reasons)


# ---------------------------------------------------------------------- the whole calibration
def read_capture(folder: str | os.PathLike, rig: CameraRig) -> list[np.ndarray]:
    """Read the views of one plate capture: one image per camera, named after it.

    A scene folder works too (its ``rig.json`` and other files are ignored).

    Raises
    ------
    FileFormatError
        A missing folder, or a camera without exactly one image.
    """
    from ..io import IMAGE_EXTENSIONS, read_image

    root = Path(folder)
    if not root.is_dir():
        raise FileFormatError(f"capture folder: expected an existing folder, got {str(root)!r}")
    views = []
    for name in rig.camera_names:
        found = [
            root / f"{name}{ext}" for ext in IMAGE_EXTENSIONS if (root / f"{name}{ext}").is_file()
        ]
        if len(found) != 1:
            raise FileFormatError(
                f"{root}: expected one image {name}.<{'|'.join(e[1:] for e in IMAGE_EXTENSIONS)}> "
                f"for camera {name}, got {len(found)}"
            )
        views.append(read_image(found[0]))
    return views


def estimate_light(
    captures: Sequence[Any],
    rig: CameraRig,
    board: Board,
    *,
    method: str = "blob",
    refine: bool = True,
    min_views: int = DEFAULT_MIN_VIEWS,
    min_marker_views: int = 1,
    max_incidence_deg: float = DEFAULT_MAX_INCIDENCE_DEG,
    max_residual_m: float = DEFAULT_MAX_RESIDUAL_M,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
    **detector_options: Any,
) -> LightEstimate:
    """Calibrate the light from one or more captures of the ArUco plate.

    For each capture: the plate pose from the markers of all views; the highlight
    centre on the plate in each view; its reflected ray. Then one least-squares point
    for the rays of all captures, refined jointly with the plate poses
    (:func:`light_from_reflections`).

    Parameters
    ----------
    captures : sequence of (sequence of images, or folder path)
        Each capture is the N views of one plate pose (``(H, W, 3)`` uint8 RGB or
        floats in [0, 1], rig order), or a folder holding one image per camera named
        after it.
    rig : CameraRig
    board : Board
    method : {"blob", "paper"}
        Highlight detector.
    refine : bool
        Refine light and plate poses jointly after the ray intersection.
    min_views : int
        Views per capture that must yield a highlight ray.
    min_marker_views : int
        Views per capture that must show markers.
    max_incidence_deg : float
        Largest angle between plate normal and a camera's line of sight.
    max_residual_m : float
        Largest accepted mean distance of the light to the rays, metres.
    max_reprojection_px : float
        Largest accepted RMS marker reprojection error of a plate pose, pixels.
    **detector_options
        Further options of :func:`srde_fusion.srde.highlight.detect_highlight`.

    Returns
    -------
    LightEstimate

    Raises
    ------
    LightError
        Markers in too few views (with the count per view), a plate nearly edge-on,
        too few views with a usable highlight (with the reason per view: none on the
        plate, under a marker, cut by the edge), or inconsistent rays.
    ImageError, FileFormatError
        Views that do not fit the rig, or unreadable capture folders.
    """
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    if not isinstance(board, Board):
        raise LightError(f"board: expected a Board, got {type(board).__name__}")
    if (
        isinstance(captures, (str, os.PathLike))
        or not isinstance(captures, Sequence)
        or not captures
    ):
        raise LightError(
            f"captures: expected a non-empty list of captures (each a list of views "
            f"or a folder), got {type(captures).__name__} {captures!r:.80}"
        )
    if isinstance(min_views, bool) or not isinstance(min_views, int) or min_views < 1:
        raise LightError(f"min_views: expected a positive integer, got {min_views!r}")
    max_incidence_deg = _check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = _check_positive(max_residual_m, "max_residual_m")
    poses, centers, reasons = [], [], []
    for c, capture in enumerate(captures):
        label = f"capture {c}" + (
            f" ({capture})" if isinstance(capture, (str, os.PathLike)) else ""
        )
        views = read_capture(capture, rig) if isinstance(capture, (str, os.PathLike)) else capture
        views = check_views(views, rig.n_cameras, rig.image_size)
        try:
            pose = estimate_plate_pose(
                views,
                rig,
                board,
                min_views=min_marker_views,
                max_reprojection_px=max_reprojection_px,
            )
        except LightError as exc:
            raise LightError(f"{label}: {exc}") from None
        _incidence_check(pose, rig, pose.views_used, max_incidence_deg, label)
        found, why = find_plate_highlights(
            views, rig, board, pose, method=method, **detector_options
        )
        n_found = int(np.all(np.isfinite(found), axis=1).sum())
        if n_found < min_views:
            details = "; ".join(r for r in why if r)
            raise LightError(
                f"{label}: expected a usable highlight on the plate in at least "
                f"{min_views} views, got {n_found}: {details}"
            )
        poses.append(pose)
        centers.append(found)
        reasons.append(why)
    return light_from_reflections(
        poses,
        centers,
        rig,
        refine=refine,
        view_reasons=reasons,
        max_incidence_deg=max_incidence_deg,
        max_residual_m=max_residual_m,
    )


def calibrate_light_files(
    capture_dirs: Sequence[str | os.PathLike],
    board_path: str | os.PathLike,
    rig_path: str | os.PathLike,
    *,
    write: bool = True,
    **options: Any,
) -> tuple[LightEstimate, CameraRig]:
    """Calibrate from capture folders and store the light in ``rig.json``.

    The previous ``rig.json`` is kept as ``rig.json.bak``.

    Parameters
    ----------
    capture_dirs : sequence of path
        One folder per plate pose, one image per camera named after it.
    board_path : path
        The plate's ``board.json``.
    rig_path : path
        The rig's ``rig.json``; rewritten with the light when ``write`` is true.
    write : bool
        Whether to write the light into ``rig_path``.
    **options
        Keyword options of :func:`estimate_light`.

    Returns
    -------
    (LightEstimate, CameraRig)
        The estimate and the rig with the light set.
    """
    rig = CameraRig.from_json(rig_path)
    board = Board.from_json(board_path)
    estimate = estimate_light(list(capture_dirs), rig, board, **options)
    new_rig = rig.with_light(estimate.position_m)
    if write:
        path = Path(rig_path)
        shutil.copy2(path, path.with_name(path.name + ".bak"))
        new_rig.to_json(path)
    return estimate, new_rig


# ---------------------------------------------------------------------- synthetic plates
def highlight_normal(point_m: Any, light_m: Any, camera_m: Any = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Return the plate normal that puts the highlight at ``point_m`` seen from ``camera_m``.

    The mirror normal is the half vector between the directions to the light and to
    the camera.

    Returns
    -------
    numpy.ndarray, (3,)
        Unit normal, pointing towards the camera side.

    Examples
    --------
    >>> highlight_normal([0, 0, 1.0], [0, -1.0, 1.0], [0, 0, 0]).round(4).tolist()
    [0.0, -0.7071, -0.7071]
    """
    p = check_point3(point_m, "point_m")
    to_light = check_point3(light_m, "light_m") - p
    to_camera = check_point3(camera_m, "camera_m") - p
    half = to_light / np.linalg.norm(to_light) + to_camera / np.linalg.norm(to_camera)
    norm = np.linalg.norm(half)
    if norm < 1e-9:
        raise LightError(
            "light_m: expected a light not exactly behind the point as seen from the "
            "camera, got opposite directions"
        )
    return half / norm


#: Linear level of the white plate (diffuse, at its centre) that ``plate_scene`` exposes for.
PLATE_WHITE_LEVEL = 0.3


def plate_scene(
    board: Board,
    rig: CameraRig,
    light_position_m: Any,
    *,
    center_m: Any,
    normal: Any = None,
    rotation_rad: float = 0.0,
    texture_dpi: float = 100.0,
    albedo: float = 0.8,
    roughness: float = 0.005,
    light_radius_m: float = 0.003,
    ambient: float = 0.05,
    noise_std: float = 0.0,
):
    """Build a synthetic scene of the calibration plate lit by a small light.

    The plate is a glossy white rectangle of ``board.plate_size_m`` carrying the
    board's markers as texture; its local axes are those of
    :meth:`PlatePose.from_center_normal` with the same arguments, which is therefore
    its true pose. The exposure puts the white plate at a fixed linear level, so the
    highlight clips as on a real camera.

    Parameters
    ----------
    board : Board
    rig : CameraRig
    light_position_m : array_like, (3,)
        The light, array frame, metres.
    center_m : array_like, (3,)
        Plate centre, array frame, metres.
    normal : array_like, (3,), optional
        Normal of the printed side; by default the one that puts the highlight at the
        plate centre as seen from the reference camera (:func:`highlight_normal`).
    rotation_rad : float
        In-plane rotation of the plate.
    texture_dpi : float
        Resolution of the marker texture.
    albedo : float
        Diffuse albedo of the white plate, in [0, 1].
    roughness : float
        Specular lobe width (GGX alpha).
    light_radius_m : float
        Radius of the spherical light.
    ambient : float
        Ambient radiance per unit albedo, relative to the plate's direct light.
    noise_std : float
        Sensor noise, linear units.

    Returns
    -------
    srde_fusion.synthetic.scenes.Scene
    """
    from ..synthetic import Light, Material, PlanarObject, Scene

    light = check_point3(light_position_m, "light_position_m")
    center = check_point3(center_m, "center_m")
    n = (
        highlight_normal(center, light, rig.reference_center_m)
        if normal is None
        else check_point3(normal, "normal")
    )
    texture = render_board_image(board, texture_dpi)
    plate = PlanarObject(
        "rectangle",
        tuple(center),
        tuple(n),
        board.plate_size_m,
        rotation_rad=rotation_rad,
        material=Material(diffuse_rgb=(albedo,) * 3, roughness=roughness),
        texture=texture,
    )
    to_light = light - center
    dist2 = float(to_light @ to_light)
    cos_l = abs(float(to_light @ np.asarray(plate.normal))) / math.sqrt(dist2)
    # Diffuse radiance of the white plate per unit exposure (the renderer's Lambert term).
    direct = albedo / math.pi * cos_l / dist2
    exposure = PLATE_WHITE_LEVEL / (direct * (1.0 + ambient))
    return Scene(
        (plate,),
        Light(tuple(light), radius_m=light_radius_m),
        ambient=ambient * direct,
        exposure=exposure,
        noise_std=noise_std,
    )
