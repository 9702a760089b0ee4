"""Pictures of a light calibration: what was found in each view, and the rays in 3D.

One figure per capture shows every view with the marker corners found and where the
plate pose puts them back, the highlight centre and where the estimated light's mirror
image (the virtual light) projects, each with its residual; a zoom around the highlight
makes sub-pixel residuals visible. One 3D figure shows the cameras, the plate poses, the
reflected rays and the estimated light. Built on :class:`matplotlib.figure.Figure` with
the Agg backend (no display, no pyplot state), like :mod:`srde_fusion.evaluation.figures`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from .._checks import check_views
from ..errors import FileFormatError, LightError
from ..evaluation import save_figure
from ..geometry import CameraRig, project_points
from .board import Board
from .captures import read_capture
from .light import LightEstimate
from .plate_pose import PlatePose

__all__ = [
    "capture_figure",
    "light_figure",
    "write_calibration_figures",
    "highlight_residuals_px",
]

#: Colours of what is drawn on the views (matplotlib colour names).
DETECTED_CORNER_COLOR = "cyan"
REPROJECTED_CORNER_COLOR = "yellow"
PLATE_COLOR = "lime"
HIGHLIGHT_COLOR = "red"
VIRTUAL_LIGHT_COLOR = "magenta"
# Half-side of the zoom around the highlight, pixels.
_ZOOM_HALF_PX = 16.0
# The largest highlight residual of a capture is drawn this long in the zoom, pixels
# (residuals are often hundredths of a pixel); the factor is a 1-2-5 step, printed.
_RESIDUAL_ARROW_PX = 10.0
# Side of the zoom's inset, as a fraction of its panel.
_INSET_SIZE = 0.34
# Longest skip reason shown under a panel, characters.
_REASON_CHARS = 70
#: File names written by :func:`write_calibration_figures` (``{c}`` = capture index).
CAPTURE_FIGURE = "capture_{c}.png"
LIGHT_FIGURE = "light_3d.png"


def highlight_residuals_px(estimate: LightEstimate, capture: int, rig: CameraRig
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Where the estimated light's mirror image projects in each view, and the residuals.

    Parameters
    ----------
    estimate : LightEstimate
    capture : int
        Index of the capture (plate pose).
    rig : CameraRig

    Returns
    -------
    predicted_px : numpy.ndarray, (N, 2), float64
        Projection of the virtual light (the light mirrored across this capture's
        plate) into every view, pixels.
    residual_px : numpy.ndarray, (N, 2), float64
        Highlight centre minus ``predicted_px``; NaN for views whose highlight was not
        used.
    """
    pose = estimate.plate_poses[capture]
    virtual_m = pose.plane.mirror(estimate.position_m)
    predicted = np.stack([rig.project(virtual_m, j) for j in range(rig.n_cameras)])
    return predicted, np.asarray(estimate.highlight_centers_px[capture]) - predicted


