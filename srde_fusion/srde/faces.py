"""Faceted objects: a mask holding two or three flat faces, one plane per face.

A box seen on an edge is one mask but two planes. Each face mirrors the known lights on
its own plane, so each face's highlights triangulate to its own virtual lights; the
plane hypotheses of :mod:`.assignment` (a reference candidate, partners on its baseline
lines, a light) are the same, only more than one of them is the answer:

1. **Planes.** The plane explaining the most highlights is the first face; each further
   face is the plane (more than ``SAME_PLANE_PX`` away from those chosen) that explains
   the most highlights the chosen ones do not, at least one light's in ``min_views``
   views. A plane that explains no highlight of its own is not a face. With one plane
   the object is a single plane and the caller takes its usual path. Sets that the
   highlights rank alike are told apart by the image (step 3): the first whose faces all
   pass is taken, two that both pass are ambiguous (:data:`AMBIGUITY_FINAL`); when all
   of them fail, the sets of the next rank are tried the same way. When every set fails,
   the planes are proposed again from every view's candidates, then from candidates
   whose blobs cut by a straight edge are centred on their arcs (:data:`RECENTRED_TRY`),
   then the well-seen planes are turned about the chords between the outline's
   corners, where the faces' edges end (:data:`HINGE_TRY`, :mod:`.hinges`), then
   highlights predicted near the outline take candidates too (:data:`NEAR_OUTLINE_TRY`),
   and last they do so among the recentred candidates (:data:`RECENTRED_NEAR_OUTLINE_TRY`).
2. **Split.** Two planes meet in a 3-D line whose image is the faces' edge. Along a
   reference pixel's ray a convex object (a ridge) shows the *farther* of the faces'
   planes (the ray enters the solid last through it), a concave one (a valley) the
   *nearer*. The rule kept is the one under which every face's own highlights (their
   mirror points seen from the reference camera) fall in that face's part of the mask;
   if no set of planes splits the mask so, the object takes the one-plane path (whose
   own checks weigh the highlights its plane does not explain); if the chosen split
   fails later (after refinement, or a reference highlight that no face explains), the
   object fails with ``status="face_split"`` and a reason: never a guess.
3. **Per face.** The face's highlights of its best-seen light go through the usual
   checks and photometric refinement on the face's part of the mask
   (``SRDE._finish``; a face whose lobe fit fails is read again without the band where
   the edge lies if its planes are a pixel off, and a fit that moves the face's plane
   off its highlight centres' stands only when the image prefers it decisively and the
   move holds when the face is read without the band by the edge; a face whose fit so
   moves its plane, or leaves it loose, its lamp taken for a point, is read with the
   lamp's radius fitted before its set fails: :data:`RADIUS_RETRY`), and
   the mask is split again with the refined planes; each face is read once more on its
   new part (a face whose light the rig knows no radius for with the lamp's radius fitted
   too, where it lowers the lobe fit's cost enough: :data:`FIT_RADIUS`), and the mask
   split again; the disparity is each face's plane on its part, pieced together, so
   fusion (which reads the disparity map) carries the edge. Two sets whose faces end on
   the same planes are one answer.

The split is geometric only; the image is not used to move the edge.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from itertools import combinations
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .._json import json_safe
from ..boxes import dilated
from ..geometry import Plane, plane_depth, plane_disparity
from .assignment import (
    BLEND_RADII,
    SAME_PLANE_PX,
    UNEXPLAINED_RATIO,
    AssignmentContext,
    PlaneScore,
    explained_pairs,
    reflection_points,
)
from .candidates import ViewCandidates
from .highlight import HighlightDetection, search_box
from .hinges import hinge_chords, hinge_plane, outline_corners
from .lights import DECISIVE_COST_RATIO, lobes_prefer, near_lights
from .refine import PlaneRefinement
from .refine.radius import RADIUS_NOTE
from .result import SRDEResult

if TYPE_CHECKING:
    from .estimator import SRDE

_log = logging.getLogger(__name__)

__all__ = [
    "FACE_RULES",
    "MAX_FACES",
    "FaceResult",
    "Faces",
    "estimate_faces",
]

#: Most faces an object may be split into.
MAX_FACES = 3

#: Which plane a pixel of a faceted object sees: the farther (a convex ridge) or the
#: nearer (a concave valley) of its faces' planes.
FACE_RULES = ("ridge", "valley")

#: A face's part of the mask must hold at least this many pixels ...
MIN_FACE_PX = 200

#: ... and this fraction of the mask.
MIN_FACE_FRACTION = 0.03

#: Most distinct planes tried as faces (those explaining the most highlights).
MAX_FACE_HYPOTHESES = 12

#: Under the kept rule each face's own highlights must outnumber those of it that fall
#: on another face's part by this factor.
OWN_HIGHLIGHT_RATIO = 2.0

#: Most sets of face planes checked against the image, best-ranked first. The same
#: highlight centres read as one light's or another's give two planes of equal support, so
#: each face may come in two versions: up to 2 ** MAX_FACES sets tie, and all are tried
#: (which one the ranking puts first is then down to rounding).
MAX_SETS_TRIED = 2 ** MAX_FACES

#: Ranks of sets tried, best first: the sets of the next rank (fewer highlights on their
#: own faces) are tried when every set of the best rank fails. A wrong plane that takes
#: a highlight of another face or light can rank a wrong set above the right one. (On the
#: faceted benchmark and its seven held-out sets, 480 objects: 346 -> 353 solved, none
#: wrong, lit faces within 0.05 px 711 -> 725; about 10 % more time on the objects whose
#: best rank fails. Every rank solved one more of those, at up to 4.9 times the time.)
RANKS_TRIED = 2

#: The refinement leaves out a face's pixels this close to another face's part, px.
FACE_EDGE_MARGIN_PX = 4.0

#: Each face is read a second time, on the part of the mask that the first readings'
#: refined planes give it: an edge drawn from start planes some pixels off gives a face a
#: strip of its neighbour (on one 3-face object the middle face held 787 px of one and
#: came out 0.15 px off; read again, 0.04 px). The second reading stands when the
#: refinement confirms it, pins it down (:data:`MAX_FACE_SIGMA_PX`) and moves the plane
#: by at most ``SAME_PLANE_PX``; else the first does.
SECOND_READING = True

#: In the second reading, a face whose light the rig knows no radius for has the lamp's
#: radius fitted with its plane (:func:`~.refine.radius.refine_plane_and_radius`, which
#: keeps the point light where a radius hardly lowers the cost). Seen in few views, a
#: point light's lobe cannot take the lamp's disc in every view at once and the plane
#: tilts instead: end faces of three-face ridges came out 0.2-0.36 px off, 0.02-0.05 px
#: with the radius fitted. A face's highlights lie near its edge, where the lobe's tail is
#: cut, so faces seen in most views gain too (one in five views went from 0.045 to
#: 0.002 px); the search is up to eight more fits of the face.
FIT_RADIUS = True

#: A face whose first reading (its lamp a point) moves its plane off its highlight
#: centres' by more than the checks allow, or leaves it loose, is read again with the
#: lamp's radius fitted before its set is refused (when the rig does not know the
#: radius; :data:`RETRY_SEARCHES`): the point light's tilt is what moves such faces. An end
#: face of a three-face ridge seen in three views of one column, its centres' plane
#: 0.07 px off, was moved 0.78 px by the point light's fit and came within 0.02 px with
#: the lamp's true radius (0.04 px with the radius fitted).
RADIUS_RETRY = True

#: The fraction of the point light's photometric cost a fitted radius must save to be
#: taken for a face the point light's fit leaves loose (its standard error above
#: MAX_FACE_SIGMA_PX). There the radius is what pins the plane down, and a radius that
#: merely helps can pin a wrong one: a wrong valley set of a ridge (111008) had its loose
#: face pinned by a 16.3 mm radius for lamps of 2-8 mm that saved 71 % of the point
#: light's cost, and was taken 2.7-4.0 px off. The right loose faces read this way
#: (33001, 73018, 83015, 143008) saved 91-99 %.
LOOSE_FACE_RADIUS_GAIN = 0.8

#: The checks (:class:`_FaceReading`'s ``refused_by``) whose failure a reading with the
#: lamp's radius fitted answers, and that reading's options of the radius search
#: (:func:`~.refine.radius.refine_plane_and_radius`). A loose face's radius must save
#: LOOSE_FACE_RADIUS_GAIN of the point light's cost measured on the same samples: where
#: the point light's fit is refused there, nothing says how much the radius explains.
RETRY_SEARCHES = {"move": {},
                  "uncertain": {"min_gain": LOOSE_FACE_RADIUS_GAIN, "point_fit_needed": True}}

_MOVED = "the photometric refinement moved its plane by"

#: A face's refined plane, not only its start plane, explains the reference view's
#: highlights of the face's own light: a start proposed from other views' centres can
#: predict the face's own reference highlight beyond the tolerance, where the refined
#: plane meets it, and the split was then refused as leaving a highlight unexplained.
FINAL_PLANES_EXPLAIN = True

#: A set of faces must explain more highlights than one plane does alone: the first
#: plane of the pool (the most highlights) that the evidence against does not outweigh
#: (the one-plane path's own refusal, ``UNEXPLAINED_RATIO``), or none if all are.
#: Measured against a plane that path refuses itself, right splits were dropped.
CREDIBLE_BAR = True

#: Two sets of faces that both pass in the first try leave the object ``ambiguous``, and
#: the later tries are not asked: they propose from other candidates and may rank one of
#: the two alone first, which would pick it without evidence against the other. (On a
#: ridge whose valley set also passed once its faces' lamp radius was fitted, the every-
#: view try took the valley set, 1.1-1.9 px off.)
AMBIGUITY_FINAL = True

#: Start of the reason of an object two sets of faces explain alike.
_TWO_SETS = "faces: two sets of"

#: When every other try fails, the faces are tried once more with each blob cut by a
#: straight chord (a face's edge, a straight stretch of the outline) centred on the
#: ellipse through the rest of its outline (:func:`.cut_highlights.arc_center`), every
#: view's candidates proposing planes: a face whose highlights reach its edge in most
#: views has centroids pixels inside its part, and no proposed plane comes near it.
RECENTRED_TRY = True

#: The last try's answer stands only when every face's lobe fit pins its plane down to
#: this standard error, px. Its faces' fits mostly move their starts by hundredths of a
#: pixel, so the plane is the recentred centres' and carries their error, which the
#: fit's own standard error does not see. (On the four faceted seed sets it was drawn
#: from, its faces within 0.05 px had at most 0.035 px; faces 0.26-0.53 px off,
#: 0.046-0.079 px.)
RECENTRED_MAX_SIGMA_PX = 0.04

#: When every other try fails, planes turned about the edges between faces join the
#: pool (:mod:`.hinges`): a face whose blobs the outline and its edge both cut has
#: centres pixels off, and no plane proposed from them comes near it; its neighbour's
#: plane turned about their edge (a chord between two corners of the outline) leaves
#: one angle to find, which such centres still fix.
HINGE_TRY = True

#: When every other try fails, the faces are tried once more with the highlights predicted
#: within a blob radius of the outline taking candidates as the others do, in the ranking
#: too. Elsewhere they take none, lest a blob the outline cuts, its centre pulled inwards,
#: count for a wrong plane; but the end face of a row, small and lit near the object's
#: outline, may then have no plane that explains two of its highlights, though its blobs
#: are whole and their centres within the tolerance of its plane's predictions (a cut
#: blob's centre, pulled by more than the tolerance, still matches nothing). The faces'
#: checks and refinement decide as in every try, and the answer is taken only if one of
#: its faces has its own light's highlights in fewer than ``min_views`` views without
#: those near the outline: the face the try is for. (A valley whose two faces had theirs
#: in three and two views was otherwise solved with a face 0.34 px off, its start fitted
#: to centres near the outline 0.31 px off, 5.7 % of the mask on the wrong face; four
#: right objects like it, every face seen away from the outline, stay refused with it.)
NEAR_OUTLINE_TRY = True

#: When every other try fails, the recentred candidates (:data:`RECENTRED_TRY`) are tried
#: once more with the predictions near the outline taking candidates
#: (:data:`NEAR_OUTLINE_TRY`): a face lit near the outline has the blobs there cut by it,
#: and their centroids, pulled inwards by pixels, match nothing; centred on their arcs
#: they are the highlights' centres again, which is what the outline rule guards
#: against. The recentred try's limit on the faces' standard errors
#: (:data:`RECENTRED_MAX_SIGMA_PX`) holds, and the try runs only with both of those
#: tries on. No face need lack highlights away from the outline, as the near-outline
#: try asks: on a valley whose faces had theirs in four and three views, the cut blobs
#: recentred put its face 0.12 px off, not the near-outline try's 0.34 px.
RECENTRED_NEAR_OUTLINE_TRY = True

#: Planes turned about the outline's chords that join the pool, at most.
HINGE_PLANES = 16

#: The best pairs of faces each further plane is tried with in the hinge try (3 in the
#: others): a turned plane is a third face beside its source and the source's neighbour.
HINGE_PAIRS_EXTENDED = 24

#: A face whose lobe fit does not confirm its plane is read once more without the band
#: where its plane and a neighbour's differ by less than this, px (where the faces' edge
#: lies if the planes are off by that much).
RETRY_EDGE_PX = 1.0

#: A face whose lobe fit moved its plane by more than SAME_PLANE_PX is read again without
#: the band where the faces' edge lies if the planes are that far off; the fit there must
#: land within this of the moved plane, px. (Right moves on the faceted benchmark and
#: held-out objects landed within 0.14 px; a move that rested on a neighbour's shading by
#: the edge, 0.63 px off its face, landed 0.63 px away, 0.22 px off the face.)
OFF_EDGE_PX = SAME_PLANE_PX / 2

#: A moved face whose reading without that band gives no confirmed fit (too few of its
#: pixels left, or a lobe fit that fails there) has nothing but its lobe fit to stand
#: on, and the fit's standard error does not see a neighbour's shading by the edge: it
#: stands only when that error is within this, px (the recentred try's limit). (Drawn
#: from the one wrong object of a set first run with the faces' last try: a 3-face end
#: face seen in two views, moved 3.86 px to 0.66 px off, 0.161 px. On the eleven faceted
#: sets it refuses that object and two right ones, each with a face 0.07-0.09 px off.)
UNCHECKED_MOVE_MAX_SIGMA_PX = RECENTRED_MAX_SIGMA_PX

#: The faces' edge is placed within this many standard errors of the refined planes ...
EDGE_SIGMAS = 2.0

#: ... and the pixels it leaves to either of two faces there may be at most this fraction
#: of the mask (the faceted benchmark's bound for a wrong split). A shallow edge (20-22
#: deg) between loosely pinned faces (standard errors 0.09-0.13 px) left 7 % and 12 %
#: open, and those objects came out with 6 % and 9 % of the mask on the wrong face; no
#: right object of the faceted benchmark's three seed sets left more than 5.5 %, counted
#: over the whole mask (more than this count, which takes each pair's own pixels).
MAX_OPEN_EDGE_FRACTION = 0.05

#: When every try fails, each is made once more with each set solved from the set's own
#: planes instead of its faces' planes refitted to their own highlights, the sets where
#: a refit moved a plane by more than ``SAME_PLANE_PX`` only. An end face of a three-face
#: ridge may keep two of its highlights away from the edge, in few views; refitted to
#: those alone its plane can land pixels off the one its highlights proposed (0.05 ->
#: 4.86 px on one), and the mask split by it gives the middle face a strip of its
#: neighbours, where that face's lobe fit fails. The faces' checks and refinement decide
#: as in every try. (Solved in place of a set's failure, a set's own planes preempted
#: later sets and tries that the refits solve: two objects already solved came out
#: worse, one face 0.03 -> 0.13 px.)
SET_PLANES_RETRY = True

#: A set solved from its own planes stands only when every face's lobe fit pins its
#: plane down to this standard error, px (the recentred try's limit, for the same
#: reason: the fits move their starts little, so a face carries its start's error, which
#: its standard error does not see). Without it, three objects of the twelve faceted
#: runs were solved with an end face seen in two views 0.85, 0.12 and 0.06 px off
#: (standard errors 0.102, 0.066 and 0.078 px); the right faces solved so had at most
#: 0.035 px, and one right face (0.019 px off) had 0.041 px and is refused.
SET_PLANES_MAX_SIGMA_PX = RECENTRED_MAX_SIGMA_PX

#: Largest standard error of a refined face's disparity over the object, px: three times
#: it stays within SAME_PLANE_PX, so another plane is told apart. (A face whose lobe fit
#: moved it off its highlight centres' plane may stand, so the fit's own certainty must
#: carry it: on the faceted benchmark and held-out objects correct faces had at most
#: 0.12 px, faces 0.3-0.6 px off 0.17-0.20 px.)
MAX_FACE_SIGMA_PX = SAME_PLANE_PX / 3

#: A face's refined plane must put its own highlights where they were seen, within
#: ``2 * max_residual_px``, but a blob cut by the face's border (the outline, or the
#: edge with another face) has its centre pulled into the part: such a highlight, whose
#: mirror point lies within a blob radius of the border and nearer to it than the
#: centre's own, may be missed by up to a blob radius. (An end face of a 3-face ridge
#: seen in three views, the mirror points 8-10 px inside the outline, blob radius 12 px:
#: its lobe fit came 0.03 px off the face and missed the centres, pulled into the face,
#: by 1.7-3.7 px; every set holding it was refused for that, and the object with it.)
CUT_MISS_ALLOWED = True


@dataclass(frozen=True)
class FaceResult:
    """One face of a faceted object.

    Parameters
    ----------
    label : int
        The face's value in :attr:`Faces.labels_box` (1, 2, ...).
    plane : Plane
        The face's plane, array frame.
    light : int
        Index of the light whose highlights fixed the plane.
    virtual_light_m : numpy.ndarray, (3,) float64
        That light mirrored across the plane, metres.
    highlight_centers : numpy.ndarray, (N, 2) float64
        That light's highlight centre per view on this face, pixels; NaN where none.
    used_views : numpy.ndarray, (N,) bool
        Views whose centre was used.
    residual_px : float
        RMS reprojection residual of the virtual light over the used views, pixels.
    n_px : int
        Mask pixels of the face.
    refinement : PlaneRefinement or None
        The photometric refinement on the face's part of the mask.
    notes : tuple of str
        What was left out for this face.
    """

    label: int
    plane: Plane
    light: int
    virtual_light_m: np.ndarray
    highlight_centers: np.ndarray
    used_views: np.ndarray
    residual_px: float
    n_px: int
    refinement: PlaneRefinement | None = field(default=None, repr=False)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """JSON-ready summary (non-finite numbers become None)."""
        return json_safe({
            "label": self.label,
            "plane": {"normal": self.plane.normal, "offset_m": self.plane.offset_m},
            "light": self.light,
            "virtual_light_m": self.virtual_light_m,
            "used_views": [int(j) for j in np.flatnonzero(self.used_views)],
            "residual_px": self.residual_px,
            "n_px": self.n_px,
            "refined": self.refinement is not None and self.refinement.ok,
            "disparity_sigma_px": (None if self.refinement is None
                                   else self.refinement.disparity_sigma_px),
            "notes": list(self.notes),
        })


@dataclass(frozen=True)
class Faces:
    """How an object was split into faces.

    Parameters
    ----------
    rule : {"ridge", "valley"}
        Which plane each pixel sees: the farther (ridge, convex) or the nearer (valley).
    labels_box : numpy.ndarray, (v1 - v0, u1 - u0) uint8
        Over the result's ``box``: 0 outside the mask, k on ``faces[k - 1]``'s part.
    faces : tuple of FaceResult
        In the order they were found (the first explains the most highlights).
    """

    rule: str
    labels_box: np.ndarray = field(repr=False)
    faces: tuple[FaceResult, ...]

    def to_dict(self) -> dict:
        """JSON-ready summary (no pixel maps)."""
        return {"rule": self.rule, "faces": [f.to_dict() for f in self.faces]}


# ---------------------------------------------------------------------- planes
def _own_views(score: PlaneScore, covered: set[tuple[int, int]]) -> int:
    """Most views in which one light's highlight is explained by this plane and no other."""
    best = 0
    for k in range(score.matched.shape[0]):
        views = np.flatnonzero(score.matched[k] >= 0)
        best = max(best, sum((int(j), int(score.matched[k, j])) not in covered for j in views))
    return best


