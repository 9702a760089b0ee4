"""The whole light calibration, from capture folders to the light written into a rig.

``estimate_light`` reads one folder per plate pose (one image per camera), finds the
plate's pose and the highlight in every view, and solves for the light;
``calibrate_light_files`` does the same from files and writes the light into
``rig.json``, keeping the previous file as a backup.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import backup_path, write_atomic
from .._checks import check_views
from ..errors import FileFormatError, LightError, RigError
from ..geometry import CameraRig
from ..io import IMAGE_EXTENSIONS, read_image
from .board import Board
from .light import (
    DEFAULT_MAX_INCIDENCE_DEG,
    DEFAULT_MAX_RESIDUAL_M,
    DEFAULT_MIN_VIEWS,
    LightEstimate,
    check_positive,
    incidence_check,
    light_from_reflections,
)
from .plate_highlights import find_plate_highlights
from .plate_pose import DEFAULT_MAX_REPROJECTION_PX, estimate_plate_pose

__all__ = [
    "estimate_light",
    "read_capture",
    "calibrate_light_files",
    "LightCalibration",
]

# ---------------------------------------------------------------------- the whole calibration
def read_capture(folder: str | os.PathLike, rig: CameraRig) -> list[np.ndarray]:
    """Read the views of one plate capture: one image per camera, named after it.

    A scene folder works too (its ``rig.json`` and other files are ignored).

    Raises
    ------
    FileFormatError
        A missing folder, or a camera without exactly one image.
    """
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
    max_incidence_deg = check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = check_positive(max_residual_m, "max_residual_m")
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
        incidence_check(pose, rig, pose.views_used, max_incidence_deg, label)
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


@dataclass(frozen=True)
class LightCalibration:
    """What :func:`calibrate_light_files` found and wrote.

    Attributes
    ----------
    estimate : LightEstimate
        The light and its residuals.
    rig : CameraRig
        The rig with the light set.
    backup : pathlib.Path or None
        Where the previous ``rig.json`` was kept; None when nothing was written.
    """

    estimate: LightEstimate
    rig: CameraRig
    backup: Path | None = None


def calibrate_light_files(
    capture_dirs: Sequence[str | os.PathLike],
    board_path: str | os.PathLike,
    rig_path: str | os.PathLike,
    *,
    write: bool = True,
    **options: Any,
) -> LightCalibration:
    """Calibrate from capture folders and store the light in ``rig.json``.

    The previous ``rig.json`` is kept as ``rig.json.bak`` (or ``.bak1``, ``.bak2``, ...: an
    earlier backup is never overwritten), and the new one is written atomically.

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
    LightCalibration
        The estimate, the rig with the light set, and the backup of the old file.
    """
    rig = CameraRig.from_json(rig_path)
    board = Board.from_json(board_path)
    estimate = estimate_light(list(capture_dirs), rig, board, **options)
    new_rig = rig.with_light(estimate.position_m)
    backup = None
    if write:
        path = Path(rig_path)
        backup = backup_path(path)
        try:
            old = path.read_bytes()
        except OSError as exc:
            raise FileFormatError(f"{backup}: could not back up {path.name}: {exc}") from None
        # The backup is written like every other file: whole or not at all.
        write_atomic(backup, old)
        new_rig.to_json(path)
    return LightCalibration(estimate, new_rig, backup)