def _panel_grid(rig: CameraRig) -> list[tuple[int, int]]:
    """(row, column) of each camera's panel: the array's layout when it is a grid."""
    centers = np.round(rig.centers_m[:, :2], 6)
    xs, ys = np.unique(centers[:, 0]), np.unique(centers[:, 1])
    cells = [(int(np.searchsorted(ys, c[1])), int(np.searchsorted(xs, c[0]))) for c in centers]
    if len(set(cells)) == rig.n_cameras:  # y grows downwards: the top row comes first
        return cells
    cols = math.ceil(math.sqrt(rig.n_cameras))
    return [(j // cols, j % cols) for j in range(rig.n_cameras)]


def _corners(pose: PlatePose, rig: CameraRig, view: int) -> tuple[np.ndarray, np.ndarray]:
    """Return one view's marker corners found and where the pose puts them, (P, 2) px each."""
    if view not in pose.views_used:
        empty = np.zeros((0, 2))
        return empty, empty
    k = pose.views_used.index(view)
    reprojected = project_points(rig, pose.to_array(pose.plate_points_m[k]), view)
    return np.asarray(pose.image_points_px[k]), reprojected


def _outline_px(pose: PlatePose, board: Board, rig: CameraRig, view: int) -> np.ndarray:
    closed = np.concatenate([board.outline_m, board.outline_m[:1]])
    return project_points(rig, pose.to_array(closed), view)


def capture_figure(views: Sequence[np.ndarray], estimate: LightEstimate, capture: int,
                   rig: CameraRig, board: Board, *, panel_width_in: float = 3.2) -> Figure:
    """Draw one capture: each view with its markers, highlight and residuals.

    Every panel shows the view with the plate outline where the pose puts it, the marker
    corners detected (``+``) and reprojected from the pose (``o``), the highlight centre
    (``+``) and the projection of the virtual light (``x``); its title gives the marker
    count, their RMS reprojection error and the highlight residual, or why the view gave
    no ray. A zoom around the highlight shows both points and the residual.

    Parameters
    ----------
    views : sequence of numpy.ndarray, (H, W, 3) or (H, W)
        The capture's views, in the rig's order.
    estimate : LightEstimate
    capture : int
        Index of the capture in ``estimate``.
    rig : CameraRig
    board : Board
    panel_width_in : float
        Width of one panel, inches.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    LightError
        ``capture`` is not a capture of ``estimate``.
    ImageError
        Views that do not fit the rig.
    """
    if (isinstance(capture, bool) or not isinstance(capture, (int, np.integer))
            or not 0 <= capture < estimate.n_captures):
        raise LightError(f"capture: expected an index in [0, {estimate.n_captures - 1}], got "
                         f"{capture!r}")
    views = check_views(views, rig.n_cameras, rig.image_size)
    pose = estimate.plate_poses[capture]
    centers = np.asarray(estimate.highlight_centers_px[capture])
    predicted, residual = highlight_residuals_px(estimate, capture, rig)
    reasons = estimate.view_reasons[capture]
    lengths = np.hypot(residual[:, 0], residual[:, 1])
    largest = float(np.nanmax(lengths)) if np.isfinite(lengths).any() else 0.0
    magnify = _nice_factor(_RESIDUAL_ARROW_PX / largest) if largest > 0 else 1.0
    cells = _panel_grid(rig)
    n_rows, n_cols = (max(c[i] for c in cells) + 1 for i in (0, 1))
    panel_h = panel_width_in * rig.height / rig.width
    fig = Figure(figsize=(panel_width_in * n_cols, (panel_h + 0.6) * n_rows + 1.0))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(n_rows, n_cols, left=0.01, right=0.99, bottom=0.08, top=0.88,
                            wspace=0.04, hspace=0.3)
    for j, (row, col) in enumerate(cells):
        ax = fig.add_subplot(grid[row, col])
        ax.set_axis_off()
        view = views[j]
        ax.imshow(view, cmap="gray" if view.ndim == 2 else None)
        outline = _outline_px(pose, board, rig, j)
        ax.plot(outline[:, 0], outline[:, 1], color=PLATE_COLOR, linewidth=0.7)
        detected, reprojected = _corners(pose, rig, j)
        ax.plot(detected[:, 0], detected[:, 1], "+", color=DETECTED_CORNER_COLOR, ms=5, mew=0.8)
        ax.plot(reprojected[:, 0], reprojected[:, 1], "o", mfc="none",
                mec=REPROJECTED_CORNER_COLOR, ms=4, mew=0.6)
        err = pose.view_errors_px[j] if j < len(pose.view_errors_px) else math.nan
        markers = pose.markers_per_view[j] if j < len(pose.markers_per_view) else 0
        lines = [f"{rig.camera_names[j]}: {markers} markers"
                 + (f", {err:.2f} px RMS" if math.isfinite(err) else "")]
        if np.all(np.isfinite(centers[j])):
            u, v = centers[j]
            ax.plot(u, v, "+", color=HIGHLIGHT_COLOR, ms=9, mew=1.2)
            ax.plot(*predicted[j], "x", color=VIRTUAL_LIGHT_COLOR, ms=6, mew=1.0)
            lines.append(f"highlight residual {np.hypot(*residual[j]):.2f} px")
            _zoom(ax, view, centers[j], predicted[j], magnify, _free_corner(outline, rig))
        else:
            reason = reasons[j] if j < len(reasons) else ""
            reason = reason if len(reason) <= _REASON_CHARS else reason[:_REASON_CHARS] + "..."
            lines.append(f"no ray: {reason or 'not used'}")
        ax.set_title("\n".join(lines), fontsize=7)
    fig.legend(handles=[
        Line2D([], [], color=PLATE_COLOR, label="plate (from the pose)"),
        Line2D([], [], ls="none", marker="+", color=DETECTED_CORNER_COLOR,
               label="marker corners found"),
        Line2D([], [], ls="none", marker="o", mfc="none", mec=REPROJECTED_CORNER_COLOR,
               label="... reprojected from the pose"),
        Line2D([], [], ls="none", marker="+", color=HIGHLIGHT_COLOR, label="highlight centre"),
        Line2D([], [], ls="none", marker="x", color=VIRTUAL_LIGHT_COLOR,
               label="projection of the estimated light's mirror image"),
        Line2D([], [], color=HIGHLIGHT_COLOR, marker=">", ms=4,
               label=f"zoom: residual x {magnify:g}"),
    ], loc="lower center", ncol=3, fontsize=7, frameon=False)
    rms = np.sqrt(np.nanmean(np.sum(residual ** 2, axis=1))) if np.isfinite(residual).any() \
        else math.nan
    fig.suptitle(f"capture {estimate.capture_index(capture)}: plate "
                 f"{np.linalg.norm(pose.center_m):.3f} m from the reference camera, markers "
                 f"{pose.reprojection_error_px:.2f} px RMS, highlights {rms:.2f} px RMS from the "
                 "estimated light", fontsize=9)
    return fig


def _nice_factor(value: float) -> float:
    """Return the largest 1-2-5 step (..., 0.5, 1, 2, 5, 10, ...) not above ``value`` (> 0)."""
    exponent = math.floor(math.log10(value))
    # default: a mantissa just below 1 from rounding in log10
    mantissa = max((m for m in (1.0, 2.0, 5.0) if m <= value / 10.0 ** exponent), default=1.0)
    return mantissa * 10.0 ** exponent


def _free_corner(outline_px: np.ndarray, rig: CameraRig) -> list[float]:
    """Return the inset ``[x0, y0, w, h]`` (axes fractions) in the corner the plate covers least."""
    w, h = rig.width, rig.height
    (u0, v0), (u1, v1) = outline_px.min(axis=0), outline_px.max(axis=0)
    best, best_overlap = None, math.inf
    for x0 in (0.02, 1.0 - _INSET_SIZE - 0.02):
        for y0 in (0.02, 1.0 - _INSET_SIZE - 0.02):
            # axes fractions -> pixels: x right, y up from the bottom of the image
            a0, a1 = x0 * w, (x0 + _INSET_SIZE) * w
            b0, b1 = (1.0 - y0 - _INSET_SIZE) * h, (1.0 - y0) * h
            overlap = max(0.0, min(a1, u1) - max(a0, u0)) * max(0.0, min(b1, v1) - max(b0, v0))
            if overlap < best_overlap:
                best, best_overlap = [x0, y0, _INSET_SIZE, _INSET_SIZE], overlap
    return best


def _zoom(ax: Any, view: np.ndarray, center_px: np.ndarray, predicted_px: np.ndarray,
          magnify: float, where: list[float]) -> None:
    """Inset a zoom around the highlight: its centre, the prediction, the residual magnified."""
    inset = ax.inset_axes(where)
    inset.imshow(view, cmap="gray" if view.ndim == 2 else None, interpolation="nearest")
    u, v = center_px
    inset.set_xlim(u - _ZOOM_HALF_PX, u + _ZOOM_HALF_PX)
    inset.set_ylim(v + _ZOOM_HALF_PX, v - _ZOOM_HALF_PX)
    inset.plot(u, v, "+", color=HIGHLIGHT_COLOR, ms=10, mew=1.2)
    inset.plot(*predicted_px, "x", color=VIRTUAL_LIGHT_COLOR, ms=7, mew=1.0)
    tip = predicted_px + magnify * (center_px - predicted_px)
    inset.annotate("", xy=tuple(tip), xytext=tuple(predicted_px),
                   arrowprops={"arrowstyle": "->", "color": HIGHLIGHT_COLOR, "lw": 1.0})
    inset.set_xticks([])
    inset.set_yticks([])
    for spine in inset.spines.values():
        spine.set_edgecolor(HIGHLIGHT_COLOR)


def light_figure(estimate: LightEstimate, rig: CameraRig, board: Board, *,
                 size_in: float = 6.5) -> Figure:
    """Draw the calibration in 3D: cameras, plate poses, reflected rays and the light.

    Shown in the array frame with the vertical axis up (``-y``): the camera centres, each
    capture's plate (outline and normal) in its own colour, the viewing ray of every used
    view to its highlight on the plate, the reflected ray from there on towards the
    light, the estimated light (star) and the rays' closed-form intersection (circle).

    Parameters
    ----------
    estimate : LightEstimate
    rig : CameraRig
    board : Board
    size_in : float
        Width and height of the figure, inches.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = Figure(figsize=(size_in, size_in))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")

    def up(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # array frame (x right, y down, z forward) -> plot axes (x, z, -y): up is up
        p = np.atleast_2d(points_m)
        return p[:, 0], p[:, 2], -p[:, 1]

    light = estimate.position_m
    shown = [rig.centers_m, light[None]]
    ax.scatter(*up(rig.centers_m), color="black", marker="^", s=18, label="cameras")
    palette = colormaps["tab10"].colors
    for c, pose in enumerate(estimate.plate_poses):
        color = palette[c % len(palette)]
        outline = pose.to_array(np.concatenate([board.outline_m, board.outline_m[:1]]))
        ax.plot(*up(outline), color=color, linewidth=1.5,
                label=f"plate, capture {estimate.capture_index(c)}")
        tip = pose.center_m + 0.1 * pose.plane.n
        ax.plot(*up(np.stack([pose.center_m, tip])), color=color, linewidth=0.8)
        shown.append(outline)
        for r in np.flatnonzero(estimate.ray_captures == c):
            hit = estimate.ray_origins_m[r]
            camera = rig.centers_m[estimate.ray_views[r]]
            ax.plot(*up(np.stack([camera, hit])), color="0.6", linewidth=0.5)
            # the reflected ray, drawn up to its point closest to the light
            reach = max(float((light - hit) @ estimate.ray_directions[r]), 0.0)
            ax.plot(*up(np.stack([hit, hit + reach * estimate.ray_directions[r]])),
                    color=color, linewidth=0.8)
    ax.plot([], [], [], color="0.6", linewidth=0.5, label="viewing rays to the highlights")
    ax.plot([], [], [], color="0.3", linewidth=0.8, label="reflected rays (plate colour)")
    ax.scatter(*up(estimate.closed_form_position_m), marker="o", s=40, facecolors="none",
               edgecolors="red", label="closed-form intersection")
    if estimate.geometric_position_m is not None:
        ax.scatter(*up(estimate.geometric_position_m), marker="x", s=40, color="red",
                   label="the highlight centres' rays (before the images)")
    ax.scatter(*up(light), marker="*", s=140, color="red", label="estimated light")
    points = np.concatenate(shown)
    lo, hi = points.min(axis=0), points.max(axis=0)
    span = np.maximum(hi - lo, 1e-3)
    ax.set_box_aspect((span[0], span[2], span[1]))  # true proportions on the plot axes
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z (forward) [m]")
    ax.set_zlabel("-y (up) [m]")
    ax.view_init(elev=20.0, azim=-60.0)
    ax.legend(loc="upper left", fontsize=7)
    x, y, z = light
    ax.set_title(f"light ({x:+.3f}, {y:+.3f}, {z:+.3f}) m, ± "
                 f"{np.linalg.norm(estimate.position_std_m) * 1000:.1f} mm; "
                 f"{estimate.n_rays} rays, {estimate.residual_m * 1000:.2f} mm mean distance",
                 fontsize=9)
    return fig


def write_calibration_figures(out_dir: str | os.PathLike, captures: Sequence[Any],
                              estimate: LightEstimate, rig: CameraRig, board: Board
                              ) -> tuple[Path, ...]:
    """Write ``capture_<c>.png`` for every capture and ``light_3d.png`` into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Created if needed.
    captures : sequence of (sequence of images, or folder path)
        The captures as given to
        :func:`~srde_fusion.calibration.captures.estimate_light`, in the same order (or
        only those it used); files are named by the index in that list.
    estimate : LightEstimate
    rig : CameraRig
    board : Board

    Returns
    -------
    tuple of pathlib.Path
        The files written, captures first.

    Raises
    ------
    LightError
        Neither as many captures as the estimate has plate poses nor as many as it was
        given.
    FileFormatError
        The folder cannot be created, or a capture folder cannot be read.
    """
    given = None if isinstance(captures, (str, os.PathLike)) else len(captures)
    # The calibration's own list (some captures may have been left out), or those it used.
    indices = estimate.capture_indices
    if indices is not None and given == len(indices) + len(estimate.skipped_captures):
        captures = [captures[i] for i in indices]
    elif given != estimate.n_captures:
        expected = (f"{estimate.n_captures} captures the estimate was made from"
                    + (f" or the {len(indices) + len(estimate.skipped_captures)} it was given"
                       if estimate.skipped_captures else ""))
        raise LightError(f"captures: expected the {expected}, got "
                         f"{'a single path' if given is None else given}")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"{out}: could not create the figure folder: {exc}") from None
    files = []
    for c, capture in enumerate(captures):
        views = read_capture(capture, rig) if isinstance(capture, (str, os.PathLike)) else capture
        fig = capture_figure(views, estimate, c, rig, board)
        files.append(save_figure(fig, out / CAPTURE_FIGURE.format(c=estimate.capture_index(c))))
    files.append(save_figure(light_figure(estimate, rig, board), out / LIGHT_FIGURE))
    return tuple(files)
