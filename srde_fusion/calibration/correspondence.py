"""Which highlight on the plate belongs to which light: geometry decides, never brightness.

With several lights a plate shows several highlights in every view. Two geometric facts
sort them:

*Within one capture* the highlights of one light in all views are images of one point,
the light's mirror image in the plate (its virtual light). So every pair of highlights in
two views proposes a point; the views whose highlight lies where that point projects
join it; the sets that most views agree on are the lights' highlight sets
(:func:`group_highlights`). A highlight set must lie behind the plate (a mirror image),
and no highlight may serve two sets.

*Across captures* each light is one 3-D point: the reflected rays of its highlight sets
from every plate pose must meet there. Each capture's sets are matched to the lights by
trying every assignment and keeping the one whose rays meet
(:func:`match_captures`); two assignments that both fit are an ambiguity. A set the
light's other captures contradict is then left out (:func:`leave_out_contradicted_sets`):
a few views of another lamp's highlight, displaced by a marker's edge, fit their own
virtual light as well as a lamp's highlights do, and the mean ray distance of the
assignment hides them.

Nothing is guessed: two competing sets with the same support, a capture whose sets fit
two assignments, or more highlight sets than lights are failures with their reasons and
numbers.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import LightError
from ..geometry import CameraRig, triangulate_rectified
from .light import (
    closest_point_to_rays,
    highlight_rms_px,
    light_from_reflections,
    reflect_highlights,
)
from .plate_pose import PlatePose

__all__ = [
    "DEFAULT_MATCH_TOLERANCE_PX",
    "AMBIGUITY_RATIO",
    "HighlightSet",
    "HighlightGrouping",
    "CaptureMatch",
    "group_highlights",
    "match_captures",
    "leave_out_contradicted_sets",
    "CONTRADICTED_SET_PX",
]

#: Largest distance (pixels) between a highlight centre and the projection of the virtual
#: light it is taken to belong to. Detected centres on a plate are good to a few hundredths
#: of a pixel on renders and a few tenths on real images; another light's highlight lies
#: tens of pixels away.
DEFAULT_MATCH_TOLERANCE_PX = 1.5


#: A capture's assignment of highlight sets to lights is accepted only if the next best
#: one has at least this many times its sum of squared ray distances.
AMBIGUITY_RATIO = 4.0


#: A light's highlight set is left out when its highlights lie farther than this (RMS,
#: pixels) from the light's images as the light's other captures place it (their light,
#: mirrored across this capture's plate as its markers place it). On 61 of 100 rendered
#: two- and three-lamp layouts that calibrate (3 plate poses each, faithful physics), the
#: 445 sets of 60 lay within 0.55 px of where their light's other captures put it; in the
#: 61st, 2 views of one lamp's highlight, displaced by a marker's edge and matched to
#: another lamp, lay 11.1 px off and put that lamp 105 mm from it. The markers' pose of
#: the capture checked is not refined by its highlights, so its error counts in full:
#: simulated with 0.3 px noise on the centres and the plate's normal off by 0.05 / 0.1 /
#: 0.2 deg (1 sigma), sets of the right light lay up to 2.4 / 4.1 / 8.0 px off (median
#: 0.7 / 1.2 / 2.3 px; 1.3 % beyond this bound at 0.2 deg).
CONTRADICTED_SET_PX = 6.0


# A light cannot be assigned more captures' sets than this many at once (the number of
# assignments tried per capture grows as L! / (L - m)!).
_MAX_ASSIGNMENTS = 50_000


@dataclass(frozen=True, eq=False)
class HighlightSet:
    """The highlights of one light in one capture: images of one virtual light.

    Attributes
    ----------
    centers_px : numpy.ndarray, (N, 2) float64
        The highlight centre in each view; NaN where this light's highlight was not found.
    candidates : numpy.ndarray, (N,) int
        Which of the view's candidates it is (-1 where none).
    virtual_light_m : numpy.ndarray, (3,) float64
        The point triangulated from the centres, array frame, metres.
    residual_px : float
        RMS reprojection distance of the centres to it, pixels.
    """

    centers_px: np.ndarray
    candidates: np.ndarray
    virtual_light_m: np.ndarray
    residual_px: float

    @property
    def views(self) -> tuple[int, ...]:
        """Views in which the set has a highlight."""
        return tuple(int(v) for v in np.flatnonzero(self.candidates >= 0))


@dataclass(frozen=True, eq=False)
class HighlightGrouping:
    """One capture's highlights sorted into sets, one set per light seen.

    Falsy when the grouping failed; ``reason`` then says why, with the numbers.

    Attributes
    ----------
    sets : tuple of HighlightSet
        Most views first.
    unmatched_px : tuple of numpy.ndarray, each (M_i, 2)
        Per view, the candidates no set took (reflections of something else, or a
        light seen in too few views).
    reason : str
        ``""`` on success.
    """

    sets: tuple[HighlightSet, ...]
    unmatched_px: tuple[np.ndarray, ...]
    reason: str = ""

    def __bool__(self) -> bool:
        return not self.reason


#: A set's worst centre is left out when, without it, the set's other centres fit their
#: virtual light this many times better (RMS): one centre pulled off its highlight (by
#: a neighbour's flank or a marker's edge) tilts the fit for all of them. Renders fit to a
#: hundredth of a pixel, real images to a few tenths; a pulled centre a pixel off put one
#: rendered lamp 7.6 mm off (its set fitting to 0.1-1.2 px, 0.01 px without it). (SRDE's
#: ``robust_triangulate``, its bound adapted from the least median of pair proposals,
#: dropped a view from 315 of 1000 sets of centres with 0.3 px noise alone; this rule from
#: none.)
PULLED_CENTRE_GAIN = 3.0


def _without_pulled(rig: CameraRig, index: np.ndarray, centers: np.ndarray, fit,
                    min_views: int):
    """Leave out a set's centres pulled off their highlight: ``(index, centers, fit)``.

    At least three centres stay (two views fit their point almost exactly, whatever they
    hold), and at least ``min_views``.
    """
    while np.sum(index >= 0) > max(min_views, 3):
        used = index >= 0
        residuals = np.where(used, fit.residuals_px, -np.inf)
        worst = int(np.argmax(residuals))
        rest = used.copy()
        rest[worst] = False
        trial_centers = centers.copy()
        trial_centers[worst] = np.nan
        refit = triangulate_rectified(rig, trial_centers)
        if not np.all(np.isfinite(refit.point_m)) or refit.inverse_depth_per_m <= 0:
            break
        before = float(np.sqrt(np.mean(fit.residuals_px[rest] ** 2)))
        after = float(np.sqrt(np.mean(refit.residuals_px[rest] ** 2)))
        # (A thousandth of a pixel is exact: float noise alone must not drop views.)
        if not before > PULLED_CENTRE_GAIN * after + 1e-3:
            break
        index = index.copy()
        index[worst] = -1
        centers, fit = trial_centers, refit
    return index, centers, fit


def _set_from(rig: CameraRig, candidates: Sequence[np.ndarray], point_m: np.ndarray,
              tolerance_px: float) -> tuple[np.ndarray, np.ndarray]:
    """For each view, the one candidate within ``tolerance_px`` of the point's image.

    Returns the candidate index per view (-1: none, -2: more than one) and the centres.
    """
    n = rig.n_cameras
    index = np.full(n, -1)
    centers = np.full((n, 2), np.nan)
    for view, cands in enumerate(candidates):
        if cands.shape[0] == 0:
            continue
        dist = np.linalg.norm(cands - rig.project(point_m, view), axis=1)
        close = np.flatnonzero(dist <= tolerance_px)
        if close.size == 1:
            index[view] = close[0]
            centers[view] = cands[close[0]]
        elif close.size > 1:
            index[view] = -2
    return index, centers


def group_highlights(
    candidates: Sequence[np.ndarray],
    rig: CameraRig,
    pose: PlatePose,
    *,
    min_views: int,
    tolerance_px: float = DEFAULT_MATCH_TOLERANCE_PX,
) -> HighlightGrouping:
    """Sort one capture's highlight candidates into per-light sets by triangulation.

    Every pair of candidates in two views proposes a virtual light; it collects, in every
    view, the one candidate within ``tolerance_px`` of its image, and is refitted to them
    until the set no longer changes; a centre without which the others fit
    :data:`PULLED_CENTRE_GAIN` times better is then left out (pulled off its highlight),
    as long as three views and ``min_views`` remain. Proposals that lie in front of the
    plate (no mirror image does) or gather fewer than ``min_views`` views are dropped.
    The sets are then taken most views first (smaller residual first); a set sharing a
    highlight with one taken before is dropped when it has fewer views and is an
    ambiguity when it has as many.

    Parameters
    ----------
    candidates : sequence of numpy.ndarray, each (M_i, 2)
        Per view, the highlight centres found (pixels).
    rig : CameraRig
    pose : PlatePose
        The plate of this capture.
    min_views : int
        Fewest views a set must span.
    tolerance_px : float
        Largest distance of a centre from its virtual light's image.

    Returns
    -------
    HighlightGrouping
        Falsy with a reason for an ambiguity, or two candidates of one view both fitting
        one set.

    Examples
    --------
    >>> from srde_fusion.calibration import PlatePose
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(640, 480))
    >>> pose = PlatePose.from_center_normal((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    >>> virtual = [(0.3, 0.2, 2.0), (-0.2, -0.25, 2.1)]   # two lights mirrored in z = 1
    >>> cands = [np.array([rig.project(v, i) for v in virtual]) for i in range(9)]
    >>> grouping = group_highlights(cands, rig, pose, min_views=2)
    >>> len(grouping.sets), [np.round(s.virtual_light_m, 6).tolist() for s in grouping.sets]
    (2, [[0.3, 0.2, 2.0], [-0.2, -0.25, 2.1]])
    """
    cands = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in candidates]
    n = rig.n_cameras
    n_plane, c_plane = pose.plane.n, pose.plane.offset_m
    proposals: dict[tuple[int, ...], HighlightSet] = {}
    conflicts: list[str] = []
    for i, j in itertools.combinations(range(n), 2):
        for a, b in itertools.product(range(len(cands[i])), range(len(cands[j]))):
            # A pair inside a set found before proposes that set again.
            if any(key[i] == a and key[j] == b for key in proposals):
                continue
            seed = np.full((n, 2), np.nan)
            seed[i], seed[j] = cands[i][a], cands[j][b]
            fit = triangulate_rectified(rig, seed)
            if not (np.all(np.isfinite(fit.point_m)) and fit.inverse_depth_per_m > 0
                    and np.nanmax(fit.residuals_px) <= tolerance_px):
                continue
            index, centers = None, None
            point = fit.point_m
            for _ in range(5):  # refit until the set stops changing
                new_index, new_centers = _set_from(rig, cands, point, tolerance_px)
                if index is not None and np.array_equal(new_index, index):
                    break
                index, centers = new_index, new_centers
                refit = triangulate_rectified(rig, centers)
                if not np.all(np.isfinite(refit.point_m)) or refit.inverse_depth_per_m <= 0:
                    break
                point, fit = refit.point_m, refit
            if index is None or np.sum(index >= 0) < min_views:
                continue
            index, centers, fit = _without_pulled(rig, index, centers, fit, min_views)
            point = fit.point_m
            # A virtual light is the light's mirror image: it lies behind the plate.
            if float(n_plane @ point) - c_plane >= 0.0:
                continue
            if np.any(index == -2):
                views = [rig.camera_names[v] for v in np.flatnonzero(index == -2)]
                conflicts.append(f"two highlights within {tolerance_px:g} px of one virtual "
                                 f"light's image in {views}")
                continue
            key = tuple(int(k) for k in index)
            if key not in proposals:
                used = index >= 0
                residual = float(np.sqrt(np.nanmean(fit.residuals_px[used] ** 2)))
                proposals[key] = HighlightSet(centers, index, np.asarray(point, float),
                                              residual)
    if conflicts:
        return HighlightGrouping((), tuple(cands), f"ambiguous highlights: {conflicts[0]}")
    ranked = sorted(proposals.values(), key=lambda s: (-len(s.views), s.residual_px))
    taken: list[HighlightSet] = []
    for candidate in ranked:
        rivals = [s for s in taken if np.any((s.candidates >= 0)
                                             & (s.candidates == candidate.candidates))]
        if not rivals:
            taken.append(candidate)
            continue
        rival = rivals[0]
        if len(rival.views) == len(candidate.views):
            where = [rig.camera_names[v] for v in
                     np.flatnonzero((rival.candidates >= 0)
                                    & (rival.candidates == candidate.candidates))]
            return HighlightGrouping(
                (), tuple(cands),
                f"ambiguous highlights: two sets of {len(rival.views)} views share the "
                f"highlights of {where} (virtual lights at "
                f"{np.round(rival.virtual_light_m, 3).tolist()} and "
                f"{np.round(candidate.virtual_light_m, 3).tolist()} m, residuals "
                f"{rival.residual_px:.2f} and {candidate.residual_px:.2f} px)")
    unmatched = []
    for view, c in enumerate(cands):
        used = {int(s.candidates[view]) for s in taken if s.candidates[view] >= 0}
        unmatched.append(c[[k for k in range(len(c)) if k not in used]])
    return HighlightGrouping(tuple(taken), tuple(unmatched))


@dataclass(frozen=True, eq=False)
class CaptureMatch:
    """How one capture's highlight sets were assigned to the lights, and the evidence.

    Attributes
    ----------
    lights : tuple of int
        Per highlight set of the capture, the light it was assigned to.
    ray_distance_m : float
        Largest mean distance, over the lights, of the reflected rays assigned so far to
        their common point (metres) under this assignment.
    runner_up_distance_m : float
        The same for the next best assignment (inf if there was none): how far from
        fitting the alternative was.
    """

    lights: tuple[int, ...]
    ray_distance_m: float
    runner_up_distance_m: float


def _ray_cost(origins: list[np.ndarray], directions: list[np.ndarray]
              ) -> tuple[float, float]:
    """(largest mean ray distance over lights, total squared distance) of ray bundles."""
    worst, total = 0.0, 0.0
    for o, d in zip(origins, directions, strict=True):
        if o.shape[0] < 2:
            continue
        try:
            _, dist = closest_point_to_rays(o, d)
        except ValueError:  # parallel rays: they fix no point, so they cannot disagree
            continue
        worst = max(worst, float(dist.mean()))
        total += float(np.sum(dist**2))
    return worst, total


def match_captures(
    groupings: Sequence[Sequence[HighlightSet]],
    poses: Sequence[PlatePose],
    rig: CameraRig,
    n_lights: int,
    *,
    max_ray_distance_m: float,
) -> tuple[tuple[CaptureMatch, ...], str]:
    """Assign every capture's highlight sets to ``n_lights`` lights by their rays.

    The first capture that shows all lights fixes their numbering; every other capture
    tries each injective assignment of its sets to the lights, and keeps the one under
    which the reflected rays of each light (all captures so far) meet best. It must fit
    (every light's rays within ``max_ray_distance_m`` of their common point, on average)
    and be clearly better than any other that fits (:data:`AMBIGUITY_RATIO`).

    Parameters
    ----------
    groupings : sequence of sequence of HighlightSet
        Per capture, its highlight sets (:func:`group_highlights`).
    poses : sequence of PlatePose
        Per capture, the plate.
    rig : CameraRig
    n_lights : int
        Number of lights.
    max_ray_distance_m : float
        Largest accepted mean distance of a light's rays to their common point.

    Returns
    -------
    matches : tuple of CaptureMatch
        Per capture (empty when the matching failed).
    reason : str
        ``""`` on success, else why no assignment could be trusted.
    """
    counts = [len(g) for g in groupings]
    too_many = [c for c, k in enumerate(counts) if k > n_lights]
    if too_many:
        c = too_many[0]
        return (), (f"capture {c}: expected at most {n_lights} lights, got {counts[c]} "
                    f"consistent highlight sets")
    full = [c for c, k in enumerate(counts) if k == n_lights]
    if not full:
        return (), (f"expected a capture showing all {n_lights} lights in enough views, got "
                    f"{counts} highlight sets per capture")
    rays = []
    for pose, sets in zip(poses, groupings, strict=True):
        rays.append([reflect_highlights(pose, s.centers_px, rig) for s in sets])
    first = full[0]
    origins = [[rays[first][k][0]] for k in range(n_lights)]
    directions = [[rays[first][k][1]] for k in range(n_lights)]
    matches: dict[int, CaptureMatch] = {
        first: CaptureMatch(tuple(range(n_lights)), _ray_cost(
            [o[0] for o in origins], [d[0] for d in directions])[0], np.inf)}
    order = sorted((c for c in range(len(groupings)) if c != first), key=lambda c: -counts[c])
    for c in order:
        m = counts[c]
        if m == 0:
            matches[c] = CaptureMatch((), 0.0, np.inf)
            continue
        scored = []
        for n_tried, assignment in enumerate(itertools.permutations(range(n_lights), m)):
            if n_tried >= _MAX_ASSIGNMENTS:
                return (), (f"capture {c}: expected at most {_MAX_ASSIGNMENTS} assignments "
                            f"of {m} highlight sets to {n_lights} lights to try, got more")
            o = [np.concatenate(origins[k]) for k in range(n_lights)]
            d = [np.concatenate(directions[k]) for k in range(n_lights)]
            for s, k in enumerate(assignment):
                o[k] = np.concatenate([o[k], rays[c][s][0]])
                d[k] = np.concatenate([d[k], rays[c][s][1]])
            worst, total = _ray_cost(o, d)
            scored.append((total, worst, assignment))
        scored.sort(key=lambda t: t[0])
        total, worst, best = scored[0]
        runner_up = scored[1] if len(scored) > 1 else (np.inf, np.inf, None)
        if worst > max_ray_distance_m:
            return (), (f"capture {c}: expected its {m} highlight sets to fit the lights "
                        f"(mean ray distance <= {max_ray_distance_m * 1000:g} mm), got "
                        f"{worst * 1000:.1f} mm at best: these highlights do not triangulate "
                        f"with the other captures' as one light each")
        if runner_up[1] <= max_ray_distance_m and runner_up[0] < AMBIGUITY_RATIO * total:
            return (), (f"capture {c}: ambiguous assignment of highlight sets to lights: "
                        f"{list(best)} and {list(runner_up[2])} both fit (mean ray distance "
                        f"{worst * 1000:.1f} and {runner_up[1] * 1000:.1f} mm); the lights "
                        f"are too close together for these plate poses")
        matches[c] = CaptureMatch(tuple(best), worst, float(runner_up[1]))
        for s, k in enumerate(best):
            origins[k].append(rays[c][s][0])
            directions[k].append(rays[c][s][1])
    return tuple(matches[c] for c in range(len(groupings))), ""


def leave_out_contradicted_sets(
    groupings: Sequence[HighlightGrouping],
    matches: Sequence[CaptureMatch],
    poses: Sequence[PlatePose],
    rig: CameraRig,
    n_lights: int,
    *,
    tolerance_px: float = CONTRADICTED_SET_PX,
    refine: bool = True,
    max_residual_m: float,
) -> tuple[tuple[HighlightGrouping, ...], tuple[CaptureMatch, ...],
           tuple[tuple[int, int, tuple[int, ...], str], ...]]:
    """Leave out highlight sets that the other captures of their light contradict.

    For a light with sets in three or more captures, each set is checked against the
    light solved from the others (:func:`~.light.light_from_reflections`): its highlights
    must lie within ``tolerance_px`` (RMS) of that light mirrored across its capture's
    plate. The worst set beyond it is left out (its highlights join the capture's
    unmatched ones), and the check runs again on the rest. With two captures the set of
    fewer views is checked against the light the other one places (left out, its light
    is seen in one capture only, which :func:`~.captures.estimate_lights` refuses: which
    of two contradicting captures is wrong, nothing tells); two sets of as many views
    both stay, and the assignment's ray distance decides as before.

    A set of one lamp's highlight is internally consistent whatever light it was
    assigned to; the mean ray distance of the assignment (over all of a light's rays,
    which their common point follows) can stay within bounds while a few of its rays
    pull the light far along the bundles' poorly fixed direction.

    Parameters
    ----------
    groupings, matches : sequence
        Per capture, its highlight sets and their lights (:func:`group_highlights`,
        :func:`match_captures`).
    poses : sequence of PlatePose
        Per capture, the plate (from its markers).
    rig : CameraRig
    n_lights : int
    tolerance_px : float
        Largest RMS distance of a kept set's highlights from the images of its light.
    refine : bool
        Solve each light from the other captures with the joint refinement.
    max_residual_m : float
        As :func:`~.light.light_from_reflections` (a solve that fails checks nothing).

    Returns
    -------
    groupings, matches : tuple
        Without the sets left out.
    left_out : tuple of (int, int, tuple of int, str)
        Per set left out: its capture, its light, its views, and why (the distance and
        the captures that placed the light).
    """
    groupings, matches = list(groupings), list(matches)
    left_out: list[tuple[int, int, tuple[int, ...], str]] = []
    for light in range(n_lights):
        while True:
            held = [(c, s) for c, m in enumerate(matches)
                    for s, j in enumerate(m.lights) if j == light]
            n_views = [len(groupings[c].sets[s].views) for c, s in held]
            if len(held) >= 3:
                checked = held
            elif len(held) == 2 and n_views[0] != n_views[1]:
                # The other capture alone checks only a set of fewer views than its own.
                checked = [held[int(np.argmin(n_views))]]
            else:
                break
            worst = None  # (distance, capture, set, other captures)
            for c, s in checked:
                others = [(o, t) for o, t in held if o != c]
                try:
                    placed = light_from_reflections(
                        [poses[o] for o, _ in others],
                        [groupings[o].sets[t].centers_px for o, t in others], rig,
                        refine=refine, max_residual_m=max_residual_m,
                        capture_spread=False)  # the position is all the check reads
                except LightError:  # the others alone fix no light: nothing to check with
                    continue
                distance = highlight_rms_px(placed.position_m, [poses[c]],
                                            [groupings[c].sets[s].centers_px], rig)
                if worst is None or distance > worst[0]:
                    worst = (distance, c, s, [o for o, _ in others])
            if worst is None or not worst[0] > tolerance_px:
                break
            distance, c, s, others = worst
            dropped = groupings[c].sets[s]
            left_out.append((c, light, dropped.views, (
                f"its highlights in views {list(dropped.views)} lie {distance:.1f} px (RMS) "
                f"from the light's images as captures {others} place it (at most "
                f"{tolerance_px:g} px)")))
            unmatched = tuple(
                np.vstack([extra, dropped.centers_px[v][None]])
                if dropped.candidates[v] >= 0 else extra
                for v, extra in enumerate(groupings[c].unmatched_px))
            groupings[c] = replace(groupings[c],
                                   sets=tuple(x for i, x in enumerate(groupings[c].sets) if i != s),
                                   unmatched_px=unmatched)
            matches[c] = replace(matches[c],
                                 lights=tuple(j for i, j in enumerate(matches[c].lights) if i != s))
    return tuple(groupings), tuple(matches), tuple(left_out)
