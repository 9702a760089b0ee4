"""Which highlight belongs to which known light, and the plane they share.

The brightest blob of one view need not belong to the same light as that of another:
triangulating them together gives a wrong virtual light with a small residual. The
lights' positions are known, and that settles the correspondence by geometry:

* one light's highlights in all views are the images of *one* point, its virtual light,
  so in a rectified rig they sit on the reference highlight's baseline lines at a single
  inverse depth;
* every light's virtual light is the mirror image of that light across the *same*
  plane, so a plane proposed from one light's virtual light predicts where every other
  light's highlight must appear, and on which views it lands on the object.

:func:`assign_lights` proposes a plane for every pairing of a reference-view candidate
(:mod:`.candidates`) with a candidate on its baseline line in another view and every
light, scores each plane by the candidates it explains (and the on-object highlights it
predicts that are missing), refits the best one to all the highlights it explains
(:func:`fit_mirror_plane`), and reports the assignment with its evidence. When another
plane explains the candidates as well, the object is reported ``"ambiguous"``: a wrong
assignment yields a wrong plane with a small residual, so a tie is a reasoned failure,
never a guess. Pure geometry on highlight centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..boxes import eroded
from ..geometry import CameraRig, Plane, plane_disparity, plane_from_lights, project_points
from .highlight import search_box
from .refine.samples import references_from_views

__all__ = [
    "AssignmentContext",
    "LightAssignment",
    "LightsSolution",
    "PlaneScore",
    "assign_lights",
    "box_corners",
    "explained_pairs",
    "fit_mirror_plane",
    "plane_gap_px",
    "reflection_points",
]


#: Two planes whose disparity differs by less than this over the object's box (pixels)
#: are the same answer.
SAME_PLANE_PX = 0.5


#: Two lights' highlights predicted closer than this many half-maximum radii can merge
#: into one blob.
BLEND_RADII = 3.0


#: A plane with more evidence against it (predicted on-object highlights that are not
#: there, on-object blobs no light explains) than this fraction of the highlights it
#: explains is not the answer: reported "inconsistent" rather than guessed.
UNEXPLAINED_RATIO = 2.0


_LIGHT_BEHIND = "put a light behind the plane"

#: A rival that explains only the best plane's highlights, as another light's, keeps the
#: object undecided when its RMS distance to them is this many times smaller (on faces
#: taken as their own masks: wrong planes fitted 0.4-0.5 px, the true ones 0.01-0.05).
CLOSER_FIT_RATIO = 5.0


#: The best plane is decided against its strongest rival when its net support (explained
#: highlights less the evidence against) is larger by at least this much.
DECISIVE_MARGIN = 2


#: Rounds of "refit the plane to what it explains, then match again".
_REFIT_ROUNDS = 3

#: The mirror-plane fit stops when a step lowers the squared residuals by less than this
#: fraction, or would move no centre by more than this many pixels (linearised).
_FIT_COST_TOLERANCE = 1e-12
_FIT_STEP_TOLERANCE_PX = 1e-7
_FIT_MAX_ITERATIONS = 50


@dataclass(frozen=True)
class LightAssignment:
    """The highlights of one light on the object, and how well the plane explains them.

    Parameters
    ----------
    light : int
        Index of the light in the lights given.
    centers_uv : numpy.ndarray, (N, 2) float64
        Highlight centre assigned to this light per view, pixels; NaN where none.
    predicted_uv : numpy.ndarray, (N, 2) float64
        Where the fitted plane puts this light's highlight in every view, pixels.
    on_object : numpy.ndarray, (N,) bool
        Views where the predicted highlight lands on the object (so a candidate was
        expected there).
    missing : numpy.ndarray, (N,) bool
        Views where it lands on the object, no candidate explains it and the view is dark
        there (not excused as blended with another light's or cut by the outline).
    residuals_px : numpy.ndarray, (N,) float64
        Distance between assigned and predicted centre, pixels; NaN where none.
    virtual_light_m : numpy.ndarray, (3,) float64
        The light mirrored across the fitted plane, array frame, metres.
    """

    light: int
    centers_uv: np.ndarray
    predicted_uv: np.ndarray
    on_object: np.ndarray
    missing: np.ndarray
    residuals_px: np.ndarray
    virtual_light_m: np.ndarray

    @property
    def n_views(self) -> int:
        """Views in which this light's highlight was assigned."""
        return int(np.count_nonzero(np.isfinite(self.centers_uv[:, 0])))

    @property
    def missing_views(self) -> tuple[int, ...]:
        """Views where the highlight should be on the object but no candidate was there."""
        return tuple(int(j) for j in np.flatnonzero(self.missing))


@dataclass(frozen=True)
class LightsSolution:
    """Outcome of :func:`assign_lights`.

    Parameters
    ----------
    status : {"ok", "no_highlight", "too_few_views", "ambiguous"}
    reason : str
        Why it failed, with the numbers ("" if ok).
    plane : Plane or None
        The plane fitted to every assigned highlight of every light (the best
        hypothesis's plane when ambiguous; None when no hypothesis was possible).
    assignments : tuple of LightAssignment
        One per light, in the lights' order (empty if no plane).
    residual_px : float
        RMS distance between assigned and predicted centres over all assignments, px.
    hypotheses : int
        Planes proposed and scored.
    evidence : str
        The winner's and the best different plane's support, in words.
    candidates_uv : tuple of numpy.ndarray
        The candidates ``(m_j, 2)`` of every view the assignment chose from.
    merged_blobs : tuple of (int, int)
        ``(view, candidate)`` of the blobs the plane explains as several lights'
        highlights merged (their centres measure no light).
    rival_plane : Plane or None
        The best hypothesis whose plane is a different answer, if any.
    """

    status: str
    reason: str
    plane: Plane | None
    assignments: tuple[LightAssignment, ...]
    residual_px: float
    hypotheses: int
    evidence: str
    candidates_uv: tuple[np.ndarray, ...] = field(repr=False, default=())
    merged_blobs: tuple[tuple[int, int], ...] = ()
    rival_plane: Plane | None = field(repr=False, default=None)

    @property
    def ok(self) -> bool:
        """Whether a plane was found and is unambiguous."""
        return self.status == "ok"

    @property
    def n_observations(self) -> int:
        """Assigned highlight centres, all lights and views together."""
        return sum(a.n_views for a in self.assignments)

    @property
    def explained_lights(self) -> list[int]:
        """The lights with assigned highlights, ascending."""
        return [a.light for a in self.assignments if a.n_views]

    def to_dict(self) -> dict:
        """JSON-ready summary of the assignment and its evidence."""
        return {
            "status": self.status,
            "reason": self.reason,
            "hypotheses": self.hypotheses,
            "evidence": self.evidence,
            "residual_px": None if not math.isfinite(self.residual_px) else self.residual_px,
            "merged_blobs": [[int(j), int(q)] for j, q in self.merged_blobs],
            "lights": [{
                "light": a.light,
                "views": [int(j) for j in np.flatnonzero(np.isfinite(a.centers_uv[:, 0]))],
                "missing_views": list(a.missing_views),
                "virtual_light_m": [float(v) for v in a.virtual_light_m],
            } for a in self.assignments],
        }


@dataclass(frozen=True)
class _Score:
    """What one plane explains."""

    plane: Plane
    matched: np.ndarray  # (K, N) int: candidate index per light and view, -1 if none
    distance_px: np.ndarray  # (K, N) float, NaN where unmatched
    predicted_uv: np.ndarray  # (K, N, 2)
    on_object: np.ndarray  # (K, N) bool
    missing: np.ndarray  # (K, N) bool: on the object, unexplained, and dark there
    n_strays: int  # candidates on the object that no light explains
    blends: tuple[tuple[int, int], ...]  # (view, candidate) of blobs of merged highlights

    @property
    def explained_lights(self) -> np.ndarray:
        """Indices of the lights with at least one explained highlight, ascending."""
        return np.flatnonzero((self.matched >= 0).any(axis=1))

    @property
    def n_matched(self) -> int:
        return int(np.count_nonzero(self.matched >= 0))

    @property
    def n_missing(self) -> int:
        return int(np.count_nonzero(self.missing))

    @property
    def n_against(self) -> int:
        """Evidence against the plane: missing highlights and stray candidates."""
        return self.n_missing + self.n_strays

    @property
    def support(self) -> int:
        """What the plane explains: highlights and blobs of merged highlights."""
        return self.n_matched + len(self.blends)

    def outweighed(self, ratio: float) -> bool:
        """Whether the evidence against, times ``ratio``, exceeds the support."""
        return self.n_against * ratio > self.support

    @property
    def key(self) -> tuple[int, int, float]:
        """Larger is better: net support, then explained highlights, then residual.

        Net support is the explained highlights and merged blobs less the evidence against.

        A plane that explains one more highlight but predicts several that are not there
        is the worse answer: each missing highlight is as much a measurement as a found
        one. A blob explained as two lights' highlights merged supports the plane though
        its centre measures neither.
        """
        return (self.support - self.n_against, self.n_matched, -self.rms_px)

    @property
    def rms_px(self) -> float:
        """RMS distance of the explained highlights from their predictions (inf if none)."""
        d = self.distance_px[self.matched >= 0]
        return float(np.sqrt(np.mean(d * d))) if d.size else math.inf


def assign_lights(rig: CameraRig, lights_m, mask: np.ndarray,
                  candidates_uv, *, tolerance_px: float = 2.0, min_views: int = 2,
                  object_depth_m: tuple[float, float] = (0.2, 10.0),
                  lit=None, blob_radius_px: float = 0.0, blob_boxes=None,
                  near_outline: bool = False) -> LightsSolution:
    """Match highlight candidates to known lights and fit the plane they share.

    Parameters
    ----------
    rig : CameraRig
        The rectified rig (camera centres differ in x and y only).
    lights_m : array_like, (K, 3), metres
        The lights, array frame.
    mask : numpy.ndarray, (H, W) bool
        The object in the reference view; a predicted highlight counts as "on the
        object" in a view when the plane point that reflects it there lies in the mask.
    candidates_uv : sequence of N array_like, each (m_j, 2), pixels
        Highlight candidates per view (any order; the reference view's must lie on
        the object).
    tolerance_px : float
        A candidate explains a predicted highlight within this distance.
    min_views : int
        A light's highlight must be assigned in at least this many views for the
        object to be solved.
    object_depth_m : (float, float)
        Plausible depth range of the object (reference camera z): planes outside it at
        the reference highlight are not proposed.
    lit : callable, optional
        ``lit(j, uv)`` -> ``(M,)`` bool: whether views ``j`` ``(M,)`` int are bright (a
        highlight, possibly not its centre) at pixels ``uv`` ``(M, 2)``, each point in its
        own view. A highlight predicted on the object
        where no candidate explains it counts against a plane only where the view is
        dark there: two lights' highlights blended into one blob, or a highlight cut by
        the outline, have a centre that explains neither, yet they are there. Without it
        every unexplained on-object prediction counts as missing.
    blob_radius_px : float
        Typical half-maximum radius of a highlight, pixels: predictions within
        :data:`BLEND_RADII` of it of another light's, or whose reflecting point lies
        closer than it to the outline, may be excused by ``lit``; no others are.
    blob_boxes : sequence of N array_like, each (m_j, 4), optional
        Each candidate's blob box ``(u0, v0, u1, v1)``, pixels. A candidate whose blob also
        holds another light's unexplained on-object prediction (inside its box and
        ``lit`` there) is a blend of both: its centre belongs to neither, so it explains
        no light (and the other light's highlight is not missing).
    near_outline : bool
        Predictions within a blob radius of the outline take candidates too (else a cut
        blob's pulled centre could count for a wrong plane): for an object whose
        reference view holds no candidate, whose highlights reach it only there.

    Returns
    -------
    LightsSolution
    """
    lights = np.atleast_2d(np.asarray(lights_m, dtype=np.float64))
    cands = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in candidates_uv]
    ref = rig.reference
    boxes = None if blob_boxes is None else [
        np.asarray(b, dtype=np.float64).reshape(-1, 4) for b in blob_boxes]
    context = _Context(rig, lights, mask, cands, lit, tolerance_px, object_depth_m, min_views,
                       blob_radius_px, boxes, near_outline=near_outline)
    # The reference view's candidates anchor the proposals; when it holds none (the
    # object turns every light's highlight away from it), every view that holds some
    # does: a highlight seen in min_views views fixes the plane from any of them.
    anchors = None
    if len(cands[ref]) == 0:
        anchors = tuple(j for j, c in enumerate(cands) if len(c))
        if len(anchors) < min_views:
            return _no_plane("no_highlight", "reference view: no highlight candidate on "
                             f"the object, and {len(anchors)} other view(s) hold one "
                             f"(min_views {min_views})", cands)
    scores = [s for s in (context.score(p) for p in context.proposals(anchors=anchors))
              if s is not None]
    if not scores and blob_boxes is not None:
        # No depth that two views agree on: merged or cut blobs, whose centres wander.
        # Planes from single pairings may still explain them as merged blobs.
        scores = [s for s in (context.score(p) for p in context.proposals(loose=True,
                                                                        anchors=anchors))
                  if s is not None]
    if not scores:
        counted = f"{sum(len(c) for c in cands)} candidates in {len(cands)} views"
        if not context.refused:
            return _no_plane("too_few_views", "no reference candidate has a partner on its "
                             "baseline line in another view at a plausible depth for any "
                             f"light ({counted})", cands, hypotheses=context.n_proposed)
        # Partners were found: say what refused every plane they gave.
        hint = ("; a face turned from the other faces' lights, as on an object of several "
                "flat faces, gives planes with a light behind them" if
                _LIGHT_BEHIND in context.refused and len(lights) > 1 else "")
        return _no_plane("too_few_views", "no plane explains the highlights: of the "
                         f"{context.n_proposed} planes proposed (each from a reference "
                         "candidate, a depth its partners in other views give, and a light), "
                         f"{context.refusals()} ({counted}){hint}", cands,
                         hypotheses=context.n_proposed)
    scores.sort(key=lambda s: s.key, reverse=True)
    best = context.refit(scores[0])
    # The strongest rival: the best hypothesis whose plane is a different answer.
    rival = next((s for s in scores[1:]
                  if context.plane_gap_px(s.plane, best.plane) > SAME_PLANE_PX), None)
    if rival is not None:
        rival = context.refit(rival)
        if context.plane_gap_px(rival.plane, best.plane) <= SAME_PLANE_PX:
            rival = None
    if best.explained_lights.size == 1:
        # Only one light's highlights: which light they belong to may also be one the
        # object turns its back on (a plane this path does not answer with).
        behind = context.rival_with_light_behind(best)
        if behind is not None and (rival is None or behind.key > rival.key):
            rival = behind
    solution = context.solution(best, rival)
    return solution


