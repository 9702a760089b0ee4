"""The whole light calibration, from capture folders to the lights written into a rig.

``estimate_light`` reads one folder per plate pose (one image per camera), finds the
plate's pose and the highlight in every view, and solves for the light;
``estimate_lights`` does the same for several lights, each showing its own highlight,
sorted to their lights by geometry (:mod:`~srde_fusion.calibration.correspondence`);
``calibrate_light_files`` does either from files and writes the lights into
``rig.json``, keeping the previous file as a backup.

The plate cannot measure a light's radius: a highlight's size is the plate's roughness
and the light's extent together, and the roughness of a printed, laminated plate is not
known well enough to separate them. ``radius_m`` stays what ``rig.json`` says (the user
measures the lamp).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._atomic import backup_path, write_atomic
from .._checks import check_views
from ..errors import FileFormatError, LightError, RigError
from ..geometry import MAX_LIGHTS, CameraRig, RigLight
from ..io import IMAGE_EXTENSIONS, read_image
from .board import Board
from .correspondence import (
    DEFAULT_MATCH_TOLERANCE_PX,
    CaptureMatch,
    HighlightGrouping,
    group_highlights,
    leave_out_contradicted_sets,
    match_captures,
)
from .light import (
    DEFAULT_MAX_INCIDENCE_DEG,
    DEFAULT_MAX_RESIDUAL_M,
    DEFAULT_MIN_VIEWS,
    LightEstimate,
    check_positive,
    incidence_check,
    light_from_reflections,
)
from .photometric import photometric_light, photometric_lights, with_photometric
from .plate_highlights import find_plate_highlight_candidates, find_plate_highlights
from .plate_pose import DEFAULT_MAX_REPROJECTION_PX, estimate_plate_pose

__all__ = [
    "estimate_light",
    "estimate_lights",
    "LightsEstimate",
    "read_capture",
    "calibrate_light_files",
    "LightCalibration",
]

_log = logging.getLogger(__name__)

# What a user can do when lamps close together merge their highlights on the plate.
ONE_LAMP_AT_A_TIME = ("calibrate each lamp alone, the others switched off "
                      "(calibrate_light_files(light=K), or calibrate-light --light K)")

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
    photometric: bool = True,
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
    (:func:`light_from_reflections`). Last, each capture's highlight is read as SRDE reads
    an object, its lobe fitted over every view, and the light it shows is mirrored back
    across the plate's pose from the markers (:mod:`~srde_fusion.calibration.photometric`):
    the blob centres are biased by the lobe's shape, the lobe fit much less.

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
    photometric : bool
        Move the light to the mean of the lights the captures' highlight images show
        (captures SRDE cannot read are left out, with their reason in
        ``LightEstimate.photometric``; with none, the ray solve's light stays).
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
        plate, under a marker, cut by the edge), or inconsistent rays. With several
        captures, one that fails these checks is left out instead (its reason in
        ``LightEstimate.skipped_captures``) and only none usable is an error.
    ImageError, FileFormatError
        Views that do not fit the rig, or unreadable capture folders.
    """
    _check_calibration_inputs(captures, rig, board, min_views)
    max_incidence_deg = check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = check_positive(max_residual_m, "max_residual_m")
    poses, centers, reasons, captured, used, skipped = [], [], [], [], [], []
    for c, capture in enumerate(captures):
        try:
            label, views, pose = _capture_pose(c, capture, rig, board, min_marker_views,
                                               max_reprojection_px, max_incidence_deg)
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
        except LightError as exc:
            # One plate pose that shows too little (a highlight under a marker in one of
            # a stereo pair's views) does not cost the others; the reason is kept.
            if len(captures) == 1:
                raise
            skipped.append(str(exc))
            continue
        captured.append(views)
        poses.append(pose)
        centers.append(found)
        reasons.append(why)
        used.append(c)
    if not poses:
        raise LightError(f"captures: expected at least one capture showing the plate and a "
                         f"usable highlight, got none of {len(captures)}: "
                         + "; ".join(skipped))
    estimate = light_from_reflections(
        poses,
        centers,
        rig,
        refine=refine,
        view_reasons=reasons,
        max_incidence_deg=max_incidence_deg,
        max_residual_m=max_residual_m,
    )
    estimate = replace(estimate, capture_indices=tuple(used), skipped_captures=tuple(skipped))
    if not photometric:
        return estimate
    # The plate poses from the markers alone: the joint refinement bent them towards the
    # biased centres.
    return with_photometric(estimate, photometric_light(estimate.position_m, captured, poses,
                                                        rig, board), rig)


