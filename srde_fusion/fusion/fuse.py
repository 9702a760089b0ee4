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

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._checks import check_disparity, check_mask, check_views
from ..errors import MaskError, RigError, SRDEError
from ..geometry import CameraRig
from ..masks import BoxedMasks, BoxMask
from ..srde import SRDE
from .checks import (
    DEFAULT_BORDER_CHECK,
    BorderCheck,
    BorderStats,
    PhotoStats,
    border_stats,
    gray_levels,
    photo_stats,
    reflection_mask,
    spill_trim,
    spilled_rim,
    textured_mask,
    weak_evidence,
)
from .estimate import ObjectEstimate, PlaneEstimator, read_estimate
from .report import SOURCE_BACKBONE, FusionResult, ObjectReport

_log = logging.getLogger(__name__)

__all__ = [
    "fuse",
]

Masker = Callable[[Sequence[np.ndarray], CameraRig], list]


def as_mask_list(masks: Any, shape: tuple[int, int]) -> BoxedMasks:
    """Validate ``masks`` (list of bool masks, (K, H, W) stack or (H, W) labels).

    Returns
    -------
    BoxedMasks
        The sequence of ``(H, W)`` bool masks, held as the objects' boxes (a
        ``BoxedMasks`` of the right shape passes through).
    """
    if isinstance(masks, BoxedMasks):
        if masks.shape != tuple(shape):
            raise MaskError(f"masks: expected masks of shape {tuple(shape)}, got {masks.shape}")
        return masks
    if isinstance(masks, np.ndarray):
        if masks.ndim == 2:
            if not np.issubdtype(masks.dtype, np.integer):
                masks = [masks]
            else:  # instance labels: 0 = background, k = object k
                check_mask(masks, shape, "masks", allow_empty=True)
                return BoxedMasks.from_labels(np.maximum(masks, 0))
        elif masks.ndim == 3:
            masks = list(masks)
        else:
            raise MaskError(f"masks: expected a list of (H, W) masks, a (K, H, W) stack or (H, W) "
                            f"labels, got an array of shape {masks.shape}")
    if not isinstance(masks, Sequence) or isinstance(masks, (str, bytes)):
        raise MaskError(f"masks: expected a list of (H, W) bool masks, got {type(masks).__name__}")
    return BoxedMasks.from_masks(masks, shape)


