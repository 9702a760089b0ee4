"""Several known lights: which highlight belongs to which light, and the plane they share.

With one light, the brightest blob on the object is its highlight. With several, each
view may show a highlight of every light that lands on the object, and the brightest blob
of one view need not belong to the same light as that of another: triangulating them
together gives a wrong virtual light with a small residual. The lights' positions are
known, and that settles the correspondence by geometry:

* one light's highlights in all views are the images of *one* point, its virtual light,
  so in a rectified rig they sit on the reference highlight's baseline lines at a single
  inverse depth;
* every light's virtual light is the mirror image of that light across the *same*
  plane, so a plane proposed from one light's virtual light predicts where every other
  light's highlight must appear, and on which views it lands on the object.

:func:`assign_lights` proposes a plane for every pairing of a reference-view candidate
with a candidate on its baseline line in another view and every light, scores each
plane by the candidates it explains (and the on-object highlights it predicts that are
missing), refits the best one to all the highlights it explains, and reports the
assignment with its evidence. When another plane explains the candidates as well, the
object is reported ``"ambiguous"``: a wrong assignment yields a wrong plane with a small
residual, so a tie is a reasoned failure, never a guess.

Pure geometry on highlight centres; :func:`find_candidates` finds the candidates in one
view's search region (every blob that stands out, not only the brightest).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from .._checks import check_point3
from ..boxes import BoxMask, eroded
from ..errors import LightError
from ..geometry import (
    MAX_LIGHTS,
    CameraRig,
    Plane,
    plane_disparity,
    plane_from_lights,
    project_points,
)
from ..imaging import luminance
from .config import BLOB_LEVEL, PEAK_SMOOTHING_SIGMA_PX, DetectorConfig
from .cut_highlights import arc_center
from .highlight import (
    HighlightDetection,
    detect_in_view,
    grown_box,
    median,
    region_background,
    search_box,
    weighted_centroid,
)
from .refine.samples import WINDOW_PER_BLOB_RADIUS, references_from_views
from .search import BaselineSearch

if TYPE_CHECKING:
    from .estimator import SRDE
    from .result import SRDEResult

__all__ = [
    "LightAssignment",
    "LightsSolution",
    "assign_lights",
    "candidate_band",
    "check_lights",
    "estimate_with_lights",
    "find_candidates",
]

#: Candidates per view at most (blobs beyond the brightest few are noise or texture).
MAX_CANDIDATES = 8


#: Radius (pixels) of the neighbourhood a highlight's peak is the maximum of.
PEAK_RADIUS_PX = 3


# Reach (pixels) of OpenCV's Gaussian kernel at the peak smoothing scale (4 sigma for
# floating-point images), plus one.
_BLUR_REACH_PX = int(math.ceil(4.0 * PEAK_SMOOTHING_SIGMA_PX)) + 1


#: Maxima within this fraction of the contrast of their neighbourhood's maximum are one
#: plateau (the flat top of a clipped blob, with rounding noise on it).
PLATEAU_SLACK = 1e-3


#: Two peaks are two highlights if the luminance between them dips below the dimmer one
#: by this fraction of its contrast; else they are the flat top of one clipped blob.
SEPARATING_DIP = 0.2


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


#: A plane from the joint lobe fit (settled where the blob centres could not settle one)
#: is refused when the centres' evidence against it outweighs what it explains by this
#: ratio: merged and outline-cut blobs leave stray pieces the lobes account for, so the
#: centres' verdict counts less than for a plane from the centres
#: (:data:`UNEXPLAINED_RATIO`). A correct plane of four lights with one merged blob had 7
#: strays against 10 explained; a three-face object flattened into one plane 7.9 px off,
#: 17 against 7.
LOBE_FIT_UNEXPLAINED_RATIO = 1.0


_LIGHT_BEHIND = "put a light behind the plane"

#: A rival that explains only the best plane's highlights, as another light's, keeps the
#: object undecided when its RMS distance to them is this many times smaller (on faces
#: taken as their own masks: wrong planes fitted 0.4-0.5 px, the true ones 0.01-0.05).
CLOSER_FIT_RATIO = 5.0


#: The best plane is decided against its strongest rival when its net support (explained
#: highlights less the evidence against) is larger by at least this much.
DECISIVE_MARGIN = 2


#: A refined plane (one light's lobe) is kept only if every light's assigned highlight
#: stays within this many times the assignment tolerance of where it puts it.
REFINED_AGREEMENT = 1.0


#: A refined several-light plane with a larger disparity standard error (pixels) is not
#: an answer: the assignment of highlights to lights is then not established either.
LIGHTS_MAX_SIGMA_PX = 0.1


#: Two planes fitted to merged blobs from different starts: one is the answer if its
#: photometric cost is this many times lower than the other's on both fits' samples.
DECISIVE_COST_RATIO = 2.0


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


# ---------------------------------------------------------------------- candidates
def find_candidates(image: np.ndarray, region: np.ndarray, config: DetectorConfig, *,
                    max_candidates: int = MAX_CANDIDATES, object_region: bool = False,
                    region_bbox: tuple[int, int, int, int] | None = None
                    ) -> list[HighlightDetection]:
    """Every highlight in a view's search region, brightest first.

    Two highlights of different lights can lie close enough to merge above one
    half-maximum level, so the single-light detector's "component with the most light"
    would return a blend of both. Here every local maximum of the luminance (smoothed
    at the blob detector's peak scale) that stands out from the region's median by the
    detector's ``min_contrast`` is a highlight, unless the luminance between it and a
    brighter one never dips by :data:`SEPARATING_DIP` of its contrast (the flat top of
    one clipped blob). Each highlight's centre is the light-weighted centroid of the
    pixels above its own half-maximum level, connected to its peak and nearer to it than
    to any other peak.

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3)
        A validated view.
    region : numpy.ndarray or BoxMask, (H, W) bool
        Where to look.
    config : DetectorConfig
        The blob detector's options (encoding, minimum contrast).
    max_candidates : int
    object_region : bool
        The region is the object's own search region (the reference view): a region
        mostly filled by one clipped blob then has its background read at a low quantile
        (:func:`~.highlight.region_background`); elsewhere the median stays.
    region_bbox : (int, int, int, int), optional
        ``region``'s bounding box ``(u0, v0, u1, v1)``, inclusive-exclusive, if known;
        found from ``region`` otherwise (as :func:`~.highlight.detect_in_view`).

    Returns
    -------
    list of HighlightDetection
        Found detections only (possibly none), ``score`` = peak contrast.
    """
    margin = config.margin_px + PEAK_RADIUS_PX
    if region_bbox is None:
        box = search_box(region, margin)
    elif region_bbox[2] > region_bbox[0] and region_bbox[3] > region_bbox[1]:
        box = grown_box(region_bbox, margin, region.shape)
    else:
        box = None  # an empty region
    if box is None:
        return []
    u0, v0, u1, v1 = box
    lum = luminance(image[v0:v1, u0:u1], config.encoding)
    inside = region[v0:v1, u0:u1]
    background = (region_background(lum[inside], float(lum[inside].max()), config.min_contrast)
                  if object_region else median(lum[inside]))
    # Peaks are looked for where something is bright: no peak (smoothed luminance above
    # background + min_contrast) lies farther than the blur's reach from a pixel above
    # that level, so twice the reach plus the peak radius around those pixels gives the
    # same filter values there as the whole crop.
    bright = inside & (lum > background + config.min_contrast)
    x, y, bw, bh = cv2.boundingRect(bright.view(np.uint8))
    if bw == 0:
        return []
    a0, b0, a1, b1 = grown_box((x, y, x + bw, y + bh), 2 * _BLUR_REACH_PX + PEAK_RADIUS_PX,
                               lum.shape)
    smooth = cv2.GaussianBlur(lum[b0:b1, a0:a1], (0, 0), PEAK_SMOOTHING_SIGMA_PX,
                              borderType=cv2.BORDER_REFLECT)
    side = 2 * PEAK_RADIUS_PX + 1
    local_max = cv2.dilate(smooth, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side)))
    # (A clipped blob's flat top is one plateau of near-equal maxima: the slack joins it.)
    slack = PLATEAU_SLACK * max(float(local_max.max()) - background, 0.0)
    peaks = inside[b0:b1, a0:a1] & (smooth >= local_max - slack) \
        & (smooth > background + config.min_contrast)
    n, labels = cv2.connectedComponents(peaks.view(np.uint8), connectivity=8)
    if n <= 1:
        return []
    # Each plateau's top and centroid from its pixels (OpenCV's statistics pass costs
    # several times the labelling).
    vv, uu = _nonzero(peaks)
    plateau = labels[vv, uu]
    size = np.bincount(plateau, minlength=n)[1:]
    where = np.stack([np.bincount(plateau, uu, n)[1:], np.bincount(plateau, vv, n)[1:]],
                     axis=1) / size[:, None]
    tops = _label_maxima(plateau, smooth[vv, uu], n)[1:]
    order = np.argsort(-tops, kind="stable")[:4 * max_candidates]
    # The brightest peaks are kept in order unless the luminance fails to dip between
    # them and one kept before (the flat top of one clipped blob).
    kept_rank = _separated_peaks(smooth, where[order], tops[order], background, max_candidates)
    kept = [int(order[p]) for p in kept_rank]
    # Each pixel above the lowest blob level belongs to its nearest kept peak. Blobs are
    # looked for in the box of those pixels (their components are the same there).
    lowest = background + BLOB_LEVEL * (float(tops[kept].min()) - background)
    candidates = inside & (lum > lowest)
    x, y, bw, bh = cv2.boundingRect(candidates.view(np.uint8))
    lum, candidates = lum[y:y + bh, x:x + bw], candidates[y:y + bh, x:x + bw]
    where = where + np.array([a0 - x, b0 - y])
    u0, v0 = u0 + x, v0 + y
    if len(kept) > 1:
        vv, uu = _nonzero(candidates)
        nearest = np.full(lum.shape, -1, dtype=np.intp)
        nearest[vv, uu] = np.argmin(np.stack([(uu - where[i][0]) ** 2 + (vv - where[i][1]) ** 2
                                              for i in kept]), axis=0)
    found = []
    for rank, i in enumerate(kept):
        level = background + BLOB_LEVEL * (tops[i] - background)
        above = candidates & (lum > level)
        if len(kept) > 1:
            above &= nearest == rank
        # Components are labelled over the box of the pixels above the level only: the
        # same components, in the same raster order.
        ax, ay, aw, ah = cv2.boundingRect(above.view(np.uint8))
        pu, pv = (int(round(c)) for c in where[i])
        if aw == 0:
            continue
        above_box = np.ascontiguousarray(above[ay:ay + ah, ax:ax + aw])
        count, parts = cv2.connectedComponents(above_box.view(np.uint8), connectivity=8)
        on_blob = 0 <= pv < above.shape[0] and 0 <= pu < above.shape[1] and above[pv, pu]
        label = parts[pv - ay, pu - ax] if on_blob else 0
        if label == 0:  # the smoothed peak sits beside its pixels: take the largest part
            if count <= 1:
                continue
            label = _largest_label(parts, count)
        blob = parts == label
        # The light-weighted centroid over the blob's box (zero off the blob).
        weights = np.where(blob, lum[ay:ay + ah, ax:ax + aw] - level, 0.0)
        center = weighted_centroid(weights) + np.array([ax + u0, ay + v0], dtype=np.float64)
        x, y, bw, bh = cv2.boundingRect(blob.view(np.uint8))
        bbox = (x + ax + u0, y + ay + v0, x + ax + bw + u0, y + ay + bh + v0)
        found.append(HighlightDetection(True, center, cv2.countNonZero(blob.view(np.uint8)),
                                        bbox, float(tops[i] - background), "", float(level)))
    return found


def _label_maxima(labels: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Largest of ``values`` per label in ``[0, n)``, ``(n,)`` float64 (0 where none)."""
    out = np.zeros(n)
    # (ufunc.at has a fast loop only when the values already have the output's type.)
    np.maximum.at(out, labels, values.astype(np.float64))
    return out


