"""SRDE with several known lights: candidates, their assignment, and the lobes' verdict.

:func:`estimate_with_lights` is :meth:`SRDE.estimate`'s path when the rig knows two or
more lights: the candidates of every view (:mod:`.candidates`) are matched to the lights
by geometry (:mod:`.assignment`), and the plane goes through the single light's checks
and photometric refinement with one lobe per light whose highlights it reads. Where the
centres cannot decide (blobs of several lights merged, two planes explaining them alike,
highlights it predicts missing) the joint lobe fit from each hypothesis decides, or the
object fails with its reason.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from .._checks import check_point3
from ..errors import LightError
from ..geometry import MAX_LIGHTS, CameraRig, Plane, project_points
from .assignment import (
    BLEND_RADII,
    SAME_PLANE_PX,
    AssignmentContext,
    LightAssignment,
    LightsSolution,
    assign_lights,
    box_corners,
    plane_gap_px,
)
from .candidates import ViewCandidates, gather_candidates
from .highlight import HighlightDetection, detect_in_view
from .refine.samples import WINDOW_PER_BLOB_RADIUS
from .search import BaselineSearch

if TYPE_CHECKING:
    from .estimator import SRDE
    from .result import SRDEResult

__all__ = [
    "check_lights",
    "dark_lamps",
    "estimate_with_lights",
    "lobes_prefer",
    "near_lights",
]


#: A plane from the joint lobe fit (settled where the blob centres could not settle one)
#: is refused when the centres' evidence against it outweighs what it explains by this
#: ratio: merged and outline-cut blobs leave stray pieces the lobes account for, so the
#: centres' verdict counts less than for a plane from the centres
#: (:data:`~.assignment.UNEXPLAINED_RATIO`). A correct plane of four lights with one
#: merged blob had 7 strays against 10 explained; a three-face object flattened into one
#: plane 7.9 px off, 17 against 7.
LOBE_FIT_UNEXPLAINED_RATIO = 1.0


#: A refined plane (one light's lobe) is kept only if every light's assigned highlight
#: stays within this many times the assignment tolerance of where it puts it.
REFINED_AGREEMENT = 1.0


#: A refined several-light plane with a larger disparity standard error (pixels) is not
#: an answer: the assignment of highlights to lights is then not established either.
LIGHTS_MAX_SIGMA_PX = 0.1


#: Two planes fitted to merged blobs from different starts: one is the answer if its
#: photometric cost is this many times lower than the other's on both fits' samples.
DECISIVE_COST_RATIO = 2.0


# ---------------------------------------------------------------------- in SRDE
def check_lights(lights: Any) -> np.ndarray:
    """Validate one light ``(3,)`` or several ``(K, 3)`` (metres); return ``(K, 3)`` float64."""
    try:
        arr = np.asarray(lights, dtype=np.float64)
    except (TypeError, ValueError):
        raise LightError(f"light: expected 3 numbers (x, y, z) in metres, got {lights!r:.80}; "
                         "several lights are K rows of them") from None
    if arr.ndim == 1:
        return check_point3(arr, "light")[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3 or not 1 <= len(arr) <= MAX_LIGHTS:
        raise LightError(f"light: expected (x, y, z) in metres or (K, 3) with 1 <= K <= "
                         f"{MAX_LIGHTS}, got an array of shape {arr.shape}")
    for i, row in enumerate(arr):
        check_point3(row, f"light[{i}]")
    return arr


def estimate_with_lights(srde: SRDE, views, mask: np.ndarray, search: np.ndarray, *,
                         gathered: ViewCandidates | None = None) -> SRDEResult:
    """:meth:`SRDE.estimate` with several known lights (``srde.lights_m``).

    Candidates in the reference search region and, in every other view, in the band
    where a highlight of the object can appear for any light; :func:`~.assignment.assign_lights`
    matches them to the lights and fits the plane. The plane then goes through the same
    checks (and, with ``srde.refine``, the same photometric refinement, on the
    highlights of the light seen in most views) as a single light's.

    With several lights, which light made a highlight is itself estimated: a refined
    plane whose disparity standard error exceeds :data:`LIGHTS_MAX_SIGMA_PX` is not
    pinned down by the images and the object is ``ambiguous`` (two faces alone were
    solved 10.3 and 1.0 px off with errors of 0.37 and 0.16 px; on the several-light
    benchmark every plane's error is below 0.03 px, and of the faces alone one correct
    plane, 0.10 px off with 0.104 px, is refused with them).

    ``gathered``: :func:`~.candidates.gather_candidates`' answer for ``search``, if the
    caller has it (the faces' estimate found it first); found here otherwise.
    """
    result = _estimate_with_lights(srde, views, mask, search, gathered)
    refinement = result.refinement
    if result.ok and refinement is not None and refinement.ok \
            and refinement.disparity_sigma_px > LIGHTS_MAX_SIGMA_PX:
        reason = (f"lights: the refined plane is not pinned down by the images (disparity "
                  f"standard error {refinement.disparity_sigma_px:.2f} px, limit "
                  f"{LIGHTS_MAX_SIGMA_PX:g} px): which light's highlights it fits is not "
                  "established"
                  + (f"; {result.lights.evidence}" if result.lights is not None
                     and result.lights.evidence else ""))
        return dataclasses.replace(srde._failed("ambiguous", reason), lights=result.lights,
                                   refinement=refinement)
    return result


def _estimate_with_lights(srde: SRDE, views, mask: np.ndarray, search: np.ndarray,
                          gathered: ViewCandidates | None) -> SRDEResult:
    rig = srde.rig
    ref = rig.reference
    if gathered is None:
        # None found by the caller means the reference view holds no candidate: the
        # other views' may still give the plane.
        gathered = gather_candidates(srde, views, search, anchor_free=True)
    if gathered is None:
        reason = detect_in_view(views[ref], search, srde.config).reason
        return srde._failed("no_highlight", f"{srde._view(ref)}: {reason}")
    found, cands, lit = gathered.found, gathered.centers_uv, gathered.lit
    blob_radius_px = gathered.blob_radius_px
    tolerance_px = 2.0 * srde.max_residual_px
    solution = assign_lights(rig, srde.lights_m, mask, cands, tolerance_px=tolerance_px,
                             min_views=srde.min_views, object_depth_m=srde.object_depth_m,
                             lit=lit, blob_boxes=[[d.bbox for d in dets] for dets in found],
                             blob_radius_px=blob_radius_px, near_outline=gathered.anchor_free)
    if not solution.ok:
        failed = dataclasses.replace(srde._failed(solution.status, solution.reason),
                                     lights=solution)
        if not srde.refine:
            return failed
        if solution.merged_blobs and solution.plane is not None \
                and solution.status in ("too_few_views", "ambiguous", "inconsistent"):
            result = _solve_merged(srde, views, mask, solution, failed, gathered)
            if not (result.ok or result.status == "ambiguous"):
                # Neither start led the lobes to a plane: the lights alone may.
                result = _solve_from_single_lights(srde, views, mask, solution, result,
                                                   gathered,
                                                   why="the merged-blob fit found no plane")
        elif solution.plane is None and solution.status == "too_few_views":
            result = _solve_from_single_lights(srde, views, mask, solution, failed, gathered)
        elif solution.status in ("ambiguous", "inconsistent") \
                and solution.rival_plane is not None:
            result = _solve_ambiguous(srde, views, mask, solution, failed, gathered)
        else:
            return failed
        return _no_highlights_left_out(srde, mask, gathered, result, failed)
    doubted = _if_a_lamp_is_dark(srde, mask, gathered, solution)
    if doubted is not None:
        return doubted
    # The light seen in most views (then with the smallest residual) carries the checks
    # and the refinement; the joint plane mirrors it onto its own virtual light.
    main = max((a for a in solution.assignments if a.n_views),
               key=lambda a: (a.n_views, -float(np.nanmax(a.residuals_px))))
    used = np.isfinite(main.centers_uv[:, 0])
    notes = tuple(_missing_note(a) for a in solution.assignments if a.missing_views)
    point = main.virtual_light_m
    w = 1.0 / (point[2] - rig.reference_center_m[2])
    detections = tuple(
        next((d for d in found[j] if np.allclose(d.center_uv, main.centers_uv[j])),
             HighlightDetection.missing(f"no highlight of light {main.light}"))
        for j in range(rig.n_cameras))
    # Lights whose highlights come near the main one's are rendered with it (their lobes
    # reach into its windows), and so is every light with assigned highlights, whose
    # windows the fit also reads: each is another measurement of the same plane, and a
    # model error of one light's lobe (a highlight cut by the outline, a flank of another
    # light) no longer decides the plane alone. The other lights are left out of the
    # windows.
    near = near_lights(np.stack([a.on_object for a in solution.assignments]),
                       np.stack([a.predicted_uv for a in solution.assignments]), main.light,
                       blob_radius_px)
    modelled = [a.light for a in solution.assignments
                if a.light != main.light and (near[a.light] or a.n_views)]
    modelled_centers = np.stack([
        np.where(np.isfinite(solution.assignments[k].centers_uv[:, :1]),
                 solution.assignments[k].predicted_uv, np.nan) for k in modelled]
    ) if modelled else None
    # The lobes need no centre, only where the highlight is. When centres measured the
    # main light in fewer than half the views, its windows also go around its highlights
    # that the plane puts on the object but no centre measured (one blob with another
    # light's, or cut by the outline), though not where the view is dark there: the lobe
    # seen from those views pins the plane down where two to four views did not. (On
    # the 240 several-light scenes, 2-4 lights, the count was chosen on: 13 scenes better
    # by over 1e-4 px, 1 worse; on 120 more run after: 1 better, none worse. With most
    # views measured, the windows added brought as much model error as information: 13
    # scenes better, 15 worse.)
    windowed = used
    if 2 * int(used.sum()) < rig.n_cameras:
        windowed = used | (main.on_object & ~main.missing)
    window_centers = np.where(used[:, None], main.centers_uv,
                              np.where(windowed[:, None], main.predicted_uv, np.nan))
    result = srde._finish(mask, point, w, used, main.centers_uv, detections, notes,
                          views=views, light=srde.lights_m[main.light],
                          modelled_lights=[srde.lights_m[k] for k in modelled],
                          modelled_centers=modelled_centers, window_centers=window_centers)
    refinement = result.refinement
    if result.ok and refinement is not None:
        # If another light's plane explains the same centres (reflected near the outline,
        # where they did not count), the centres' lead is no answer, whether the
        # refinement confirms the plane or not: it fits the one light's lobe it is given,
        # and fitted the wrong light's lobe to another light's blobs as readily (faces
        # taken alone, 3.5 and 4.9 px off). The lobes of both decide between the two.
        context = gathered.context(srde, mask)
        best = context.score(solution.plane, at_least=1)
        same = None if best is None else context.same_centres_other_light(best)
        if same is not None:
            doubt = context.solution(best, same, same_centres=True)
            if not refinement.ok:
                doubt = dataclasses.replace(doubt, reason=(
                    f"{doubt.reason}; the photometric refinement did not confirm the best "
                    f"plane ({refinement.reason})"))
            failed = dataclasses.replace(srde._failed("ambiguous", doubt.reason), lights=doubt)
            return _no_highlights_left_out(srde, mask, gathered,
                                           _solve_ambiguous(srde, views, mask, doubt, failed,
                                                            gathered),
                                           failed)
        explained = solution.explained_lights
        if not refinement.ok and len(explained) == 1:
            # One light's highlights, and the images do not confirm the plane: only the
            # blob centres give them to that light, and pulled centres of large blobs gave
            # a face taken alone to another light's plane 16 px off. A single light's
            # geometric plane may stand; here, as for a face (faces.py), it does not.
            reason = (f"lights: the photometric refinement did not confirm the plane that "
                      f"gives the highlights to light {explained[0]} ({refinement.reason}), "
                      f"and with {len(srde.lights_m)} lights known their centres alone do "
                      f"not say whose they are; {solution.evidence}")
            doubt = dataclasses.replace(solution, status="inconsistent", reason=reason)
            return dataclasses.replace(srde._failed("inconsistent", reason,
                                                    plane=result.plane), lights=doubt)
    if result.ok and refinement is not None and refinement.ok:
        # The refinement sees the lights' highlights near their centres; every light's
        # assigned centres must still agree with its plane, else the joint geometric
        # plane stands.
        worst_px = _worst_reprojection_px(rig, srde.lights_m, solution, result.plane)
        limit_px = REFINED_AGREEMENT * tolerance_px
        if worst_px > limit_px and solution.merged_blobs:
            # Blob centres and blob light disagree where some blobs are merged: the few
            # centres that measure a light may be the wrong ones. Only the lobes' fit
            # from the best plane and from its rival, agreeing, settles it.
            reason = (f"lights: the plane of {solution.n_observations} highlight centre(s) "
                      f"and the photometric fit disagree by up to {worst_px:.1f} px (limit "
                      f"{limit_px:g} px) with {len(solution.merged_blobs)} merged blob(s); "
                      + solution.evidence)
            doubt = dataclasses.replace(solution, status="inconsistent", reason=reason)
            return _lobes_checked(srde, mask, gathered, _solve_merged(
                srde, views, mask, doubt, dataclasses.replace(
                    srde._failed("inconsistent", reason), lights=doubt), gathered))
        if worst_px > limit_px and lobes_prefer(srde, views, mask, main.light, modelled,
                                                main.on_object, refinement.plane,
                                                solution.plane):
            # Centres cut by the outline or pulled by a neighbour's flank can tilt the joint
            # plane while the lobes, which model both, settle it: the refined plane stands
            # when it explains the images decisively better on both planes' samples.
            note = (f"refinement: the refined plane misses light highlights by up to "
                    f"{worst_px:.1f} px (limit {limit_px:g} px) but explains the images "
                    f"{DECISIVE_COST_RATIO:g}x better than the joint plane; it stands")
            result = dataclasses.replace(result, notes=(*result.notes, note))
            return _lobes_checked(srde, mask, gathered, dataclasses.replace(
                result, lights=_solved_on(srde, mask, solution, result.plane, gathered)))
        if worst_px > limit_px:
            note = (f"refinement: kept the joint plane; the refined plane misses light "
                    f"highlights by up to {worst_px:.1f} px (limit {limit_px:g} px)")
            result = srde._finish(mask, point, w, used, main.centers_uv, detections,
                                  (*notes, note), views=views, light=srde.lights_m[main.light],
                                  refine=False)
            result = dataclasses.replace(result, refinement=refinement)
    return dataclasses.replace(result, lights=solution)


def _no_highlights_left_out(srde: SRDE, mask: np.ndarray, gathered: ViewCandidates,
                            result: SRDEResult, failed: SRDEResult) -> SRDEResult:
    """Refuse a joint-lobe-fit plane that leaves out highlights another plane explains.

    First, a plane whose reading needs a listed lamp dark where another reading explains
    as much is ``ambiguous`` (:func:`_lobes_checked`).

    The lobe fit settles objects whose blob centres no plane explains cleanly; it cannot
    see highlights it does not model. If a plane hypothesis explains one light's
    highlights in ``min_views`` views that the fitted plane accounts for in none (neither
    explains, nor predicts a highlight in or within a few blob radii of those blobs;
    :func:`~.faces.unexplained_plane`), the object holds a second flat face (or another
    surface) and one plane is the wrong answer: ``inconsistent``, with a note to ask for
    faces. Two faces of a faceted object, each lit, were otherwise solved as one plane
    0.9 and 7.9 px off on a face. So is a plane with more evidence against it than it
    explains (:data:`LOBE_FIT_UNEXPLAINED_RATIO`; a plane from the centres is refused at
    half, rule 10): a three-face object whose every face had a light of its own was
    solved as one plane 7.9 px off on a face, with 16 blobs on the object that no light
    explained.
    """
    if not result.ok:
        return result
    checked = _lobes_checked(srde, mask, gathered, result)
    if not checked.ok:
        return checked
    from .faces import unexplained_plane

    rig = srde.rig
    context = gathered.context(srde, mask)
    pool = [s for s in (context.score(p) for p in context.proposals()) if s is not None]
    pool += [s for s in (context.score(p) for p in context.proposals(loose=True))
             if s is not None]
    other = unexplained_plane(context, pool, [result.plane], srde.min_views)
    if other is None:
        # Scored whatever it explains: a plane that explains no blob at all, as a light's
        # highlight or as merged ones, is not let through on that account (a face of three,
        # alone, was solved 1.9 px off by a lobe fit whose plane put every light's
        # highlight off the object, or at its outline, while the centres saw six blobs on it
        # that no light explained).
        own = context.score(result.plane, at_least=0)
        if own is not None and own.support == 0:
            reason = ("lights: the joint lobe fit's plane explains none of the blobs on the "
                      "object (it puts every light's highlight off the object or at its "
                      "outline); another surface or face (SRDE(max_faces=2..3) splits flat "
                      "faces); " + "; ".join(result.notes[-1:]))
            return dataclasses.replace(failed, status="inconsistent", reason=reason)
        if own is None or not own.outweighed(LOBE_FIT_UNEXPLAINED_RATIO):
            return checked
        # The rule the centres' planes obey (10), with the lobes' benefit of the doubt:
        # a plane with more evidence against it than it explains is not the answer.
        reason = (f"lights: the joint lobe fit's plane has more evidence against it "
                  f"({own.n_missing} highlight(s) predicted on the object and not there, "
                  f"{own.n_strays} blob(s) on the object no light explains) than the "
                  f"{own.support} highlight(s) and merged blobs it explains (another surface or "
                  f"face: SRDE(max_faces=2..3) splits flat faces); "
                  + "; ".join(result.notes[-1:]))
        return dataclasses.replace(failed, status="inconsistent", reason=reason)
    gap_px = plane_gap_px(rig, box_corners(mask), other.plane, result.plane)
    reason = (f"lights: the joint lobe fit's plane leaves out highlights that another plane "
              f"({gap_px:.1f} px away) explains ({other.n_matched} highlight(s)): a second face "
              f"or surface (SRDE(max_faces=2..3) splits flat faces); "
              + "; ".join(result.notes[-1:]))
    return dataclasses.replace(failed, status="inconsistent", reason=reason)


def dark_lamps(on_object: np.ndarray, missing: np.ndarray, min_views: int) -> list[int]:
    """Lamps a reading needs dark: every highlight it puts on the object missing.

    ``on_object`` and ``missing`` ``(K, N)`` bool: where each lamp's highlight is predicted
    on the object, and where it is not there (the view dark there). A lamp needs to be
    dark when it is missing in ``min_views`` views or more and seen in none: not assigned
    a blob, nor bright inside a blob of merged highlights (a lamp whose highlight merges
    with another's is lit, though no centre measures it).
    """
    return [k for k in range(len(missing))
            if _seen_nowhere(on_object[k], missing[k])
            and np.count_nonzero(missing[k]) >= min_views]


def _seen_nowhere(on_object: np.ndarray, missing: np.ndarray) -> bool:
    """Whether a lamp is missing in every view where the plane puts it on the object ``(N,)``.

    (A view where it is assigned a blob, or bright inside a merged one, is on the object
    and not missing.)
    """
    return not np.any(on_object & ~missing)


def _if_a_lamp_is_dark(srde: SRDE, mask: np.ndarray, gathered: ViewCandidates,
                       solution: LightsSolution) -> SRDEResult | None:
    """Return ``ambiguous`` if the reading needs a lamp dark and another explains as much.

    See :func:`_dark_lamp_doubt`; None if the solution's reading stands.
    """
    doubt = _dark_lamp_doubt(srde, mask, gathered, solution)
    if not doubt:
        return None
    return dataclasses.replace(srde._failed("ambiguous", doubt), lights=dataclasses.replace(
        solution, status="ambiguous", reason=doubt))


def _lobes_checked(srde: SRDE, mask: np.ndarray, gathered: ViewCandidates,
                   result: SRDEResult) -> SRDEResult:
    """Return a plane the lobes settled, unless its reading needs a lamp dark as another's.

    The lobes see the blobs' light, not whether a lamp the rig lists is lit: from two
    readings that each need a lamp dark they pick one (a listed lamp switched off, two
    lamps: the plane that gives the lit lamp's blobs to the dark lamp was kept in 11 of
    22 solved objects). The plane's own assignment (:func:`_solved_on`) is asked as the
    centres' is, and a plane that stands is noted with the lamps it does not see where it
    puts them (:func:`_missing_note`).
    """
    if not result.ok or result.lights is None or result.lights.plane is None:
        return result
    doubted = _if_a_lamp_is_dark(srde, mask, gathered, result.lights)
    if doubted is None:
        # The same notes on lamps not seen where the plane puts them as the centres' path.
        missing = tuple(_missing_note(a) for a in result.lights.assignments
                        if a.missing_views)
        return dataclasses.replace(result, notes=(*result.notes, *missing))
    return dataclasses.replace(doubted, notes=result.notes, refinement=result.refinement)


def _dark_lamp_doubt(srde: SRDE, mask: np.ndarray, gathered: ViewCandidates,
                     solution: LightsSolution) -> str:
    """Why the plane's reading of the blobs is not established by a lamp it needs dark.

    A plane that gives every blob to one lamp and puts another lamp's highlights on the
    object where the view is dark, in ``min_views`` or more views and in every view
    where it puts them there (:func:`dark_lamps`), reads the images as that lamp
    switched off. The same blobs are also the image of one virtual light for
    every other lamp, on the plane that mirrors that lamp onto it
    (:meth:`~.assignment.AssignmentContext.other_lights_planes`). If such a plane
    explains as many blobs (highlights and merged blobs), as that lamp's, and needs no
    more lamps dark, the images do not say which lamp is lit: ``ambiguous`` (the reason
    says so), never the first reading. With two lamps listed and one switched off, the
    two readings are each other's mirror, and the one kept put the lit lamp's blobs on
    the dark lamp in 11 of 22 solved objects, 0.39-11.4 px off
    (``benchmarks/dark_lamp.py``).

    When the reference view holds no candidate (``gathered.anchor_free``), another lamp's
    reading that explains as many blobs leaves the lamp unestablished whatever lamps
    either reading needs dark: the blobs lie near the outline in a few views, a plane
    that gives them to one lamp puts the others' highlights off the object or into
    the dark reference view, and what tells the readings apart is only highlights
    missing, which a listed lamp that is off also explains. (With the last of two lamps
    off, such objects were solved 1.4-2.3 px off, their blobs given to the dark lamp,
    in 8 of 40 frames; readings that explain two lamps' highlights stand.)
    Returns "" when the reading stands.
    """
    explained = solution.explained_lights
    if len(explained) != 1:
        return ""
    dark = dark_lamps(np.stack([a.on_object for a in solution.assignments]),
                       np.stack([a.missing for a in solution.assignments]), srde.min_views)
    anchor_free = gathered.anchor_free
    if not dark and not anchor_free:
        return ""
    a = explained[0]
    context = gathered.context(srde, mask)
    support = solution.n_observations + len(solution.merged_blobs)
    for k, plane in context.other_lights_planes(solution.plane, a):
        score = context.score(plane, at_least=0)
        if score.explained_lights.tolist() != [k] or score.support < support:
            continue
        other_dark = dark_lamps(score.on_object, score.missing, srde.min_views)
        if len(other_dark) > len(dark) and not anchor_free:
            continue
        gap_px = context.plane_gap_px(plane, solution.plane)
        unseen = " and ".join(f"light {d}'s highlights in view(s) "
                              f"{list(solution.assignments[d].missing_views)}" for d in dark)
        reading = (f"light {k}'s on a plane {gap_px:.1f} px away"
                   + (" that needs " + " and ".join(f"light {d}" for d in other_dark)
                      + " dark instead" if other_dark else " that every lamp lit explains"))
        if not dark:
            return (f"lights: the reference view shows no highlight on the object, and the "
                    f"blobs of the other views are light {a}'s on the best plane and "
                    f"{reading}: which lamp made them is not established (only highlights "
                    f"missing tell the readings apart, and a listed lamp that is off "
                    f"explains those too); {solution.evidence}")
        return (f"lights: the blobs are light {a}'s on the best plane, which puts "
                f"{unseen} on the object where the view is dark (is that lamp switched off "
                f"or hidden?), and {reading}: which lamp made them is not established (list "
                f"only the lamps that are lit); {solution.evidence}")
    return ""


def _missing_note(assignment: LightAssignment) -> str:
    """Return the note on a light the plane puts on the object where it is not seen."""
    note = (f"light {assignment.light}: highlight expected on the object but not found in "
            f"view(s) {list(assignment.missing_views)}")
    if _seen_nowhere(assignment.on_object, assignment.missing):
        note += " (none of its highlights is seen: is the lamp switched off or hidden?)"
    return note


def near_lights(on_object: np.ndarray, predicted_uv: np.ndarray, main: int,
                blob_radius_px: float) -> np.ndarray:
    """Which lights' highlights reach into the main light's fitting windows, ``(K,)`` bool.

    A light is near when, in some view where both are predicted on the object
    (``on_object`` ``(K, N)``), its highlight lies within the window's reach plus
    :data:`~.assignment.BLEND_RADII` blob radii of the main one's (``predicted_uv`` ``(K, N, 2)``):
    its lobe's flank is in the windows, so the refinement renders it. The main light is
    not near itself.
    """
    reach_px = (WINDOW_PER_BLOB_RADIUS + BLEND_RADII) * blob_radius_px
    gaps = np.linalg.norm(predicted_uv - predicted_uv[main], axis=2)  # (K, N)
    near = np.any(on_object & on_object[main] & (gaps < reach_px), axis=1)
    near[main] = False
    return near


def _lobe_options(srde: SRDE, main: int, modelled: list[int],
                  behind: tuple[int, ...] = ()) -> dict:
    """Return ``refine_plane``'s light options with light ``main`` fitted.

    The ``modelled`` lights are rendered with it, every other light is cut out of its
    windows but those ``behind`` the plane (they light nothing on it).
    """
    lights = srde.lights_m
    others = [k for k in range(len(lights))
              if k != main and k not in modelled and k not in behind]
    return dict(lobe=srde.refine_lobe, other_lights_m=lights[others] if others else None,
                modelled_lights_m=lights[modelled] if modelled else None,
                light_radius_m=srde.light_radii_m[main], pixel_samples=srde.refine_pixels)


def lobes_prefer(srde: SRDE, views, mask: np.ndarray, main: int, modelled: list[int],
                 used: np.ndarray, refined: Plane, joint: Plane) -> bool:
    """Whether the refined plane explains the images decisively better than the joint one.

    Both planes' photometric costs on the samples placed for each in turn
    (``refine.plane.compare_planes``), with the same lights rendered as the refinement
    did: the refined plane must be at least :data:`DECISIVE_COST_RATIO` times cheaper on
    both. ``used`` ``(N,)`` bool: the views whose samples count (the main light's
    highlight on the object).
    """
    options = _lobe_options(srde, main, modelled)
    costs = _costs_on_samples(views, srde.rig, srde.lights_m, mask,
                              [(refined, main, used, options), (joint, main, used, options)])
    # (Both planes render the same lights here: a cost of inf is a plane that lights
    # nothing where the main light's highlight is, and counts against it.)
    return bool(costs[0, 1] > DECISIVE_COST_RATIO * costs[0, 0]
                and costs[1, 1] > DECISIVE_COST_RATIO * costs[1, 0])


def _plain_context(srde: SRDE, mask: np.ndarray, solution: LightsSolution) -> AssignmentContext:
    """Return the hypothesis machinery on the solution's blob centres alone.

    No brightness test and no blob boxes: predictions, and matches within the
    assignment's tolerance.
    """
    return AssignmentContext(srde.rig, srde.lights_m, mask, solution.candidates_uv, None,
                    2.0 * srde.max_residual_px, srde.object_depth_m, srde.min_views, 0.0)


def _lights_on_object(srde: SRDE, mask: np.ndarray, solution: LightsSolution,
                      starts: list[Plane]) -> list[np.ndarray] | None:
    """Each start's predicted on-object highlights ``(K, N)`` bool; None if one has none."""
    context = _plain_context(srde, mask, solution)
    presents = [context.predict(plane)[1] for plane in starts]
    return presents if all(p.any() for p in presents) else None


def _solve_merged(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                  failed: SRDEResult, gathered: ViewCandidates) -> SRDEResult:
    """Solve an object whose highlights are merged blobs by one lobe per light.

    No blob centre measures a light, but the blobs' light does: the joint photometric
    fit (:func:`_solve_by_lobes`) of every light present on the object, started from the
    best plane and from its rival.
    """
    # Lights present on the object (a candidate, or a merged blob holding them).
    present = np.stack([a.on_object & ~a.missing for a in solution.assignments])
    starts = [solution.plane] + ([solution.rival_plane] if solution.rival_plane is not None
                                 else [])
    note = (f"lights: highlights merged in {len(solution.merged_blobs)} blob(s); a joint fit "
            f"of one lobe per light")
    return _solve_by_lobes(srde, views, mask, solution, failed, gathered, starts,
                           [present] * len(starts), note)


def _solve_ambiguous(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                     failed: SRDEResult, gathered: ViewCandidates) -> SRDEResult:
    """Decide between the best plane and its rival by their lobes.

    ``ambiguous``: one virtual light seen in every view is the mirror image of each light
    across a different plane: which light made it, the centres cannot say. The lobes can
    (their shape and falloff across the views follow the light's direction and
    distance). ``inconsistent``: the best plane is contradicted by highlights it predicts
    and does not find (centres pulled by blended or cut blobs tilt every hypothesis).
    Either way the joint fit runs from both planes (:func:`_solve_by_lobes`): the fits
    must end on one plane, or one plane must explain both fits' samples
    :data:`DECISIVE_COST_RATIO` times better.
    """
    starts = [solution.plane, solution.rival_plane]
    if solution.status == "ambiguous":
        starts += _same_centres_planes(srde, mask, solution, starts)
    presents = _lights_on_object(srde, mask, solution, starts)
    if presents is None:
        return failed
    alike = {2: "two", 3: "three", 4: "four"}.get(len(starts), str(len(starts)))
    note = (f"lights: {alike} planes explain the blob centres alike; a joint fit of one "
            "lobe per light"
            if solution.status == "ambiguous" else
            "lights: the best plane is contradicted by highlights it predicts; a joint fit of "
            "one lobe per light from it and its rival")
    # The best plane and its rival must fit; further starts only offer another light.
    return _solve_by_lobes(srde, views, mask, solution, failed, gathered, starts, presents,
                           note, must_fit=2)


def _same_centres_planes(srde: SRDE, mask: np.ndarray, solution: LightsSolution,
                         starts: list[Plane]) -> list[Plane]:
    """Planes giving the best plane's highlights to each further light, as starts.

    When the best plane explains one light's highlights, every other light is mirrored
    onto the same virtual light by its own plane (the centres cannot tell them apart);
    with three or more lights the rival is only one of them. Those plausible for their
    light (``AssignmentContext.other_lights_planes``) and more than ``SAME_PLANE_PX`` from every
    start are returned.
    """
    explained = solution.explained_lights
    if len(explained) != 1 or solution.plane is None:
        return []
    context = _plain_context(srde, mask, solution)
    found: list[Plane] = []
    for _, plane in context.other_lights_planes(solution.plane, explained[0]):
        if all(context.plane_gap_px(plane, p) > SAME_PLANE_PX for p in [*starts, *found]):
            found.append(plane)
    return found


def _solve_from_single_lights(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                              failed: SRDEResult, gathered: ViewCandidates, *,
                              why: str = "no plane explains the blob centres") -> SRDEResult:
    """Solve an object whose candidates no plane explains, from each light on its own.

    When highlights of two lights blend (one lit the object's middle, the other's flank
    reaches in from beside the outline), every blob's centre is pulled off both lights'
    and no depth is agreed on a baseline line. Each light alone, as single-light SRDE
    sees it (the brightest blob of each view, triangulated with its outliers dropped),
    still gives a plane near the right one: those planes start the joint fit of the
    lights predicted on the object (:func:`_solve_by_lobes`), which decides as for
    merged blobs. The same starts serve when the fit from the merged blobs' best plane
    and its rival found no plane (``why`` says which case, in the note).
    """
    starts: list[Plane] = []
    for k in range(len(srde.lights_m)):
        alone = _one_light(srde, k).estimate(views, mask)
        if alone.ok and alone.plane is not None:
            starts.append(alone.plane)
    presents = _lights_on_object(srde, mask, solution, starts) if starts else None
    if presents is None:
        return failed
    note = (f"lights: {why}; single-light planes of "
            f"{len(starts)} light(s) start a joint fit of one lobe per light")
    return _solve_by_lobes(srde, views, mask, solution, failed, gathered, starts, presents,
                           note)


def _one_light(srde: SRDE, k: int) -> SRDE:
    """Return the same estimator told of light ``k`` only, geometric (no refinement)."""
    one = copy.copy(srde)
    one.light_m = srde.lights_m[k]
    one.lights_m = srde.lights_m[k:k + 1]
    one.light_radii_m = srde.light_radii_m[k:k + 1]
    one.refine = False
    one.search = BaselineSearch(srde.rig, one.light_m, srde.object_depth_m)
    return one


def _solve_by_lobes(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                    failed: SRDEResult, gathered: ViewCandidates, starts: list[Plane],
                    presents: list[np.ndarray], note: str, *, must_fit: int = 0) -> SRDEResult:
    """Fit one lobe per light on one plane from several starts, and decide.

    ``presents[i]`` ``(K, N)`` bool: the lights start ``i`` puts on the object. Every light
    present for some start is rendered (:class:`~.refine.joint.JointLobeModel`); each
    start's fit places its samples around the highlights of its own main light (the one
    present in most views), so two starts that explain one blob by different lights are
    judged on that blob. The fits must end on one plane, or on several of which one
    explains the samples of each fit :data:`DECISIVE_COST_RATIO` times better than every
    other plane does (:func:`_decisive_fit`). Otherwise ``failed``, with a note (no fit
    explains the images) or as ``"ambiguous"`` (planes the images do not tell apart).

    ``must_fit``: the first ``must_fit`` starts are hypotheses that explain the centres
    alike (the best plane and its rival). Such a start with a known light behind its plane
    (a face turned from that light, which the one-plane fit refuses to render) whose fit
    fails is not ruled out by the images; the other starts' fits alone are then no answer:
    ``ambiguous``. (Faces of a ridge taken as their own masks were solved 6 and 9 px off
    this way while such fits rendered the light behind the plane and were always refused;
    a fit may still be refused for another reason, as on a three-face object taken as one
    plane.) Further starts (:func:`_same_centres_planes`) only offer the lobes another
    light, and a refused fit from one of them is not an answer left open (in a trial that
    checked every one-light plane for such starts, holding them to it turned 8 of 140
    right faces taken alone ambiguous, seeds 61000+).
    """
    from .refine import refine_plane

    rig, lights = srde.rig, srde.lights_m
    everywhere = np.logical_or.reduce(presents).any(axis=1)  # (K,)

    corners = box_corners(mask)
    fits: list = []  # (fit, main, used, modelled, behind) of distinct planes
    mains: set[int] = set()
    for i, (start, present) in enumerate(zip(starts, presents, strict=True)):
        main = int(np.argmax(present.sum(axis=1)))
        mains.add(main)
        used = present[main]
        # A light behind the start's plane lights nothing on it: not rendered (a plane
        # with a light behind it is a face turned from that light).
        behind = tuple(np.flatnonzero(start.signed_distance(lights) <= 0.0).tolist())
        modelled = [k for k in np.flatnonzero(everywhere).tolist()
                    if k != main and k not in behind]
        fit = refine_plane(views, rig, lights[main], mask, start,
                           centers_uv=_centres(rig, start, lights[main], used),
                           **_lobe_options(srde, main, modelled, behind))
        if i < must_fit and not fit.ok and behind:
            reason = (f"{note} (lights {np.flatnonzero(everywhere).tolist()}): the fit from "
                      f"the plane with light(s) {list(behind)} behind it (a face turned from "
                      f"them, as on an object of several flat faces) was refused ({fit.reason}); "
                      "the images do not rule that plane out"
                      + (f"; {solution.evidence}" if solution.evidence else ""))
            return dataclasses.replace(failed, status="ambiguous", reason=reason)
        if (fit.ok or _settled_at_start(fit)) \
                and all(plane_gap_px(rig, corners, fit.plane, f.plane) > SAME_PLANE_PX
                        for f, *_ in fits):
            fits.append((fit, main, used, modelled, behind))
    mains = sorted(mains)
    note = f"{note} (lights {np.flatnonzero(everywhere).tolist()}, main {mains})"
    if not fits:
        return dataclasses.replace(failed, notes=(*failed.notes, note + " explained none"))
    winner, costs = _decisive_fit(srde, views, mask, fits)
    if winner is None:
        evidence = f"; {solution.evidence}" if solution.evidence else ""
        undecided = [(i, j) for i in range(len(fits)) for j in range(i + 1, len(fits))
                     if not (_beats(costs, i, j) or _beats(costs, j, i))]
        if not undecided:  # every pair decided, in a circle
            reason = (f"{note} ends on {len(fits)} planes, each explaining the images "
                      f"{DECISIVE_COST_RATIO:g}x worse than another{evidence}")
            return dataclasses.replace(failed, status="ambiguous", reason=reason)
        i, j = undecided[0]
        gap_px = plane_gap_px(rig, corners, fits[i][0].plane, fits[j][0].plane)
        reason = (f"{note} ends on planes {gap_px:.1f} px apart from two starts, neither "
                  f"explaining the images {DECISIVE_COST_RATIO:g}x better (costs "
                  f"{costs[i, i]:.3g} vs {costs[i, j]:.3g} and {costs[j, i]:.3g} vs "
                  f"{costs[j, j]:.3g})"
                  + (f" ({len(fits)} distinct planes)" if len(fits) > 2 else "") + evidence)
        return dataclasses.replace(failed, status="ambiguous", reason=reason)
    fit, main, used, *_ = fits[winner]
    centers = _centres(rig, fit.plane, lights[main], np.ones(rig.n_cameras, bool))
    detections = tuple(HighlightDetection.missing(f"light {main}: in a merged blob")
                       for _ in range(rig.n_cameras))
    result = srde._finish_on_plane(
        mask, fit.plane, lights[main], used, centers, detections,
        (*failed.notes, note + f" gives the plane (RMS {fit.residual:.3g})"), refine=False)
    if not result.ok:
        return dataclasses.replace(failed, notes=(*failed.notes, note + f": {result.reason}"))
    return dataclasses.replace(result, refinement=fit,
                               lights=_solved_on(srde, mask, solution, result.plane, gathered))


def _settled_at_start(fit) -> bool:
    """Whether a refused lobe fit kept a start that could be the answer.

    A start on the right plane with clean highlights leaves the fit nothing to improve:
    it ends at or above the start's own best cost and is refused as "does not improve"
    (its plane, the start's, is kept). That plane still contends in the lobes' judge if
    its lobe explains the images as a refined plane's must (the residual check,
    ``PlaneRefinement.explains_images``), however far above its start the fit ended;
    dropped, it let another light's plane win unopposed (faces taken alone, 10.9 and 8.6
    px off, whose own planes' fits ended 0.05 % and 0.5 % above their starts, the latter's
    plane 240 times cheaper than the winner's). A start its lobe does not explain cannot
    be an answer and does not hold the judge open (two faces alone were left ambiguous
    by another light's start, 5 and 16 px off, whose lobe the residual check refuses).
    """
    return (not fit.ok and math.isfinite(fit.cost_final) and math.isfinite(fit.cost_initial)
            and fit.cost_initial <= fit.cost_final and fit.explains_images)


def _decisive_fit(srde: SRDE, views, mask: np.ndarray, fits: list
                  ) -> tuple[int | None, np.ndarray]:
    """Which of the lobe fits' distinct planes the images prefer decisively, if one.

    ``fits``: ``(fit, main, used, modelled, behind)`` per distinct plane (the lights its
    fit rendered beside ``main``, and those behind its start's plane). Every plane is scored on
    every fit's samples (:func:`~.refine.plane.compare_planes`, samples placed around
    that fit's own main light, every fit's main light rendered where it lies in front of
    the plane scored); plane ``i`` beats plane ``j`` when it is
    :data:`DECISIVE_COST_RATIO` times cheaper on ``i``'s and ``j``'s samples, wherever both
    have a cost (:func:`_beats`). The answer is the plane that beats every other. Each
    pair is judged: when only the first two fits were compared, a face lit by one light
    was handed to another's plane, 12 px off, though a third fit's plane was 57 times
    cheaper than it on its own samples.

    Returns
    -------
    winner : int or None
        Index into ``fits``; 0 when there is one fit; None when no plane beats all others.
    costs : numpy.ndarray, (F, F)
        ``costs[s, p]``: plane ``p``'s best photometric cost on fit ``s``'s samples.
    """
    if len(fits) == 1:
        return 0, np.zeros((1, 1))
    # Every fit's main light is rendered on every fit's samples (each plane with those in
    # front of it): a plane is judged by how its own light explains the blobs there, not
    # by the light another fit gave them. (Rendered with that light alone, a face's own
    # plane lost 950x on the other light's samples, while that light's plane, its face's
    # light behind it, had no cost on the face's: another light's plane, 7 px off, won.)
    mains = sorted({main for _, main, *_ in fits})
    costs = _costs_on_samples(views, srde.rig, srde.lights_m, mask, [
        (fit.plane, main, used,
         _lobe_options(srde, main, _judged_lights(main, modelled, mains), behind))
        for fit, main, used, modelled, behind in fits])
    return _winner(costs), costs


def _judged_lights(main: int, modelled: list[int], mains: list[int]) -> list[int]:
    """Return the lights the judge renders beside ``main`` on its fit's samples.

    The fit's own (``modelled``), then every other fit's main light.
    """
    return modelled + [k for k in mains if k != main and k not in modelled]


def _costs_on_samples(views, rig: CameraRig, lights: np.ndarray, mask: np.ndarray,
                      planes: list) -> np.ndarray:
    """Every plane's best photometric cost on every plane's samples, ``(P, P)``.

    ``planes``: ``(plane, main, used, options)`` each: the samples of plane ``s`` are
    placed around its main light's highlights in the ``used`` views and rendered with
    ``options`` (:func:`_lobe_options`); ``costs[s, p]`` is plane ``p``'s cost there
    (:func:`~.refine.plane.compare_planes`; ``inf`` where ``p`` renders none of those
    lights).
    """
    from .refine.plane import compare_planes

    n = len(planes)
    costs = np.zeros((n, n))
    for s, (plane, main, used, options) in enumerate(planes):
        order = [s] + [p for p in range(n) if p != s]
        costs[s, order] = compare_planes(views, rig, lights[main], mask,
                                         [planes[p][0] for p in order],
                                         _centres(rig, plane, lights[main], used), **options)
    return costs


def _winner(costs: np.ndarray) -> int | None:
    """Return the plane that beats every other (:func:`_beats`), or None.

    No inference through a third plane: two planes never judged against each other (each
    renders none of the lights placed on the other's samples) leave the answer open even
    when one of them beats a plane that beats the other.
    """
    n = len(costs)
    for i in range(n):
        if all(_beats(costs, i, j) for j in range(n) if j != i):
            return i
    return None


def _beats(costs: np.ndarray, i: int, j: int) -> bool:
    """Plane ``i`` is :data:`DECISIVE_COST_RATIO` times cheaper than ``j`` where both are judged.

    On each fit's samples where both planes have a cost (``inf``: a plane that renders
    none of the lights placed there, which says nothing of it), and on one at least.
    """
    judged = False
    for s in (i, j):  # i's samples, then j's
        if np.isfinite(costs[s, i]) and np.isfinite(costs[s, j]):
            if not costs[s, j] > DECISIVE_COST_RATIO * costs[s, i]:
                return False
            judged = True
    return judged


def _solved_on(srde: SRDE, mask: np.ndarray, solution: LightsSolution, plane: Plane,
               gathered: ViewCandidates) -> LightsSolution:
    """Return the solution of a plane the lobes settled: blobs assigned on that plane.

    The fit may end on the rival plane, or on one no hypothesis proposed; the assignment
    of the geometric hypothesis it started from then belongs to another plane. The
    candidates are matched again to the lights' highlights this plane predicts, with the
    assignment's own tests (``gathered``'s brightness and blob boxes): a prediction inside
    a blob of merged highlights, or bright beside another light's, is not missing, and
    the merged blobs are this plane's. A light none of the candidates explains keeps no
    centre. (Matched on the centres alone, every highlight in a merged blob read as
    missing: on a scene of two lamps, both lit, each lamp's highlight in all nine views.)
    """
    context = gathered.context(srde, mask)
    on_plane = context.solution(context.score(plane, at_least=0), None)
    evidence = (on_plane.evidence if on_plane.n_observations or on_plane.merged_blobs
                else "no blob centre lies on a highlight of this plane")
    return dataclasses.replace(
        solution, status="ok", reason="", plane=plane, assignments=on_plane.assignments,
        residual_px=on_plane.residual_px, merged_blobs=on_plane.merged_blobs,
        evidence=f"{evidence}; the plane from the joint fit of one lobe per light")


def _centres(rig: CameraRig, plane: Plane, light: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Return the light's highlight centre in every used view, ``(N, 2)``; NaN elsewhere."""
    virtual = plane.mirror(light)
    centers = project_points(rig, virtual, np.arange(rig.n_cameras))
    return np.where(used[:, None], centers, np.nan)


def _worst_reprojection_px(rig: CameraRig, lights: np.ndarray, solution: LightsSolution,
                           plane: Plane) -> float:
    """Largest distance between an assigned highlight and where ``plane`` puts it, px."""
    virtual = plane.mirror(lights)
    worst = 0.0
    for a in solution.assignments:
        views = np.flatnonzero(np.isfinite(a.centers_uv[:, 0]))
        if views.size:
            predicted = project_points(rig, virtual[a.light], views)
            worst = max(worst, float(np.max(np.linalg.norm(predicted - a.centers_uv[views],
                                                           axis=1))))
    return worst