def _no_plane(status: str, reason: str, cands, hypotheses: int = 0) -> LightsSolution:
    return LightsSolution(status, reason, None, (), math.nan, hypotheses, "", tuple(cands))


def reflection_points(plane: Plane, virtual_m: np.ndarray, centers_m: np.ndarray):
    """Where the plane reflects the light towards each camera, and how far along.

    The point is where the segment from the camera centre ``C`` to the virtual light
    ``V`` crosses the plane: ``C + t (V - C)``, on the segment for ``0 < t < 1``.
    ``virtual_m`` and ``centers_m`` (metres, array frame) broadcast against each other
    (e.g. ``(K, 1, 3)`` lights' virtual lights and ``(N, 3)`` centres); returns the
    points ``(..., 3)`` and ``t`` ``(...)``.
    """
    n = plane.n
    toward = virtual_m - centers_m
    t = (plane.offset_m - centers_m @ n) / (toward @ n)
    return centers_m + t[..., None] * toward, t


class _Context:
    """The fixed inputs of one assignment and the geometry every hypothesis shares."""

    def __init__(self, rig: CameraRig, lights: np.ndarray, mask: np.ndarray, cands, lit,
                 tolerance_px: float, object_depth_m, min_views: int,
                 blob_radius_px: float, boxes=None, *, all_lights_in_front: bool = True,
                 near_outline: bool = False) -> None:
        # One plane per object has every light in front of it; a face of a faceted
        # object may turn its back on the other faces' lights (they then predict nothing).
        self.all_lights_in_front = all_lights_in_front
        # Every score lets predictions near the outline take candidates (score's
        # near_outline), ranking included: the faces' last try (faces.NEAR_OUTLINE_TRY).
        self.near_outline = near_outline
        self.rig = rig
        self.lit = lit
        self.boxes = boxes
        self.blend_px = BLEND_RADII * float(blob_radius_px)
        self.blob_radius_px = float(blob_radius_px)
        side = 2 * int(math.ceil(blob_radius_px)) + 1
        self.inner = eroded(mask, np.ones((side, side), np.uint8))
        self.min_views = int(min_views)
        self.lights = lights
        self.mask = mask
        self.cands = cands
        # Every view's candidates in one array: the view of each and where each view starts.
        counts = np.array([len(c) for c in cands], dtype=np.intp)
        self.cand_view = np.repeat(np.arange(len(cands)), counts)
        self.cand_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        self.all_cands = np.concatenate([np.reshape(c, (-1, 2)) for c in cands]) \
            if len(cands) else np.zeros((0, 2))
        self.all_boxes = None if boxes is None else (
            np.concatenate([np.reshape(b, (-1, 4)) for b in boxes]) if len(boxes)
            else np.zeros((0, 4)))
        self.tolerance_px = float(tolerance_px)
        self.object_depth_m = object_depth_m
        self.n_proposed = 0
        self.refused: dict[str, int] = {}  # why proposed planes were refused: how many
        self.behind: list[Plane] = []  # planes refused only for a light behind them
        k = rig.intrinsics
        offsets = rig.centers_m - rig.reference_center_m
        self.steps = np.stack([-k.fx * offsets[:, 0], -k.fy * offsets[:, 1]], axis=1)  # (N, 2)
        self.corners = box_corners(mask)
        # Each plane's disparity at the corners: the faces' ranking compares the same
        # planes thousands of times.
        self._at_corners: dict[Plane, np.ndarray] = {}

    # -------------------------------------------------------------- proposals
    def proposals(self, *, loose: bool = False, anchors: tuple[int, ...] | None = None):
        """Candidate planes: an anchor view's candidate, a depth its partners agree on, a light.

        Partners of an anchor candidate lie on its baseline lines; each gives the virtual
        light's inverse depth ``w``. Partners from different views at the same ``w``
        (within the tolerance) are one virtual light seen several times: only depths
        that two views agree on are proposed when three or more views have candidates,
        which keeps the proposals from growing with every pairing of unrelated blobs.

        ``loose``: every partner within a blob radius of the baseline line proposes its
        own depth (the centres of merged or outline-cut blobs wander off the line and
        disagree on the depth; such planes are only starts for the joint lobe fit).

        ``anchors``: the views whose candidates anchor proposals, the reference's only by
        default. The cameras share one ``z`` plane, so a virtual light at inverse depth
        ``w`` moves by ``w`` times the difference of two views' steps between them, and
        any view can anchor. (The reference view may see a face's blob cut by the
        outline where the other views see it whole.)
        """
        line_px = max(self.tolerance_px, self.blob_radius_px) if loose else self.tolerance_px
        for anchor in (self.rig.reference,) if anchors is None else anchors:
            yield from self._anchored_proposals(anchor, line_px, loose)

    def _anchored_proposals(self, anchor: int, line_px: float, loose: bool):
        """:meth:`proposals` from one view's candidates, partners within ``line_px``."""
        rig = self.rig
        steps = self.steps - self.steps[anchor]
        span = float(np.max(np.hypot(steps[:, 0], steps[:, 1])))
        others = [j for j in range(rig.n_cameras) if j != anchor and len(self.cands[j])
                  and float(steps[j] @ steps[j]) > 0.0]
        need = 2 if len(others) >= 2 and not loose else 1
        for c_anchor in self.cands[anchor]:
            ray = rig.rays(c_anchor)
            depths, views = [], []
            for j in others:
                step = steps[j]
                norm2 = float(step @ step)
                d = self.cands[j] - c_anchor
                w = d @ step / norm2  # inverse depth of the virtual light
                perp = np.abs(d[:, 0] * step[1] - d[:, 1] * step[0]) / math.sqrt(norm2)
                keep = (perp <= line_px) & (w > 0.0)
                depths += w[keep].tolist()
                views += [j] * int(keep.sum())
            order = np.argsort(depths)
            depths, views = np.asarray(depths)[order], np.asarray(views)[order]
            # Runs of depths closer than the tolerance (as a shift in the widest view).
            breaks = np.flatnonzero(np.diff(depths) * span > self.tolerance_px) + 1
            for run in np.split(np.arange(len(depths)), breaks):
                if run.size == 0 or len(set(views[run].tolist())) < need:
                    continue
                virtual = rig.centers_m[anchor] + ray / float(np.median(depths[run]))
                # The reference camera's ray through the virtual light (z = 1).
                ref_ray = ray if anchor == rig.reference else (
                    (virtual - rig.reference_center_m)
                    / (virtual[2] - rig.reference_center_m[2]))
                for light in self.lights:
                    self.n_proposed += 1
                    plane = self._plane(light, virtual, ref_ray)
                    if plane is not None:
                        yield plane

    def _plane(self, light: np.ndarray, virtual: np.ndarray, ray: np.ndarray) -> Plane | None:
        """Return the bisector plane of a light and a virtual light, if a plausible one."""
        rig = self.rig
        if np.linalg.norm(virtual - light) < 1e-9:
            return self._refuse("put the virtual light on the light")
        plane = plane_from_lights(light, virtual, rig.reference_center_m)
        why = self._implausible(plane)
        if not why or why == _LIGHT_BEHIND:
            # The reflection point of the reference candidate must be at a plausible depth.
            n = plane.n
            t = (plane.offset_m - float(n @ rig.reference_center_m)) / float(n @ ray)
            in_range = self.object_depth_m[0] <= t <= self.object_depth_m[1]
            if in_range and not why:
                return plane
            if in_range and np.any(plane.signed_distance(self.lights) > 0.0):
                self.behind.append(plane)  # a rival, never an answer (rival_with_light_behind)
            why = why or (f"put the object outside its depth range "
                          f"{self.object_depth_m[0]:g}-{self.object_depth_m[1]:g} m")
        return self._refuse(why)

    def rival_with_light_behind(self, best: _Score) -> _Score | None:
        """Return the best plane refused only because a known light lies behind it, if any.

        A flat object turned away from one of the lights (a box's face) has that light
        behind its plane; the one-plane path does not answer with such planes, but one
        that explains the highlights as well as the best plane makes the best plane no
        answer either. Scored as a face's plane is (the lights behind it predict
        nothing); planes within ``SAME_PLANE_PX`` of the best are not rivals.
        """
        scores = [s for s in map(self.score, self.behind) if s is not None
                  and self.plane_gap_px(s.plane, best.plane) > SAME_PLANE_PX]
        return max(scores, key=lambda s: s.key, default=None)

    def other_lights_planes(self, plane: Plane, light: int) -> list[tuple[int, Plane]]:
        """Each other light's plane through ``plane``'s virtual light of ``light``.

        The bisector of that virtual light and light ``k`` mirrors ``k`` onto the same
        point: ``(k, plane)`` for every ``k != light`` whose plane is plausible for it
        (``k`` and the cameras in front; other lights may lie behind, a face turned from
        them).
        """
        virtual = plane.mirror(self.lights[light])
        planes = []
        for k, other in enumerate(self.lights):
            if k == light:
                continue
            through = plane_from_lights(other, virtual, self.rig.reference_center_m)
            if self._implausible(through) in ("", _LIGHT_BEHIND) \
                    and through.signed_distance(other) > 0.0:
                planes.append((k, through))
        return planes

    def same_centres_other_light(self, best: _Score) -> _Score | None:
        """Return a plane that gives the best one's highlights to another light, if any.

        The centres of one light's highlights are one virtual light ``V``; the bisector
        of ``V`` and any other light ``k`` mirrors ``k`` onto the same point, so it predicts
        the same highlights in every view. The proposals find that plane only when its
        reflection points lie well inside the object: near the outline its predictions
        take no candidate (a cut blob's centre moves), and it is never scored as a rival.
        Here both planes are scored with those predictions matched: a plausible plane
        (:meth:`other_lights_planes`) that then explains the same highlights as the best
        plane, as ``k``'s, with evidence against it not decisively larger, is returned
        (scored so), the first such light; None otherwise.
        """
        lights = best.explained_lights
        if lights.size != 1:
            return None
        planes = self.other_lights_planes(best.plane, int(lights[0]))
        whole = self.score(best.plane, at_least=1, near_outline=True) if planes else None
        if whole is None:
            return None
        for k, plane in planes:
            score = self.score(plane, at_least=best.n_matched, near_outline=True)
            if score is not None and score.explained_lights.tolist() == [k] \
                    and explained_pairs(score) == explained_pairs(whole) \
                    and whole.key[0] - score.key[0] < DECISIVE_MARGIN:
                return score
        return None

    def _plausible(self, plane: Plane) -> bool:
        return not self._implausible(plane)

    def _implausible(self, plane: Plane) -> str:
        """Why no object can lie on ``plane`` here ("" if one can)."""
        n = plane.n
        if not (np.all(np.isfinite(n)) and n[2] < 0.0):
            return "turn the plane away from the cameras"
        if np.any(plane.signed_distance(self.rig.centers_m) <= 0.0):
            return "put a camera behind the plane"
        in_front = plane.signed_distance(self.lights) > 0.0
        if not (np.all(in_front) if self.all_lights_in_front else np.any(in_front)):
            return _LIGHT_BEHIND
        return ""

    def _refuse(self, why: str) -> None:
        """Count a proposed plane refused for ``why``; return None (no plane, no score)."""
        self.refused[why] = self.refused.get(why, 0) + 1

    def refusals(self) -> str:
        """Why the planes proposed so far were refused, in words ("" if none was)."""
        return ", ".join(f"{count} {why}" for why, count in self.refused.items())

    # -------------------------------------------------------------- scoring
    def predict(self, plane: Plane, *, region: np.ndarray | None = None):
        """Predicted highlights, whether on the object, whether near its outline.

        Returns ``uv`` ``(K, N, 2)``, ``on_object`` ``(K, N)`` and ``near_edge`` ``(K, N)``
        (on the object within a blob radius of the outline). ``region`` ``(H, W)`` bool:
        the reference-view region that counts as the object for ``on_object`` (the mask
        by default).
        """
        rig = self.rig
        virtual = plane.mirror(self.lights)  # (K, 3)
        centers = rig.centers_m  # (N, 3)
        uv = project_points(rig, virtual[:, None, :], np.arange(len(centers)))  # (K, N, 2)
        points, t = reflection_points(plane, virtual[:, None, :], centers)
        ref_uv = rig.project(points)
        # (NaN where a light behind a face's plane has no mirror point: off the image.)
        ref_uv = np.where(np.isfinite(ref_uv), ref_uv, -1.0)
        ru = np.rint(ref_uv[..., 0]).astype(np.int64)
        rv = np.rint(ref_uv[..., 1]).astype(np.int64)
        h, w = self.mask.shape
        # A light behind the plane is reflected nowhere on its front (a face turned from
        # it; a plane with every light in front loses nothing here).
        inside = (ru >= 0) & (ru < w) & (rv >= 0) & (rv < h) & (t > 0) & (t < 1) \
            & (plane.signed_distance(self.lights) > 0.0)[:, None]
        on_object = np.zeros(inside.shape, dtype=bool)
        on_object[inside] = (self.mask if region is None else region)[rv[inside], ru[inside]]
        near_edge = on_object.copy()
        near_edge[inside] &= ~self.inner[rv[inside], ru[inside]]
        return uv, on_object, near_edge

    def score(self, plane: Plane | None, *, at_least: int = 2, near_outline: bool = False
              ) -> _Score | None:
        """Score what ``plane`` explains; None if it explains fewer than ``at_least``.

        ``near_outline``: predictions near the outline take candidates too (to ask whether
        a plane could explain the same centres, not to rank it); always in a context made
        with ``near_outline`` (the faces' last try, ranking included).
        """
        if plane is None:
            return None
        near_outline = near_outline or self.near_outline
        uv, on_object, near_edge = self.predict(plane)
        n_lights, n_views = on_object.shape
        matched = np.full((n_lights, n_views), -1)
        distance = np.full((n_lights, n_views), np.nan)
        # Every light against every candidate of its view at once; then nearest first,
        # a candidate explains one light at most (views never compete, so one order over
        # all views matches each view's own). A blob cut by the outline has its centre
        # off the light's: predictions near the outline take no candidate.
        view = self.cand_view
        gaps = np.linalg.norm(uv[:, view, :] - self.all_cands[None], axis=2)  # (K, M)
        usable = (gaps <= self.tolerance_px) \
            & (on_object if near_outline else on_object & ~near_edge)[:, view]
        lights, flat = np.nonzero(usable)
        taken = np.zeros(len(view), dtype=bool)
        for at in np.argsort(gaps[lights, flat], kind="stable"):
            light, c = int(lights[at]), int(flat[at])
            j = int(view[c])
            if matched[light, j] >= 0 or taken[c]:
                continue
            matched[light, j] = c - self.cand_start[j]
            distance[light, j] = gaps[light, c]
            taken[c] = True
        bright = self._bright(uv, on_object & (matched < 0))
        blobs, covered, cut = self._blends(uv, matched, distance, bright)
        missing = on_object & (matched < 0) & ~covered
        if bright is not None and self.blend_px > 0.0:
            # Unexplained but bright where another light's highlight is predicted close by
            # (one blob of both) or where the outline cuts the blob: not a missing one.
            gaps = np.linalg.norm(uv[:, None, :, :] - uv[None, :, :, :], axis=3)  # (K, K, N)
            gaps[np.arange(n_lights), np.arange(n_lights)] = np.inf
            excusable = np.any(gaps < self.blend_px, axis=1) | near_edge
            missing &= ~(excusable & bright)
        if np.count_nonzero(matched >= 0) + len(blobs) < at_least:
            return self._refuse(f"explain fewer than {at_least} highlights")
        return _Score(plane, matched, distance, uv, on_object, missing,
                      self._strays(plane, matched, blobs, cut), tuple(blobs))

    def _bright(self, uv: np.ndarray, ask: np.ndarray) -> np.ndarray | None:
        """Whether each asked prediction ``(K, N)`` falls where its view is bright.

        False where not asked; None without ``lit``.
        """
        if self.lit is None:
            return None
        bright = np.zeros(ask.shape, dtype=bool)
        lights, views = np.nonzero(ask)
        if lights.size:
            bright[lights, views] = self.lit(views, uv[lights, views])
        return bright

    def _blends(self, uv: np.ndarray, matched: np.ndarray, distance: np.ndarray,
                bright: np.ndarray | None):
        """Find the blobs that hold more than one light's highlight; unmatch them (in place).

        A blob whose box holds the on-object prediction of a light it was not matched to
        (and that is bright there) is highlights merged: its centre lies between theirs and
        measures none of them, yet it shows they are there. So is an unmatched blob that
        holds two or more predictions. An unmatched blob holding one is that light's
        highlight cut by the outline or merged with the flank of one off the object:
        there, unmeasured.

        Returns ``(blobs, covered, held)``: the ``(view, candidate)`` pairs of the merged
        blobs, ``(K, N)`` bool, the predictions that lie in a blob without being measured by
        it, and the flat indices of the candidates whose blob holds such a prediction.
        """
        covered = np.zeros(matched.shape, dtype=bool)
        blobs: list[tuple[int, int]] = []
        none = np.zeros(0, dtype=np.intp)
        if self.boxes is None or bright is None:
            return blobs, covered, none
        lights, views = np.nonzero(bright)  # on the object, unmatched, bright there
        if lights.size == 0:
            return blobs, covered, none
        p = uv[lights, views]  # (P, 2)
        u0, v0, u1, v1 = self.all_boxes.T
        # Which candidate's box holds each such prediction of its own view, (P, M).
        holds = (self.cand_view[None, :] == views[:, None]) \
            & (p[:, :1] >= u0) & (p[:, :1] < u1) & (p[:, 1:] >= v0) & (p[:, 1:] < v1)
        covered[lights[holds.any(axis=1)], views[holds.any(axis=1)]] = True
        for c in np.flatnonzero(holds.any(axis=0)):  # view by view, candidates in order
            j = int(self.cand_view[c])
            q = c - int(self.cand_start[j])
            owner = np.flatnonzero(matched[:, j] == q)
            if owner.size:
                matched[owner, j] = -1
                distance[owner, j] = np.nan
                covered[owner, j] = True
            if owner.size or np.count_nonzero(holds[:, c]) >= 2:
                blobs.append((j, q))
        return blobs, covered, np.flatnonzero(holds.any(axis=0))

    def _strays(self, plane: Plane, matched: np.ndarray, blobs, held: np.ndarray) -> int:
        """Candidates well inside the object (by ``plane``) that no light explains.

        With every light known, each highlight on the object belongs to one of them.
        Near the outline a blob may be the flank of a highlight just off the object. A
        blob that holds a light's unmeasured prediction (``held``, flat candidate indices:
        a highlight cut by the outline, whose centre moved inwards off its light's) is
        that light's, not a stray.
        """
        free = np.ones(len(self.cand_view), dtype=bool)
        light_idx, view_idx = np.nonzero(matched >= 0)
        free[self.cand_start[view_idx] + matched[light_idx, view_idx]] = False
        free[[self.cand_start[view] + q for view, q in blobs]] = False
        free[held] = False
        if not free.any():
            return 0
        maps = references_from_views(self.rig, plane)[self.cand_view[free]]  # (M', 2, 3)
        uv = self.all_cands[free]
        ref_uv = np.einsum("mij,mj->mi", maps[:, :, :2], uv) + maps[:, :, 2]
        u = np.rint(ref_uv[:, 0]).astype(np.intp)
        v = np.rint(ref_uv[:, 1]).astype(np.intp)
        h, w = self.mask.shape
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        return int(np.count_nonzero(self.inner[v[ok], u[ok]]))

    # -------------------------------------------------------------- the joint plane
    def refit(self, score: _Score) -> _Score:
        """Fit the plane to every highlight it explains, match again; repeat."""
        for _ in range(_REFIT_ROUNDS):
            plane = self._fit(score)
            again = self.score(plane) if plane is not None and self._plausible(plane) else None
            if again is None or again.key < score.key:
                return score
            settled = np.array_equal(again.matched, score.matched)
            score = again
            if settled:
                break
        return score

    def fit(self, score: _Score) -> Plane | None:
        """Least-squares plane to the highlights ``score.matched`` assigns (no rematching)."""
        return self._fit(score)

    def _fit(self, score: _Score) -> Plane | None:
        """Least-squares plane: predicted minus assigned centres over every assignment."""
        light_idx, view_idx = np.nonzero(score.matched >= 0)
        if len(light_idx) < 2:
            return None
        observed = np.stack([self.cands[j][score.matched[k, j]]
                             for k, j in zip(light_idx, view_idx, strict=True)])
        return fit_mirror_plane(self.rig, score.plane, self.lights[light_idx], view_idx,
                                observed)

    def plane_gap_px(self, a: Plane, b: Plane) -> float:
        """Largest disparity difference of two planes at the object's box corners, px.

        :func:`plane_gap_px` at :attr:`corners`, each plane's disparities computed once.
        """
        return _largest_gap_px(self._disparity_at_corners(a), self._disparity_at_corners(b))

    def _disparity_at_corners(self, plane: Plane) -> np.ndarray:
        if plane not in self._at_corners:
            self._at_corners[plane] = plane_disparity(plane, self.rig, self.corners)
        return self._at_corners[plane]

    # -------------------------------------------------------------- the answer
    def solution(self, best: _Score, rival: _Score | None, *, same_centres: bool = False
                 ) -> LightsSolution:
        """Return the answer from the best hypothesis and its strongest rival, with evidence.

        ``same_centres``: the rival is :meth:`same_centres_other_light`'s (the same
        highlights as another light's): ambiguous.
        """
        rig = self.rig
        virtual = best.plane.mirror(self.lights)
        assignments = []
        for k in range(len(self.lights)):
            centers = np.full((rig.n_cameras, 2), np.nan)
            for j in np.flatnonzero(best.matched[k] >= 0):
                centers[j] = self.cands[j][best.matched[k, j]]
            residual = np.linalg.norm(centers - best.predicted_uv[k], axis=1)
            assignments.append(LightAssignment(k, centers, best.predicted_uv[k],
                                               best.on_object[k], best.missing[k], residual,
                                               virtual[k]))
        d = best.distance_px[best.matched >= 0]
        rms = float(np.sqrt(np.mean(d * d))) if d.size else math.nan
        evidence = (f"best plane explains {best.n_matched} highlight(s), RMS {rms:.2f} px, "
                    f"and {len(best.blends)} blob(s) as merged highlights; "
                    f"{best.n_missing} predicted on the object are not there, "
                    f"{best.n_strays} on the object belong to no light")
        if rival is not None:
            gap_px = self.plane_gap_px(rival.plane, best.plane)
            behind = np.flatnonzero(rival.plane.signed_distance(self.lights) <= 0.0).tolist()
            evidence += (f"; the best different plane ({gap_px:.1f} px away"
                         + (f", light {behind} behind it" if behind else "") + ") explains "
                         f"{rival.n_matched} and {len(rival.blends)} merged "
                         f"({rival.n_missing} missing, {rival.n_strays} stray)")
        status, reason = "ok", ""
        decisive = rival is None or best.key[0] - rival.key[0] >= DECISIVE_MARGIN
        if same_centres:
            status = "ambiguous"
            reason = (f"lights: the highlights are one virtual light, explained as light "
                      f"{best.explained_lights[0]}'s and as light {rival.explained_lights[0]}'s "
                      f"(the same image points; the plane giving them to light "
                      f"{rival.explained_lights[0]} reflects some near the outline, where a "
                      "centre is not trusted, and explains them all once they count); which "
                      "light they belong to is not established; " + evidence)
        elif rival is not None and rival.key[:2] >= best.key[:2]:
            status = "ambiguous"
            reason = ("lights: two different planes explain the highlights equally well; "
                      + evidence)
        elif best.outweighed(UNEXPLAINED_RATIO):
            status = "inconsistent"
            reason = (f"lights: the evidence against the best plane ({best.n_against}) is more "
                      f"than 1/{UNEXPLAINED_RATIO:g} of the "
                      f"{best.support} highlight(s) and merged blobs it "
                      "explains (blended or hidden highlights, or an unknown light); "
                      + evidence)
        elif len(self.lights) > 1 and not decisive \
                and best.explained_lights.size == 1 \
                and np.any(best.on_object.sum(axis=1)[(best.matched < 0).all(axis=1)]
                           >= self.min_views):
            # Only one light's blobs are explained while other lights are predicted on the
            # object, and no plane that gives them to another light is clearly contradicted:
            # nothing ties the blobs to that light rather than to another.
            status = "ambiguous"
            lights = best.explained_lights.tolist()
            reason = (f"lights: only light {lights}'s highlights are explained, while other "
                      "lights' are predicted on the object and not seen apart (blended or "
                      "cut); which light the blobs belong to is not established; " + evidence)
        elif _same_highlights_other_light(best, rival) and (
                not decisive or rival.rms_px * CLOSER_FIT_RATIO < best.rms_px):
            # One virtual light, two lights: both planes mirror a light onto the same point,
            # so they predict the same highlights in every view. What separates them is
            # only where their reflection points fall, near the outline or off it; a lead
            # in count is no answer when the rival fits its highlights far closer (the
            # extra ones are centres cut by the outline, which the rival leaves out).
            status = "ambiguous"
            reason = (f"lights: the highlights are one virtual light, explained as light "
                      f"{best.explained_lights[0]}'s and as light {rival.explained_lights[0]}'s "
                      "(the same image points; the planes differ only in where they reflect "
                      "them, near the outline or not); which light they belong to is not "
                      "established; " + evidence)
        elif max(a.n_views for a in assignments) < self.min_views:
            status = "too_few_views"
            reason = (f"lights: no light's highlight is measured in {self.min_views} or more "
                      "views (a blob of merged highlights measures none of them); " + evidence)
        return LightsSolution(status, reason, best.plane, tuple(assignments), rms,
                              self.n_proposed, evidence, tuple(self.cands), best.blends,
                              None if rival is None else rival.plane)