def _largest_label(labels: np.ndarray, count: int) -> int:
    """Return the label of the largest component in ``cv2.connectedComponents``' output.

    ``count`` components with the background 0, ``count > 1``; ties go to the lowest label.
    """
    return 1 + int(np.argmax(np.bincount(labels.ravel(), minlength=count)[1:]))


def _centers(found) -> list[np.ndarray]:
    """Return each view's candidate centres ``(m_j, 2)`` from its detections, pixels."""
    return [np.array([d.center_uv for d in dets]).reshape(-1, 2) for dets in found]


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero`` of a 2-D bool array: rows, then columns, in raster order.

    (OpenCV's scan, in the same order, is a few times faster.)
    """
    uv = cv2.findNonZero(mask.view(np.uint8)) if mask.size else None
    if uv is None:  # OpenCV's answer when nothing is set
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    uv = uv.reshape(-1, 2)
    return uv[:, 1].astype(np.intp), uv[:, 0].astype(np.intp)


def _separated_peaks(smooth: np.ndarray, where: np.ndarray, tops: np.ndarray,
                     background: float, max_peaks: int) -> list[int]:
    """Ranks of the peaks kept: brightest first, each dipping from every one kept before.

    Peak p is kept when the luminance dips (:func:`_dips`) between it and every brighter
    peak kept before it, until ``max_peaks`` are kept. Each kept peak is tested against
    the peaks still in the running in one array pass, so the passes number the peaks
    kept, not the pairs.

    Parameters
    ----------
    smooth : numpy.ndarray, (h, w) float32
    where : numpy.ndarray, (M, 2) float64
        Peak positions ``(u, v)``, brightest first.
    tops : numpy.ndarray, (M,) float64
        Their smoothed maxima.
    background : float
    max_peaks : int

    Returns
    -------
    list of int
        Ranks into ``where``, ascending.
    """
    kept: list[int] = []
    running = np.arange(len(where))
    while running.size and len(kept) < max_peaks:
        q = int(running[0])
        kept.append(q)
        running = running[1:]
        if running.size:
            running = running[_dips(smooth, where, tops, background, running,
                                    np.full(running.size, q))]
    return kept


def _dips(smooth: np.ndarray, where: np.ndarray, tops: np.ndarray, background: float,
          p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Whether the luminance dips between peaks ``p`` and brighter peaks ``q``, ``(P,)`` bool.

    Two peaks are two highlights if the smoothed luminance sampled along the segment
    between them (one sample per pixel of its length, rounded to pixels, from p towards
    q) falls below p's top by :data:`SEPARATING_DIP` of its contrast. Every pair is
    sampled in one set of array operations.
    """
    a, b = where[p], where[q]                                              # (P, 2)
    d = b - a
    steps = np.maximum(np.ceil(np.hypot(d[:, 0], d[:, 1])).astype(np.intp) + 1, 2)
    # np.linspace(0, 1, n) is i * (1 / (n - 1)) with the last sample set to 1 exactly.
    ends = np.cumsum(steps)
    starts = ends - steps
    pair = np.repeat(np.arange(p.size), steps)
    t = (np.arange(int(ends[-1])) - starts[pair]) * (1.0 / (steps - 1))[pair]
    t[ends - 1] = 1.0
    us = np.rint(a[pair, 0] + t * d[pair, 0]).astype(np.intp)
    vs = np.rint(a[pair, 1] + t * d[pair, 1]).astype(np.intp)
    low = np.minimum.reduceat(smooth[vs, us], starts).astype(np.float64)
    top = tops[p]
    return low < top - SEPARATING_DIP * (top - background)


def candidate_band(rig: CameraRig, view: int, box: tuple[int, int, int, int],
                   inverse_depth_m: tuple[float, float]
                   ) -> tuple[BoxMask, tuple[int, int, int, int] | None]:
    """Where a highlight of the reference box can appear in another view, and its box.

    A virtual light seen inside the reference box ``(u0, v0, u1, v1)`` at inverse depth
    ``w`` appears in view j moved by ``-w (fx dX_j, fy dY_j)``; over ``w`` in
    ``inverse_depth_m`` the box sweeps a band along the baseline.

    Returns
    -------
    band : BoxMask
        Reads as the ``(H, W)`` bool band (held over its bounding box).
    bbox : (int, int, int, int) or None
        The band's bounding box ``(u0, v0, u1, v1)``, inclusive-exclusive; None if the
        band leaves the image.
    """
    k = rig.intrinsics
    offset = rig.centers_m[view, :2] - rig.reference_center_m[:2]
    step = np.array([-k.fx * offset[0], -k.fy * offset[1]])
    w_lo, w_hi = inverse_depth_m
    u0, v0, u1, v1 = box
    span_px = float(np.hypot(*step)) * (w_hi - w_lo)
    n = max(2, int(math.ceil(span_px / max(1.0, 0.5 * min(u1 - u0, v1 - v0)))) + 1)
    boxes = []  # the box moved to each inverse depth, clipped to the image
    for w in np.linspace(w_lo, w_hi, n):
        du, dv = step * w
        a0, b0 = int(math.floor(u0 + du)), int(math.floor(v0 + dv))
        a1, b1 = int(math.ceil(u1 + du)), int(math.ceil(v1 + dv))
        a0, b0, a1, b1 = max(a0, 0), max(b0, 0), min(a1, rig.width), min(b1, rig.height)
        if a1 > a0 and b1 > b0:
            boxes.append((a0, b0, a1, b1))
    shape = (rig.height, rig.width)
    if not boxes:
        return BoxMask.empty(shape), None
    bbox = (min(b[0] for b in boxes), min(b[1] for b in boxes),
            max(b[2] for b in boxes), max(b[3] for b in boxes))
    crop = np.zeros((bbox[3] - bbox[1], bbox[2] - bbox[0]), dtype=bool)
    for a0, b0, a1, b1 in boxes:
        crop[b0 - bbox[1]:b1 - bbox[1], a0 - bbox[0]:a1 - bbox[0]] = True
    return BoxMask.from_crop(bbox, crop, shape), bbox


# ---------------------------------------------------------------------- assignment
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
                  lit=None, blob_radius_px: float = 0.0, blob_boxes=None) -> LightsSolution:
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
                       blob_radius_px, boxes)
    if len(cands[ref]) == 0:
        return _no_plane("no_highlight", "reference view: no highlight candidate on the "
                         "object", cands)
    scores = [s for s in (context.score(p) for p in context.proposals()) if s is not None]
    if not scores and blob_boxes is not None:
        # No depth that two views agree on: merged or cut blobs, whose centres wander.
        # Planes from single pairings may still explain them as merged blobs.
        scores = [s for s in (context.score(p) for p in context.proposals(loose=True))
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
                 blob_radius_px: float, boxes=None, *, all_lights_in_front: bool = True
                 ) -> None:
        # One plane per object has every light in front of it; a face of a faceted
        # object may turn its back on the other faces' lights (they then predict nothing).
        self.all_lights_in_front = all_lights_in_front
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
        self.corners = _box_corners(mask)

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
        a plane could explain the same centres, not to rank it).
        """
        if plane is None:
            return None
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
        """Largest disparity difference of two planes at the object's box corners, px."""
        return _plane_gap_px(self.rig, self.corners, a, b)

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