@dataclass(frozen=True)
class _Split:
    """One set of face planes, the rule that splits the mask among them, and its worth."""

    scores: tuple[PlaneScore, ...]
    rule: str
    labels: np.ndarray
    value: tuple[int, int]  # (own highlights less foreign ones, the planes' net support)
    explained: int = 0  # own highlights and those the faces' edge cuts, less foreign ones


@dataclass(frozen=True, eq=False)
class _FaceSet:
    """One set of face planes while its faces are read: what each face's reading needs.

    ``chosen``: each face's score, its plane refitted to its own highlights or the set's
    own (:data:`SET_PLANES_RETRY`); ``labels``:
    the mask split among them over ``box`` (face ``f`` is label ``f + 1``).
    """

    srde: SRDE
    views: Sequence[np.ndarray]  # the frame as the backend holds it (``backend.prepare``)
    chosen: tuple[PlaneScore, ...]
    labels: np.ndarray
    box: tuple[int, int, int, int]
    gathered: ViewCandidates
    context: AssignmentContext


@dataclass(frozen=True)
class _FaceReading:
    """One face of a set, read and checked (:func:`_checked_face`).

    ``face`` is None when a check failed; ``result`` is then the failure, naming the
    face. ``refused_by``: which check failed ("" when none did; ``"move"`` for the
    checks on how far the lobe fit moved the plane, ``"uncertain"`` for its standard
    error; also ``"reading"``, ``"unconfirmed"``, ``"miss"``), ``why`` its reason
    without the face's name. ``light``: the light that fixes the face, when the face was
    read that far (else None). ``modelled``: the lights rendered beside it. ``notes``:
    the notes of a reading refused by a check after it was solved (its lobe fit's, such
    as which radius a radius search took).
    """

    result: SRDEResult
    face: FaceResult | None
    modelled: list[int]
    refused_by: str = ""
    why: str = ""
    light: int | None = None
    notes: tuple[str, ...] = ()


