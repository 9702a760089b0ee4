"""Highlight candidates: every blob that stands out where an object's highlight can be.

With one light, the brightest blob on the object is its highlight. With several, each
view may show a highlight of every light that lands on the object, merged or apart, so
every blob that stands out is a candidate: :func:`find_candidates` finds them in one
view's search region (every local maximum of the smoothed luminance that clears the
contrast threshold and is not the flat top of a brighter clipped blob), and
:func:`gather_candidates` in the reference search region and in every other view's band
(:func:`candidate_band`: the reference box swept along the baseline over the virtual
lights' possible depths). Which light each candidate belongs to is
:mod:`.assignment`'s question.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..boxes import BoxMask
from ..geometry import CameraRig
from ..imaging import luminance
from .assignment import AssignmentContext
from .config import BLOB_LEVEL, PEAK_SMOOTHING_SIGMA_PX, DetectorConfig
from .cut_highlights import arc_center
from .highlight import (
    HighlightDetection,
    grown_box,
    median,
    region_background,
    search_box,
    weighted_centroid,
)
from .search import BaselineSearch

if TYPE_CHECKING:
    from .estimator import SRDE

__all__ = [
    "MAX_CANDIDATES",
    "ViewCandidates",
    "candidate_band",
    "find_candidates",
    "gather_candidates",
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


def find_candidates(image: np.ndarray, region: np.ndarray, config: DetectorConfig, *,
                    max_candidates: int = MAX_CANDIDATES, object_region: bool = False,
                    region_bbox: tuple[int, int, int, int] | None = None,
                    min_background: float = 0.0) -> list[HighlightDetection]:
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
    min_background : float
        The background level is at least this, linear luminance: a band that is mostly
        dark background would otherwise make the object's own body a highlight.

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
    if object_region:
        background = region_background(lum[inside], float(lum[inside].max()), config.min_contrast)
    else:
        background = median(lum[inside], overwrite=True)
    background = max(float(background), min_background)
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
        nearest[vv, uu] = _nearest(uu, vv, where[kept])
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
        fill = above[ay:ay + ah, ax:ax + aw].astype(np.uint8)
        if 0 <= pv < above.shape[0] and 0 <= pu < above.shape[1] and above[pv, pu]:
            # The component of the peak's pixel: filled from it, 1 -> 2.
            area, _, _, (x, y, bw, bh) = cv2.floodFill(fill, None, (pu - ax, pv - ay), 2,
                                                       flags=8)
            blob = fill == 2
        else:  # the smoothed peak sits beside its pixels: take the largest part
            count, parts = cv2.connectedComponents(fill, connectivity=8)
            blob = parts == _largest_label(parts, count)
            x, y, bw, bh = cv2.boundingRect(blob.view(np.uint8))
            area = cv2.countNonZero(blob.view(np.uint8))
        # The light-weighted centroid over the box of the pixels above the level (zero
        # off the blob).
        weights = np.where(blob, lum[ay:ay + ah, ax:ax + aw] - level, 0.0)
        center = weighted_centroid(weights) + np.array([ax + u0, ay + v0], dtype=np.float64)
        bbox = (x + ax + u0, y + ay + v0, x + ax + bw + u0, y + ay + bh + v0)
        found.append(HighlightDetection(True, center, int(area), bbox,
                                        float(tops[i] - background), "", float(level)))
    return found


def _nearest(uu: np.ndarray, vv: np.ndarray, peaks: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``peaks`` ``(K, 2)`` to each pixel, the first on ties."""
    best = (uu - peaks[0, 0]) ** 2 + (vv - peaks[0, 1]) ** 2
    index = np.zeros(uu.shape, dtype=np.intp)
    for k in range(1, len(peaks)):
        d = (uu - peaks[k, 0]) ** 2 + (vv - peaks[k, 1]) ** 2
        closer = d < best
        best = np.where(closer, d, best)
        index[closer] = k
    return index


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
    anchor_free : bool
        The reference view holds no candidate (``gather_candidates(anchor_free=True)``):
        the object's highlights are seen only where they reach it from other views,
        near its outline, and every score lets predictions there take candidates.
    """

    found: list
    centers_uv: list
    lit: Any
    blob_radius_px: float
    anchor_free: bool = False

    @property
    def boxes(self) -> list[np.ndarray]:
        """Each candidate's blob box ``(u0, v0, u1, v1)`` per view, ``(m_j, 4)`` float."""
        return [np.asarray([d.bbox for d in dets], dtype=np.float64).reshape(-1, 4)
                for dets in self.found]

    def context(self, srde: SRDE, mask: np.ndarray, **options) -> AssignmentContext:
        """Return the hypothesis machinery on these candidates, as the assignment has it.

        The same :class:`~.assignment.AssignmentContext` that
        :func:`~.assignment.assign_lights` builds.

        With ``srde``'s lights and tolerances; ``options`` go to the context.
        """
        if self.anchor_free:
            options["near_outline"] = True
        return AssignmentContext(srde.rig, srde.lights_m, mask, self.centers_uv, self.lit,
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


def gather_candidates(srde: SRDE, views, search: np.ndarray, *, anchor_free: bool = False
                      ) -> ViewCandidates | None:
    """Candidates in the reference search region and in every other view's band.

    The band is where a highlight of the object can appear for any light (the search
    region's box swept along the baseline over the virtual-light depths of every
    reference candidate and light). None when the reference region holds no candidate,
    unless ``anchor_free``: then the band spans the depths of a virtual light seen
    anywhere in the region's box, and None only when fewer than ``srde.min_views`` views
    hold a candidate.
    """
    rig, config = srde.rig, srde.config
    ref = rig.reference
    ref_found = find_candidates(views[ref], search, config, object_region=True)
    box = search_box(search, 0)
    if ref_found:
        # Inverse depths of a virtual light seen at any reference candidate, any light.
        w_range = [BaselineSearch(rig, light, srde.object_depth_m).inverse_depth_range(
            d.center_uv) for light in srde.lights_m for d in ref_found]
        w_lo, w_hi = min(w[0] for w in w_range), max(w[1] for w in w_range)
    elif anchor_free and box is not None:
        # No reference highlight to sweep from: a highlight lies on the object in every
        # view that sees one, so the band is the region's box over the object's depths.
        # That band holds the object's whole body and much dark background, so the
        # body's level in the reference view is the least background a highlight stands
        # out from.
        near_m, far_m = srde.object_depth_m
        w_lo, w_hi = 1.0 / far_m, 1.0 / near_m
        u0, v0, u1, v1 = box
        body = luminance(views[ref][v0:v1, u0:u1], config.encoding)[
            np.asarray(search[v0:v1, u0:u1], dtype=bool)]
        min_background = float(np.median(body))
    else:
        return None
    found: list[list[HighlightDetection]] = []
    for j in range(rig.n_cameras):
        if j == ref:
            found.append(ref_found)
        else:
            band, band_bbox = candidate_band(rig, j, box, (w_lo, w_hi))
            found.append([] if band_bbox is None else
                         find_candidates(views[j], band, config, region_bbox=band_bbox,
                                         min_background=0.0 if ref_found else min_background))
    if not ref_found and sum(bool(dets) for dets in found) < srde.min_views:
        return None
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
    return ViewCandidates(found, cands, lit, blob_radius_px, anchor_free=not ref_found)