def fuse(backbone_disparity: np.ndarray, views: Sequence[np.ndarray], rig: CameraRig,
         masks: Any, srde: PlaneEstimator | None = None, *,
         border_check: BorderCheck | None = DEFAULT_BORDER_CHECK
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
    mask_list = as_mask_list(masks, (h, w))
    if border_check is not None and not isinstance(border_check, BorderCheck):
        raise SRDEError(f"border_check: expected a BorderCheck or None, got "
                        f"{type(border_check).__name__}")
    if srde is None and mask_list:
        srde = SRDE(rig)

    fused = backbone.copy()
    source = np.zeros((h, w), dtype=np.int32)
    context = _Context(backbone, rig, border_check)
    if border_check is not None and mask_list:
        # The lights tell a highlight from background (spill_trim): the rig's, or the
        # estimator's when the rig was given without them.
        lights_m = rig.light_positions_m
        own_rig = getattr(srde, "rig", None)
        if not len(lights_m) and isinstance(own_rig, CameraRig):
            lights_m = own_rig.light_positions_m
        context = _Context(backbone, rig, border_check,
                           textured_mask(views[rig.reference], border_check.min_gradient),
                           [gray_levels(v) for v in views], lights_m)

    reports = []
    _log.info("fusing %d object(s)", len(mask_list))
    for k, box_mask in enumerate(mask_list.boxes, start=1):
        # The estimator takes a full-image mask; it lives only while it estimates.
        estimate = read_estimate(srde.estimate(views, box_mask.full()))
        n_mask = box_mask.pixel_count
        if not estimate.ok:
            reports.append(ObjectReport(
                k, "fallback", f"SRDE failed ({estimate.status}): {estimate.reason}", estimate,
                n_mask, 0))
            continue
        if estimate.image_shape != (h, w):
            raise SRDEError(f"srde: expected estimate() to return an ({h}, {w}) disparity map, "
                            f"got shape {estimate.image_shape}")
        # Everything an object's decision reads lies within a few pixels of its mask.
        window = _window(box_mask, context, (h, w))
        u0, v0, u1, v1 = window
        free = source[v0:v1, u0:u1] == SOURCE_BACKBONE
        decision = _decide(k, estimate, box_mask, window, free, context)
        if decision.take is not None:
            fused[v0:v1, u0:u1][decision.take] = estimate.window(window)[decision.take]
            source[v0:v1, u0:u1][decision.take] = k
        reports.append(decision.report)
        _log.debug("object %d: %s - %s", k, decision.report.status, decision.report.reason)

    return FusionResult(fused, source, tuple(reports), backbone)


def _window(box_mask: BoxMask, context: _Context, shape: tuple[int, int]
            ) -> tuple[int, int, int, int]:
    """Return the mask's box grown by what the checks read beyond it, within the image."""
    # The outline band reaches width_px outside the mask; one more pixel keeps the
    # morphology at the window's edge as it is on the whole image.
    margin = (context.check.width_px if context.check is not None else 0) + 2
    u0, v0, u1, v1 = box_mask.box
    h, w = shape
    return max(u0 - margin, 0), max(v0 - margin, 0), min(u1 + margin, w), min(v1 + margin, h)


@dataclass(frozen=True)
class _Context:
    """What every object's decision reads: the backbone, the rig and the check's maps."""

    backbone: np.ndarray                   # (H, W) float32, NaN = invalid
    rig: CameraRig
    check: BorderCheck | None
    textured: np.ndarray | None = None     # (H, W) bool, reference view
    grays: list[np.ndarray] | None = None  # N x (H, W) float32
    lights_m: np.ndarray | None = None     # (L, 3) float64, the known lights


@dataclass(frozen=True)
class _Decision:
    """One object's outcome: its report, and the pixels that take SRDE's disparity."""

    report: ObjectReport
    take: np.ndarray | None = None         # (h, w) bool over the window; None on fallback


def _virtual_lights_m(estimate: ObjectEstimate, lights_m: np.ndarray | None) -> np.ndarray:
    """Each light in front of one of the estimate's planes mirrored in it, ``(V, 3)`` m."""
    planes = [p for p in (estimate.plane, *estimate.face_planes) if p is not None]
    if lights_m is None or not len(lights_m) or not planes:
        return np.zeros((0, 3))
    return np.concatenate([plane.mirror(lights_m[plane.signed_distance(lights_m) > 0])
                           for plane in planes])


def _decide(k: int, estimate: ObjectEstimate, box_mask: BoxMask,
            window: tuple[int, int, int, int], free: np.ndarray, context: _Context
            ) -> _Decision:
    """Check one successful estimate against the backbone; say which pixels take it.

    Every map is read over ``window = (u0, v0, u1, v1)``, the mask's box and the margin
    the checks need, so an object costs memory in proportion to its size. ``free``
    marks the window's pixels no earlier object has taken.
    """
    u0, v0, u1, v1 = window
    origin = (u0, v0)
    mask = box_mask.window(window)
    srde_disp = estimate.window(window)
    n_mask = box_mask.pixel_count
    rig, check = context.rig, context.check
    backbone = context.backbone[v0:v1, u0:u1]
    textured = None if context.textured is None else context.textured[v0:v1, u0:u1]
    grays = context.grays
    trimmed = np.zeros_like(mask)
    reflection = None
    if check is not None and (check.trim_disagreement > 0 or check.photo_ring_px > 0):
        # Only the spill trim and the photometric checks (with the rim search) leave it out.
        reflection = reflection_mask(mask, backbone, textured, grays, rig,
                                     _virtual_lights_m(estimate, context.lights_m),
                                     check.width_px, origin, estimate.face_labels(window))
    if check is not None and check.trim_disagreement > 0:
        trimmed = spill_trim(mask, srde_disp, backbone, textured, grays, rig, check, origin,
                             reflection)
    n_trimmed = int(np.count_nonzero(trimmed))
    object_mask = mask & ~trimmed
    checked_mask = object_mask  # what the outline checks judge
    photo = PhotoStats()
    rim_depth_px = 0
    if check is not None and check.photo_ring_px > 0:
        photo = photo_stats(mask, trimmed, srde_disp, backbone, textured, grays, rig, check,
                            origin, reflection)
        if photo.n_px >= check.min_px and photo.cost_srde > photo.cost_backbone \
                and check.trim_disagreement > 0:
            # The mask may hold a ring of background around the object: check the object
            # inside it instead, and leave the ring to the backbone.
            spilled = spilled_rim(mask, trimmed, srde_disp, backbone, textured, grays, rig,
                                  check, origin, reflection)
            if spilled.depth_px:
                rim_depth_px, photo = spilled.depth_px, spilled.photo
                checked_mask = object_mask & ~spilled.rim
                trimmed = trimmed | spilled.background
                n_trimmed = int(np.count_nonzero(trimmed))
                object_mask = mask & ~trimmed
    stats = BorderStats()
    if check is not None:
        # A faceted object's faces are each checked on their own stretch of the outline.
        stats = border_stats(estimate.plane, rig, backbone, checked_mask, textured, check,
                             origin, estimate.face_planes, estimate.face_labels(window))
    common = dict(border_px=stats.n_px, border_ratio_low=stats.ratio_low,
                  border_ratio_high=stats.ratio_high,
                  border_median_diff_px=stats.median_diff_px, trimmed_px=n_trimmed,
                  photo_px=photo.n_px, photo_cost_srde=photo.cost_srde,
                  photo_cost_backbone=photo.cost_backbone)
    checked = check is not None and stats.n_px >= check.min_px
    suspicion = weak_evidence(estimate, photo)
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
    where = (f" (the worst of its {stats.n_faces_checked} faces' stretches)"
             if stats.n_faces_checked > 1 else "")
    if rim_depth_px:
        where += (f" (inside the mask's outer {rim_depth_px} px, background around the "
                  f"object)")
    if contradiction:
        return _Decision(ObjectReport(
            k, "fallback", f"SRDE contradicts the backbone around the object's outline"
            f"{where}: {contradiction}, over {stats.n_px} textured px)", estimate, n_mask, 0,
            **common))
    photo_checked = check is not None and photo.n_px >= check.min_px
    if photo_checked and (photo.cost_srde
                          > check.max_photo_ratio * photo.cost_backbone + check.photo_margin):
        return _Decision(ObjectReport(
            k, "fallback", f"SRDE's plane does not explain the object's outline in the other "
            f"views: mean grey difference {photo.cost_srde:.3f} against the backbone's "
            f"{photo.cost_backbone:.3f} (limit {check.max_photo_ratio:g} x backbone + "
            f"{check.photo_margin:g}) over {photo.n_px} px of the mask's inner ring",
            estimate, n_mask, 0, **common))
    # Only valid disparity replaces the backbone, whatever an estimator returns.
    take = object_mask & np.isfinite(srde_disp) & (srde_disp >= 0) & free
    n_take = int(np.count_nonzero(take))
    if check is None:
        reason = "SRDE used (border check disabled)"
    elif not checked:
        reason = (f"SRDE used unchecked: only {stats.n_px} textured px with a valid "
                  f"backbone around the outline (need {check.min_px})")
    else:
        reason = (f"SRDE agrees with the backbone around the object's outline{where} "
                  f"(backbone/srde q{check.low_quantile:g} = {stats.ratio_low:.2f}, "
                  f"q{check.high_quantile:g} = {stats.ratio_high:.2f} over "
                  f"{stats.n_px} px)")
    if photo_checked:
        reason += (f"; photometric cost on the inner ring {photo.cost_srde:.3f} "
                   f"(backbone {photo.cost_backbone:.3f})")
    if n_trimmed:
        reason += (f"; {n_trimmed} textured mask px at the edge are not the object and keep "
                   f"the backbone")
    return _Decision(ObjectReport(k, "srde", reason, estimate, n_mask, n_take, **common), take)