@dataclass(frozen=True)
class ViewCandidates:
    """Highlight candidates of every view, and how to ask whether a view is bright.

    Parameters
    ----------
    found : list of list of HighlightDetection
        The candidates of each view, brightest first.
    centers_uv : list of numpy.ndarray, each (m_j, 2)
        Their centres, pixels.
    lit : callable
        ``lit(j, uv)`` -> ``(M,)`` bool: view j is bright at pixels ``uv`` ``(M, 2)`` (above
        the half-maximum level of its dimmest candidate); ``j`` is one view or ``(M,)``,
        each point's own.
    blob_radius_px : float
        Median half-maximum radius of the candidates, pixels.
    """

    found: list
    centers_uv: list
    lit: Any
    blob_radius_px: float

    @property
    def boxes(self) -> list[np.ndarray]:
        """Each candidate's blob box ``(u0, v0, u1, v1)`` per view, ``(m_j, 4)`` float."""
        return [np.asarray([d.bbox for d in dets], dtype=np.float64).reshape(-1, 4)
                for dets in self.found]

    def context(self, srde: SRDE, mask: np.ndarray, **options) -> _Context:
        """Return the hypothesis machinery on these candidates, as :func:`assign_lights` has it.

        With ``srde``'s lights and tolerances; ``options`` go to the context.
        """
        return _Context(srde.rig, srde.lights_m, mask, self.centers_uv, self.lit,
                        2.0 * srde.max_residual_px, srde.object_depth_m, srde.min_views,
                        self.blob_radius_px, self.boxes, **options)

    def recentred(self, views, encoding: str) -> ViewCandidates | None:
        """Return these candidates with each cut blob centred on its arc (:func:`.arc_center`).

        A blob cut by a straight chord (a face's edge, a straight stretch of the outline)
        has its centroid pulled into the part left; the ellipse through the rest of its
        outline has the whole highlight's centre. Each blob is read again as the largest
        component above its level in its box. None when no blob is cut.
        """
        found, moved = [], False
        for j, dets in enumerate(self.found):
            row = []
            for d in dets:
                u0, v0, u1, v1 = d.bbox
                above = luminance(views[j][v0:v1, u0:u1], encoding) > d.level
                count, parts = cv2.connectedComponents(above.view(np.uint8), connectivity=8)
                center = arc_center(parts == _largest_label(parts, count)) if count > 1 \
                    else None
                if center is not None:
                    d = dataclasses.replace(d, center_uv=center + np.array([u0, v0], float))
                    moved = True
                row.append(d)
            found.append(row)
        if not moved:
            return None
        return ViewCandidates(found, _centers(found), self.lit, self.blob_radius_px)


