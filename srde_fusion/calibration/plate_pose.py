"""The plate's pose in the array frame, from the marker corners of every view.

All cameras of the rectified array share one orientation and differ only by their known
centres, so one rigid pose of the plate explains the marker corners of all views: it is
found by PnP in the best view and refined over all of them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._checks import (
    check_views,
)
from ..errors import LightError
from ..geometry import Plane, project_points, rotation_from_vector
from .board import Board
from .markers import MarkerDetection, detect_markers

__all__ = [
    "PlatePose",
    "estimate_plate_pose",
    "pose_from_detections",
]

# A plate pose needs the corners of at least this many markers in some view for PnP.
MIN_MARKERS_FOR_PNP = 1


# Largest reprojection error (RMS, px) of a plate pose that is still trusted.
DEFAULT_MAX_REPROJECTION_PX = 2.0


# ---------------------------------------------------------------------- pose
@dataclass(frozen=True, eq=False)
class PlatePose:
    """The plate's pose in the array frame, and the marker corners it rests on.

    ``X_array = rotation @ X_plate + translation_m``.

    Parameters
    ----------
    rotation : numpy.ndarray, (3, 3), float64
        ``array_from_plate`` rotation.
    translation_m : numpy.ndarray, (3,), float64
        The plate centre in the array frame, metres.
    reprojection_error_px : float
        RMS distance between detected and reprojected marker corners over all views
        used, pixels; NaN for a pose given rather than measured.
    view_errors_px : numpy.ndarray, (N,), float64
        RMS reprojection error per view; NaN for views without markers.
    markers_per_view : tuple of int
        Number of board markers found in each view.
    views_used : tuple of int
        Views whose corners entered the pose.
    plate_points_m : tuple of numpy.ndarray, each (P, 3)
        Per used view, the board corners seen (plate frame, metres).
    image_points_px : tuple of numpy.ndarray, each (P, 2)
        Per used view, where they were detected, pixels.
    """

    rotation: np.ndarray
    translation_m: np.ndarray
    reprojection_error_px: float = math.nan
    view_errors_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    markers_per_view: tuple[int, ...] = ()
    views_used: tuple[int, ...] = ()
    plate_points_m: tuple[np.ndarray, ...] = ()
    image_points_px: tuple[np.ndarray, ...] = ()

    @property
    def center_m(self) -> np.ndarray:
        """The plate centre in the array frame, ``(3,)``, metres."""
        return self.translation_m

    @property
    def normal(self) -> np.ndarray:
        """Unit plate normal on the printed side (plate -z) in the array frame, ``(3,)``."""
        return -self.rotation[:, 2]

    @property
    def plane(self) -> Plane:
        """The plate's plane, normal oriented towards the reference camera (origin)."""
        return Plane.from_point_normal(self.translation_m, self.normal)

    @property
    def has_corners(self) -> bool:
        """Whether the pose carries the marker corners it was measured from."""
        return len(self.views_used) > 0

    def to_array(self, points_plate_m: Any) -> np.ndarray:
        """Map plate-frame points ``(..., 3)`` to the array frame, metres."""
        p = np.asarray(points_plate_m, dtype=np.float64)
        return p @ self.rotation.T + self.translation_m

    def to_plate(self, points_m: Any) -> np.ndarray:
        """Map array-frame points ``(..., 3)`` to the plate frame, metres."""
        p = np.asarray(points_m, dtype=np.float64)
        return (p - self.translation_m) @ self.rotation

    def moved(self, rotation: np.ndarray, translation_m: np.ndarray, rig) -> PlatePose:
        """Return the same measurement at another pose, with its reprojection errors."""
        rms, view_err = _reprojection_errors(
            rotation,
            translation_m,
            rig,
            self.views_used,
            self.plate_points_m,
            self.image_points_px,
            len(self.markers_per_view),
        )
        return replace(
            self,
            rotation=rotation,
            translation_m=translation_m,
            reprojection_error_px=rms,
            view_errors_px=view_err,
        )

    @classmethod
    def from_center_normal(
        cls, center_m: Any, normal: Any, *, rotation_rad: float = 0.0
    ) -> PlatePose:
        """Build a pose from the plate centre and the normal of its printed side.

        The normal is flipped to face the array origin if needed. The plate's x axis is
        the array x axis projected onto the plate (the y axis if the normal is within
        about 25 deg of x), turned by ``rotation_rad`` about the normal (positive turns
        x towards y). This is a given pose, not a measurement: it carries no corners.
        """
        c = np.asarray(center_m, dtype=np.float64)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        if np.dot(n, -c) < 0:
            n = -n
        z = -n
        # The same in-plane axes as the renderer's planar objects (srde_fusion.synthetic):
        # the array x axis projected onto the plate, or y when the plate faces along x.
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = ref - np.dot(ref, n) * n
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        cos, sin = math.cos(rotation_rad), math.sin(rotation_rad)
        x, y = cos * x + sin * y, -sin * x + cos * y
        return cls(np.stack([x, y, z], axis=1), c)