def _check_calibration_inputs(captures: Any, rig: Any, board: Any, min_views: Any) -> None:
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


def _capture_pose(c: int, capture: Any, rig: CameraRig, board: Board, min_marker_views: int,
                  max_reprojection_px: float, max_incidence_deg: float):
    """Read one capture and find its plate: ``(label, views, pose)``."""
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
    return label, views, pose


@dataclass(frozen=True, eq=False)
class LightsEstimate:
    """Several lights found from plate captures, and how their highlights were sorted.

    Attributes
    ----------
    lights : tuple of LightEstimate
        One per light, ordered by x (left to right in the array frame); each with its
        own residuals and uncertainty, exactly as a single light's.
    groupings : tuple of HighlightGrouping
        Per capture, its highlights sorted into sets, one per light seen (the evidence:
        virtual lights and reprojection residuals).
    matches : tuple of CaptureMatch
        Per capture, which light each of its sets was assigned to (indices into
        ``lights``), with the ray distances of that assignment and of the runner-up.
    view_notes : tuple of tuple of tuple of str
        Per capture and view, the highlights found but not used, and why.
    left_out : tuple of str
        Highlight sets matched to a light but contradicted by the light's other captures,
        left out (:func:`~.correspondence.leave_out_contradicted_sets`), and why.
    """

    lights: tuple[LightEstimate, ...]
    groupings: tuple[HighlightGrouping, ...]
    matches: tuple[CaptureMatch, ...]
    view_notes: tuple[tuple[tuple[str, ...], ...], ...]
    left_out: tuple[str, ...] = ()

    @property
    def n_lights(self) -> int:
        """Number of lights found."""
        return len(self.lights)

    @property
    def positions_m(self) -> np.ndarray:
        """Light positions, ``(L, 3)`` float64, metres."""
        return np.array([est.position_m for est in self.lights])

    def summary(self) -> str:
        """Describe every light and the evidence of the assignment, in a few lines each."""
        lines = [f"{self.n_lights} light(s) from {len(self.groupings)} plate pose(s)"]
        for c, (grouping, match) in enumerate(zip(self.groupings, self.matches, strict=True)):
            sets = ", ".join(
                f"light {k}: {len(s.views)} views, {s.residual_px:.2f} px"
                for s, k in zip(grouping.sets, match.lights, strict=True))
            runner = ("" if not np.isfinite(match.runner_up_distance_m) else
                      f"; next best assignment {match.runner_up_distance_m * 1000:.1f} mm")
            lines.append(f"capture {c}: {sets} (rays meet within "
                         f"{match.ray_distance_m * 1000:.1f} mm{runner})")
        lines += [f"left out: {note}" for note in self.left_out]
        for k, est in enumerate(self.lights):
            lines.append(f"light {k}:")
            lines += ["  " + line for line in est.summary().splitlines()]
        return "\n".join(lines)


#: Most lights read from the highlights' images (``photometric``); with more, the rays'
#: lights stay. The plate's one fitted plane moves every light by the same two mirrors,
#: so the images correct what the lights' errors share. On 31 rendered two-lamp layouts
#: that made SRDE's masked EPE on objects lit by those lamps better in 22 (mean 0.0118 ->
#: 0.0062 px, 0.0050 px with the true lights); on 21 three-lamp layouts, in 9 (mean
#: 0.0132 -> 0.0131 px, median 0.0065 -> 0.0098): there the rays decide
#: (``benchmarks/light_calibration_multi.py``, its downstream table).
MAX_IMAGE_READ_LIGHTS = 2