def gather_candidates(srde: SRDE, views, search: np.ndarray) -> ViewCandidates | None:
    """Candidates in the reference search region and in every other view's band.

    The band is where a highlight of the object can appear for any light (the search
    region's box swept along the baseline over the virtual-light depths of every
    reference candidate and light). None when the reference region holds no candidate.
    """
    rig, config = srde.rig, srde.config
    ref = rig.reference
    ref_found = find_candidates(views[ref], search, config, object_region=True)
    if not ref_found:
        return None
    # Inverse depths of a virtual light seen at any reference candidate, for any light.
    w_range = [BaselineSearch(rig, light, srde.object_depth_m).inverse_depth_range(d.center_uv)
               for light in srde.lights_m for d in ref_found]
    w_lo, w_hi = min(w[0] for w in w_range), max(w[1] for w in w_range)
    box = search_box(search, 0)
    found: list[list[HighlightDetection]] = []
    for j in range(rig.n_cameras):
        if j == ref:
            found.append(ref_found)
        else:
            band, band_bbox = candidate_band(rig, j, box, (w_lo, w_hi))
            found.append([] if band_bbox is None else
                         find_candidates(views[j], band, config, region_bbox=band_bbox))
    cands = _centers(found)
    # The half-maximum level of each view's dimmest candidate.
    level_of_view = np.array([min((d.level for d in dets), default=math.inf) for dets in found])
    patch_means: dict[tuple[int, int, int], float] = {}  # (view, u, v) -> mean luminance

    def lit(j, uv: np.ndarray) -> np.ndarray:
        # Mean linear luminance over the 3 x 3 pixels around each point, against the
        # half-maximum level of the view's dimmest highlight. The hypotheses of one object
        # ask about the same pixels again and again: each patch is read once, and the
        # patches not yet read go through one luminance call (its fixed cost dominates).
        j = np.broadcast_to(np.asarray(j, dtype=np.intp), (len(uv),))
        u = np.clip(np.rint(uv[:, 0]).astype(np.intp), 1, rig.width - 2)
        v = np.clip(np.rint(uv[:, 1]).astype(np.intp), 1, rig.height - 2)
        keys = list(zip(j.tolist(), u.tolist(), v.tolist(), strict=True))
        new = [key for key in dict.fromkeys(keys) if key not in patch_means]
        if new:
            patches = np.stack([views[view][b - 1:b + 2, a - 1:a + 2] for view, a, b in new])
            pixels = patches.reshape((len(new), 9) + patches.shape[3:])  # raster order
            patch_means.update(zip(new, luminance(pixels, config.encoding).mean(axis=1).tolist(),
                                   strict=True))
        lum = np.array([patch_means[key] for key in keys], dtype=np.float64)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= rig.width - 1) & (uv[:, 1] >= 0) \
            & (uv[:, 1] <= rig.height - 1)
        return inside & (lum > level_of_view[j])

    blob_radius_px = float(np.median([math.sqrt(d.area_px / math.pi) for dets in found
                                      for d in dets]))
    return ViewCandidates(found, cands, lit, blob_radius_px)