def choose_faces(context: AssignmentContext, scores: list[PlaneScore], *, max_faces: int,
                 min_views: int, box, inside: np.ndarray, keep_proposed: bool = False,
                 pooled: bool = False, pairs_extended: int = 3
                 ) -> tuple[list[_Split], str, list[PlaneScore]]:
    """Rank the sets of face planes by how well their splits agree with the highlights.

    The distinct refitted planes explaining the most highlights (at most
    :data:`MAX_FACE_HYPOTHESES`) are tried in pairs, and the best pair with each further
    plane: a set counts when some rule puts every face's highlights on its own part
    (:func:`_evaluate`). The best set is the one with the most highlights on their own
    faces (less those elsewhere), then the most net support. A set must explain more
    highlights than the first plane of the pool does alone, of the planes the evidence
    against does not outweigh (:data:`CREDIBLE_BAR`), counting those the faces'
    edge cuts (:data:`CUT_BY_EDGE`): they do not place the split, but the single plane's
    count holds every highlight it explains.

    ``keep_proposed`` (the second try of :func:`estimate_faces`): each proposed plane
    joins the pool beside its refit, and the pool holds twice as many. A refit moves a
    plane onto every highlight it explains, and a face's centres cut by the outline or
    the edge can pull it pixels off the plane the well-seen centres proposed; the
    refits of the face that explains most crowd the planes of faces seen in fewer views
    out of a pool of :data:`MAX_FACE_HYPOTHESES`.

    ``pooled``: ``scores`` are the pool already (distinct planes, most highlights first).

    Returns
    -------
    ranked : list of _Split
        The distinct sets (one set reached in two orders counts once), best first; empty
        when none counts.
    why : str
        Why no set counts, when some plane explains highlights the first one does not
        ("" when none does: the object is one plane).
    pool : list of PlaneScore
        The distinct refitted planes tried, most highlights first.
    """
    pool = list(scores) if pooled else _face_pool(context, scores, keep_proposed=keep_proposed)
    if len(pool) < 2:
        return [], "", pool
    splits: list[_Split] = []
    why = ""
    # Evidence of a second face: a plane explaining, in min_views views, one light's
    # highlights the plane that explains the most does not.
    first = explained_pairs(pool[0])
    second = any(_own_views(p, first) >= min_views for p in pool[1:])
    kept = _KeptPerPlane(context.rig, context.lights, box)
    for a, b in combinations(range(len(pool)), 2):
        split, reason = _evaluate(context, (pool[a], pool[b]), min_views, box, inside, kept)
        if split is not None:
            splits.append(split)
        elif not why and second:
            why = reason
    if max_faces > 2 and splits:
        for pair in sorted(splits, key=lambda s: s.value, reverse=True)[:pairs_extended]:
            for third in pool:
                if any(third is s for s in pair.scores):
                    continue
                split, _ = _evaluate(context, (*pair.scores, third), min_views, box, inside,
                                     kept)
                if split is not None and split.value > pair.value:
                    splits.append(split)
    # Faces must explain more highlights than one credible plane does alone (which counts
    # every highlight it explains, near an edge or not).
    bar = len(first)
    if CREDIBLE_BAR:
        # (The pool is in the order of the highlights its planes' proposals explain: the
        # first credible plane takes the first plane's place.)
        credible = [p for p in pool if not p.outweighed(UNEXPLAINED_RATIO)]
        bar = len(explained_pairs(credible[0])) if credible else 0
    splits = [s for s in splits if s.explained > bar]
    splits.sort(key=lambda s: s.value, reverse=True)

    def same_planes(a: _Split, b: _Split) -> bool:
        # The same set in another order (a pair and a third, or another pair and a third).
        return _same_planes(context, [x.plane for x in a.scores], [y.plane for y in b.scores])

    ranked: list[_Split] = []
    for split in splits:
        if not any(same_planes(split, kept) for kept in ranked):
            ranked.append(split)
    return ranked, (why if not ranked else ""), pool


def _face_pool(context: AssignmentContext, scores: list[PlaneScore], *,
              keep_proposed: bool = False) -> list[PlaneScore]:
    """Return the distinct refitted planes that explain the most highlights, most first.

    At most :data:`MAX_FACE_HYPOTHESES`; with ``keep_proposed`` each proposed plane joins
    beside its refit, and twice as many are kept (:func:`choose_faces`).
    """
    ranked = sorted(scores, key=_by_highlights, reverse=True)
    pool: list[PlaneScore] = []
    cap = 2 * MAX_FACE_HYPOTHESES if keep_proposed else MAX_FACE_HYPOTHESES
    for score in ranked:
        refit = context.refit(score)
        for candidate in (refit, score) if keep_proposed else (refit,):
            if all(context.plane_gap_px(candidate.plane, p.plane) > SAME_PLANE_PX
                   for p in pool):
                pool.append(candidate)
            if len(pool) == cap:
                return pool
    return pool


def _by_highlights(score: PlaneScore) -> tuple[int, int, float]:
    """Sort key of the pool: explained highlights, then net support, then residual."""
    return score.n_matched, score.key[0], score.key[2]


def _views_of_one_light(score: PlaneScore) -> int:
    """Return the most views in which one light's highlights are explained by ``score``."""
    return int((score.matched >= 0).sum(axis=1).max())


def _evaluate(context: AssignmentContext, faces: tuple[PlaneScore, ...], min_views: int, box,
              inside: np.ndarray, kept: _KeptPerPlane) -> tuple[_Split | None, str]:
    """Split the mask among ``faces`` by the rule their highlights agree with, if one does.

    Each face must have one light's highlights on its own part in ``min_views`` views,
    and :data:`OWN_HIGHLIGHT_RATIO` times more of its highlights there than elsewhere;
    each part must be large enough. Both rules passing with the same count is no split.
    ``kept`` holds each plane's depth map and mirror points from one set to the next.
    """
    rig, lights = context.rig, context.lights
    passing, problems = [], []
    for rule in FACE_RULES:
        labels = split_faces([f.plane for f in faces], rig, box, inside, rule,
                             depth=kept.depth)
        where = _highlights_by_face(rig, lights, list(faces), labels, box,
                                    context.blob_radius_px, mirror_points=kept.mirror_points)
        ok, _, problem = _rule_fit(where, min_views)
        small = _too_small(labels, inside)
        if not ok or small:
            problems.append(f"{rule}: {problem or small}")
            continue
        own: set[tuple[int, int]] = set()
        cut: set[tuple[int, int]] = set()
        foreign = 0
        for f, (score, w) in enumerate(zip(faces, where, strict=True)):
            for k, j in zip(*np.nonzero(_own(w, f + 1)), strict=True):
                own.add((int(j), int(score.matched[k, j])))
            for k, j in zip(*np.nonzero(w == CUT_BY_EDGE), strict=True):
                cut.add((int(j), int(score.matched[k, j])))
            foreign += int(np.count_nonzero((w >= 0) & (w != f + 1)))
        value = (len(own) - foreign, sum(f.key[0] for f in faces))
        passing.append(_Split(faces, rule, labels, value, len(own | cut) - foreign))
    if len(passing) == 2 and passing[0].value == passing[1].value:
        return None, "both the ridge and the valley rule fit the highlights alike"
    if not passing:
        return None, "; ".join(problems)
    return max(passing, key=lambda s: s.value), ""


# ---------------------------------------------------------------------- split
def split_faces(planes: list[Plane], rig, box: tuple[int, int, int, int], inside: np.ndarray,
                rule: str, *, depth=None) -> np.ndarray:
    """Label each mask pixel with the face whose plane it sees under ``rule``.

    Parameters
    ----------
    planes : list of Plane
        The faces' planes, array frame.
    rig : CameraRig
    box : (int, int, int, int)
        ``(u0, v0, u1, v1)`` of ``inside``, pixels.
    inside : numpy.ndarray, (v1 - v0, u1 - u0) bool
        The mask over the box.
    rule : {"ridge", "valley"}
        Ridge: the farther plane along the pixel's ray; valley: the nearer. A plane the
        ray meets behind the camera (or never) is never seen.
    depth : callable, optional
        ``depth(plane, rule)`` -> :func:`_filled_depth` over ``box``, where the same
        planes are split again and again (:class:`_KeptPerPlane`); computed here otherwise.

    Returns
    -------
    numpy.ndarray, (v1 - v0, u1 - u0) uint8
        0 outside the mask, k for ``planes[k - 1]``.
    """
    if depth is None:
        def depth(plane: Plane, rule: str) -> np.ndarray:
            return _filled_depth(plane, rig, box, rule)
    # The first plane of the farthest (ridge) or nearest (valley) depth, plane by plane:
    # numpy's arg-reduction across a stack of planes reads it with a stride per pixel.
    first = depth(planes[0], rule)
    pick = np.zeros(first.shape, dtype=np.uint8)
    top = first
    for f, plane in enumerate(planes[1:], start=1):
        z = depth(plane, rule)
        better = z > top if rule == "ridge" else z < top
        pick[better] = f
        top = np.where(better, z, top)
    # (The picked depth is finite where some plane is seen: the others are the fill.)
    return np.where(inside & np.isfinite(top), pick + 1, 0).astype(np.uint8)


def _filled_depth(plane: Plane, rig, box: tuple[int, int, int, int], rule: str
                  ) -> np.ndarray:
    """Return the plane's depth over ``box``, ``(h, w)`` float64, filled where rays miss it.

    The fill is the depth no other face loses to under ``rule``: -inf for a ridge (the
    farther plane is seen), +inf for a valley.
    """
    z = np.asarray(plane_depth(plane, rig, window=box), dtype=np.float64)
    return np.where(np.isfinite(z) & (z > 0), z, -np.inf if rule == "ridge" else np.inf)


