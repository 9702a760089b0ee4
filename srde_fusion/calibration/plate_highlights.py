"""Where the light's highlight is on the calibration plate, in every view.

The search is kept to the plate's free centre (inside its outline, away from the
markers); a highlight that touches a marker or the plate's edge is clipped, so its centre
would be biased, and is rejected with a reason rather than used.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from .._checks import check_views
from ..geometry import CameraRig
from ..srde import detect_highlight
from .board import Board
from .plate_pose import PlatePose

__all__ = [
    "plate_highlight_region",
    "find_plate_highlights",
    "find_plate_highlight_candidates",
]

# The highlight search keeps this far (metres, on the plate) from the plate edge, and
# this fraction of a marker's side away from each marker (the marker's black edges
# would otherwise pass for highlight gradients).
_EDGE_MARGIN_FRACTION = 0.1
_MARKER_MARGIN_FRACTION = 0.15


# ...and this many pixels from both, once projected.
_REGION_EROSION_PX = 2


# A blob closer than this (pixels) to the search region's border beyond its own radius
# is taken to be cut by it.
_CLIP_MARGIN_PX = 1.0


# Several highlights in one view are found one after the other, each search leaving out a
# disc around the blobs found before: this many blob radii (of the half-maximum blob)
# plus this many pixels. A blob found next that reaches such a disc is its skirt, or a
# highlight so close that the other biases its centre, and is not used. Wider discs lost
# highlights of lamps 13 cm apart on a plate 1 m away (clipped blobs of 12 px radius,
# 37 px apart).
_EXCLUSION_RADII = 1.5
_EXCLUSION_MARGIN_PX = 2.0
# Searches per view, per highlight wanted: skirts found and refused take searches too.
_SEARCHES_PER_HIGHLIGHT = 3


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


def _reaches(center_uv: np.ndarray, area_px: int, distance_px: np.ndarray) -> bool:
    """Whether a round blob of this area reaches a blocked pixel.

    ``distance_px`` is the distance map to the blocked pixels (:func:`_distance_to`).
    """
    h, w = distance_px.shape
    u = int(np.clip(round(center_uv[0]), 0, w - 1))
    v = int(np.clip(round(center_uv[1]), 0, h - 1))
    return float(distance_px[v, u]) < math.sqrt(max(area_px, 1) / math.pi) + _CLIP_MARGIN_PX


def _distance_to(blocked: np.ndarray) -> np.ndarray:
    """Distance (pixels) of every pixel to the nearest blocked one (inf: none blocked)."""
    if not blocked.any():
        return np.full(blocked.shape, np.inf, dtype=np.float32)
    return cv2.distanceTransform((~blocked).astype(np.uint8), cv2.DIST_L2, 5)


def _candidates_in_view(
    view: np.ndarray,
    rig: CameraRig,
    board: Board,
    pose: PlatePose,
    camera: int,
    max_candidates: int,
    detector_options: dict[str, Any],
) -> tuple[np.ndarray, tuple[str, ...]]:
    """Every usable highlight centre of one view, brightest first, and why others were not."""
    name = rig.camera_names[camera]
    plate, labels = _plate_maps(rig, board, pose, camera)
    remaining = _free_region(plate, labels)
    to_marker, to_edge = _distance_to(labels > 0), _distance_to(~plate)
    h, w = remaining.shape
    vv, uu = np.mgrid[0:h, 0:w]
    centers, notes = [], []
    # Left-out areas as (centre, radius, box), to measure a new blob's distance to them.
    left_out: list[tuple[np.ndarray, float, tuple[int, int, int, int]]] = []
    # Up to one candidate more than wanted: it is reported, not dropped silently (a
    # highlight more than expected is for the caller to judge).
    for _ in range(_SEARCHES_PER_HIGHLIGHT * (max_candidates + 1)):
        det = detect_highlight(view, remaining, encoding=rig.image_encoding, **detector_options)
        if not det.found:
            break
        center = np.asarray(det.center_uv, dtype=np.float64)
        radius = math.sqrt(max(det.area_px, 1) / math.pi)
        if _reaches(center, det.area_px, to_marker):
            notes.append(f"{name}: highlight at ({center[0]:.0f}, {center[1]:.0f}) partly under "
                         f"marker {_nearest_marker(center, labels, board)}")
        elif _reaches(center, det.area_px, to_edge):
            notes.append(f"{name}: highlight at ({center[0]:.0f}, {center[1]:.0f}) cut by the "
                         f"plate edge")
        elif any(_gap_px(center, *area) < radius + _CLIP_MARGIN_PX for area in left_out):
            # The skirt of a highlight found before, or a highlight touching it: its
            # centre would be pulled either way.
            notes.append(f"{name}: blob at ({center[0]:.0f}, {center[1]:.0f}) touches a "
                         f"brighter highlight")
        else:
            centers.append(center)
        reach = _EXCLUSION_RADII * radius + _EXCLUSION_MARGIN_PX
        disc = np.square(uu - center[0]) + np.square(vv - center[1]) <= reach * reach
        # The blob's box too: it holds the peak the detector started from, which may lie
        # outside the disc around a lopsided blob's centre (and would be found again).
        u0, v0, u1, v1 = det.bbox
        disc[v0:v1, u0:u1] = True
        remaining &= ~disc
        left_out.append((center, reach, det.bbox))
        if len(centers) > max_candidates:
            break
    return np.array(centers, dtype=np.float64).reshape(-1, 2), tuple(notes)


def _gap_px(point_uv: np.ndarray, center_uv: np.ndarray, radius_px: float,
            box: tuple[int, int, int, int]) -> float:
    """Distance (pixels) from a point to a left-out area: a disc and a box of pixels."""
    u0, v0, u1, v1 = box
    du = max(u0 - point_uv[0], 0.0, point_uv[0] - (u1 - 1))
    dv = max(v0 - point_uv[1], 0.0, point_uv[1] - (v1 - 1))
    to_disc = float(np.hypot(*(point_uv - center_uv))) - radius_px
    return max(min(to_disc, math.hypot(du, dv)), 0.0)


def find_plate_highlight_candidates(
    views: Sequence[np.ndarray],
    rig: CameraRig,
    board: Board,
    pose: PlatePose,
    *,
    max_per_view: int,
    method: str = "blob",
    **detector_options: Any,
) -> tuple[tuple[np.ndarray, ...], tuple[tuple[str, ...], ...]]:
    """Find every highlight on the plate in each view (several lights, several highlights).

    Each view is searched inside :func:`plate_highlight_region`, brightest blob first;
    each further search leaves out a disc around the blobs found before. A blob that
    reaches a marker, the plate edge or the disc of a brighter highlight is not used (its
    centre would be biased) and is reported. Which highlight belongs to which light is
    not decided here (:func:`~srde_fusion.calibration.group_highlights`).

    Parameters
    ----------
    views : sequence of numpy.ndarray, (H, W, 3) or (H, W)
        One image per rig camera.
    rig : CameraRig
    board : Board
    pose : PlatePose
    max_per_view : int
        Most highlights wanted per view (the number of lights); one search more is made,
        so a view showing more is seen.
    method : {"blob", "paper"}
        Highlight detector (:func:`srde_fusion.srde.highlight.detect_highlight`).
    **detector_options
        Further keyword options of the detector.

    Returns
    -------
    centers_px : tuple of numpy.ndarray, each (M_i, 2), float64
        Per view, the usable highlight centres ``(u, v)``, brightest first (``M_i`` may
        exceed ``max_per_view`` by one).
    notes : tuple of tuple of str
        Per view, the blobs found but not used, and why.
    """
    views = check_views(views, rig.n_cameras, rig.image_size)
    options = {"method": method, **detector_options}
    out = [_candidates_in_view(view, rig, board, pose, i, max_per_view, options)
           for i, view in enumerate(views)]
    return tuple(c for c, _ in out), tuple(n for _, n in out)