def estimate_lights(
    captures: Sequence[Any],
    rig: CameraRig,
    board: Board,
    *,
    n_lights: int | None = None,
    method: str = "blob",
    refine: bool = True,
    photometric: bool = True,
    min_views: int = DEFAULT_MIN_VIEWS,
    min_marker_views: int = 1,
    max_incidence_deg: float = DEFAULT_MAX_INCIDENCE_DEG,
    max_residual_m: float = DEFAULT_MAX_RESIDUAL_M,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
    match_tolerance_px: float = DEFAULT_MATCH_TOLERANCE_PX,
    **detector_options: Any,
) -> LightsEstimate:
    """Calibrate several lights from captures of the ArUco plate showing several highlights.

    For each capture: the plate pose from the markers; every highlight on the plate in
    every view (:func:`find_plate_highlight_candidates`); the highlights sorted into one
    set per light by triangulating their virtual lights (:func:`group_highlights`). The
    sets of all captures are assigned to the lights by their reflected rays
    (:func:`match_captures`: each light is one point the rays of its sets must meet), and
    a set its light's other captures contradict is left out
    (:func:`~.correspondence.leave_out_contradicted_sets`, named in ``left_out``).
    Then each light is solved as :func:`estimate_light` solves one
    (:func:`light_from_reflections`), with the same residuals and uncertainty. Then, with
    ``photometric`` and at most :data:`MAX_IMAGE_READ_LIGHTS` lights, each capture is read
    from its highlights' images as :func:`estimate_light` reads one light's: SRDE, told of
    the rays' lights, fits one lobe per light on the plate's free centre, and the fitted
    plane ``P'`` gives each light the capture shows ``mirror(mirror(L, P'), P)`` across the
    markers' pose ``P`` (:func:`~.photometric.photometric_lights`). One fitted plane per
    capture cannot move the lights apart, so with three or more lamps the rays decide.
    (Reading each light alone, on the part of the plate nearer its own highlight, made 8 of
    10 lights worse on 7 rendered layouts: the other lamps' lobes are beside it.)

    Parameters
    ----------
    captures : sequence of (sequence of images, or folder path)
        As for :func:`estimate_light`. At least one capture must show every light in
        ``min_views`` views; others may show some of them.
    rig : CameraRig
    board : Board
    n_lights : int, optional
        Number of lights; by default counted: then every capture must show the same
        number of highlight sets (lamps whose highlights merge in some captures would
        otherwise count as a phantom light between them).
    method, refine, photometric, min_views, min_marker_views, max_incidence_deg,
    max_residual_m, max_reprojection_px, **detector_options
        As for :func:`estimate_light` (``min_views``: per light and capture; ``photometric``:
        with at most :data:`MAX_IMAGE_READ_LIGHTS` lights);
        ``max_residual_m`` also bounds the ray distance of an accepted assignment.
    match_tolerance_px : float
        Largest distance of a highlight from the image of the virtual light it joins.

    Returns
    -------
    LightsEstimate

    Raises
    ------
    LightError
        As :func:`estimate_light`; when counting finds one light whose highlight no
        capture's lobe fit confirms (merged highlights of close lamps); and highlights
        that cannot be sorted without a guess:
        two equally supported highlight sets sharing highlights, more highlight sets than
        lights, no capture showing every light, a capture whose sets fit no assignment
        or two of them, a light seen in one capture only (of two or more), two lights
        never seen in one view of any capture (one may be the merged highlight of two
        lamps), or, when counting, captures that show different numbers of lights.
    """
    _check_calibration_inputs(captures, rig, board, min_views)
    if n_lights is not None and (isinstance(n_lights, bool) or not isinstance(n_lights, int)
                                 or not 1 <= n_lights <= MAX_LIGHTS):
        raise LightError(f"n_lights: expected an integer in [1, {MAX_LIGHTS}] or None "
                         f"(detect), got {n_lights!r}")
    max_incidence_deg = check_positive(max_incidence_deg, "max_incidence_deg")
    max_residual_m = check_positive(max_residual_m, "max_residual_m")
    match_tolerance_px = check_positive(match_tolerance_px, "match_tolerance_px")
    poses, groupings, notes, captured = [], [], [], []
    for c, capture in enumerate(captures):
        label, views, pose = _capture_pose(c, capture, rig, board, min_marker_views,
                                           max_reprojection_px, max_incidence_deg)
        captured.append(views)
        candidates, why = find_plate_highlight_candidates(
            views, rig, board, pose, max_per_view=n_lights or MAX_LIGHTS, method=method,
            **detector_options)
        grouping = group_highlights(candidates, rig, pose, min_views=min_views,
                                    tolerance_px=match_tolerance_px)
        if not grouping:
            raise LightError(f"{label}: {grouping.reason}")
        poses.append(pose)
        groupings.append(grouping)
        notes.append(why)
    k = n_lights or max(len(g.sets) for g in groupings)
    if k == 0:
        details = "; ".join(n for per_view in notes for note in per_view for n in [note])
        raise LightError(
            f"highlights: expected one highlight of a light in at least {min_views} views of "
            f"a capture, got none{': ' + details if details else ''}")
    counts = [len(g.sets) for g in groupings]
    if n_lights is None and len(set(counts)) > 1:
        # Highlights of lamps close together merge into one blob in some views or plate
        # poses and not in others; the merged blob is consistent with a phantom light
        # between them. A count that varies between captures is that, or a light lost
        # under a marker: either way the count is not known.
        raise LightError(
            f"lights: expected every capture to show the same number of lights when counting "
            f"them, got {counts} highlight sets per capture (highlights of lamps close "
            f"together merge, or sit on a marker); give the number of lights, or "
            f"{ONE_LAMP_AT_A_TIME}")
    matches, reason = match_captures([g.sets for g in groupings], poses, rig, k,
                                     max_ray_distance_m=max_residual_m)
    if reason:
        if max(counts) < k:
            # No capture shows every lamp apart: close lamps merge on every plate pose.
            reason += (f" (a lamp whose highlight misses the plate's free centre needs "
                       f"other plate poses; lamps close together merge their highlights on "
                       f"every pose: {ONE_LAMP_AT_A_TIME})")
        raise LightError(reason)
    groupings, matches, left_out = leave_out_contradicted_sets(
        groupings, matches, poses, rig, k, refine=refine, max_residual_m=max_residual_m)
    if len(groupings) >= 2:
        # A light seen in one capture only was never checked against another plate pose.
        seen = [sum(light in m.lights for m in matches) for light in range(k)]
        lonely = [light for light in range(k) if seen[light] < 2]
        if lonely:
            only = [c for c, m in enumerate(matches) if lonely[0] in m.lights]
            why_lonely = [f"; its set in capture {c} was left out: {note}"
                          for c, j, _, note in left_out if j == lonely[0]]
            raise LightError(
                f"lights: expected every light in at least 2 of the {len(groupings)} captures "
                f"(so that its rays are checked across plate poses), got a light seen only in "
                f"capture {only[0]}{''.join(why_lonely[:1])}; add captures that show it, or check "
                f"the number of lights")
    apart = _never_in_one_view(groupings, matches, k, rig.n_cameras)
    if apart is not None:
        # Two lamps whose highlights merge in some views give a blob whose centre is the
        # image of a point between them, consistent across views and plate poses as a
        # lamp's: told three lamps, the merged blob of two of them came back as a light
        # 0.13 m from both, its rays meeting within 0.4 mm, and it was never seen in a
        # view where the lamp beside it showed on its own. Lamps whose highlights share the
        # plate's free centre show in common views.
        a, b = apart
        where = "; ".join(
            f"capture {c}: " + ", ".join(
                f"{'first' if j == a else 'second'} in views {list(st.views)}"
                for st, j in zip(g.sets, m.lights, strict=True) if j in (a, b))
            for c, (g, m) in enumerate(zip(groupings, matches, strict=True))
            if a in m.lights or b in m.lights)
        raise LightError(
            f"lights: expected every two lights to show in a common view of some capture, "
            f"got two that never do ({where}): one of them may be the merged highlight of "
            f"two lamps (a light between them); add captures where both show apart, "
            f"check the number of lights, or {ONE_LAMP_AT_A_TIME}")
    estimates = []
    for light in range(k):
        centers, reasons = [], []
        for c, (grouping, match, per_view) in enumerate(zip(groupings, matches, notes,
                                                             strict=True)):
            found = [s for s, j in zip(grouping.sets, match.lights, strict=True) if j == light]
            cc = found[0].centers_px if found else np.full((rig.n_cameras, 2), np.nan)
            centers.append(cc)
            set_left_out = {v: note for at, j, views, note in left_out
                            if (at, j) == (c, light) for v in views}
            reasons.append(tuple(
                "" if np.all(np.isfinite(cc[v])) else
                "; ".join((f"{rig.camera_names[v]}: "
                           + (f"set left out: {set_left_out[v]}" if v in set_left_out
                              else "no highlight of this light"),) + per_view[v])
                for v in range(rig.n_cameras)))
        try:
            estimates.append(light_from_reflections(
                poses, centers, rig, refine=refine, view_reasons=reasons,
                max_incidence_deg=max_incidence_deg, max_residual_m=max_residual_m))
        except LightError as exc:
            raise LightError(f"light {light}: {exc}") from None
    if photometric and k <= MAX_IMAGE_READ_LIGHTS:
        # Every capture is read as estimate_light reads one lamp's: SRDE told of the rays'
        # lights fits one lobe per light on the plate's one plane.
        fits = photometric_lights(np.array([e.position_m for e in estimates]), captured, poses,
                                  rig, board, [m.lights for m in matches])
        if k == 1 and n_lights is None and fits[0].n_used == 0:
            # One lamp's lobe described every capture of a single rendered lamp (even on
            # rough plates, under a 12 mm lamp) and none of lamps 4-8 cm apart whose
            # highlights merge, which counting takes for one lamp between them.
            raise LightError(
                f"lights: counted one light, but its highlight fits one lamp's lobe in none "
                f"of the {len(poses)} captures ({fits[0].reasons[0]}); lamps close together "
                f"whose highlights merge into one blob look like this: give the number of "
                f"lights (with one, the rays' light is kept), or {ONE_LAMP_AT_A_TIME}")
        estimates = [with_photometric(e, fit, rig, shared_move=k > 1)
                     for e, fit in zip(estimates, fits, strict=True)]
    # Lights left to right (then top to bottom): an order that does not depend on which
    # capture happened to fix the numbering.
    order = sorted(range(k), key=lambda j: tuple(estimates[j].position_m[:2]))
    new_index = {old: new for new, old in enumerate(order)}
    matches = tuple(replace(m, lights=tuple(new_index[j] for j in m.lights)) for m in matches)
    return LightsEstimate(tuple(estimates[j] for j in order), tuple(groupings), matches,
                          tuple(notes),
                          tuple(f"capture {c}, light {new_index[j]}: set left out, {note}"
                                for c, j, _, note in left_out))