class _KeptPerPlane:
    """Each plane's depth map and mirror points, computed once while sets are ranked.

    Ranking the sets of faces splits the mask for every pair and triple of up to 24
    planes under both rules: a plane's :func:`_filled_depth` and its score's
    :func:`_mirror_points` are the same in every set it joins. (Planes equal as values
    are one key: a normal's -0.0 against 0.0 changes no finite depth.)
    """

    def __init__(self, rig, lights_m: np.ndarray, box: tuple[int, int, int, int]) -> None:
        self.rig, self.lights_m, self.box = rig, lights_m, box
        self._depths: dict[tuple[Plane, str], np.ndarray] = {}
        self._mirrored: dict[tuple[Plane, bytes], list] = {}

    def depth(self, plane: Plane, rule: str) -> np.ndarray:
        """Return :func:`_filled_depth` of ``plane`` under ``rule``."""
        if (plane, rule) not in self._depths:
            self._depths[plane, rule] = _filled_depth(plane, self.rig, self.box, rule)
        return self._depths[plane, rule]

    def mirror_points(self, score: PlaneScore) -> list:
        """Return :func:`_mirror_points` of ``score`` (its plane and the highlights it explains)."""
        key = (score.plane, (score.matched >= 0).tobytes())
        if key not in self._mirrored:
            self._mirrored[key] = _mirror_points(self.rig, self.lights_m, score)
        return self._mirrored[key]


def _label_at(labels: np.ndarray, box, uv: np.ndarray) -> np.ndarray:
    """Labels ``(M,)`` at reference pixels ``uv`` ``(M, 2)``; 0 outside the box."""
    return _value_at(labels, box, uv, np.intp)


def _value_at(values: np.ndarray, box, uv: np.ndarray, dtype) -> np.ndarray:
    """``values`` (over ``box``) at reference pixels ``uv`` ``(M, 2)`` rounded; 0 outside."""
    u, v, ok = _box_pixels(box, uv)
    out = np.zeros(len(uv), dtype=dtype)
    out[ok] = values[v[ok], u[ok]]
    return out


def _box_pixels(box, uv: np.ndarray):
    """Pixels ``uv`` ``(M, 2)`` rounded, in the box's own ``(u, v)``, and which lie in it."""
    u0, v0, u1, v1 = box
    u = np.rint(uv[:, 0]).astype(np.intp) - u0
    v = np.rint(uv[:, 1]).astype(np.intp) - v0
    return u, v, (u >= 0) & (u < u1 - u0) & (v >= 0) & (v < v1 - v0)


#: A reference candidate this many times the median candidate's area or more ...
GLOW_AREA_RATIO = 10.0

#: ... whose peak rises this fraction of the median candidate's or less is a face's
#: diffuse glow, not a highlight (the reference check of a split does not count it).
GLOW_SCORE_RATIO = 0.25

#: Marks a highlight whose mirror point lies within a blob radius of another face's part:
#: the faces' edge cuts its blob, so its centre measures neither face.
CUT_BY_EDGE = -2

#: Marks a highlight whose mirror point lies on its own face's part but within a blob
#: radius of another's: the edge may cut its blob (its centre is then pulled off the
#: light's), yet the side it lies on still tells the rule.
OWN_NEAR_EDGE = -3


def _own(where: np.ndarray, label: int) -> np.ndarray:
    """Where ``where`` puts a face's highlight on the face's own part, near its edge or not."""
    return (where == label) | (where == OWN_NEAR_EDGE)


def _highlights_by_face(rig, lights_m: np.ndarray, scores: list[PlaneScore], labels, box,
                        edge_px: float, face_labels=None, *, mirror_points=None
                        ) -> list[np.ndarray]:
    """Per face: the label under each explained highlight, ``(K, N)`` int.

    -1 where the face's plane explains no highlight; where the highlight's mirror point
    lies within ``edge_px`` of another face's part, :data:`OWN_NEAR_EDGE` if it lies on
    the face's own part and :data:`CUT_BY_EDGE` otherwise. ``face_labels``: each
    score's own label in ``labels`` (by default 1, 2, ... in order). ``mirror_points``:
    ``mirror_points(score)`` -> :func:`_mirror_points`, where they are kept
    (:class:`_KeptPerPlane`); computed here otherwise.
    """
    if face_labels is None:
        face_labels = range(1, len(scores) + 1)
    # Every explained highlight's mirror point in the reference view, then the labels
    # and the edge test at all of them at once.
    asked, points_uv = [], []
    for f, score in enumerate(scores):
        found = _mirror_points(rig, lights_m, score) if mirror_points is None \
            else mirror_points(score)
        for k, views, uv in found:
            asked.append((f, k, views))
            points_uv.append(uv)
    out = [np.full(score.matched.shape, -1, dtype=np.intp) for score in scores]
    if not asked:
        return out
    uv = np.concatenate(points_uv)
    label = _label_at(labels, box, uv)
    cut = _near_other_face_at(labels, box, uv, edge_px)
    own = np.concatenate([np.full(len(views), face_labels[f]) for f, _, views in asked])
    where = np.where(cut & (label > 0), np.where(label == own, OWN_NEAR_EDGE, CUT_BY_EDGE),
                     label)
    start = 0
    for f, k, views in asked:
        out[f][k, views] = where[start:start + len(views)]
        start += len(views)
    return out


def _mirror_points(rig, lights_m: np.ndarray, score: PlaneScore) -> list:
    """Where the score's explained highlights reflect, seen from the reference camera.

    ``(light, views, uv)`` per light with explained highlights: the views ``(M,)`` and the
    mirror points' reference pixels ``(M, 2)``.
    """
    found = []
    for k in range(score.matched.shape[0]):
        views = np.flatnonzero(score.matched[k] >= 0)
        if views.size:
            points, _ = reflection_points(score.plane, score.plane.mirror(lights_m[k]),
                                          rig.centers_m[views])
            found.append((k, views, rig.project(points)))
    return found


def _near_other_face(labels: np.ndarray, edge_px: float) -> np.ndarray:
    """Mask pixels within ``edge_px`` of another face's part, ``(h, w)`` uint8 (1 = near)."""
    side = 2 * int(math.ceil(edge_px)) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    near = np.zeros(labels.shape, dtype=bool)
    for f in range(1, int(labels.max()) + 1):
        grown = cv2.dilate((labels == f).view(np.uint8), kernel).view(bool)
        near |= grown & (labels > 0) & (labels != f)
    return near.view(np.uint8)


def _near_other_face_at(labels: np.ndarray, box, uv: np.ndarray, edge_px: float) -> np.ndarray:
    """Whether reference pixels ``uv`` ``(M, 2)`` are near another face's part, ``(M,)`` bool.

    :func:`_near_other_face`'s map read at the points (False outside the box), without
    drawing it: ranking the sets of faces asks about a few highlights of each split.
    """
    u, v, inside = _box_pixels(box, uv)
    r = int(math.ceil(edge_px))
    out = np.zeros(len(uv), dtype=bool)
    at = np.flatnonzero(inside)
    own = labels[v[at], u[at]]
    at, own = at[own > 0], own[own > 0]
    if at.size == 0:
        return out
    # The dilation's element around every point, read from the labels padded with 0
    # (beyond the box the dilation's border adds nothing).
    element = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)).astype(bool)
    dv, du = np.nonzero(element)
    padded = np.pad(labels, r)
    around = padded[v[at, None] + dv[None], u[at, None] + du[None]]  # (P, element pixels)
    out[at] = np.any((around > 0) & (around != own[:, None]), axis=1)
    return out


def _rule_fit(where: list[np.ndarray], min_views: int) -> tuple[bool, int, str]:
    """Whether every face's highlights fall on its own part; own count; what failed."""
    total, problems = 0, []
    for f, w in enumerate(where):
        own_per_light = _own(w, f + 1).sum(axis=1)
        foreign = int(np.count_nonzero((w >= 0) & (w != f + 1)))
        own = int(own_per_light.sum())
        total += own
        if own_per_light.max() < min_views or own < OWN_HIGHLIGHT_RATIO * foreign:
            problems.append(f"face {f + 1}: {own} highlight(s) on its part, {foreign} elsewhere")
    return not problems, total, "; ".join(problems)


# ---------------------------------------------------------------------- the estimate
def estimate_faces(srde: SRDE, views, mask: np.ndarray, gathered: ViewCandidates | None, *,
                   every_view: bool = False, cut_only: bool = False) -> SRDEResult | None:
    """:meth:`SRDE.estimate` for an object of up to ``srde.max_faces`` flat faces.

    Returns None when the highlights show one plane only (or none): the caller then
    takes its usual path, unchanged. Otherwise an ``ok`` result whose ``faces`` holds
    every face and whose disparity is the faces' planes pieced together, or a failure
    with its reason (``"face_split"`` when the planes do not split the mask consistently
    with the highlights; a face's own failure, named, otherwise).

    ``gathered``: :func:`~.candidates.gather_candidates` for the object's search region
    (None: no candidate, so no faces). ``every_view``: the second try only (below), for
    an object the one-plane path could not solve either; an ``ok`` result or None.
    ``cut_only`` (with ``every_view``): only the last tries, from cut blobs centred on
    their arcs on (:func:`_later_tries`), for an object whose centres no plane explains.
    """
    if gathered is None:
        return None
    if every_view:
        later = _later_tries(srde, views, mask, gathered, cut_only=cut_only)
        if later is None and SET_PLANES_RETRY:
            later = _later_tries(srde, views, mask, gathered, cut_only=cut_only,
                                 set_planes=True)
        return later
    result = _estimate_faces(srde, views, mask, gathered, anchors=None)
    if result is None or result.ok:
        return result
    if AMBIGUITY_FINAL and result.status == "ambiguous" and result.reason.startswith(_TWO_SETS):
        return result
    # Sets of face planes were tried and failed. The reference view may see a face's
    # blob cut by the outline or the edge (its centre pulled by pixels) where the other
    # views see it whole: the planes its candidates propose then miss that face or start
    # it off. Every view's candidates propose then, and the proposed planes join the
    # pool beside their refits (choose_faces' keep_proposed), as a second try only: the
    # extra planes also widen the sets a right split competes with (first, they lost
    # four objects the reference's planes solve, gaining one). An object that shows one
    # plane (None) is tried again only when the one-plane path fails too (SRDE.estimate):
    # tried here, a flat object with max_faces=3 took three times as long. Last come the
    # tries from blobs cut by a face's edge centred on their arcs on (_later_tries).
    later = _later_tries(srde, views, mask, gathered)
    if later is not None:
        return later
    if SET_PLANES_RETRY:
        # Every try failed: each is made again with the sets' own planes, where refitting
        # them to their faces' highlights moved one (SET_PLANES_RETRY).
        again = _estimate_faces(srde, views, mask, gathered, anchors=None, set_planes=True)
        if again is not None and again.ok:
            return again
        # (Two sets that both pass from their own planes: the first try's failure stands.)
        if again is None or again.status != "ambiguous":
            later = _later_tries(srde, views, mask, gathered, set_planes=True)
            if later is not None:
                return later
    return result