def estimate_with_lights(srde: SRDE, views, mask: np.ndarray, search: np.ndarray, *,
                         gathered: ViewCandidates | None = None) -> SRDEResult:
    """:meth:`SRDE.estimate` with several known lights (``srde.lights_m``).

    Candidates in the reference search region and, in every other view, in the band
    where a highlight of the object can appear for any light; :func:`assign_lights`
    matches them to the lights and fits the plane. The plane then goes through the same
    checks (and, with ``srde.refine``, the same photometric refinement, on the
    highlights of the light seen in most views) as a single light's.

    With several lights, which light made a highlight is itself estimated: a refined
    plane whose disparity standard error exceeds :data:`LIGHTS_MAX_SIGMA_PX` is not
    pinned down by the images and the object is ``ambiguous`` (two faces alone were
    solved 10.3 and 1.0 px off with errors of 0.37 and 0.16 px; on the several-light
    benchmark every plane's error is below 0.03 px, and of the faces alone one correct
    plane, 0.10 px off with 0.104 px, is refused with them).

    ``gathered``: :func:`gather_candidates`' answer for ``search``, if the caller has it
    (the faces' estimate found it first); found here otherwise.
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
    if gathered is None:  # (none found by the caller finds none here either, cheaply)
        gathered = gather_candidates(srde, views, search)
    if gathered is None:
        reason = detect_in_view(views[ref], search, srde.config).reason
        return srde._failed("no_highlight", f"{srde._view(ref)}: {reason}")
    found, cands, lit = gathered.found, gathered.centers_uv, gathered.lit
    blob_radius_px = gathered.blob_radius_px
    tolerance_px = 2.0 * srde.max_residual_px
    solution = assign_lights(rig, srde.lights_m, mask, cands, tolerance_px=tolerance_px,
                             min_views=srde.min_views, object_depth_m=srde.object_depth_m,
                             lit=lit, blob_boxes=[[d.bbox for d in dets] for dets in found],
                             blob_radius_px=blob_radius_px)
    if not solution.ok:
        failed = dataclasses.replace(srde._failed(solution.status, solution.reason),
                                     lights=solution)
        if not srde.refine:
            return failed
        if solution.merged_blobs and solution.plane is not None \
                and solution.status in ("too_few_views", "ambiguous", "inconsistent"):
            result = _solve_merged(srde, views, mask, solution, failed)
            if not (result.ok or result.status == "ambiguous"):
                # Neither start led the lobes to a plane: the lights alone may.
                result = _solve_from_single_lights(srde, views, mask, solution, result,
                                                   why="the merged-blob fit found no plane")
        elif solution.plane is None and solution.status == "too_few_views":
            result = _solve_from_single_lights(srde, views, mask, solution, failed)
        elif solution.status in ("ambiguous", "inconsistent") \
                and solution.rival_plane is not None:
            result = _solve_ambiguous(srde, views, mask, solution, failed)
        else:
            return failed
        return _no_highlights_left_out(srde, mask, gathered, result, failed)
    # The light seen in most views (then with the smallest residual) carries the checks
    # and the refinement; the joint plane mirrors it onto its own virtual light.
    main = max((a for a in solution.assignments if a.n_views),
               key=lambda a: (a.n_views, -float(np.nanmax(a.residuals_px))))
    used = np.isfinite(main.centers_uv[:, 0])
    notes = tuple(
        f"light {a.light}: highlight expected on the object but not found in view(s) "
        f"{list(a.missing_views)}" for a in solution.assignments if a.missing_views)
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
                                           _solve_ambiguous(srde, views, mask, doubt, failed),
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
            return _solve_merged(srde, views, mask, doubt, dataclasses.replace(
                srde._failed("inconsistent", reason), lights=doubt))
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
            return dataclasses.replace(result, lights=_solved_on(srde, mask, solution,
                                                                 result.plane))
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
            return result
        # The rule the centres' planes obey (10), with the lobes' benefit of the doubt:
        # a plane with more evidence against it than it explains is not the answer.
        reason = (f"lights: the joint lobe fit's plane has more evidence against it "
                  f"({own.n_missing} highlight(s) predicted on the object and not there, "
                  f"{own.n_strays} blob(s) on the object no light explains) than the "
                  f"{own.support} highlight(s) and merged blobs it explains (another surface or "
                  f"face: SRDE(max_faces=2..3) splits flat faces); "
                  + "; ".join(result.notes[-1:]))
        return dataclasses.replace(failed, status="inconsistent", reason=reason)
    gap_px = _plane_gap_px(rig, _box_corners(mask), other.plane, result.plane)
    reason = (f"lights: the joint lobe fit's plane leaves out highlights that another plane "
              f"({gap_px:.1f} px away) explains ({other.n_matched} highlight(s)): a second face "
              f"or surface (SRDE(max_faces=2..3) splits flat faces); "
              + "; ".join(result.notes[-1:]))
    return dataclasses.replace(failed, status="inconsistent", reason=reason)


def near_lights(on_object: np.ndarray, predicted_uv: np.ndarray, main: int,
                blob_radius_px: float) -> np.ndarray:
    """Which lights' highlights reach into the main light's fitting windows, ``(K,)`` bool.

    A light is near when, in some view where both are predicted on the object
    (``on_object`` ``(K, N)``), its highlight lies within the window's reach plus
    :data:`BLEND_RADII` blob radii of the main one's (``predicted_uv`` ``(K, N, 2)``):
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