def _never_in_one_view(groupings: Sequence[HighlightGrouping],
                       matches: Sequence[CaptureMatch], k: int, n_views: int
                       ) -> tuple[int, int] | None:
    """Return two lights whose highlights share no view of any capture, or None."""
    together = np.zeros((k, k), dtype=int)
    for grouping, match in zip(groupings, matches, strict=True):
        seen = np.zeros((k, n_views), dtype=int)
        for highlight_set, light in zip(grouping.sets, match.lights, strict=True):
            seen[light] = highlight_set.candidates >= 0
        together += seen @ seen.T
    pairs = np.argwhere(np.triu(together == 0, 1))
    return (int(pairs[0][0]), int(pairs[0][1])) if len(pairs) else None


@dataclass(frozen=True)
class LightCalibration:
    """What :func:`calibrate_light_files` found and wrote.

    Attributes
    ----------
    estimate : LightEstimate
        The (first) light and its residuals.
    rig : CameraRig
        The rig with the lights set.
    backup : pathlib.Path or None
        Where the previous ``rig.json`` was kept; None when nothing was written.
    lights : LightsEstimate or None
        With several lights, all of them and how their highlights were sorted; None when
        one light was calibrated the single-light way.
    light_index : int or None
        The one light of ``rig.lights`` calibrated alone (``calibrate_light_files(light=)``),
        the others written back as they were; None otherwise.
    """

    estimate: LightEstimate
    rig: CameraRig
    backup: Path | None = None
    lights: LightsEstimate | None = None
    light_index: int | None = None

    @property
    def estimates(self) -> tuple[LightEstimate, ...]:
        """Every light's estimate calibrated here, in the order of ``rig.lights``.

        One light calibrated alone (``light_index``) gives its estimate only.
        """
        return (self.estimate,) if self.lights is None else self.lights.lights