def _later_tries(srde: SRDE, views, mask: np.ndarray, gathered: ViewCandidates, *,
                 cut_only: bool = False, set_planes: bool = False) -> SRDEResult | None:
    """Return the faces from every view's candidates, else from the last tries (ok or None).

    In order: recentred candidates, turned planes, predictions near the outline matched,
    and those matched among recentred candidates. ``cut_only``: the last tries alone,
    without every view's candidates (:func:`_recentred_try` first). ``set_planes``: each
    try solves its sets from their own planes only (:data:`SET_PLANES_RETRY`).
    """
    if not cut_only:
        again = _estimate_faces(srde, views, mask, gathered,
                                anchors=tuple(range(srde.rig.n_cameras)),
                                set_planes=set_planes)
        if again is not None and again.ok:
            return again
    # (The cut blobs are read again once, for both tries that use them.)
    recentred = gathered.recentred(views, srde.config.encoding) if RECENTRED_TRY else None
    solved = _recentred_try(srde, views, mask, recentred, set_planes=set_planes)
    if solved is not None:
        return solved
    hinged = _hinge_try(srde, views, mask, gathered, set_planes=set_planes)
    if hinged is not None:
        return hinged
    near_outline = _near_outline_try(srde, views, mask, gathered, set_planes=set_planes)
    if near_outline is not None:
        return near_outline
    if RECENTRED_NEAR_OUTLINE_TRY and NEAR_OUTLINE_TRY:
        return _recentred_try(srde, views, mask, recentred, near_outline=True,
                              set_planes=set_planes)
    return None


def _near_outline_try(srde: SRDE, views, mask: np.ndarray, gathered: ViewCandidates, *,
                      set_planes: bool = False) -> SRDEResult | None:
    """Return the faces with predictions near the outline matched, if ok.

    (:data:`NEAR_OUTLINE_TRY`.) Every view's candidates propose planes, as in the second
    try. None when no set of faces passes, or when every face of the set that passes
    explains its own light's highlights in ``min_views`` views without those near the
    outline: the caller's failure stands.
    """
    if not NEAR_OUTLINE_TRY:
        return None
    again = _estimate_faces(srde, views, mask, gathered,
                            anchors=tuple(range(srde.rig.n_cameras)), near_outline=True,
                            set_planes=set_planes)
    if again is None or not again.ok:
        return None
    context = gathered.context(srde, mask, all_lights_in_front=False)
    seen = [_own_light_views(context, face) for face in again.faces.faces]
    if min(seen) >= srde.min_views:
        _log.debug("faces: the near-outline try's faces all have their own highlights away "
                   "from the outline (%s views); not taken", seen)
        return None
    return again


def _own_light_views(context: AssignmentContext, face: FaceResult) -> int:
    """Return the views in which ``face``'s plane explains its own light's highlight.

    Scored as ``context`` scores (predictions near the outline taking no candidate
    unless it was made with ``near_outline``).
    """
    matched = context.score(face.plane, at_least=0).matched  # (at_least=0: always a score)
    return int(np.count_nonzero(matched[face.light] >= 0))


def _hinge_try(srde: SRDE, views, mask: np.ndarray, gathered: ViewCandidates, *,
               set_planes: bool = False) -> SRDEResult | None:
    """Return the faces with planes turned about the edges of the planes found, if ok.

    (:data:`HINGE_TRY`.) Each well-seen plane of the pool, turned about every chord
    between the outline's corners, gives the plane that explains the most candidates
    beyond it (:func:`.hinges.hinge_plane`); those planes join the pool. None when no
    set of faces passes: the caller's failure stands.
    """
    if not HINGE_TRY:
        return None
    again = _estimate_faces(srde, views, mask, gathered,
                            anchors=tuple(range(srde.rig.n_cameras)), hinges=True,
                            set_planes=set_planes)
    return again if again is not None and again.ok else None


def _recentred_try(srde: SRDE, views, mask: np.ndarray, recentred: ViewCandidates | None,
                   *, near_outline: bool = False, set_planes: bool = False
                   ) -> SRDEResult | None:
    """Return the faces from candidates whose cut blobs are centred on their arcs, if ok.

    (:data:`RECENTRED_TRY`.) ``recentred``: the candidates so centred
    (:meth:`~.candidates.ViewCandidates.recentred`; None when no blob is cut or the try
    is off). None when there are none, no set of faces passes, or a face's standard
    error exceeds :data:`RECENTRED_MAX_SIGMA_PX` (or no refinement gave one): the
    caller's failure stands. ``near_outline``: predictions near the outline take
    candidates too (:data:`RECENTRED_NEAR_OUTLINE_TRY`).
    """
    if recentred is None:
        return None
    again = _estimate_faces(srde, views, mask, recentred,
                            anchors=tuple(range(srde.rig.n_cameras)), near_outline=near_outline,
                            set_planes=set_planes)
    if again is None or not again.ok:
        return None
    sigmas = _face_sigmas_px(again)
    if not all(sigma <= RECENTRED_MAX_SIGMA_PX for sigma in sigmas):
        _log.debug("faces: the recentred try's faces are pinned down to %s px only", sigmas)
        return None
    return again


def _face_sigmas_px(result: SRDEResult) -> list[float]:
    """Each face's refined standard error over the object, px, of an ``ok`` faces result.

    Infinite for a face without refinement: nothing then pins it down beyond its start
    plane (a try whose faces start from centres alone asks for this bound).
    """
    return [math.inf if face.refinement is None else face.refinement.disparity_sigma_px
            for face in result.faces.faces]


def _estimate_faces(srde: SRDE, views, mask: np.ndarray, gathered,
                    anchors: tuple[int, ...] | None, *, hinges: bool = False,
                    near_outline: bool = False, set_planes: bool = False
                    ) -> SRDEResult | None:
    """:func:`estimate_faces` with the planes proposed from ``anchors``' candidates.

    ``hinges``: the pool's well-seen planes and the planes turned about the outline's
    chords from them (:func:`_hinge_scores`) instead; only sets holding a turned plane
    are tried (the others were the earlier tries'). ``near_outline``: highlights
    predicted near the outline take candidates in every score (:data:`NEAR_OUTLINE_TRY`).
    ``set_planes``: each set is solved from its own planes, and only if refitting them
    to their faces' highlights moved one (:data:`SET_PLANES_RETRY`).
    """
    context = gathered.context(srde, mask, all_lights_in_front=False,
                               near_outline=near_outline)
    scores = [s for s in (context.score(p) for p in context.proposals(anchors=anchors))
              if s is not None]
    turned: list[PlaneScore] = []
    if hinges:
        sources, turned = _hinge_scores(context, scores, mask, srde.min_views)
        scores = sources + turned
    box = search_box(mask, 0)
    u0, v0, u1, v1 = box
    inside = mask[v0:v1, u0:u1]
    ranked, why, pool = choose_faces(context, scores, max_faces=srde.max_faces,
                                     min_views=srde.min_views, box=box, inside=inside,
                                     keep_proposed=anchors is not None, pooled=hinges,
                                     pairs_extended=HINGE_PAIRS_EXTENDED if hinges else 3)
    if hinges:
        ranked = [split for split in ranked
                  if any(face is plane for face in split.scores for plane in turned)]
    if not ranked:
        if why:
            # Evidence of a second plane that splits nothing consistently: the one-plane
            # path weighs the unexplained highlights itself (several lights' merged or cut
            # blobs on one plane look like this too).
            _log.debug("faces: no split holds each face's highlights (%s)", why)
        return None
    # The highlight centres rank the sets; where they cannot tell sets apart, the image
    # decides. The sets tried are those with as many highlights on their own faces as
    # the best (a wrong light's blobs can tie a wrong set with the right one, or rank
    # it first on net support alone; its faces' lobe fits then fail). A set is taken
    # when every face passes its checks and refinement; a set that fails gives way to
    # the next. Two sets of equal rank that both pass: ambiguous. When every set of the
    # best rank fails, the next rank's are tried the same way: a right split can rank
    # below wrong ones that borrow a highlight of another face or light, and the
    # image, which refused those, decides for it.
    failures: list[SRDEResult] = []
    for rank in sorted({s.value[0] for s in ranked}, reverse=True)[:RANKS_TRIED]:
        tied = [s for s in ranked if s.value[0] == rank]
        tried = ([s for s in tied if len(s.scores) == len(tied[0].scores)]
                 + [s for s in tied if len(s.scores) != len(tied[0].scores)])[:MAX_SETS_TRIED]
        solved: tuple[_Split, SRDEResult] | None = None
        for split in tried:
            if solved is not None and split.value < solved[0].value:
                break
            result = _solve_split(srde, views, mask, context, gathered, split, pool, box,
                                  inside, set_planes=set_planes)
            if result is None:
                continue  # the set's own planes are its refitted ones: tried already
            if not result.ok:
                failures.append(result)
            elif solved is None:
                solved = (split, result)
            elif _same_faces(context, solved[1], result):
                continue  # the same faces, reached from another set's starting planes
            else:
                return srde._failed("ambiguous", f"{_TWO_SETS} {len(split.scores)} "
                                    f"planes split the mask with the same support "
                                    f"({split.value[0]} highlights on their own faces; "
                                    f"{solved[0].rule} and {split.rule}) and the image "
                                    "confirms both")
        if solved is not None:
            return solved[1]
    if not failures:
        return None
    first = failures[0]
    if len(failures) == 1:
        return first
    return replace(first, reason=f"{first.reason} (and {len(failures) - 1} other set(s) of "
                   f"face planes failed: " + "; ".join(f.reason for f in failures[1:]) + ")")