def _same_highlights_other_light(best: _Score, rival: _Score | None) -> bool:
    """Whether ``rival`` explains only highlights ``best`` explains, as another single light.

    Both explain one light's highlights each, different lights, and the rival's
    ``(view, candidate)`` pairs are among the best's.
    """
    if rival is None:
        return False
    lights = [s.explained_lights for s in (best, rival)]
    if any(ls.size != 1 for ls in lights) or lights[0][0] == lights[1][0]:
        return False
    return explained_pairs(rival) <= explained_pairs(best)


def explained_pairs(score: _Score) -> set[tuple[int, int]]:
    """``(view, candidate)`` of every highlight the plane explains."""
    lights, views = np.nonzero(score.matched >= 0)
    return {(int(j), int(score.matched[k, j])) for k, j in zip(lights, views, strict=True)}


#: The hypothesis machinery (proposals, scores, refits) that :mod:`.faces` shares: one
#: plane per face instead of one per object.
AssignmentContext = _Context
PlaneScore = _Score


def fit_mirror_plane(rig: CameraRig, start: Plane, lights_m: np.ndarray,
                     views: np.ndarray, observed_uv: np.ndarray) -> Plane | None:
    """Plane whose mirror images of the lights project closest to the observed centres.

    Gauss-Newton with Levenberg damping on the plane's two tilts (about ``start``'s
    normal) and its offset, with the analytic Jacobian of the projection: the problem
    has three unknowns and a handful of observations, for which a general solver's
    setup costs many times the arithmetic.

    Parameters
    ----------
    rig : CameraRig
    start : Plane
        The first guess (its tilts and offset are the zero of the parameters).
    lights_m : numpy.ndarray, (M, 3), metres
        The light of each observation, array frame.
    views : numpy.ndarray, (M,) int
        The view of each observation.
    observed_uv : numpy.ndarray, (M, 2), pixels
        The highlight centre each observation assigns.

    Returns
    -------
    Plane or None
        The least-squares plane; None if the normal equations are singular or the fit
        leaves the finite numbers.
    """
    n0, c0 = np.asarray(start.n, dtype=np.float64), float(start.offset_m)
    helper = np.eye(3)[int(np.argmin(np.abs(n0)))]
    e1 = np.cross(n0, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n0, e1)
    tilts = np.stack([e1, e2])  # (2, 3)
    centers = rig.centers_m[views]
    k = rig.intrinsics
    focal = np.array([k.fx, k.fy])
    principal = np.array([k.cx, k.cy])

    def evaluate(p):
        m = n0 + p[:2] @ tilts
        norm = float(np.linalg.norm(m))
        n = m / norm
        c = c0 + p[2]
        s = lights_m @ n - c  # (M,) signed distances of the lights
        virtual = lights_m - 2.0 * s[:, None] * n
        rel = virtual - centers
        uv = focal * rel[:, :2] / rel[:, 2:3] + principal
        return (n, norm, s, rel), c, (uv - observed_uv).ravel()

    def jacobian(n, norm, s, rel):
        # n = m / |m| with m = n0 + p0 e1 + p1 e2: d n / d p_i = (I - n n^T) e_i / |m|.
        dn = (tilts - (tilts @ n)[:, None] * n) / norm  # (2, 3)
        dvirtual = np.empty((len(s), 3, 3))  # (M, parameter, xyz)
        for i in range(2):
            dvirtual[:, i] = -2.0 * (lights_m @ dn[i])[:, None] * n - 2.0 * s[:, None] * dn[i]
        dvirtual[:, 2] = 2.0 * n
        z = rel[:, 2]
        du = focal[0] * (dvirtual[:, :, 0] - rel[:, 0:1] / z[:, None] * dvirtual[:, :, 2]) \
            / z[:, None]
        dv = focal[1] * (dvirtual[:, :, 1] - rel[:, 1:2] / z[:, None] * dvirtual[:, :, 2]) \
            / z[:, None]
        return np.stack([du, dv], axis=1).reshape(-1, 3)  # rows as the residuals ravel

    p = np.zeros(3)
    state, c, r = evaluate(p)
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(_FIT_MAX_ITERATIONS):
        jac = jacobian(*state)
        # Columns scaled to unit norm, as the tilts (radians) and the offset (metres) move
        # the centres by very different amounts.
        scale = np.linalg.norm(jac, axis=0)
        scale[scale == 0.0] = 1.0
        js = jac / scale
        normal = js.T @ js
        gradient = js.T @ r
        accepted = False
        while damping <= 1e8:
            try:
                step = -np.linalg.solve(normal + damping * np.diag(np.diag(normal) + 1e-12),
                                        gradient) / scale
            except np.linalg.LinAlgError:
                return None
            # Converged: the step would move no centre by more than the tolerance (at the
            # minimum, rounding alone decides whether the cost still drops).
            if float(np.max(np.abs(jac @ step))) <= _FIT_STEP_TOLERANCE_PX:
                break
            trial = p + step
            state_t, c_t, r_t = evaluate(trial)
            cost_t = float(r_t @ r_t)
            if np.isfinite(cost_t) and cost_t <= cost:
                accepted = True
                break
            damping *= 10.0
        if not accepted:
            break
        shrink = cost - cost_t
        p, state, c, r, cost = trial, state_t, c_t, r_t, cost_t
        damping = max(damping / 10.0, 1e-9)
        if shrink <= _FIT_COST_TOLERANCE * max(cost, 1e-300):
            break
    n = state[0]
    if not (np.all(np.isfinite(n)) and math.isfinite(c)):
        return None
    return Plane(tuple(float(v) for v in n), float(c))


def box_corners(mask: np.ndarray) -> np.ndarray:
    """Corner pixels ``(4, 2)`` of the mask's bounding box."""
    u0, v0, u1, v1 = search_box(mask, 0)
    u1, v1 = u1 - 1, v1 - 1
    return np.array([[u0, v0], [u1, v0], [u0, v1], [u1, v1]], dtype=np.float64)


def plane_gap_px(rig: CameraRig, corners: np.ndarray, a: Plane, b: Plane) -> float:
    """Largest disparity difference of two planes at pixels ``corners`` ``(M, 2)``, px."""
    return _largest_gap_px(plane_disparity(a, rig, corners), plane_disparity(b, rig, corners))


def _largest_gap_px(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)))