def _calibrated_lights(rig: CameraRig, positions_m: np.ndarray) -> tuple[tuple[RigLight, ...],
                                                                        list[int]]:
    """Move the rig's lights to calibrated positions; say which estimate each one took.

    When the rig already lists as many lights, each keeps its name and radius (which the
    plate cannot measure) and takes the nearest estimate (a one-to-one assignment of
    least total distance); otherwise the lights are new, unnamed, radius unknown.
    """
    k = len(positions_m)
    if len(rig.lights) != k:
        if rig.lights:
            _log.warning("rig lists %d light(s), the calibration found %d: names and radii "
                         "are dropped", len(rig.lights), k)
        return tuple(RigLight(tuple(p)) for p in positions_m), list(range(k))
    old = rig.light_positions_m
    cost = np.linalg.norm(old[:, None] - positions_m[None], axis=2)
    rows, cols = linear_sum_assignment(cost)
    take = [int(cols[list(rows).index(i)]) for i in range(k)]
    return tuple(replace(light, position_m=tuple(float(v) for v in positions_m[j]))
                 for light, j in zip(rig.lights, take, strict=True)), take


def calibrate_light_files(
    capture_dirs: Sequence[str | os.PathLike],
    board_path: str | os.PathLike,
    rig_path: str | os.PathLike,
    *,
    write: bool = True,
    n_lights: int | str | None = None,
    light: int | str | None = None,
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
    n_lights : int, "auto" or None
        Lights to calibrate: a number, ``"auto"`` (as many as the captures show), or
        None: as many as ``rig.json`` lists (one if none). One light is calibrated with
        :func:`estimate_light`, several with :func:`estimate_lights`; lights already in
        ``rig.json`` keep their names and radii.
    light : int, str or None
        Calibrate one lamp of several from captures that show it alone (the other lamps
        switched off): the index of one of the lights ``rig.json`` lists, its name, or
        the number of lights it lists to add a new one. A string is a name first: digits
        that name no light are an index. That light is calibrated the
        single-light way and keeps its name and radius; the other lights are written
        back as they were. Lamps so close that their highlights merge on the plate
        cannot be told apart in one capture; calibrated one at a time they can. Not
        with ``n_lights`` (other than 1).
    **options
        Keyword options of :func:`estimate_light` / :func:`estimate_lights`
        (``photometric`` applies to up to :data:`MAX_IMAGE_READ_LIGHTS` lights: more are
        solved from their rays).

    Returns
    -------
    LightCalibration
        The estimates, the rig with the lights set, and the backup of the old file.
    """
    rig = CameraRig.from_json(rig_path)
    board = Board.from_json(board_path)
    if light is not None:
        if n_lights not in (None, 1):
            raise LightError(f"light and n_lights: one lamp is calibrated alone (light="
                             f"{light!r}), expected n_lights None or 1, got {n_lights!r}")
        index = _light_index(rig, light)
        # The captures show this lamp alone: SRDE reading the plate is told of it only
        # (with its radius, if rig.json gives one).
        alone = rig.with_lights(rig.lights[index:index + 1])
        options.pop("match_tolerance_px", None)
        estimate = estimate_light(list(capture_dirs), alone, board, **options)
        position = tuple(float(v) for v in estimate.position_m)
        lights = list(rig.lights)
        if index < len(lights):
            lights[index] = replace(lights[index], position_m=position)
        else:
            lights.append(RigLight(position))
        new_rig = rig.with_lights(lights)
        return LightCalibration(estimate, new_rig, _write_rig(new_rig, rig_path, write),
                                light_index=index)
    if n_lights is None:
        n_lights = max(len(rig.lights), 1)
    elif n_lights != "auto" and (isinstance(n_lights, bool) or not isinstance(n_lights, int)):
        raise LightError(f"n_lights: expected a number of lights, 'auto' or None, got "
                         f"{n_lights!r}")
    if n_lights == 1:
        # One light has no highlights to sort: the matching tolerance does not apply.
        options.pop("match_tolerance_px", None)
        estimate = estimate_light(list(capture_dirs), rig, board, **options)
        lights, found = _calibrated_lights(rig, estimate.position_m[None])
        multi = None
    else:
        multi = estimate_lights(list(capture_dirs), rig, board,
                                n_lights=None if n_lights == "auto" else n_lights, **options)
        lights, take = _calibrated_lights(rig, multi.positions_m)
        multi = replace(multi, lights=tuple(multi.lights[j] for j in take),
                        matches=tuple(replace(m, lights=tuple(take.index(j) for j in m.lights))
                                      for m in multi.matches))
        estimate = multi.lights[0]
    new_rig = rig.with_lights(lights)
    return LightCalibration(estimate, new_rig, _write_rig(new_rig, rig_path, write), multi)


def _light_index(rig: CameraRig, light: Any) -> int:
    """Return the index ``light`` names: an index, a name, or ``len(rig.lights)`` (a new one).

    A string is a light's name; one of digits that names no light is an index (as the
    command line gives it), so a light named "2" is found by its name.
    """
    names = [lt.name for lt in rig.lights]
    if isinstance(light, str):
        if names.count(light) == 1:
            return names.index(light)
        if light.isascii() and light.isdigit() and light not in names:
            return _light_index(rig, int(light))
        known = [n for n in names if n]
        raise LightError(f"light: expected the name of one of the rig's lights "
                         f"({', '.join(map(repr, known)) if known else 'none is named'}) or "
                         f"an index, got {light!r}")
    if isinstance(light, bool) or not isinstance(light, (int, np.integer)) \
            or not 0 <= light <= len(names):
        which = (f"an index 0-{len(names) - 1} of the rig's {len(names)} light(s), or "
                 f"{len(names)} to add one" if names else "0 to add the rig's first light")
        raise LightError(f"light: expected {which}, got {light!r}")
    if len(names) >= MAX_LIGHTS and light == len(names):
        raise LightError(f"light: the rig already lists {len(names)} lights, the most it "
                         f"can hold; expected an index 0-{len(names) - 1}, got {light!r}")
    return int(light)


def _write_rig(new_rig: CameraRig, rig_path: str | os.PathLike, write: bool) -> Path | None:
    """Write ``new_rig`` over ``rig_path``, keeping the old file; the backup's path or None."""
    if not write:
        return None
    path = Path(rig_path)
    backup = backup_path(path)
    try:
        old = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"{backup}: could not back up {path.name}: {exc}") from None
    # The backup is written like every other file: whole or not at all.
    write_atomic(backup, old)
    new_rig.to_json(path)
    return backup