def _hinge_scores(context: AssignmentContext, scores: list[PlaneScore], mask: np.ndarray,
                  min_views: int) -> tuple[list[PlaneScore], list[PlaneScore]]:
    """Return the pool's well-seen planes and the distinct planes turned about chords from them.

    A source is a plane of the pool (:func:`_face_pool`) explaining one light's
    highlights in ``min_views`` views. Each is turned about every chord of the outline's
    corners (:func:`.hinges.hinge_chords`), matching candidates within the assignment's
    tolerance and, apart, within a blob radius (cut blobs' centres stray by more than
    the tolerance). A turned plane must explain one light's highlights in ``min_views``
    views, as a face must; the :data:`HINGE_PLANES` explaining the most are kept.
    """
    rig, lights = context.rig, context.lights
    sources = [s for s in _face_pool(context, scores, keep_proposed=True)
               if _views_of_one_light(s) >= min_views]
    chords = hinge_chords(mask, outline_corners(mask))
    tolerances = tuple(sorted({context.tolerance_px,
                               max(context.tolerance_px, context.blob_radius_px)}))
    found: list[PlaneScore] = []
    for source in sources:
        source_uv = np.concatenate([uv for _, _, uv in _mirror_points(rig, lights, source)])
        for chord in chords:
            for plane, _ in hinge_plane(rig, lights, mask, source.plane, chord, source_uv,
                                        context.cands, tolerances):
                score = context.score(plane, near_outline=True)
                if score is not None and _views_of_one_light(score) >= min_views \
                        and all(context.plane_gap_px(score.plane, other.plane) > SAME_PLANE_PX
                                for other in (*sources, *found)):
                    found.append(score)
    found.sort(key=_by_highlights, reverse=True)
    _log.debug("faces: %d plane(s) turned about %d chord(s) from %d source(s)", len(found),
               len(chords), len(sources))
    return sources, found[:HINGE_PLANES]


def _same_faces(context: AssignmentContext, a: SRDEResult, b: SRDEResult) -> bool:
    """Whether two solved sets end on the same face planes (each within SAME_PLANE_PX)."""
    return _same_planes(context, [face.plane for face in a.faces.faces],
                        [face.plane for face in b.faces.faces])


def _same_planes(context: AssignmentContext, planes_a: list[Plane], planes_b: list[Plane]
                 ) -> bool:
    """Whether two sets of planes are the same set: as many, each one near one of the other.

    Near: within ``SAME_PLANE_PX`` over the object (``context.plane_gap_px``).
    """
    return len(planes_a) == len(planes_b) and all(
        any(context.plane_gap_px(p, q) <= SAME_PLANE_PX for q in planes_b) for p in planes_a)


def _solve_split(srde: SRDE, views, mask: np.ndarray, context: AssignmentContext, gathered,
                 split: _Split, pool: list[PlaneScore], box, inside: np.ndarray, *,
                 set_planes: bool = False) -> SRDEResult | None:
    """Solve each face of one set of face planes and piece the faces together.

    An ``ok`` result whose ``faces`` holds every face, or the first check that failed.
    Each face starts from its plane refitted to its own highlights; with ``set_planes``
    from the set's own plane instead (:data:`SET_PLANES_RETRY`), and None when no refit
    moved a plane by more than ``SAME_PLANE_PX`` (the same planes: solved already).
    """
    rig, lights = srde.rig, srde.lights_m
    edge_px = gathered.blob_radius_px
    # Each face's plane refitted to its own highlights alone (those away from the edge
    # when there are two or more: the edge may pull a cut blob's centre; never those on
    # another face), and the mask split again by the refitted planes.
    where = _highlights_by_face(rig, lights, list(split.scores), split.labels, box, edge_px)
    # Every highlight a face's plane explains off the other faces' parts is that face's,
    # whether or not its fit uses it (near the edge its centre may be pulled); the fits'
    # own highlights below are some of these.
    theirs = [replace(score, matched=np.where(_own(w, f + 1) | (w == CUT_BY_EDGE),
                                              score.matched, -1))
              for f, (score, w) in enumerate(zip(split.scores, where, strict=True))]
    owns, refitted = [], []
    for f, (score, w) in enumerate(zip(split.scores, where, strict=True)):
        strict = np.where(w == f + 1, score.matched, -1)
        own = replace(score, matched=strict if np.count_nonzero(strict >= 0) >= 2
                      else np.where(_own(w, f + 1), score.matched, -1))
        plane = context.fit(own) if own.n_matched >= 2 else None
        owns.append(own)
        refitted.append(own if plane is None else replace(own, plane=plane))
    if not set_planes:
        return _solve_faces(srde, views, mask, context, gathered, split.rule, refitted,
                            theirs, pool, box, inside)
    moved_px = [context.plane_gap_px(a.plane, b.plane)
                for a, b in zip(owns, refitted, strict=True)]
    f = int(np.argmax(moved_px))
    if moved_px[f] <= SAME_PLANE_PX:
        return None
    result = _solve_faces(srde, views, mask, context, gathered, split.rule, owns, theirs,
                          pool, box, inside)
    if not result.ok:
        return result
    sigmas = _face_sigmas_px(result)
    loose = int(np.argmax(sigmas))
    if sigmas[loose] > SET_PLANES_MAX_SIGMA_PX:
        return srde._failed("inconsistent", f"faces: from the set's own planes, face "
                            f"{loose + 1}'s refined plane has a standard error of "
                            f"{sigmas[loose]:.3f} px (limit {SET_PLANES_MAX_SIGMA_PX:g} px)",
                            plane=result.faces.faces[loose].plane)
    return replace(result, notes=(*result.notes, f"faces: solved from the set's own planes "
                                  f"after every try from planes refitted to each face's own "
                                  f"highlights failed (face {f + 1}'s refit moved its plane "
                                  f"{moved_px[f]:.2f} px)"))


def _solve_faces(srde: SRDE, views, mask: np.ndarray, context: AssignmentContext, gathered,
                 rule: str, chosen: list[PlaneScore], theirs: list[PlaneScore],
                 pool: list[PlaneScore], box, inside: np.ndarray) -> SRDEResult:
    """Solve each face of a set from the planes of ``chosen`` (:func:`_solve_split`).

    ``theirs``: each face's highlights off the other faces' parts (a list this call may
    extend).
    """
    rig, lights = srde.rig, srde.lights_m
    edge_px = gathered.blob_radius_px
    labels = split_faces([s.plane for s in chosen], rig, box, inside, rule)
    faces: list[FaceResult] = []
    results = []
    modelled_by_face = []
    face_set = _FaceSet(srde, views, tuple(chosen), labels, box, gathered, context)
    parts = _face_parts(labels, box, mask.shape, len(chosen))
    for f, face_mask in enumerate(parts):
        reading = _checked_face(face_set, face_mask, f)
        search = RETRY_SEARCHES.get(reading.refused_by) if RADIUS_RETRY else None
        if search is not None and srde.light_radii_m[reading.light] is None:
            # Seen in few views, a point light's lobe cannot take the lamp's disc in every
            # view at once, and the plane tilts (or is left loose) instead: the face is
            # read again with the lamp's radius fitted (as its second reading below does
            # for every face) before the set is refused.
            again = _checked_face(face_set, face_mask, f, radius_search=search)
            if again.face is None:
                # Whether the search took a radius at all (a loose face's must save most
                # of the point light's cost) is part of why the reading failed.
                radius = "".join(f"; {note}" for note in again.notes
                                 if note.startswith(RADIUS_NOTE))
                return replace(reading.result, reason=f"{reading.result.reason} (read again "
                               f"with the lamp's radius fitted: {again.why}{radius})")
            reading = again
        if reading.face is None:
            return reading.result
        results.append(reading.result)
        faces.append(reading.face)
        modelled_by_face.append(reading.modelled)
    # The refined planes move the edge a little: split again, and check again.
    planes = [face.plane for face in faces]
    labels = split_faces(planes, rig, box, inside, rule)
    if SECOND_READING:
        faces, results = _read_again(srde, views, mask, faces, results, modelled_by_face,
                                     labels, box, context)
        planes = [face.plane for face in faces]
        labels = split_faces(planes, rig, box, inside, rule)
    refined = [replace(s, plane=p) for s, p in zip(chosen, planes, strict=True)]
    ok, _, problems = _rule_fit(_highlights_by_face(rig, lights, refined, labels, box, edge_px),
                                srde.min_views)
    if not ok:
        return srde._failed("face_split", f"faces: after refinement the {rule} rule no longer "
                            f"puts each face's highlights on its own part ({problems})")
    small = _too_small(labels, inside)
    if small:
        return srde._failed("face_split", small)
    face_disparity = [plane_disparity(face.plane, rig, window=box) for face in faces]
    open_px = _edge_uncertain_px(faces, face_disparity, labels)
    if open_px > MAX_OPEN_EDGE_FRACTION * np.count_nonzero(inside):
        # A shallow edge between faces whose planes the images pin down loosely: a plane
        # error within the standard errors moves the edge across many pixels.
        return srde._failed("face_split", f"faces: the refined planes' standard errors leave "
                            f"{open_px} of the mask's {np.count_nonzero(inside)} px to either "
                            f"of two faces (within {EDGE_SIGMAS:g} standard errors of their "
                            f"edge; limit {MAX_OPEN_EDGE_FRACTION:.0%})")
    # (A highlight near the edge that a face's fit left out may lie away from the edge
    # the refined planes draw: it is still explained.)
    if FINAL_PLANES_EXPLAIN:
        # Only the face's own light counts: another light's highlight that a face's plane
        # happens to predict there is no sign that the face accounts for it.
        for face in faces:
            final = context.score(face.plane, at_least=1, near_outline=True)
            if final is not None:
                own_light = np.full(final.matched.shape, -1)
                own_light[face.light] = final.matched[face.light]
                theirs.append(replace(final, matched=own_light))
    stray = _unexplained_reference(rig, gathered, theirs, labels, box, edge_px)
    if stray:
        # With every light known, each highlight on the object is some light's on some
        # face: one that no face explains means a face is missing or a plane is wrong.
        return srde._failed("face_split", f"faces: the reference view's highlight(s) at "
                            f"{stray} lie on the object away from the faces' edges, and none of "
                            f"the {len(faces)} faces explains them")
    left_out = unexplained_plane(context, pool, planes, srde.min_views)
    if left_out is not None:
        # Near the faces' edge the reference check above excuses a blob (the edge cuts
        # highlights); a whole light's highlights in several views are not cut blobs.
        views_left = sorted({int(j) for k in range(left_out.matched.shape[0])
                             for j in np.flatnonzero(left_out.matched[k] >= 0)})
        return srde._failed("face_split", f"faces: a plane explains highlights in views "
                            f"{views_left} that none of the {len(faces)} faces explains: a face "
                            f"is missing or a plane is wrong", plane=left_out.plane)
    disparity = np.full(inside.shape, np.nan, dtype=np.float32)
    for f, face in enumerate(faces):
        part = labels == f + 1
        disparity[part] = face_disparity[f][part]
        faces[f] = FaceResult(face.label, face.plane, face.light, face.virtual_light_m,
                              face.highlight_centers, face.used_views, face.residual_px,
                              int(part.sum()), face.refinement, face.notes)
    main = max(range(len(faces)), key=lambda f: faces[f].n_px)
    first = results[main]
    notes = (f"faces: {len(faces)} faces ({rule}: each pixel sees the "
             f"{'farther' if rule == 'ridge' else 'nearer'} plane), "
             + ", ".join(f"face {f.label} {f.n_px} px by light {f.light}" for f in faces),
             *(f"face {f.label}: {note}" for f in faces for note in f.notes))
    return SRDEResult("ok", "", disparity, box, mask.shape, first.plane, first.virtual_light_m,
                      first.highlight_centers, first.used_views, first.residual_px,
                      srde.method, notes, first.detections, first.refinement,
                      faces=Faces(rule, labels, tuple(faces)))