def _reprojection_errors(rotation, translation_m, rig, views, plate_points, image_points, n_views):
    view_err = np.full(n_views, np.nan)
    squares = []
    for i, obj, img in zip(views, plate_points, image_points, strict=True):
        d2 = np.sum((project_points(rig, obj @ rotation.T + translation_m, i) - img) ** 2, axis=1)
        view_err[i] = float(np.sqrt(d2.mean()))
        squares.append(d2)
    rms = float(np.sqrt(np.concatenate(squares).mean())) if squares else math.nan
    return rms, view_err


def estimate_plate_pose(
    views: Sequence[np.ndarray],
    rig,
    board: Board,
    *,
    min_views: int = 1,
    min_markers: int = 1,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
) -> PlatePose:
    """Estimate one pose of the plate in the array frame from the markers of all views.

    Each view with at least ``min_markers`` markers contributes its corners. The pose
    is initialised by planar PnP (both IPPE solutions) in the view with the most
    markers and refined by Levenberg-Marquardt over the 6 degrees of freedom on the
    corners of all those views together (cameras differ only by their centres).

    Parameters
    ----------
    views : sequence of numpy.ndarray, (H, W, 3) or (H, W)
        One image per rig camera, in rig order.
    rig : CameraRig
    board : Board
    min_views : int
        Views with markers needed.
    min_markers : int
        Markers a view needs to count.
    max_reprojection_px : float
        Largest RMS reprojection error accepted, pixels.

    Returns
    -------
    PlatePose

    Raises
    ------
    LightError
        Markers in too few views (the message lists how many each view had), or
        corners that no single plate pose explains.
    """
    views = check_views(views, rig.n_cameras, rig.image_size)
    detections = [detect_markers(v, board, encoding=rig.image_encoding) for v in views]
    return pose_from_detections(
        detections,
        rig,
        board,
        min_views=min_views,
        min_markers=min_markers,
        max_reprojection_px=max_reprojection_px,
    )


def pose_from_detections(
    detections: Sequence[MarkerDetection],
    rig,
    board: Board,
    *,
    min_views: int = 1,
    min_markers: int = 1,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
) -> PlatePose:
    """Solve the joint plate pose from per-view marker detections.

    See :func:`estimate_plate_pose` for the parameters.
    """
    counts = tuple(d.n_markers for d in detections)
    used = tuple(i for i, c in enumerate(counts) if c >= max(min_markers, MIN_MARKERS_FOR_PNP))
    if len(used) < min_views:
        listing = ", ".join(f"{rig.camera_names[i]}: {c}" for i, c in enumerate(counts))
        raise LightError(
            f"plate markers: expected at least {min_markers} of the board's "
            f"{len(board.markers)} markers in at least {min_views} views, got them in "
            f"{len(used)} (markers per view: {listing})"
        )
    pairs = [detections[i].correspondences(board) for i in used]
    obj = tuple(p[0] for p in pairs)
    img = tuple(p[1] for p in pairs)
    # (P,) camera index of every corner, so one projection covers all views.
    cameras = np.concatenate([np.full(o.shape[0], i) for i, o in zip(used, obj, strict=True)])
    obj_all, img_all = np.concatenate(obj), np.concatenate(img)

    def residuals(params: np.ndarray) -> np.ndarray:
        r, t = rotation_from_vector(params[:3]), params[3:]
        return (project_points(rig, obj_all @ r.T + t, cameras) - img_all).ravel()

    best = used.index(max(used, key=lambda i: counts[i]))
    n_sol, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        obj[best], img[best], rig.intrinsics.matrix, None, flags=cv2.SOLVEPNP_IPPE
    )
    if n_sol == 0:
        raise LightError(
            f"plate pose: PnP found no pose from the {counts[used[best]]} markers of view "
            f"{rig.camera_names[used[best]]}"
        )
    fits = []
    # Planar PnP has two mirror-like solutions; all views together tell them apart.
    for rvec, tvec in zip(rvecs, tvecs, strict=True):
        # The view's camera frame is the array frame shifted by the camera centre.
        start = np.concatenate([np.ravel(rvec), np.ravel(tvec) + rig.centers_m[used[best]]])
        fits.append(least_squares(residuals, start, method="lm", x_scale="jac"))
    fit = min(fits, key=lambda f: f.cost)
    rotation, translation = rotation_from_vector(fit.x[:3]), fit.x[3:]
    rms, view_err = _reprojection_errors(
        rotation, translation, rig, used, obj, img, len(detections)
    )
    if not rms <= max_reprojection_px:
        worst = used[int(np.nanargmax(view_err[list(used)]))]
        raise LightError(
            f"plate pose: expected marker corners consistent with one plate pose "
            f"(RMS reprojection error <= {max_reprojection_px:g} px), got "
            f"{rms:.2f} px (worst view {rig.camera_names[worst]}: "
            f"{view_err[worst]:.2f} px)"
        )
    return PlatePose(rotation, translation, rms, view_err, counts, used, obj, img)
