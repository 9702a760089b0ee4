"""Where the reference view's highlight can appear in every other view.

A virtual light seen at ``c_ref`` in the reference view appears in camera j at
``c_ref + step * w`` with ``step = (-fx dX_j, -fy dY_j)`` and ``w = 1 / z`` its inverse
depth (DESIGN §3); over V's plausible depth range that is a segment along the baseline.
Each candidate V also fixes the depth of the mirror point on the object, hence how far
the object moves between the views: a candidate counts only if it lands on the reference
search region moved by that shift. A detector backend picks the brightest candidate
(luminance smoothed at the blob's scale); the search region is then a disc of the
reference blob's size around it, within the reference search region moved by V's shift
(and, for the paper detector, also by the object's shift, so that object edges, which sit
at the object's disparity and not at V's, stay out).

Pure geometry: no pixel of an image is read here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..boxes import BoxMask
from ..geometry import CameraRig
from .highlight import HighlightDetection

__all__ = ["Candidates", "BaselineSearch", "shifted_window"]

# The reference highlight's search capsule in other views: this many times the reference
# blob's half-diagonal, plus a margin, around the line where the highlight can appear.
CAPSULE_SCALE = 2.0
CAPSULE_MARGIN_PX = 6.0
# Spacing of the candidate virtual-light positions along a baseline, pixels.
REGION_SAMPLE_PX = 0.5
# Longest segment along a baseline that is sampled, pixels: beyond every legal rig (fx
# below 1e6 px, cameras within 1 km) and short enough for exact float sample indices.
_MAX_SEGMENT_PX = 1e13


@dataclass(frozen=True)
class Candidates:
    """Positions along a baseline where a view can show the reference highlight.

    ``centers`` ``(n, 2)`` float: the reference centre moved by ``step * w_v`` (inverse
    depths ``w_v`` of V); ``pix`` their pixels; ``shift`` ``(n, 2)`` int: the object's
    image shift for each; ``ok`` those that land on the object. ``lo``/``hi``: the
    ``(u, v)`` crop, inclusive-exclusive, that smoothing at ``sigma_px`` reads.
    """

    step: np.ndarray
    w_v: np.ndarray
    centers: np.ndarray
    pix: np.ndarray
    shift: np.ndarray
    ok: np.ndarray
    sigma_px: float
    half_diagonal_px: float
    lo: tuple[int, int]
    hi: tuple[int, int]


@dataclass(frozen=True, eq=False)
class BaselineSearch:
    """The search geometry of one rig, light and object depth range.

    Parameters
    ----------
    rig : CameraRig
    light_m : numpy.ndarray, (3,) float64
        The light in the array frame, metres.
    object_depth_m : (float, float)
        Plausible depth range (reference camera z, metres) of the object.
    paper_detector : bool
        Keep the paper detector's regions inside the object as it appears in each view.
    """

    rig: CameraRig
    light_m: np.ndarray
    object_depth_m: tuple[float, float]
    paper_detector: bool = False

    def candidates(self, j: int, ref_det: HighlightDetection, search: np.ndarray
                   ) -> Candidates | None:
        """Where along its baseline view j can show the reference highlight; None if nowhere."""
        return self.all_candidates([j], ref_det, search)[j]

    def all_candidates(self, views, ref_det: HighlightDetection, search: np.ndarray
                       ) -> dict[int, Candidates | None]:
        """:meth:`candidates` of several views at once.

        The reference ray's geometry is computed once, and the samples of every view go
        through one set of array operations (each sample's arithmetic is the one a
        single view's search does, so the candidates are the same bit for bit).

        Returns
        -------
        dict
            View index -> its Candidates, or None where it can show the highlight nowhere.
        """
        rig = self.rig
        k = rig.intrinsics
        h, w = rig.height, rig.width
        c = ref_det.center_uv
        ray = _RefRay(self, c)
        w_lo, w_hi = ray.w_range
        found: dict[int, Candidates | None] = {j: None for j in views}
        segments = []                                  # (view, step, first, last, n)
        for j in views:
            offset = rig.centers_m[j, :2] - rig.reference_center_m[:2]
            # Numbers no camera has (the rig refuses them) end here as "nowhere", not as
            # overflow warnings or an allocation the size of fx * baseline.
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                step = np.array([-k.fx * offset[0], -k.fy * offset[1]])
                span_px = float(np.hypot(*step)) * (w_hi - w_lo)
            if not (span_px <= _MAX_SEGMENT_PX and np.all(np.isfinite(step))
                    and math.isfinite(w_lo) and w_hi >= w_lo):
                continue
            # The samples are those of linspace(w_lo, w_hi, n), but only the ones whose
            # centres can fall inside the image are made: the segment along the baseline
            # grows with fx * baseline, the image does not.
            n = int(math.ceil(span_px / REGION_SAMPLE_PX)) + 1
            kept = _indices_in_image(c, step, w_lo, w_hi, n, (w, h))
            if kept is not None:
                segments.append((j, step, *kept, n))
        if not segments:
            return found
        sizes = np.array([last - first + 1 for _, _, first, last, _ in segments])
        ends = np.cumsum(sizes)
        starts = ends - sizes
        w_v = np.concatenate([_linspace_part(w_lo, w_hi, n, first, last)
                              for _, _, first, last, n in segments])
        step = np.repeat(np.stack([seg[1] for seg in segments]), sizes, axis=0)  # (M, 2)
        centers = c + step * w_v[:, None]                                    # (M, 2) (u, v)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            shift_px = step * ray.mirror_inverse_depth(w_v)[:, None]
        # A shift beyond the image size moves every pixel out of it, as NaN does; bounded
        # so that the cast to integers stays exact.
        bound = 4.0 * max(w, h)
        shift = np.rint(np.clip(np.nan_to_num(shift_px, nan=bound), -bound, bound)).astype(int)
        pix = np.rint(centers).astype(int)
        src = pix - shift
        ok = ((pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
              & (src[:, 0] >= 0) & (src[:, 0] < w) & (src[:, 1] >= 0) & (src[:, 1] < h))
        ok[ok] = search[src[ok, 1], src[ok, 0]]
        # Per view: whether any sample is on the object, and the box of those that are.
        any_ok = np.logical_or.reduceat(ok, starts)
        big = np.iinfo(pix.dtype).max
        low = np.minimum.reduceat(np.where(ok[:, None], pix, big), starts, axis=0)
        high = np.maximum.reduceat(np.where(ok[:, None], pix, -big), starts, axis=0)
        u0, v0, u1, v1 = ref_det.bbox
        half_diagonal = 0.5 * math.hypot(u1 - u0, v1 - v0)
        sigma = max(1.0, 0.5 * half_diagonal)
        pad = int(math.ceil(3 * sigma))
        for i, (j, step_j, *_) in enumerate(segments):
            if not any_ok[i]:
                continue
            part = slice(int(starts[i]), int(ends[i]))
            lo = (max(int(low[i, 0]) - pad, 0), max(int(low[i, 1]) - pad, 0))
            hi = (min(int(high[i, 0]) + pad + 1, w), min(int(high[i, 1]) + pad + 1, h))
            found[j] = Candidates(step_j, w_v[part], centers[part], pix[part], shift[part],
                                  ok[part], sigma, half_diagonal, lo, hi)
        return found

    def region_at(self, cand: Candidates, best: int, search: np.ndarray,
                  search_bbox: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Return the search region of a view around its candidate ``best``, ``(H, W)`` bool.

        The image-sized array of :meth:`boxed_region_at`'s region.
        """
        return np.asarray(self.boxed_region_at(cand, best, search, search_bbox)[0])

    def boxed_region_at(self, cand: Candidates, best: int, search: np.ndarray,
                        search_bbox: tuple[int, int, int, int] | None = None
                        ) -> tuple[BoxMask, tuple[int, int, int, int] | None]:
        """Return the search region around candidate ``best`` and its bounding box.

        The region is held over the box it can be True in, without an image-sized array
        per view: the detector reads only the region's bounding box and a margin around it.

        Parameters
        ----------
        cand : Candidates
        best : int
            Index of the chosen candidate.
        search : numpy.ndarray, (H, W) bool
            The reference view's search region.
        search_bbox : (int, int, int, int), optional
            ``(u0, v0, u1, v1)``, inclusive-exclusive, a box holding every pixel of
            ``search`` (its bounding box). The region lies inside it moved with the
            highlight, so only that part of the disc is computed; the region is the same.

        Returns
        -------
        region : BoxMask
            Reads as the ``(H, W)`` bool region.
        bbox : (int, int, int, int) or None
            The region's bounding box ``(u0, v0, u1, v1)``, inclusive-exclusive; None if
            the region is empty.
        """
        h, w = self.rig.height, self.rig.width
        radius = CAPSULE_SCALE * cand.half_diagonal_px + CAPSULE_MARGIN_PX
        cu, cv = (float(c) for c in cand.centers[best])
        # Python floats round as numpy's float64 scalars do: the same box.
        bu0, bv0 = max(math.floor(cu - radius), 0), max(math.floor(cv - radius), 0)
        bu1, bv1 = min(math.ceil(cu + radius) + 1, w), min(math.ceil(cv + radius) + 1, h)
        # Moved with the highlight, the reference region clips the blob the same way in
        # every view, so the clip biases all centroids alike. The paper detector is also
        # kept inside the object as it appears in view j: its edges would be gradient rings.
        moves = [np.rint(cand.step * cand.w_v[best]).astype(int).tolist()]
        if self.paper_detector:
            moves.append(cand.shift[best].tolist())
        if search_bbox is not None:
            # Outside the moved search box every moved window is False: skip those pixels.
            su0, sv0, su1, sv1 = search_bbox
            for du, dv in moves:
                bu0, bv0 = max(bu0, su0 + du), max(bv0, sv0 + dv)
                bu1, bv1 = min(bu1, su1 + du), min(bv1, sv1 + dv)
        if bu1 <= bu0 or bv1 <= bv0:
            return BoxMask.empty((h, w)), None
        du2 = (np.arange(bu0, bu1) - cu) ** 2                                 # (w',)
        dv2 = (np.arange(bv0, bv1) - cv) ** 2                                 # (h',)
        # Rounding keeps du2 + dv2 growing with |u - cu| and |v - cv|: if the box's
        # farthest corner is in the disc, every pixel is.
        if max(du2[0], du2[-1]) + max(dv2[0], dv2[-1]) <= radius * radius:
            disc = shifted_window(search, moves[0], (bu0, bv0, bu1, bv1))
            moves = moves[1:]
        else:
            disc = du2[None, :] + dv2[:, None] <= radius * radius
        for moved in moves:
            disc &= shifted_window(search, moved, (bu0, bv0, bu1, bv1))
        x, y, bw, bh = cv2.boundingRect(disc.view(np.uint8))
        if bw == 0:
            return BoxMask.empty((h, w)), None
        return (BoxMask.from_crop((bu0, bv0, bu1, bv1), disc, (h, w)),
                (bu0 + x, bv0 + y, bu0 + x + bw, bv0 + y + bh))

    def inverse_depth_range(self, center_uv: np.ndarray) -> tuple[float, float]:
        """Range of ``w = 1 / z`` of a virtual light seen at ``center_uv`` in the reference view.

        The mirror point H lies on the ray at distance t, V beyond it with
        ``|V - H| = |H - L|`` (H is on the bisector plane of L and V), so V's distance
        along the ray is ``t + |t k - L|``, increasing in t: the object's depth range
        maps to an interval of V's depth.
        """
        rig = self.rig
        ray = rig.rays(center_uv)
        unit = ray / np.linalg.norm(ray)
        light = self.light_m - rig.reference_center_m
        w_range = []
        for z_obj in self.object_depth_m:
            t = z_obj / unit[2]
            distance = t + float(np.linalg.norm(t * unit - light))
            w_range.append(1.0 / (distance * unit[2]))
        return w_range[1], w_range[0]

    def mirror_inverse_depth(self, center_uv: np.ndarray, w_v: np.ndarray) -> np.ndarray:
        """``1 / z`` of the mirror point H for virtual lights at inverse depths ``w_v``.

        Inverting ``d = t + |t k - L|`` for the distance t of H along the unit ray k:
        ``t = (d^2 - |L|^2) / (2 (d - k · L))``.
        """
        rig = self.rig
        ray = rig.rays(center_uv)
        unit = ray / np.linalg.norm(ray)
        light = self.light_m - rig.reference_center_m
        distance = 1.0 / (w_v * unit[2])
        t = (distance ** 2 - light @ light) / (2.0 * (distance - unit @ light))
        return 1.0 / (t * unit[2])

    def off_object(self) -> HighlightDetection:
        """Return the failed detection of a view where no candidate lies on the object."""
        return HighlightDetection.missing(
            f"no position along the baseline (object depth {self.object_depth_m[0]:g}-"
            f"{self.object_depth_m[1]:g} m) lies on the object")


class _RefRay:
    """The reference highlight's ray, computed once for every view's search.

    The same arithmetic as :meth:`BaselineSearch.inverse_depth_range` and
    :meth:`BaselineSearch.mirror_inverse_depth`, with what does not depend on the view
    (or on ``w_v``) kept.
    """

    def __init__(self, search: BaselineSearch, center_uv: np.ndarray) -> None:
        rig = search.rig
        ray = rig.rays(center_uv)
        self.unit = ray / np.linalg.norm(ray)
        self.light = search.light_m - rig.reference_center_m
        self.light_sq = self.light @ self.light
        self.unit_light = self.unit @ self.light
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            self.w_range = search.inverse_depth_range(center_uv)

    def mirror_inverse_depth(self, w_v: np.ndarray) -> np.ndarray:
        """``1 / z`` of the mirror point for virtual lights at inverse depths ``w_v``."""
        distance = 1.0 / (w_v * self.unit[2])
        t = (distance ** 2 - self.light_sq) / (2.0 * (distance - self.unit_light))
        return 1.0 / (t * self.unit[2])


def _indices_in_image(center_uv, step, w_lo: float, w_hi: float, n: int,
                      size: tuple[int, int]) -> tuple[int, int] | None:
    """First and last of the ``n`` samples whose centre may round to a pixel of the image.

    Sample i sits at ``center_uv + step * w_i`` with ``w_i = w_lo + i * dw``; the range is
    widened by one sample and half a pixel each way, so every sample outside it lies
    outside the image. None if none can be inside.
    """
    lo, hi = w_lo, w_hi
    for c, s, extent in zip(center_uv, step, size, strict=True):
        # Pixels round from [-0.5, extent - 0.5); allow half a pixel more either side.
        a, b = -1.0 - c, float(extent) - c
        if s == 0.0:
            if not a <= 0.0 <= b:
                return None
            continue
        ta, tb = sorted((a / s, b / s))
        lo, hi = max(lo, ta), min(hi, tb)
    if not lo <= hi:
        return None
    if n == 1:
        return 0, 0
    dw = (w_hi - w_lo) / (n - 1)
    if dw == 0.0:
        return 0, n - 1
    first = max(int(math.floor((lo - w_lo) / dw)) - 1, 0)
    last = min(int(math.ceil((hi - w_lo) / dw)) + 1, n - 1)
    return (first, last) if first <= last else None


def _linspace_part(start: float, stop: float, n: int, first: int, last: int) -> np.ndarray:
    """Return samples ``first..last`` of ``np.linspace(start, stop, n)``, bit for bit, ``(k,)``."""
    if n == 1:
        return np.array([start], dtype=np.float64)
    # linspace computes i * ((stop - start) / (n - 1)) + start and sets the end exactly.
    out = np.arange(first, last + 1, dtype=np.float64) * ((stop - start) / (n - 1)) + start
    if last == n - 1:
        out[-1] = stop
    return out


def shifted_window(mask: np.ndarray, shift_uv, box: tuple[int, int, int, int]) -> np.ndarray:
    """``mask`` moved by ``shift_uv`` pixels, read over ``box = (u0, v0, u1, v1)``.

    Pixel ``(u, v)`` of the result is ``mask[v - dv, u - du]``, False where that falls
    outside the image; a slice copy, not a per-pixel gather.
    """
    du, dv = (int(s) for s in shift_uv)
    u0, v0, u1, v1 = box
    h, w = mask.shape
    out = np.zeros((v1 - v0, u1 - u0), dtype=bool)
    src_v0, src_v1 = max(v0 - dv, 0), min(v1 - dv, h)
    src_u0, src_u1 = max(u0 - du, 0), min(u1 - du, w)
    if src_v1 > src_v0 and src_u1 > src_u0:
        out[src_v0 + dv - v0:src_v1 + dv - v0, src_u0 + du - u0:src_u1 + du - u0] = \
            mask[src_v0:src_v1, src_u0:src_u1]
    return out