def _checked_face(face_set: _FaceSet, face_mask: np.ndarray, f: int, *,
                  radius_search: dict | None = None) -> _FaceReading:
    """Solve face ``f`` of a set on its part (``face_mask``) and check its lobe fit.

    ``radius_search``: as :func:`_solve_face`.
    """
    srde, context = face_set.srde, face_set.context
    tolerance_px = 2.0 * srde.max_residual_px

    def failed(check: str, status: str, why: str, plane, light: int | None = None):
        failure = srde._failed(status, f"face {f + 1} of {len(face_set.chosen)}: {why}",
                               plane=plane)
        return _FaceReading(failure, None, [], check, why, light,
                            result.notes if result.ok else ())

    result, face, modelled = _solve_face(face_set, face_mask, f, radius_search=radius_search)
    if result.ok and srde.refine and not face.refinement:
        # The planes that drew the edge may be a pixel off, the edge then some pixels
        # off, and the face's windows hold its neighbour's shading: read the face once
        # more without the band where its plane and a neighbour's are within
        # RETRY_EDGE_PX of each other (where the edge may lie).
        narrow, again = _read_off_edge(face_set, face_mask, f, RETRY_EDGE_PX,
                                       radius_search=radius_search)
        if again is not None and again[0].ok and again[1].refinement:
            (result, face, modelled), face_mask = again, narrow
    if not result.ok:
        return failed("reading", result.status, result.reason, result.plane)
    if srde.refine and not face.refinement:
        # A face's highlights are few and may lie near its edge: without the image's
        # confirmation its plane from the centres alone is not trusted.
        return failed("unconfirmed", "inconsistent", f"the photometric refinement did not "
                      f"confirm its plane ({face.refinement.reason})", face.plane, face.light)
    sigma_px = face.refinement.disparity_sigma_px if face.refinement is not None else 0.0
    if sigma_px > MAX_FACE_SIGMA_PX:
        # The lobe fit does not pin the face down: another plane SAME_PLANE_PX away
        # would fit within three standard errors.
        return failed("uncertain", "inconsistent", f"the photometric refinement leaves its "
                      f"plane uncertain by {sigma_px:.2f} px (standard error over the object; "
                      f"limit {MAX_FACE_SIGMA_PX:g} px)", face.plane, face.light)
    moved_px = context.plane_gap_px(face.refinement.initial_plane, face.plane) \
        if face.refinement is not None else 0.0
    if moved_px > SAME_PLANE_PX and lobes_prefer(
            srde, face_set.views, face_mask, face.light, modelled, face.used_views,
            face.plane, face.refinement.initial_plane):
        # Centres pulled by the faces' edge or a clipped top can put the start a pixel
        # off; the lobe fit that lands on a plane explaining the face's images
        # decisively better than its start, on both planes' samples, stands.
        face = replace(face, notes=(*face.notes, f"refinement: moved the plane by "
                                    f"{moved_px:.2f} px from its highlight centres' plane, "
                                    f"which explains the images at least "
                                    f"{DECISIVE_COST_RATIO:g}x worse"))
    elif moved_px > SAME_PLANE_PX:
        # The image and the highlight centres disagree about the face: a plane pieced
        # from the wrong highlights, or windows the edge cuts, that the lobe fit bent.
        return failed("move", "inconsistent", f"{_MOVED} {moved_px:.2f} px over the object "
                      f"(limit {SAME_PLANE_PX:g} px)", face.plane, face.light)
    if moved_px > SAME_PLANE_PX:
        # A start that far off put the edge where the face's part may hold its
        # neighbour's shading, which can pull the fit too: the move must hold when the
        # face is read without that band.
        off_edge_px = _off_edge_gap_px(face_set, face_mask, f, face, moved_px,
                                       radius_search=radius_search)
        if off_edge_px is None:
            if sigma_px > UNCHECKED_MOVE_MAX_SIGMA_PX:
                return failed("move", "inconsistent", f"{_MOVED} {moved_px:.2f} px, nothing "
                              f"read away from the faces' edge confirms the move, and its "
                              f"standard error ({sigma_px:.3f} px) is more than "
                              f"{UNCHECKED_MOVE_MAX_SIGMA_PX:g} px", face.plane, face.light)
        elif off_edge_px > OFF_EDGE_PX:
            return failed("move", "inconsistent", f"{_MOVED} {moved_px:.2f} px, but read "
                          f"without the band where the faces' edge lies if the planes are "
                          f"that far off, it lands {off_edge_px:.2f} px from there (limit "
                          f"{OFF_EDGE_PX:g} px): the move rests on pixels by the edge",
                          face.plane, face.light)
    miss_px = _worst_miss_px(srde.rig, srde.lights_m[face.light], face,
                             face_set.labels == f + 1, face_set.box,
                             face_set.gathered.blob_radius_px)
    if miss_px > tolerance_px:
        return failed("miss", "inconsistent", f"its refined plane misses its own highlights "
                      f"by up to {miss_px:.1f} px (limit {tolerance_px:g} px)", face.plane,
                      face.light)
    return _FaceReading(result, face, modelled, light=face.light)


def _face_parts(labels: np.ndarray, box, shape: tuple[int, int], n_faces: int
                ) -> list[np.ndarray]:
    """Each face's part of the mask as the refinement reads it, ``(H, W)`` bool each.

    Faces ``1 .. n_faces`` of ``labels`` (over ``box``); a face without pixels has an
    empty part.
    The refinement reads each face away from its neighbours: the edge is where the
    planes put it, and blocks near it may hold the neighbour's shading, so the pixels
    within :data:`FACE_EDGE_MARGIN_PX` of another face's part are left out.
    """
    u0, v0, u1, v1 = box
    near_edge = _near_other_face(labels, FACE_EDGE_MARGIN_PX).view(bool)
    parts = []
    for f in range(1, n_faces + 1):
        part = np.zeros(shape, dtype=bool)
        part[v0:v1, u0:u1] = (labels == f) & ~near_edge
        parts.append(part)
    return parts


def _read_again(srde: SRDE, views, mask: np.ndarray, faces: list[FaceResult], results,
                modelled_by_face, labels: np.ndarray, box, context: AssignmentContext
                ) -> tuple[list[FaceResult], list[SRDEResult]]:
    """Each face refined once more on its part as the refined planes draw it (``labels``).

    Starts from the face's refined plane and reads the same highlights' windows, less
    the pixels within :data:`FACE_EDGE_MARGIN_PX` of another face's part. A face whose
    second reading is not confirmed, not pinned down or moves it by more than
    ``SAME_PLANE_PX``, or whose part is smaller than :data:`MIN_FACE_PX`, keeps its
    first. Returns the faces and their results.
    """
    lights = srde.lights_m
    out, read = [], []
    parts = _face_parts(labels, box, mask.shape, len(faces))
    for f, (face, face_mask) in enumerate(zip(faces, parts, strict=True)):
        if np.count_nonzero(face_mask) < MIN_FACE_PX:
            # The refined planes leave the face (almost) no part: nothing to read, and
            # the split's size check refuses the set.
            out.append(face)
            read.append(results[f])
            continue
        # A face tilts to make up for a lamp's unknown radius (refine/radius.py), most
        # where few views see its light: this reading fits the radius too.
        again = srde._finish_on_plane(face_mask, face.plane, lights[face.light],
                                      face.used_views, face.highlight_centers,
                                      results[f].detections, (), views=views,
                                      modelled_lights=[lights[k] for k in modelled_by_face[f]],
                                      radius_search={} if FIT_RADIUS else None)
        refinement = again.refinement
        if (again.ok and refinement is not None and refinement.ok
                and refinement.disparity_sigma_px <= MAX_FACE_SIGMA_PX
                and context.plane_gap_px(again.plane, face.plane) <= SAME_PLANE_PX):
            out.append(replace(face, plane=again.plane, virtual_light_m=again.virtual_light_m,
                               refinement=refinement, notes=(*face.notes, *again.notes)))
            read.append(again)
        else:
            out.append(face)
            read.append(results[f])
    return out, read


def _unexplained_reference(rig, gathered, scores: list[PlaneScore], labels, box,
                           edge_px: float) -> str:
    """List the reference candidates on a face's part, off its edges, that no face explains.

    A *glow* is not a highlight: a blob :data:`GLOW_AREA_RATIO` times the median
    candidate's area or more whose peak rises :data:`GLOW_SCORE_RATIO` times the median
    candidate's or less above its surroundings is a face's diffuse shading, brighter
    than the object's background level, not a light's mirror image.
    """
    ref = rig.reference
    explained = {int(q) for s in scores for q in s.matched[:, ref] if q >= 0}
    found = [d for dets in gathered.found for d in dets]
    area = float(np.median([d.area_px for d in found]))
    score = float(np.median([d.score for d in found]))
    stray = []
    for q, uv in enumerate(gathered.centers_uv[ref]):
        point = np.asarray(uv, dtype=np.float64)[None]
        det = gathered.found[ref][q]
        glow = det.area_px >= GLOW_AREA_RATIO * area and det.score <= GLOW_SCORE_RATIO * score
        if q not in explained and not glow and _label_at(labels, box, point)[0] > 0 \
                and not _near_other_face_at(labels, box, point, edge_px)[0]:
            stray.append(f"({uv[0]:.0f}, {uv[1]:.0f})")
    return ", ".join(stray)