def _plain_context(srde: SRDE, mask: np.ndarray, solution: LightsSolution) -> _Context:
    """Return the hypothesis machinery on the solution's blob centres alone.

    No brightness test and no blob boxes: predictions, and matches within the
    assignment's tolerance.
    """
    return _Context(srde.rig, srde.lights_m, mask, solution.candidates_uv, None,
                    2.0 * srde.max_residual_px, srde.object_depth_m, srde.min_views, 0.0)


def _lights_on_object(srde: SRDE, mask: np.ndarray, solution: LightsSolution,
                      starts: list[Plane]) -> list[np.ndarray] | None:
    """Each start's predicted on-object highlights ``(K, N)`` bool; None if one has none."""
    context = _plain_context(srde, mask, solution)
    presents = [context.predict(plane)[1] for plane in starts]
    return presents if all(p.any() for p in presents) else None


def _solve_merged(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                  failed: SRDEResult) -> SRDEResult:
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
    return _solve_by_lobes(srde, views, mask, solution, failed, starts,
                           [present] * len(starts), note)


def _solve_ambiguous(srde: SRDE, views, mask: np.ndarray, solution: LightsSolution,
                     failed: SRDEResult) -> SRDEResult:
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
    return _solve_by_lobes(srde, views, mask, solution, failed, starts, presents, note,
                           must_fit=2)


