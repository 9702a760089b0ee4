"""Fusion of a backbone disparity map with SRDE on flat glossy objects.

Inside each object's mask the disparity comes from SRDE (the plane found from the
specular highlight); everywhere else it is the backbone's, untouched. Each object falls
back to the backbone on its own, with the reason recorded, when SRDE fails or when its
plane grossly contradicts the backbone where the backbone can be trusted.

Where can it be trusted? Not inside the object: there is nothing to match. Along the
object's outline the backbone matches the silhouette against the background, but an
occluding edge mixes both depths: right at the edge a network or SGBM reports the
object's disparity on some pixels and the background's on others, and sometimes only the
background's. What holds whatever the matcher does is the occlusion order: the object
occludes what lies around its outline, so the backbone there is not much *nearer* than
the object. The check looks at the ratio ``backbone / srde`` on the textured band around
the outline and rejects SRDE when the bulk of that band lies clearly above 1 (SRDE puts
the object behind its own surroundings), or when even its top is far below 1 (SRDE puts
the object several times nearer than anything seen along its outline). An object nearer
than SRDE says, but not absurdly so, cannot be told from a backbone that only sees the
background there. ``benchmarks/fusion_eval.py`` records what was measured and the rules
tried before this one.

The fused map never loses a valid backbone pixel: a pixel is either the backbone's value,
bit for bit, or a finite SRDE value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from .._checks import check_disparity, check_mask, check_views
from .._json import json_safe
from ..errors import BackboneError, LightError, MaskError, RigError, SRDEError
from ..geometry import CameraRig, plane_disparity
from ..imaging import REC709_LUMA, saturation_mask, to_float
from ..masks import resolve_masker

__all__ = [
    "BorderCheck",
    "ObjectReport",
    "FusionResult",
    "fuse",
    "postprocess",
    "HybridStereo",
    "SOURCE_BACKBONE",
    "DEFAULT_BORDER_CHECK",
]

#: Value of :attr:`FusionResult.source` where the backbone's disparity is kept.
SOURCE_BACKBONE = 0

Backbone = Callable[[np.ndarray, np.ndarray], np.ndarray]
Masker = Callable[[Sequence[np.ndarray], CameraRig], list]


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


@dataclass(frozen=True)
class ObjectReport:
    """What happened to one object during fusion.

    Attributes
    ----------
    index : int
        The object's number k (1-based); its pixels carry ``k`` in the source map when
        SRDE was used.
    status : {"srde", "fallback"}
        Whether SRDE's disparity replaced the backbone's inside the mask.
    reason : str
        Why, in words with the numbers behind the decision.
    srde : SRDEResult
        SRDE's full result for this object (plane, virtual light, highlight centres).
    pixel_count : int
        Pixels in the object's mask.
    replaced_px : int
        Pixels whose disparity now comes from SRDE (0 on fallback).
    border_px : int
        Band pixels the check used (0 when it did not run).
    border_ratio_low, border_ratio_high : float
        The tested low and high quantiles of ``backbone / srde`` over the band (NaN when
        the check did not run).
    border_median_diff_px : float
        Median of ``srde - backbone`` over the band, pixels (NaN when not run); for
        information, not used in the decision.
    trimmed_px : int
        Mask pixels found not to belong to the object (textured, contradicting SRDE,
        better explained by the backbone, connected to the mask's edge); they keep the
        backbone's disparity.
    photo_px : int
        Ring pixels the photometric check used (0 when it did not run).
    photo_cost_srde, photo_cost_backbone : float
        Mean photometric cost on the ring with SRDE's and with the backbone's disparity,
        grey values in [0, 1] (NaN when the check did not run).
    """

    index: int
    status: str
    reason: str
    srde: Any
    pixel_count: int
    replaced_px: int
    border_px: int = 0
    border_ratio_low: float = math.nan
    border_ratio_high: float = math.nan
    border_median_diff_px: float = math.nan
    trimmed_px: int = 0
    photo_px: int = 0
    photo_cost_srde: float = math.nan
    photo_cost_backbone: float = math.nan

    @property
    def used_srde(self) -> bool:
        """True when SRDE's disparity was used for this object."""
        return self.status == "srde"

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable summary (NaN becomes None)."""
        return {
            "index": self.index,
            "status": self.status,
            "reason": self.reason,
            "pixel_count": self.pixel_count,
            "replaced_px": self.replaced_px,
            "border": {
                "px": self.border_px,
                "ratio_low": json_safe(self.border_ratio_low),
                "ratio_high": json_safe(self.border_ratio_high),
                "median_diff_px": json_safe(self.border_median_diff_px),
            },
            "trimmed_px": self.trimmed_px,
            "photo": {
                "px": self.photo_px,
                "cost_srde": json_safe(self.photo_cost_srde),
                "cost_backbone": json_safe(self.photo_cost_backbone),
            },
            "srde": _srde_to_dict(self.srde),
        }


@dataclass(frozen=True)
class FusionResult:
    """The fused disparity map and where each pixel came from.

    Attributes
    ----------
    disparity : numpy.ndarray, (H, W), float32, pixels
        Fused stereo-pair disparity; NaN where neither source is valid.
    source : numpy.ndarray, (H, W), int32
        0 where the backbone's value is kept, ``k`` where object ``k``'s SRDE plane is used.
    objects : tuple of ObjectReport
        One report per object, in mask order.
    backbone_disparity : numpy.ndarray, (H, W), float32, pixels
        The backbone's map as fused (non-finite and negative values turned into NaN).
    """

    disparity: np.ndarray
    source: np.ndarray
    objects: tuple[ObjectReport, ...]
    backbone_disparity: np.ndarray = field(repr=False)

    @property
    def srde_disparity(self) -> np.ndarray:
        """SRDE alone: every object's SRDE disparity, fallbacks included, NaN elsewhere.

        Returns
        -------
        numpy.ndarray, (H, W), float32, pixels
        """
        out = np.full(self.disparity.shape, np.nan, dtype=np.float32)
        for obj in self.objects:
            srde_disp = getattr(obj.srde, "disparity", None)
            if srde_disp is None:
                continue
            fill = np.isfinite(srde_disp) & np.isnan(out)
            out[fill] = srde_disp[fill]
        return out

    def report(self) -> dict[str, Any]:
        """Return a JSON-serialisable summary of the fusion."""
        valid = np.isfinite(self.disparity)
        return {
            "image_size": [int(self.disparity.shape[1]), int(self.disparity.shape[0])],
            "n_objects": len(self.objects),
            "n_srde": sum(o.status == "srde" for o in self.objects),
            "n_fallback": sum(o.status == "fallback" for o in self.objects),
            "pixels_from_srde": int(np.count_nonzero(self.source != SOURCE_BACKBONE)),
            "pixels_from_backbone": int(np.count_nonzero(valid & (self.source == SOURCE_BACKBONE))),
            "invalid_px": int(np.count_nonzero(~valid)),
            "objects": [o.to_dict() for o in self.objects],
        }




def _srde_to_dict(result: Any) -> dict[str, Any]:
    """JSON view of an SRDE result, tolerant of missing fields."""
    plane = getattr(result, "plane", None)
    used = getattr(result, "used_views", None)
    return {
        "status": str(getattr(result, "status", "unknown")),
        "reason": str(getattr(result, "reason", "")),
        "method": getattr(result, "method", None),
        "plane": None if plane is None else {
            "normal": json_safe(plane.normal),
            "offset_m": json_safe(plane.offset_m),
        },
        "virtual_light_m": json_safe(getattr(result, "virtual_light_m", None)),
        "highlight_centers_px": json_safe(getattr(result, "highlight_centers", None)),
        "used_views": None if used is None else [bool(u) for u in np.asarray(used).ravel()],
        "residual_px": json_safe(getattr(result, "residual_px", None)),
    }


def _srde_ok(result: Any) -> bool:
    ok = getattr(result, "ok", None)
    return bool(ok) if ok is not None else getattr(result, "status", None) == "ok"


def _as_mask_list(masks: Any, shape: tuple[int, int]) -> list[np.ndarray]:
    """Validate ``masks`` (list of bool masks, (K, H, W) stack or (H, W) labels)."""
    if isinstance(masks, np.ndarray):
        if masks.ndim == 2:
            if not np.issubdtype(masks.dtype, np.integer):
                masks = [masks]
            else:  # instance labels: 0 = background, k = object k
                values = np.unique(masks)
                masks = [masks == v for v in values[values > 0]]
        elif masks.ndim == 3:
            masks = list(masks)
        else:
            raise MaskError(f"masks: expected a list of (H, W) masks, a (K, H, W) stack or (H, W) "
                            f"labels, got an array of shape {masks.shape}")
    if not isinstance(masks, Sequence) or isinstance(masks, (str, bytes)):
        raise MaskError(f"masks: expected a list of (H, W) bool masks, got {type(masks).__name__}")
    return [check_mask(m, shape, f"masks[{i}]") for i, m in enumerate(masks)]


def _gradient_magnitude(gray: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy)


def _clipped(reference: np.ndarray) -> np.ndarray:
    """Return the clipped highlights and their rim in the reference view, (H, W) bool."""
    return cv2.dilate(saturation_mask(reference).astype(np.uint8),
                      np.ones((5, 5), np.uint8)).astype(bool)


def _textured(reference: np.ndarray, min_gradient: float) -> np.ndarray:
    """Pixels of the reference view that carry texture a matcher can lock onto."""
    # Texture is judged on the encoded values (luma), as a network trained on 8-bit
    # images sees them; linear luminance would squash texture in dark regions.
    textured = _gradient_magnitude(_gray(reference)) > min_gradient
    # Clipped highlights have strong, view-dependent edges that the backbone mismatches.
    return textured & ~_clipped(reference)


def _border_band(mask: np.ndarray, width_px: int) -> np.ndarray:
    """Pixels within ``width_px`` of the mask's outline, on either side, (H, W) bool."""
    size = 2 * width_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    m = mask.astype(np.uint8)
    inner = cv2.erode(m, kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    outer = cv2.dilate(m, kernel).astype(bool)
    return outer & ~inner


@dataclass(frozen=True)
class _BorderStats:
    n_px: int = 0
    ratio_low: float = math.nan
    ratio_high: float = math.nan
    median_diff_px: float = math.nan


def _border_stats(result: Any, rig: CameraRig, backbone: np.ndarray, mask: np.ndarray,
                  textured: np.ndarray, check: BorderCheck) -> _BorderStats:
    plane = getattr(result, "plane", None)
    if plane is None:
        return _BorderStats()
    band = _border_band(mask, check.width_px) & textured & np.isfinite(backbone)
    vs, us = np.nonzero(band)
    # SRDE's plane, extended beyond the mask onto the outer half of the band.
    srde_px = plane_disparity(plane, rig, np.stack([us, vs], axis=-1).astype(np.float64))
    keep = np.isfinite(srde_px) & (srde_px > 0)
    if not keep.any():
        return _BorderStats()
    srde_px, backbone_px = srde_px[keep], backbone[vs[keep], us[keep]].astype(np.float64)
    low, high = np.quantile(backbone_px / srde_px, [check.low_quantile, check.high_quantile])
    return _BorderStats(int(keep.sum()), float(low), float(high),
                        float(np.median(srde_px - backbone_px)))



def _gray(image: np.ndarray) -> np.ndarray:
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
    size = 2 * width_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    inner = cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE)
    return mask & (inner == 0)


def _cost_map(grays: list[np.ndarray], rig: CameraRig, mask: np.ndarray,
              disparity_px: np.ndarray, radius_px: int) -> np.ndarray:
    """Return the photometric cost averaged over a window within the mask, (H, W) float32.

    NaN outside the mask and where no pixel of the window could be compared.
    """
    vs, us = np.nonzero(mask & np.isfinite(disparity_px))
    cost = np.zeros(mask.shape, np.float32)
    valid = np.zeros(mask.shape, np.float32)
    per_pixel = _photo_cost(grays, rig, us, vs, disparity_px[vs, us])
    ok = np.isfinite(per_pixel)
    cost[vs[ok], us[ok]] = per_pixel[ok]
    valid[vs[ok], us[ok]] = 1.0
    size = (2 * radius_px + 1, 2 * radius_px + 1)
    total = cv2.boxFilter(cost, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(valid, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    return np.where(mask & (count > 0), mean, np.nan).astype(np.float32)


def _trim(mask: np.ndarray, srde_disp: np.ndarray, backbone: np.ndarray,
          textured: np.ndarray, grays: list[np.ndarray], rig: CameraRig,
          check: BorderCheck) -> np.ndarray:
    """Return the mask pixels that are not the object, (H, W) bool.

    A glossy textureless object offers no texture except along its outline, so textured
    mask pixels where the backbone contradicts SRDE's plane and matches the other views
    better (window means of the photometric cost) are background the mask spilled over;
    only regions touching the mask's edge and reaching deeper than the outline band are
    trimmed, so a textured patch inside the object cannot punch holes into it.

    Known limit: image noise makes the object's interior look textured, and inside an
    unclipped highlight the backbone matches the reflection better than SRDE's plane
    matches the surface, so with noisy views part of a highlight can be trimmed
    (``benchmarks/degradation.py``: about 1 px object EPE at 5-20 grey levels of noise).
    Judging texture after a blur removed that but trimmed the highlight rim of clean
    views instead.
    """
    candidates = (mask & textured & np.isfinite(backbone) & np.isfinite(srde_disp)
                  & (np.abs(backbone - srde_disp) > check.trim_disagreement * srde_disp))
    if not candidates.any():
        return candidates
    # One pixel's cost is at the mercy of image noise (which also makes a textureless
    # object look textured): compare window means over the mask instead.
    cost_srde = _cost_map(grays, rig, mask, srde_disp, check.width_px)
    cost_backbone = _cost_map(grays, rig, mask, backbone, check.width_px)
    candidates &= cost_srde > check.max_photo_ratio * cost_backbone + check.photo_margin
    _, labels = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
    touching = np.unique(labels[_inner_ring(mask, 1) & candidates])
    # The object's own silhouette edge is textured and mixes both depths; only regions
    # reaching deeper into the mask than the outline band are spilled-over background.
    deep = np.unique(labels[mask & ~_inner_ring(mask, check.width_px) & candidates])
    keep = np.intersect1d(touching, deep)
    return np.isin(labels, keep[keep > 0])


@dataclass(frozen=True)
class _PhotoStats:
    n_px: int = 0
    cost_srde: float = math.nan
    cost_backbone: float = math.nan


def _photo_stats(mask: np.ndarray, trimmed: np.ndarray, srde_disp: np.ndarray, backbone: np.ndarray,
                 textured: np.ndarray, grays: list[np.ndarray], rig: CameraRig,
                 check: BorderCheck) -> _PhotoStats:
    """Return the photometric cost of SRDE and the backbone on the mask's inner ring."""
    # Only ring pixels next to texture (the silhouette edge): inside a glossy object the
    # shading follows the reflection, whose depth is the virtual light's, not the
    # surface's, so a uniform interior would favour whichever hypothesis is nearer it.
    near_texture = cv2.dilate(textured.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ring = (_inner_ring(mask, check.photo_ring_px) & near_texture & np.isfinite(srde_disp)
            & np.isfinite(backbone))
    if trimmed.any():
        # Next to trimmed background the mask is background too, texture or not.
        size = 4 * check.width_px + 1
        ring &= cv2.dilate(trimmed.astype(np.uint8), np.ones((size, size), np.uint8)) == 0
    vs, us = np.nonzero(ring)
    cost_srde = _photo_cost(grays, rig, us, vs, srde_disp[vs, us])
    cost_backbone = _photo_cost(grays, rig, us, vs, backbone[vs, us])
    both = np.isfinite(cost_srde) & np.isfinite(cost_backbone)
    if not both.any():
        return _PhotoStats()
    return _PhotoStats(int(both.sum()), float(cost_srde[both].mean()),
                       float(cost_backbone[both].mean()))


def fuse(backbone_disparity: np.ndarray, views: Sequence[np.ndarray], rig: CameraRig,
         masks: Any, srde: Any = None, *, border_check: BorderCheck | None = DEFAULT_BORDER_CHECK
         ) -> FusionResult:
    """Fuse a backbone disparity map with SRDE inside the object masks.

    Each object is handled on its own: SRDE estimates its plane; if SRDE fails, or its
    disparity contradicts the backbone on the object's textured border (see
    :class:`BorderCheck`), the object keeps the backbone's disparity and its report says
    why. Otherwise every mask pixel where SRDE's disparity is finite takes that value.
    Where masks overlap, the earlier object keeps the pixel.

    Parameters
    ----------
    backbone_disparity : numpy.ndarray, (H, W), float, pixels
        The backbone's stereo-pair disparity for the reference view. NaN, inf and
        negative values mean *invalid* and stay NaN unless SRDE fills them.
    views : sequence of numpy.ndarray, (H, W, 3) uint8
        One image per rig camera, in the rig's order.
    rig : CameraRig
        The rig, with its light position unless ``srde`` carries one.
    masks : list of (H, W) bool, (K, H, W) bool or (H, W) int labels
        One mask per object, in the reference view.
    srde : SRDE, optional
        The estimator (anything with ``estimate(views, mask) -> SRDEResult``);
        ``SRDE(rig)`` by default.
    border_check : BorderCheck or None
        How SRDE is checked against the backbone; None trusts SRDE whenever it succeeds.

    Returns
    -------
    FusionResult

    Raises
    ------
    DisparityError
        ``backbone_disparity`` is not an (H, W) numeric array of the rig's image size.
    ImageError
        Wrong number, size or type of views.
    MaskError
        A mask of the wrong shape or dtype, or an empty one.
    SRDEError
        ``srde.estimate`` returned a disparity map that is not ``(H, W)``.

    Notes
    -----
    Inputs are never modified. Outside the objects that use SRDE, the output equals
    ``backbone_disparity`` cast to float32, bit for bit, for every finite non-negative
    value.
    """
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    w, h = rig.image_size
    backbone = check_disparity(backbone_disparity, (h, w), "backbone_disparity")
    views = check_views(views, rig.n_cameras, rig.image_size)
    mask_list = _as_mask_list(masks, (h, w))
    if border_check is not None and not isinstance(border_check, BorderCheck):
        raise SRDEError(f"border_check: expected a BorderCheck or None, got "
                        f"{type(border_check).__name__}")
    if srde is None and mask_list:
        from ..srde import SRDE

        srde = SRDE(rig)

    fused = backbone.copy()
    source = np.zeros((h, w), dtype=np.int32)
    textured = grays = None
    if border_check is not None and mask_list:
        textured = _textured(views[rig.reference], border_check.min_gradient)
        grays = [_gray(v) for v in views]

    reports = []
    for k, mask in enumerate(mask_list, start=1):
        result = srde.estimate(views, mask)
        n_mask = int(np.count_nonzero(mask))
        if not _srde_ok(result):
            reports.append(ObjectReport(
                k, "fallback",
                f"SRDE failed ({getattr(result, 'status', 'unknown')}): "
                f"{getattr(result, 'reason', '')}", result, n_mask, 0))
            continue
        srde_disp = np.asarray(result.disparity, dtype=np.float32)
        if srde_disp.shape != (h, w):
            raise SRDEError(f"srde: expected estimate() to return an ({h}, {w}) disparity map, "
                            f"got shape {srde_disp.shape}")
        reports.append(_decide(k, result, srde_disp, mask, n_mask, backbone, rig, textured,
                               grays, border_check, fused, source))

    return FusionResult(fused, source, tuple(reports), backbone)


def _suspicion(result: Any, photo: _PhotoStats) -> str:
    """Say why SRDE's own evidence for its plane is weak ("" if it is not)."""
    refinement = getattr(result, "refinement", None)
    if refinement is not None and not refinement.ok:
        return "its photometric refinement kept the initial plane"
    if photo.n_px and photo.cost_srde > photo.cost_backbone:
        return (f"its plane explains the outline worse than the backbone "
                f"({photo.cost_srde:.3f} > {photo.cost_backbone:.3f})")
    return ""


def _decide(k: int, result: Any, srde_disp: np.ndarray, mask: np.ndarray, n_mask: int,
            backbone: np.ndarray, rig: CameraRig, textured: np.ndarray | None,
            grays: list[np.ndarray] | None,
            check: BorderCheck | None, fused: np.ndarray, source: np.ndarray) -> ObjectReport:
    """Check one successful SRDE result, write it into ``fused``/``source`` if accepted."""
    trimmed = np.zeros_like(mask)
    if check is not None and check.trim_disagreement > 0:
        trimmed = _trim(mask, srde_disp, backbone, textured, grays, rig, check)
    n_trimmed = int(np.count_nonzero(trimmed))
    object_mask = mask & ~trimmed
    stats = _BorderStats()
    if check is not None:
        stats = _border_stats(result, rig, backbone, object_mask, textured, check)
    photo = _PhotoStats()
    if check is not None and check.photo_ring_px > 0:
        photo = _photo_stats(mask, trimmed, srde_disp, backbone, textured, grays, rig, check)
    common = dict(border_px=stats.n_px, border_ratio_low=stats.ratio_low,
                  border_ratio_high=stats.ratio_high,
                  border_median_diff_px=stats.median_diff_px, trimmed_px=n_trimmed,
                  photo_px=photo.n_px, photo_cost_srde=photo.cost_srde,
                  photo_cost_backbone=photo.cost_backbone)
    checked = check is not None and stats.n_px >= check.min_px
    suspicion = _suspicion(result, photo)
    contradiction = ""
    if checked and stats.ratio_low > check.max_behind_ratio:
        contradiction = (f"it puts the object behind what the backbone sees around it "
                         f"(q{check.low_quantile:g} of backbone/srde = "
                         f"{stats.ratio_low:.2f} > {check.max_behind_ratio:g}")
    elif checked and stats.ratio_high < check.min_front_ratio:
        contradiction = (f"it puts the object far in front of anything the backbone sees "
                         f"there (q{check.high_quantile:g} of backbone/srde = "
                         f"{stats.ratio_high:.2f} < {check.min_front_ratio:g}")
    elif checked and suspicion and stats.ratio_low > check.suspect_behind_ratio:
        contradiction = (f"{suspicion}, and it puts the object behind what the backbone sees "
                         f"around it (q{check.low_quantile:g} of backbone/srde = "
                         f"{stats.ratio_low:.2f} > {check.suspect_behind_ratio:g}")
    elif checked and suspicion and stats.ratio_high < check.suspect_front_ratio:
        contradiction = (f"{suspicion}, and it puts the object far in front of anything the "
                         f"backbone sees there (q{check.high_quantile:g} of backbone/srde = "
                         f"{stats.ratio_high:.2f} < {check.suspect_front_ratio:g}")
    if contradiction:
        return ObjectReport(
            k, "fallback", f"SRDE contradicts the backbone around the object's outline: "
            f"{contradiction}, over {stats.n_px} textured px)", result, n_mask, 0, **common)
    photo_checked = check is not None and photo.n_px >= check.min_px
    if photo_checked and (photo.cost_srde
                          > check.max_photo_ratio * photo.cost_backbone + check.photo_margin):
        return ObjectReport(
            k, "fallback", f"SRDE's plane does not explain the object's outline in the other "
            f"views: mean grey difference {photo.cost_srde:.3f} against the backbone's "
            f"{photo.cost_backbone:.3f} (limit {check.max_photo_ratio:g} x backbone + "
            f"{check.photo_margin:g}) over {photo.n_px} px of the mask's inner ring",
            result, n_mask, 0, **common)
    # Only valid disparity replaces the backbone, whatever an estimator returns.
    take = (object_mask & np.isfinite(srde_disp) & (srde_disp >= 0)
            & (source == SOURCE_BACKBONE))
    fused[take] = srde_disp[take]
    source[take] = k
    n_take = int(np.count_nonzero(take))
    if check is None:
        reason = "SRDE used (border check disabled)"
    elif not checked:
        reason = (f"SRDE used unchecked: only {stats.n_px} textured px with a valid "
                  f"backbone around the outline (need {check.min_px})")
    else:
        reason = (f"SRDE agrees with the backbone around the object's outline "
                  f"(backbone/srde q{check.low_quantile:g} = {stats.ratio_low:.2f}, "
                  f"q{check.high_quantile:g} = {stats.ratio_high:.2f} over "
                  f"{stats.n_px} px)")
    if photo_checked:
        reason += (f"; photometric cost on the inner ring {photo.cost_srde:.3f} "
                   f"(backbone {photo.cost_backbone:.3f})")
    if n_trimmed:
        reason += (f"; {n_trimmed} textured mask px at the edge are not the object and keep "
                   f"the backbone")
    return ObjectReport(k, "srde", reason, result, n_mask, n_take, **common)



def _rig_with_light(rig: CameraRig, light: Any) -> CameraRig:
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    if light is not None:
        return rig.with_light(light)
    if rig.light_position_m is None:
        raise LightError("light: expected a light position (x, y, z) in metres, given here or in "
                         "the rig, got None")
    return rig


def postprocess(disparity: np.ndarray, views: Sequence[np.ndarray], rig: CameraRig,
                masks: Any = None, *, light: Any = None, srde_method: str = "default",
                border_check: BorderCheck | None = DEFAULT_BORDER_CHECK) -> FusionResult:
    """Fix a disparity map an existing pipeline produced, on flat glossy objects.

    Parameters
    ----------
    disparity : numpy.ndarray, (H, W), float, pixels
        The pipeline's disparity for the reference view of ``rig`` (stereo-pair
        convention, ``d = fx * B / z``).
    views : sequence of numpy.ndarray, (H, W, 3) uint8
        One image per rig camera.
    rig : CameraRig
    masks : None, path, array, list of masks or masker
        Where the objects are: None runs the built-in
        :class:`~srde_fusion.masks.stages.HighlightSegmenter`; a path or array is read as user
        masks (:class:`~srde_fusion.masks.stages.UserMasks`); a callable
        ``masker(views, rig) -> list of masks`` is called.
    light : array_like (3,), optional
        Light position in the array frame, metres; the rig's by default.
    srde_method : str
        SRDE variant, see :class:`~srde_fusion.srde.estimator.SRDE`.
    border_check : BorderCheck or None
        See :func:`fuse`.

    Returns
    -------
    FusionResult
    """
    rig = _rig_with_light(rig, light)
    views = check_views(views, rig.n_cameras, rig.image_size)
    w, h = rig.image_size
    backbone = check_disparity(disparity, (h, w), "disparity")
    masker = resolve_masker(masks).masker
    from ..srde import SRDE

    return fuse(backbone, views, rig, masker(views, rig), SRDE(rig, method=srde_method),
                border_check=border_check)


class HybridStereo:
    """A stereo model made reliable on flat glossy objects: backbone + SRDE + fusion.

    Parameters
    ----------
    backbone : callable
        ``backbone(left, right) -> (H, W) float32`` disparity in pixels (see
        ``srde_fusion.adapters.load_backbone`` to build one from an ONNX file or a
        torch module). It receives the views of the rig's stereo pair.
    rig : CameraRig
    light : array_like (3,), optional
        Light position in the array frame, metres; the rig's by default.
    masker : callable, optional
        ``masker(views, rig) -> list of (H, W) bool``; the built-in
        :class:`~srde_fusion.masks.stages.HighlightSegmenter` by default. Paths and arrays are
        taken as fixed user masks.
    srde_method : str
        SRDE variant, see :class:`~srde_fusion.srde.estimator.SRDE`.
    border_check : BorderCheck or None
        See :func:`fuse`.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(32, 24), light_position_m=(0, -0.3, 0))
    >>> model = HybridStereo(lambda left, right: np.full((24, 32), 5.0, np.float32), rig,
    ...                      masker=lambda views, rig: [])
    >>> views = [np.zeros((24, 32, 3), np.uint8)] * 2
    >>> result = model(views)
    >>> float(result.disparity[0, 0]), result.objects
    (5.0, ())
    """

    def __init__(self, backbone: Backbone, rig: CameraRig, light: Any = None,
                 masker: Any = None, *, srde_method: str = "default",
                 border_check: BorderCheck | None = DEFAULT_BORDER_CHECK) -> None:
        if not callable(backbone):
            raise BackboneError(f"backbone: expected a callable backbone(left, right), got "
                            f"{type(backbone).__name__}")
        self.rig = _rig_with_light(rig, light)
        self.backbone = backbone
        self.masker = resolve_masker(masker).masker
        self.srde_method = srde_method
        self.border_check = border_check
        self._srde = None

    @property
    def srde(self) -> Any:
        """The SRDE estimator for this rig (built on first use)."""
        if self._srde is None:
            from ..srde import SRDE

            self._srde = SRDE(self.rig, method=self.srde_method)
        return self._srde

    def __call__(self, views: Sequence[np.ndarray]) -> FusionResult:
        """Run backbone, mask stage, SRDE and fusion on one set of views.

        Parameters
        ----------
        views : sequence of numpy.ndarray, (H, W, 3) uint8
            One image per rig camera.

        Returns
        -------
        FusionResult
        """
        rig = self.rig
        views = check_views(views, rig.n_cameras, rig.image_size)
        left, right = (views[i] for i in rig.stereo_pair)
        disparity = self.backbone(left, right)
        # Checked here so that a masker returning None or a generator is a MaskError.
        masks = _as_mask_list(self.masker(views, rig), (rig.height, rig.width))
        srde = self.srde if masks else None
        return fuse(disparity, views, rig, masks, srde, border_check=self.border_check)