def unexplained_plane(context: AssignmentContext, pool: list[PlaneScore],
                       planes: list[Plane], min_views: int) -> PlaneScore | None:
    """Return a hypothesis explaining one light's highlights that no face accounts for.

    With every light known, a highlight on the object is some light's on some face. A
    face accounts for a blob its plane explains, and for one whose box holds its
    plane's prediction of some light on the object (or within a blob radius of its
    outline: the blob's near side is on the object) or whose centre lies within
    :data:`~.assignment.BLEND_RADII` blob radii of one (a blob merged with another, or cut
    by the faces' edge or the outline with the predicted centre on the hidden side, has
    its centre moved by up to a few radii). A plane (from
    the hypotheses the faces were chosen from) that explains one light's highlights in
    ``min_views`` views none of the faces accounts for is a face left out: its
    highlights lie on the parts given to its neighbours (the middle face of three left
    out), so the pieced disparity would be wrong there. None when there is none.
    """
    reach_px = BLEND_RADII * context.blob_radius_px
    # A highlight whose mirror point lies just off the outline still shows its blob's
    # near half on the object: predictions within a blob radius of the mask count.
    side = 2 * int(math.ceil(context.blob_radius_px)) + 1
    near_mask = dilated(context.mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE,
                                                                (side, side)))
    covered: set[tuple[int, int]] = set()
    for plane in planes:
        score = context.score(plane)
        if score is not None:
            covered |= explained_pairs(score)
        uv, on_object, _ = context.predict(plane, region=near_mask)
        for j, boxes in enumerate(context.boxes):
            p = uv[on_object[:, j], j]  # (M, 2)
            near = np.linalg.norm(context.cands[j][:, None] - p[None], axis=2) <= reach_px
            for q, (a0, b0, a1, b1) in enumerate(boxes):
                held = (p[:, 0] >= a0) & (p[:, 0] < a1) & (p[:, 1] >= b0) & (p[:, 1] < b1)
                if np.any(held | near[q]):
                    covered.add((j, q))
    return next((p for p in pool if _own_views(p, covered) >= min_views), None)


def _worst_miss_px(rig, light_m: np.ndarray, face: FaceResult, part: np.ndarray, box,
                   reach_px: float) -> float:
    """Largest distance from a face's used highlight centre to where its plane puts it, px.

    ``part``: the face's part of the mask over ``box`` ``(h, w)`` bool. A highlight its
    part's border may cut (:data:`CUT_MISS_ALLOWED`: its mirror point within ``reach_px``
    of the border, the centre's deeper inside) counts only if missed by more than
    ``reach_px``; 0 when every highlight is so excused.
    """
    views = np.flatnonzero(face.used_views)
    virtual = face.plane.mirror(light_m)
    predicted = np.stack([rig.project(virtual, camera=int(j)) for j in views])
    centers = face.highlight_centers[views]
    miss = np.linalg.norm(predicted - centers, axis=1)
    if CUT_MISS_ALLOWED:
        # Depth into the part, px: 0 on pixels off it (beyond the box too).
        inside = cv2.distanceTransform(np.pad(part, 1).view(np.uint8), cv2.DIST_L2,
                                       cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
        origins = rig.centers_m[views]
        lit, _ = reflection_points(face.plane, virtual, origins)
        # Where each centre's ray meets the plane: the segment from the camera through a
        # point on the ray (all cameras share one orientation).
        seen, _ = reflection_points(face.plane, origins + rig.rays(centers), origins)
        depth_lit, depth_seen = (_value_at(inside, box, np.nan_to_num(rig.project(p), nan=-1e9),
                                           np.float64) for p in (lit, seen))
        excused = (depth_lit < reach_px) & (depth_seen > depth_lit) & (miss <= reach_px)
        miss = miss[~excused]
    return float(np.max(miss)) if miss.size else 0.0


def _off_edge_gap_px(face_set: _FaceSet, face_mask: np.ndarray, f: int, face: FaceResult,
                     moved_px: float, *, radius_search: dict | None = None) -> float | None:
    """How far the face's lobe fit lands from its moved plane without the edge's band, px.

    The face is read again without the pixels where its start plane and a neighbour's
    are within ``moved_px`` of each other (where the faces' edge lies if the planes are
    that far off) and refined as before (``radius_search`` as :func:`_solve_face`). None
    when nothing is left out, too little is left, or that fit fails: then nothing says
    the move is wrong.
    """
    _, again = _read_off_edge(face_set, face_mask, f, moved_px, radius_search=radius_search)
    if again is None or not again[0].ok or not again[1].refinement:
        return None
    return face_set.context.plane_gap_px(again[1].plane, face.plane)


def _read_off_edge(face_set: _FaceSet, face_mask: np.ndarray, f: int, limit_px: float, *,
                   radius_search: dict | None = None):
    """Solve face ``f`` again without the band where the edge lies if planes are off.

    The band: pixels where the face's start plane and a neighbour's are within
    ``limit_px`` of each other (:func:`_edge_band`). Returns ``(narrow, solved)``: the
    face's mask without the band, and :func:`_solve_face`'s answer on it, None when the
    band holds none of the face's pixels or leaves fewer than :data:`MIN_FACE_PX`
    (``radius_search`` as :func:`_solve_face`).
    """
    u0, v0, u1, v1 = box = face_set.box
    narrow = face_mask.copy()
    narrow[v0:v1, u0:u1] &= ~_edge_band(face_set.chosen, f, face_set.srde.rig, box, limit_px)
    if not MIN_FACE_PX <= np.count_nonzero(narrow) < np.count_nonzero(face_mask):
        return narrow, None
    return narrow, _solve_face(face_set, narrow, f, radius_search=radius_search)


def _edge_uncertain_px(faces: list[FaceResult], disparity: list[np.ndarray],
                       labels: np.ndarray) -> int:
    """Pixels that may belong to either of two faces, given the planes' standard errors.

    A pixel of face ``a`` or ``b`` where the two planes' disparities (``disparity``, each
    face's over the box) differ by less than :data:`EDGE_SIGMAS` times their combined
    standard error (``hypot`` of the refined faces' ``disparity_sigma_px``) changes face
    when the planes move within it.
    """
    sigma = [face.refinement.disparity_sigma_px if face.refinement is not None else 0.0
             for face in faces]
    undecided = np.zeros(labels.shape, dtype=bool)
    for a, b in combinations(range(len(faces)), 2):
        limit = EDGE_SIGMAS * math.hypot(sigma[a], sigma[b])
        either = (labels == faces[a].label) | (labels == faces[b].label)
        undecided |= either & (np.abs(disparity[a] - disparity[b]) < limit)
    return int(np.count_nonzero(undecided))


def _edge_band(scores: list[PlaneScore], f: int, rig, box, limit_px: float) -> np.ndarray:
    """Pixels of the box where face ``f``'s plane and another's are within ``limit_px``.

    Returns ``(v1 - v0, u1 - u0)`` bool: where a face's plane off by ``limit_px`` moves
    the faces' edge to.
    """
    own = plane_disparity(scores[f].plane, rig, window=box)
    band = np.zeros(own.shape, dtype=bool)
    for g, other in enumerate(scores):
        if g != f:
            band |= np.abs(own - plane_disparity(other.plane, rig, window=box)) < limit_px
    return band


def _too_small(labels: np.ndarray, inside: np.ndarray) -> str:
    """Why a face's part is too small ("" if none is)."""
    total = int(np.count_nonzero(inside))
    limit = max(MIN_FACE_PX, int(math.ceil(MIN_FACE_FRACTION * total)))
    counts = np.bincount(labels.ravel(), minlength=int(labels.max()) + 1)[1:]
    small = [f"face {f + 1}: {int(n)} px" for f, n in enumerate(counts) if n < limit]
    if small:
        return (f"faces: a face's part of the {total}-px mask is too small ("
                + ", ".join(small) + f"; needs {limit} px)")
    return ""


def _face_light(face_set: _FaceSet, f: int) -> tuple[int, np.ndarray, np.ndarray]:
    """Return the light that fixes face ``f``'s plane: the one seen on its part in most views.

    Returns ``(main, own, where)``: the light's index (ties to the closest fit), the
    ``(K, N)`` bool of each light's highlights explained on the face's own part, and
    :func:`_highlights_by_face`'s labels of them.
    """
    srde, score, label = face_set.srde, face_set.chosen[f], f + 1
    where = _highlights_by_face(srde.rig, srde.lights_m, [score], face_set.labels,
                                face_set.box, face_set.gathered.blob_radius_px, [label])[0]
    own = _own(where, label) & (score.matched >= 0)
    counts = own.sum(axis=1)
    distance = np.where(own, score.distance_px, np.inf)
    main = int(max(range(len(srde.lights_m)),
                   key=lambda k: (counts[k], -float(np.min(distance[k])))))
    return main, own, where


def _solve_face(face_set: _FaceSet, face_mask: np.ndarray, f: int, *,
                radius_search: dict | None = None):
    """Check and refine face ``f`` of a set on its part of the mask (``face_mask``).

    Returns ``(SRDEResult, FaceResult or None, modelled)``, ``modelled`` the indices of
    the lights the refinement rendered beside the face's own.

    The face's light must be seen on its own part in ``srde.min_views`` views.
    ``radius_search``: None, the lamp a point (or its radius, where the rig knows it);
    else the refinement fits the lamp's radius too, if the rig does not know it, with
    these options of :func:`~.refine.radius.refine_plane_and_radius` (a dict).
    """
    srde, score, label, gathered = face_set.srde, face_set.chosen[f], f + 1, face_set.gathered
    rig, lights = srde.rig, srde.lights_m
    main, own, where = _face_light(face_set, f)
    counts = own.sum(axis=1)
    if counts[main] < srde.min_views:
        return srde._failed("too_few_views", f"faces: face {label} keeps its own highlights "
                            f"on its own part in {int(counts[main])} view(s) (needs "
                            f"{srde.min_views})", plane=score.plane), None, []
    centers = np.full((rig.n_cameras, 2), np.nan)
    for j in np.flatnonzero(own[main]):
        centers[j] = gathered.centers_uv[j][score.matched[main, j]]
    used = np.isfinite(centers[:, 0])
    detections = tuple(
        next((d for d in gathered.found[j] if np.allclose(d.center_uv, centers[j])),
             HighlightDetection.missing(f"no highlight of light {main} on face {label}"))
        for j in range(rig.n_cameras))
    # Lights whose highlights on this face come near the main one's are rendered with it.
    near = near_lights(score.on_object, score.predicted_uv, main, gathered.blob_radius_px)
    modelled = [k for k in np.flatnonzero(near).tolist() if np.any(_own(where[k], label))]
    result = srde._finish_on_plane(face_mask, score.plane, lights[main], used, centers,
                                   detections, (), views=face_set.views,
                                   modelled_lights=[lights[k] for k in modelled],
                                   radius_search=radius_search)
    face = None
    if result.ok:
        face = FaceResult(label, result.plane, main, result.virtual_light_m, centers, used,
                          result.residual_px, int(face_mask.sum()), result.refinement,
                          result.notes)
    return result, face, modelled
