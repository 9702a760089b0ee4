"""The checks that decide whether an object keeps SRDE's plane or the backbone's values.

All of them look where the backbone can be trusted: the textured surroundings along the
object's outline (occlusion order), the mask's inner ring seen by the other views
(photometric cost), and textured pixels at the mask's edge that are not the object (spill
trim). The last two leave out the highlights of the known lights, where the backbone
follows a reflection (:func:`reflection_mask`). :class:`BorderCheck` holds their
thresholds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import SRDEError
from ..geometry import CameraRig, Plane, plane_disparity
from ..imaging import REC709_LUMA, saturation_mask, to_float
from .estimate import ObjectEstimate

__all__ = [
    "border_band",
    "reflection_mask",
    "spilled_rim",
    "SpilledRim",
    "textured_mask",
    "BorderCheck",
    "DEFAULT_BORDER_CHECK",
]

@dataclass(frozen=True)
class BorderCheck:
    """How SRDE is checked against the backbone around an object's outline.

    The *band* is every pixel within ``width_px`` of the mask's outline, inside or
    outside, whose reference image shows texture (Sobel gradient of the encoded grey
    image above ``min_gradient``), away from clipped highlights, and where the backbone
    is valid. There the ratio ``backbone / srde`` is formed, with SRDE's plane extended
    beyond the mask. At an occluding edge the backbone reports the object's disparity
    (ratio 1) or the background's (ratio < 1), rarely more (something in front of the
    object). SRDE is rejected when the ``low_quantile`` of the ratio is above
    ``max_behind_ratio`` (SRDE puts the object behind what surrounds it) or when the
    ``high_quantile`` is below ``min_front_ratio`` (SRDE puts it several times nearer
    than anything seen along its outline).

    Parameters
    ----------
    width_px : int
        Half-width of the band around the outline, pixels.
    min_gradient : float
        Gradient magnitude (Sobel 3x3 on grey values in [0, 1]) above which a band pixel
        counts as textured.
    low_quantile, high_quantile : float
        The quantiles of ``backbone / srde`` over the band that are tested, in (0, 1).
    max_behind_ratio : float
        Largest accepted ``low_quantile`` of the ratio (> 1).
    min_front_ratio : float
        Smallest accepted ``high_quantile`` of the ratio, in (0, 1).
    min_px : int
        Fewest band pixels for the check to run; with fewer, SRDE is accepted
        unchecked and the report says so.
    photo_ring_px : int
        Width of the inner ring of the mask (pixels within this distance of its outline)
        on which the photometric check compares SRDE with the backbone; 0 disables the
        check.
    max_photo_ratio, photo_margin : float
        SRDE is rejected when its mean photometric cost on the ring exceeds
        ``max_photo_ratio * backbone_cost + photo_margin`` (cost: median over the other
        cameras of the absolute grey difference, values in [0, 1]).
    suspect_front_ratio, suspect_behind_ratio : float
        The stricter ``min_front_ratio`` (in (0, 1)) and ``max_behind_ratio`` (> 1)
        applied when SRDE's own evidence is weak: its photometric refinement kept the
        initial plane, or its photometric cost on the ring is above the backbone's
        (within the margin that the photometric check allows).
    trim_disagreement : float
        A textured mask pixel whose backbone disparity differs from SRDE's by more than
        this fraction of SRDE's, and which the backbone explains photometrically better,
        is not part of the object when it is connected to the mask's edge: it keeps the
        backbone's disparity. 0 disables the trim.
    """

    width_px: int = 4
    min_gradient: float = 0.08
    low_quantile: float = 0.75
    high_quantile: float = 0.95
    max_behind_ratio: float = 1.25
    min_front_ratio: float = 0.25
    min_px: int = 30
    photo_ring_px: int = 3
    max_photo_ratio: float = 1.25
    photo_margin: float = 0.02
    suspect_front_ratio: float = 0.5
    suspect_behind_ratio: float = 1.15
    trim_disagreement: float = 0.2

    def __post_init__(self) -> None:
        if int(self.width_px) != self.width_px or self.width_px < 1:
            raise SRDEError(f"width_px: expected a positive integer, got {self.width_px!r}")
        if not (isinstance(self.min_gradient, (int, float)) and math.isfinite(self.min_gradient)
                and self.min_gradient >= 0):
            raise SRDEError(f"min_gradient: expected a finite number >= 0, got "
                             f"{self.min_gradient!r}")
        if not 0.0 < self.low_quantile <= self.high_quantile < 1.0:
            raise SRDEError(f"low_quantile, high_quantile: expected 0 < low <= high < 1, got "
                             f"{self.low_quantile!r}, {self.high_quantile!r}")
        if not (isinstance(self.max_behind_ratio, (int, float))
                and 1.0 < self.max_behind_ratio < math.inf):
            raise SRDEError(f"max_behind_ratio: expected a finite number > 1, got "
                             f"{self.max_behind_ratio!r}")
        if not (isinstance(self.min_front_ratio, (int, float))
                and 0.0 < self.min_front_ratio < 1.0):
            raise SRDEError(f"min_front_ratio: expected a number in (0, 1), got "
                             f"{self.min_front_ratio!r}")
        if int(self.min_px) != self.min_px or self.min_px < 1:
            raise SRDEError(f"min_px: expected a positive integer, got {self.min_px!r}")
        if int(self.photo_ring_px) != self.photo_ring_px or self.photo_ring_px < 0:
            raise SRDEError(f"photo_ring_px: expected an integer >= 0, got "
                            f"{self.photo_ring_px!r}")
        if not (isinstance(self.suspect_front_ratio, (int, float))
                and 0.0 < self.suspect_front_ratio < 1.0):
            raise SRDEError(f"suspect_front_ratio: expected a number in (0, 1), got "
                            f"{self.suspect_front_ratio!r}")
        if not (isinstance(self.suspect_behind_ratio, (int, float))
                and 1.0 < self.suspect_behind_ratio < math.inf):
            raise SRDEError(f"suspect_behind_ratio: expected a finite number > 1, got "
                            f"{self.suspect_behind_ratio!r}")
        for name in ("max_photo_ratio", "photo_margin", "trim_disagreement"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise SRDEError(f"{name}: expected a finite number >= 0, got {value!r}")


#: The outline check :func:`fuse` runs unless told otherwise.
DEFAULT_BORDER_CHECK = BorderCheck()


def _gradient_magnitude(gray: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy)


def _clipped(reference: np.ndarray) -> np.ndarray:
    """Return the clipped highlights and their rim in the reference view, (H, W) bool."""
    return cv2.dilate(saturation_mask(reference).astype(np.uint8),
                      np.ones((5, 5), np.uint8)).astype(bool)


def textured_mask(reference: np.ndarray, min_gradient: float) -> np.ndarray:
    """Pixels of the reference view that carry texture a matcher can lock onto."""
    # Texture is judged on the encoded values (luma), as a network trained on 8-bit
    # images sees them; linear luminance would squash texture in dark regions.
    textured = _gradient_magnitude(gray_levels(reference)) > min_gradient
    # Clipped highlights have strong, view-dependent edges that the backbone mismatches.
    return textured & ~_clipped(reference)


def _disc(radius_px: int) -> np.ndarray:
    """Return the checks' morphology kernel: a disc of ``radius_px``, uint8."""
    size = 2 * radius_px + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def border_band(mask: np.ndarray, width_px: int) -> np.ndarray:
    """Pixels within ``width_px`` of the mask's outline, on either side, (H, W) bool."""
    kernel = _disc(width_px)
    m = mask.astype(np.uint8)
    inner = cv2.erode(m, kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    outer = cv2.dilate(m, kernel).astype(bool)
    return outer & ~inner


@dataclass(frozen=True)
class BorderStats:
    n_px: int = 0
    ratio_low: float = math.nan
    ratio_high: float = math.nan
    median_diff_px: float = math.nan
    n_faces_checked: int = 0


def border_stats(plane: Plane | None, rig: CameraRig, backbone: np.ndarray, mask: np.ndarray,
                  textured: np.ndarray, check: BorderCheck, origin: tuple[int, int] = (0, 0),
                  faces: tuple[Plane, ...] = (), face_labels: np.ndarray | None = None
                  ) -> BorderStats:
    """Compare SRDE's plane with the backbone on the textured band around the outline.

    The maps may be a window of the image whose top-left pixel is ``origin = (u0, v0)``,
    holding the band whole.

    A faceted object (``faces``, with ``face_labels`` over the window: 0 outside the
    mask, k on ``faces[k - 1]``'s part) is checked face by face: each band pixel belongs
    to the face whose part is nearest, each face's plane is extended onto its own stretch
    of the band only, and the quantiles are those of the worst face among those with
    ``check.min_px`` band pixels (``ratio_low`` the largest, ``ratio_high`` the smallest),
    so one face's contradiction is not averaged away by its neighbours. With no face
    that large, the faces' stretches are pooled.
    """
    if plane is None:
        return BorderStats()
    band = border_band(mask, check.width_px) & textured & np.isfinite(backbone)
    vs, us = np.nonzero(band)
    # SRDE's plane, extended beyond the mask onto the outer half of the band.
    uv = np.stack([us + origin[0], vs + origin[1]], axis=-1).astype(np.float64)
    if faces and face_labels is not None:
        owner = nearest_face(face_labels)[vs, us]
        srde_px = np.full(len(vs), np.nan)
        for f, face in enumerate(faces):
            mine = owner == f + 1
            srde_px[mine] = plane_disparity(face, rig, uv[mine])
    else:
        owner = np.ones(len(vs), dtype=np.intp)
        srde_px = plane_disparity(plane, rig, uv)
    keep = np.isfinite(srde_px) & (srde_px > 0)
    if not keep.any():
        return BorderStats()
    srde_px, backbone_px = srde_px[keep], backbone[vs[keep], us[keep]].astype(np.float64)
    owner = owner[keep]
    ratio = backbone_px / srde_px
    quantiles = [np.quantile(ratio[owner == f], [check.low_quantile, check.high_quantile])
                 for f in np.unique(owner) if np.count_nonzero(owner == f) >= check.min_px]
    checked = len(quantiles)
    if not quantiles:
        quantiles = [np.quantile(ratio, [check.low_quantile, check.high_quantile])]
    low = max(float(q[0]) for q in quantiles)
    high = min(float(q[1]) for q in quantiles)
    return BorderStats(int(keep.sum()), low, high, float(np.median(srde_px - backbone_px)),
                       checked if faces else 0)


def nearest_value(source: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Give every pixel the value of its nearest ``source`` pixel, ``(h, w)``.

    ``source`` ``(h, w)`` bool must hold at least one pixel; ``values`` ``(h, w)`` is
    read there only. Distances are Euclidean (OpenCV's 5x5 mask).
    """
    # Distance to the nearest source pixel, and which one: each is its own label.
    _, index = cv2.distanceTransformWithLabels((~source).view(np.uint8), cv2.DIST_L2, 5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    lookup = np.zeros(int(index.max()) + 1, dtype=values.dtype)
    lookup[index[source]] = values[source]
    return lookup[index]


def nearest_face(face_labels: np.ndarray) -> np.ndarray:
    """Label every pixel with the face whose part of the mask is nearest, ``(h, w)`` uint8.

    ``face_labels``: 0 outside the mask, k on face k's part. All 0 when it has no face.
    """
    inside = face_labels > 0
    if not inside.any():
        return np.zeros_like(face_labels)
    return nearest_value(inside, face_labels.astype(np.uint8, copy=False))


def gray_levels(image: np.ndarray) -> np.ndarray:
    """Return the encoded grey values in [0, 1], (H, W) float32."""
    gray = to_float(image)
    return (gray @ REC709_LUMA).astype(np.float32) if gray.ndim == 3 else gray.astype(np.float32)


#: Width of the pixel blocks handed to cv2.remap (it refuses maps 32767 px or wider).
_REMAP_ROW_PX = 4096


def _photo_cost(grays: list[np.ndarray], rig: CameraRig, us: np.ndarray, vs: np.ndarray,
                disparity_px: np.ndarray) -> np.ndarray:
    """Return the per-pixel photometric cost of a disparity, (N,) float32, grey in [0, 1].

    Each reference pixel is looked up in every other camera where the hypothesis puts it
    (a rectified array moves it by ``d * (dX, dY * fy / fx) / B``); the cost is the
    median absolute grey difference over the cameras it lands in, NaN if none.
    """
    if us.size == 0:
        return np.zeros(0, dtype=np.float32)
    offsets = rig.centers_m - rig.centers_m[rig.reference]
    fx, fy = rig.intrinsics.fx, rig.intrinsics.fy
    steps = disparity_px / rig.baseline_m
    reference = grays[rig.reference][vs, us]
    # remap wants maps narrower than 32767 columns: fold the pixel list into rows.
    n = us.size
    rows = -(-n // _REMAP_ROW_PX)
    costs = []
    for j, gray in enumerate(grays):
        if j == rig.reference:
            continue
        map_u = np.full(rows * _REMAP_ROW_PX, -1.0, np.float32)
        map_v = np.full(rows * _REMAP_ROW_PX, -1.0, np.float32)
        map_u[:n] = us - steps * offsets[j, 0]
        map_v[:n] = vs - steps * (fy / fx) * offsets[j, 1]
        sample = cv2.remap(gray, map_u.reshape(rows, -1), map_v.reshape(rows, -1),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=math.nan).ravel()[:n]
        costs.append(np.abs(sample - reference))
    costs = np.sort(np.asarray(costs), axis=0)  # NaN sorts last
    n_valid = np.count_nonzero(np.isfinite(costs), axis=0)
    cols = np.arange(costs.shape[1])
    low = costs[np.maximum((n_valid - 1) // 2, 0), cols]
    high = costs[np.maximum(n_valid // 2, 0), cols]
    return np.where(n_valid > 0, 0.5 * (low + high), np.nan).astype(np.float32)


def _inner_ring(mask: np.ndarray, width_px: int) -> np.ndarray:
    """Return the mask pixels within ``width_px`` of its outline, (H, W) bool."""
    inner = cv2.erode(mask.astype(np.uint8), _disc(width_px), borderType=cv2.BORDER_REPLICATE)
    return mask & (inner == 0)


def _cost_map(grays: list[np.ndarray], rig: CameraRig, mask: np.ndarray,
              disparity_px: np.ndarray, radius_px: int, origin: tuple[int, int] = (0, 0)
              ) -> np.ndarray:
    """Return the photometric cost averaged over a window within the mask, (h, w) float32.

    NaN outside the mask and where no pixel of the window could be compared. ``mask``
    and ``disparity_px`` may be a part of the image starting at ``origin = (u0, v0)``.
    """
    vs, us = np.nonzero(mask & np.isfinite(disparity_px))
    cost = np.zeros(mask.shape, np.float32)
    valid = np.zeros(mask.shape, np.float32)
    per_pixel = _photo_cost(grays, rig, us + origin[0], vs + origin[1], disparity_px[vs, us])
    ok = np.isfinite(per_pixel)
    cost[vs[ok], us[ok]] = per_pixel[ok]
    valid[vs[ok], us[ok]] = 1.0
    size = (2 * radius_px + 1, 2 * radius_px + 1)
    total = cv2.boxFilter(cost, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(valid, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    return np.where(mask & (count > 0), mean, np.nan).astype(np.float32)


def _continues_outside(mask: np.ndarray, backbone: np.ndarray) -> np.ndarray:
    """Pixels whose backbone disparity continues the surroundings', ``(h, w)`` bool.

    Within :data:`_RIM_CONTINUITY` of the backbone's at the nearest pixel outside the mask
    (the window holds a margin), as spilled background is; False where either is NaN, and
    everywhere when nothing lies outside the mask.
    """
    if mask.all():
        return np.zeros_like(mask)
    beyond = nearest_value(~mask, backbone)
    with np.errstate(invalid="ignore"):  # NaN beyond (a hole outside): no continuation
        return np.abs(backbone - beyond) <= _RIM_CONTINUITY * beyond


def spill_trim(mask: np.ndarray, srde_disp: np.ndarray, backbone: np.ndarray,
               textured: np.ndarray, grays: list[np.ndarray], rig: CameraRig,
               check: BorderCheck, origin: tuple[int, int] = (0, 0),
               reflection: np.ndarray | None = None) -> np.ndarray:
    """Return the mask pixels that are not the object, (h, w) bool.

    The maps (not ``grays``, whole views) may be a window of the image starting at
    ``origin = (u0, v0)`` that holds the mask and a margin of a pixel.

    A glossy textureless object offers no texture except along its outline, so textured
    mask pixels where the backbone contradicts SRDE's plane and matches the other views
    better (window means of the photometric cost) are background the mask spilled over;
    only regions touching the mask's edge and reaching deeper than the outline band are
    trimmed, so a textured patch inside the object cannot punch holes into it; and only
    pixels whose backbone disparity continues the surroundings' (within 10 % of the
    backbone at the nearest pixel outside the mask), as spilled background does.

    On a highlight's flanks a matcher follows the reflection, and there the backbone
    matches the other views better than SRDE's plane does: the pixels of ``reflection``
    (:func:`reflection_mask`) are the object's however they touch the outline (against
    a dark background a matcher smears the reflection's value over the object's edge and
    beyond, so the continuity test alone let faceted objects lose a highlight's ring of
    1400 px, a face 4.9 px off in the fused map).

    Known limit: image noise makes the object's interior look textured, and where the
    backbone on a highlight's flank neither follows its virtual light nor the object,
    but continues the surroundings, part of a highlight can still be trimmed. Judging
    texture after a blur removed that but trimmed the highlight rim of clean views
    instead.

    Parameters
    ----------
    reflection : numpy.ndarray, (h, w) bool, optional
        Pixels on a highlight where the backbone follows its virtual light; none by
        default.
    """
    candidates = (mask & textured & np.isfinite(backbone) & np.isfinite(srde_disp)
                  & (np.abs(backbone - srde_disp) > check.trim_disagreement * srde_disp))
    if not candidates.any():
        return candidates
    # Spilled background continues the surroundings. On a highlight's flank the backbone
    # matches the reflection instead (faceted objects lost whole flanks at the outline to
    # the backbone this way, a face 2-7 px off in the fused map).
    candidates &= _continues_outside(mask, backbone)
    if reflection is not None:
        candidates &= ~reflection
    if not candidates.any():
        return candidates
    # One pixel's cost is at the mercy of image noise (which also makes a textureless
    # object look textured): compare window means over the mask instead.
    cost_srde = _cost_map(grays, rig, mask, srde_disp, check.width_px, origin)
    cost_backbone = _cost_map(grays, rig, mask, backbone, check.width_px, origin)
    candidates &= cost_srde > check.max_photo_ratio * cost_backbone + check.photo_margin
    _, labels = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
    touching = np.unique(labels[_inner_ring(mask, 1) & candidates])
    # The object's own silhouette edge is textured and mixes both depths; only regions
    # reaching deeper into the mask than the outline band are spilled-over background.
    deep = np.unique(labels[mask & ~_inner_ring(mask, check.width_px) & candidates])
    keep = np.intersect1d(touching, deep)
    return np.isin(labels, keep[keep > 0])


def reflection_mask(mask: np.ndarray, backbone: np.ndarray, textured: np.ndarray,
                    grays: list[np.ndarray], rig: CameraRig, virtual_lights_m: np.ndarray,
                    margin_px: int, origin: tuple[int, int] = (0, 0),
                    face_labels: np.ndarray | None = None) -> np.ndarray:
    """Return the pixels on a highlight where the backbone follows its virtual light.

    A highlight is the image of a virtual light (a light mirrored in the object's plane)
    and a matcher follows it: on its flanks the backbone puts it at the virtual light's
    depth, which no surface disparity explains. A virtual light's highlight is every part
    of the mask brighter than the object's body by :data:`_HIGHLIGHT_CONTRAST` that comes
    within ``margin_px`` of the virtual light's reference-view image, grown by
    ``margin_px`` (a matcher locks onto its flanks); on it, the pixels whose backbone
    disparity is within :data:`_RIM_CONTINUITY` of the virtual light's are the
    reflection. The body's grey is the darkest of the common levels among the mask's
    untextured pixels, on each face of a faceted object (their shading differs): a median
    would follow a large highlight's flanks, and several lights' highlights may cover so
    much of the object that the brightest common level is theirs. Known limit: in a mask
    spilled far over a darker background the body is the background's, and background at
    about the virtual light's depth next to the object is spared as well
    (``benchmarks/degradation.py``, masks dilated by 64 px).

    Parameters
    ----------
    mask, backbone, textured : numpy.ndarray, (h, w)
        A window of the image starting at ``origin = (u0, v0)``.
    grays : list of numpy.ndarray, (H, W) float32
        Every view's grey levels (:func:`gray_levels`), whole.
    rig : CameraRig
    virtual_lights_m : numpy.ndarray, (V, 3)
        The known lights mirrored in the estimate's planes, metres, the rig's frame.
    margin_px : int
    origin : (int, int)
    face_labels : numpy.ndarray, (h, w) uint8, optional
        Over the window: k on the estimate's k-th face, 0 elsewhere; the mask is one face
        by default.

    Returns
    -------
    numpy.ndarray, (h, w) bool
    """
    out = np.zeros(mask.shape, dtype=bool)
    points = np.asarray(virtual_lights_m, dtype=np.float64).reshape(-1, 3)
    depth_m = points[:, 2] - rig.reference_center_m[2]
    points, depth_m = points[depth_m > 0], depth_m[depth_m > 0]
    if not len(points) or not mask.any():
        return out
    u0, v0 = origin
    gray = grays[rig.reference][v0:v0 + mask.shape[0], u0:u0 + mask.shape[1]]
    # A highlight brightens the surface smoothly: smoothed, image noise and fine texture
    # do not make lone pixels bright.
    gray = cv2.GaussianBlur(gray, (0, 0), _HIGHLIGHT_SMOOTHING_PX)
    faces = [mask] if face_labels is None else [
        mask & (face_labels == k) for k in np.unique(face_labels[mask]) if k > 0]
    bright = np.zeros(mask.shape, dtype=bool)
    for face in faces:
        bright |= face & (gray > _body_gray(gray[face & ~textured] if (face & ~textured).any()
                                            else gray[face]) + _HIGHLIGHT_CONTRAST)
    n, labels = cv2.connectedComponents(bright.view(np.uint8), connectivity=8)
    if n <= 1:
        return out
    uv = rig.project(points, rig.reference) - np.asarray(origin, dtype=np.float64)
    for (u, v), disparity_px in zip(uv, rig.depth_to_disparity(depth_m), strict=True):
        a0, b0 = int(math.floor(u)) - margin_px, int(math.floor(v)) - margin_px
        near = labels[max(b0, 0):max(b0 + 2 * margin_px + 2, 0),
                      max(a0, 0):max(a0 + 2 * margin_px + 2, 0)]
        parts = np.unique(near[near > 0])
        if not parts.size:
            continue
        highlight = cv2.dilate(np.isin(labels, parts).view(np.uint8), _disc(margin_px)) > 0
        with np.errstate(invalid="ignore"):  # NaN backbone: not the reflection
            out |= highlight & (np.abs(backbone - disparity_px)
                                <= _RIM_CONTINUITY * disparity_px)
    return out & mask


def _body_gray(values: np.ndarray) -> float:
    """Return the darkest common grey level of ``values`` (in [0, 1]), the body's."""
    bins = np.bincount(np.clip(values * _GRAY_BINS, 0, _GRAY_BINS - 1).astype(np.intp),
                       minlength=_GRAY_BINS)[:-1]  # (the top bin holds clipped cores)
    common = np.flatnonzero(bins >= _BODY_SHARE * bins.max())
    return (int(common[0]) + 0.5) / _GRAY_BINS if common.size else 1.0


@dataclass(frozen=True)
class PhotoStats:
    n_px: int = 0
    cost_srde: float = math.nan
    cost_backbone: float = math.nan


def photo_stats(mask: np.ndarray, trimmed: np.ndarray, srde_disp: np.ndarray, backbone: np.ndarray,
                 textured: np.ndarray, grays: list[np.ndarray], rig: CameraRig,
                 check: BorderCheck, origin: tuple[int, int] = (0, 0),
                 reflection: np.ndarray | None = None) -> PhotoStats:
    """Return the photometric cost of SRDE and the backbone on the mask's inner ring.

    The maps may be a window of the image starting at ``origin = (u0, v0)``. The pixels
    of ``reflection`` (:func:`reflection_mask`) are left out: where the backbone follows
    a highlight's virtual light it explains the views better than any surface does.
    """
    # Only ring pixels next to texture (the silhouette edge): inside a glossy object the
    # shading follows the reflection, whose depth is the virtual light's, not the
    # surface's, so a uniform interior would favour whichever hypothesis is nearer it.
    near_texture = cv2.dilate(textured.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ring = (_inner_ring(mask, check.photo_ring_px) & near_texture & np.isfinite(srde_disp)
            & np.isfinite(backbone))
    if reflection is not None:
        ring &= ~reflection
    if trimmed.any():
        # Next to trimmed background the mask is background too, texture or not.
        size = 4 * check.width_px + 1
        ring &= cv2.dilate(trimmed.astype(np.uint8), np.ones((size, size), np.uint8)) == 0
    vs, us = np.nonzero(ring)
    u, v = us + origin[0], vs + origin[1]
    cost_srde = _photo_cost(grays, rig, u, v, srde_disp[vs, us])
    cost_backbone = _photo_cost(grays, rig, u, v, backbone[vs, us])
    both = np.isfinite(cost_srde) & np.isfinite(cost_backbone)
    if not both.any():
        return PhotoStats()
    return PhotoStats(int(both.sum()), float(cost_srde[both].mean()),
                       float(cost_backbone[both].mean()))


#: Depths (pixels inwards from the mask's outline) at which :func:`spilled_rim` looks
#: for the object's own outline inside a mask that spilled over the background.
RIM_DEPTHS_PX = (2, 4, 8, 16, 32, 64)
#: The object left inside the rim must keep at least this share of the mask.
_MIN_INNER_FRACTION = 0.25
#: Share of the rim's textured pixels the backbone must put behind SRDE's plane.
_RIM_BEHIND_FRACTION = 0.5
#: Largest relative difference between a mask pixel's backbone disparity and the one at
#: the nearest pixel outside the mask for the pixel to continue the surroundings (spilled
#: background: :func:`spill_trim` and :func:`spilled_rim`).
_RIM_CONTINUITY = 0.1
#: How much brighter than the object's body (encoded grey, in [0, 1]) a highlight is.
_HIGHLIGHT_CONTRAST = 0.03
#: Bins of the grey-level histogram whose common levels hold the object's body.
_GRAY_BINS = 64
#: A grey level is one of the mask's common ones when its bin holds this share of the
#: fullest bin's pixels.
_BODY_SHARE = 0.25
#: Gaussian sigma (px) of the smoothing before the highlight is told from the body.
_HIGHLIGHT_SMOOTHING_PX = 2.0


@dataclass(frozen=True)
class SpilledRim:
    """A rim of a mask found to be background around the object (:func:`spilled_rim`).

    Attributes
    ----------
    rim : numpy.ndarray, (h, w) bool
        The mask's pixels within ``depth_px`` of its outline: the checks leave them out.
    background : numpy.ndarray, (h, w) bool
        The rim's pixels that keep the backbone (those of (a) in :func:`spilled_rim`,
        farther than the outline band from what is left and from the mask's outline,
        where a matcher mixes both depths; elsewhere in the rim nothing tells the
        object's edge from the background, and SRDE's plane stays).
    depth_px : int
        The rim's depth, pixels; 0 when none was found (both maps empty).
    photo : PhotoStats
        The photometric costs on the inner ring of what the rim leaves (empty when none
        was found).
    """

    rim: np.ndarray
    background: np.ndarray
    depth_px: int
    photo: PhotoStats = PhotoStats()


def spilled_rim(mask: np.ndarray, trimmed: np.ndarray, srde_disp: np.ndarray,
                backbone: np.ndarray, textured: np.ndarray, grays: list[np.ndarray],
                rig: CameraRig, check: BorderCheck, origin: tuple[int, int] = (0, 0),
                reflection: np.ndarray | None = None) -> SpilledRim:
    """Find a rim of the mask that is background all around the object.

    A mask dilated by a careless segmenter holds a ring of the background around the
    object. That ring is too thin for :func:`spill_trim` (which trims only what reaches
    deeper than the outline band) and is textured, so SRDE's plane explains the mask's
    inner ring worse than the backbone and the object looks suspect. The object's own
    outline lies further in: the shallowest depth of :data:`RIM_DEPTHS_PX` is taken at
    which (a) most of the rim's textured pixels (:data:`_RIM_BEHIND_FRACTION`) have a
    backbone disparity behind SRDE's plane by more than ``check.trim_disagreement`` and
    within :data:`_RIM_CONTINUITY` of the backbone's at the nearest pixel outside the
    mask (background that continues the surroundings; a mirror-like object's own rim
    also looks "behind", where the backbone matched a reflection, but at the reflection's
    depth, not the neighbouring background's), and (b) on the inner ring of what is
    left SRDE's plane explains the other views at least as well as the backbone (over
    ``check.min_px`` pixels). A wrong plane meets (b) at no depth, and a textureless
    object's own rim has no outline texture to meet it with, so both keep the mask. The
    maps may be a window of the image starting at ``origin``; the pixels of
    ``reflection`` (:func:`reflection_mask`) are neither background nor outline evidence.
    """
    none = np.zeros_like(mask)
    total = int(np.count_nonzero(mask))
    continues = _continues_outside(mask, backbone)
    for depth in RIM_DEPTHS_PX:
        rim = _inner_ring(mask, depth) & ~trimmed
        inner = mask & ~rim & ~trimmed
        if np.count_nonzero(inner) < _MIN_INNER_FRACTION * total:
            break
        seen = rim & textured & np.isfinite(backbone) & np.isfinite(srde_disp)
        if reflection is not None:
            seen &= ~reflection
        if np.count_nonzero(seen) < check.min_px:
            continue
        with np.errstate(invalid="ignore"):  # NaN outside ``seen``: not behind
            behind = (seen & (backbone < (1.0 - check.trim_disagreement) * srde_disp)
                      & continues)
        if np.count_nonzero(behind) < _RIM_BEHIND_FRACTION * np.count_nonzero(seen):
            continue
        photo = photo_stats(inner, none, srde_disp, backbone, textured, grays, rig, check,
                            origin, reflection)
        if photo.n_px >= check.min_px and photo.cost_srde <= photo.cost_backbone:
            # Along an outline, the object's or the mask's, a matcher mixes both depths
            # (a background-fattened edge looks like background): those bands stay.
            band = cv2.dilate(inner.astype(np.uint8), _disc(check.width_px)).astype(bool)
            band |= _inner_ring(mask, check.width_px)
            return SpilledRim(rim, behind & ~band, depth, photo)
    return SpilledRim(none, none, 0)


def weak_evidence(estimate: ObjectEstimate, photo: PhotoStats) -> str:
    """Say why SRDE's own evidence for its plane is weak ("" if it is not)."""
    if estimate.kept_initial_plane:
        return "its photometric refinement kept the initial plane"
    if photo.n_px and photo.cost_srde > photo.cost_backbone:
        return (f"its plane explains the outline worse than the backbone "
                f"({photo.cost_srde:.3f} > {photo.cost_backbone:.3f})")
    return ""