def _same_centres_planes(srde: SRDE, mask: np.ndarray, solution: LightsSolution,
                         starts: list[Plane]) -> list[Plane]:
    """Planes giving the best plane's highlights to each further light, as starts.

    When the best plane explains one light's highlights, every other light is mirrored
    onto the same virtual light by its own plane (the centres cannot tell them apart);
    with three or more lights the rival is only one of them. Those plausible for their
    light (``_Context.other_lights_planes``) and more than ``SAME_PLANE_PX`` from every
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
                              failed: SRDEResult, *,
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
    return _solve_by_lobes(srde, views, mask, solution, failed, starts, presents, note)


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
                    failed: SRDEResult, starts: list[Plane], presents: list[np.ndarray],
                    note: str, *, must_fit: int = 0) -> SRDEResult:
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

    corners = _box_corners(mask)
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
                and all(_plane_gap_px(rig, corners, fit.plane, f.plane) > SAME_PLANE_PX
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
        gap_px = _plane_gap_px(rig, corners, fits[i][0].plane, fits[j][0].plane)
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
                               lights=_solved_on(srde, mask, solution, result.plane))


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


def _solved_on(srde: SRDE, mask: np.ndarray, solution: LightsSolution,
               plane: Plane) -> LightsSolution:
    """Return the solution of the joint lobe fit's plane: blobs assigned on that plane.

    The fit may end on the rival plane, or on one no hypothesis proposed; the assignment
    of the geometric hypothesis it started from then belongs to another plane. The
    candidates are matched again to the lights' highlights this plane predicts (within
    the assignment's tolerance); a light none of them explains keeps no centre.
    """
    rig, lights = srde.rig, srde.lights_m
    context = _plain_context(srde, mask, solution)
    score = context.score(plane)
    if score is not None:
        on_plane = context.solution(score, None)
        assignments, residual_px = on_plane.assignments, on_plane.residual_px
        evidence = on_plane.evidence
    else:
        uv, on_object, _ = context.predict(plane)
        virtual = plane.mirror(lights)
        none = np.full((rig.n_cameras, 2), np.nan)
        assignments = tuple(
            LightAssignment(k, none.copy(), uv[k], on_object[k],
                            np.zeros(rig.n_cameras, bool), np.full(rig.n_cameras, np.nan),
                            virtual[k]) for k in range(len(lights)))
        residual_px, evidence = math.nan, "no blob centre lies on a highlight of this plane"
    return dataclasses.replace(
        solution, status="ok", reason="", plane=plane, assignments=assignments,
        residual_px=residual_px,
        evidence=f"{evidence}; the plane from the joint fit of one lobe per light")


def _centres(rig: CameraRig, plane: Plane, light: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Return the light's highlight centre in every used view, ``(N, 2)``; NaN elsewhere."""
    virtual = plane.mirror(light)
    centers = project_points(rig, virtual, np.arange(rig.n_cameras))
    return np.where(used[:, None], centers, np.nan)


def _box_corners(mask: np.ndarray) -> np.ndarray:
    """Corner pixels ``(4, 2)`` of the mask's bounding box."""
    u0, v0, u1, v1 = search_box(mask, 0)
    u1, v1 = u1 - 1, v1 - 1
    return np.array([[u0, v0], [u1, v0], [u0, v1], [u1, v1]], dtype=np.float64)


def _plane_gap_px(rig: CameraRig, corners: np.ndarray, a: Plane, b: Plane) -> float:
    """Largest disparity difference of two planes at pixels ``corners`` ``(M, 2)``, px."""
    return float(np.max(np.abs(plane_disparity(a, rig, corners)
                               - plane_disparity(b, rig, corners))))


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
