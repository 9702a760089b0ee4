"""What the refinement compares: block-averaged luminance samples around each highlight.

For every view a window around the highlight centre is cut, pixels outside the object
(as the current plane maps the reference mask into that view) are dropped, and the rest
is averaged over small blocks (larger blocks on larger windows) into samples with their
pixel ray, camera centre, luminance and clipping flag.

A sample is a mean over its block's area, not a value at its centre: on a lobe's steep
flank the two differ, and the difference shifts the fitted highlight. The model is
therefore averaged over the same square (:func:`support_points`: Gauss-Legendre points
across the block, which integrate it exactly up to third order along each axis). An
every-pixel sample is read at its centre (:data:`PIXEL_SUPPORT_POINTS`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from ...boxes import eroded_crop
from ...geometry import CameraRig, Plane, project_points
from ...imaging import REC709_LUMA, luminance, saturation_mask, to_linear

# --- fitting window -------------------------------------------------------------------
#: The window's half-size is at most this fraction of the smaller image side.
MAX_WINDOW_FRACTION = 0.2


#: Smallest half-size of the window, pixels.
MIN_WINDOW_HALF_PX = 8


#: The window reaches this many half-maximum radii of the highlight blob from its centre.
WINDOW_PER_BLOB_RADIUS = 3.0


#: Block samples per window side at most; larger windows average larger blocks.
SAMPLES_PER_SIDE = 30


#: On a rig of this many cameras or fewer, every pixel is a sample. Two views carry
#: little evidence each, and a block around the clipped core turns its unclipped pixels
#: into one lower bound: on the stereo pair of the mismatched-physics benchmark, blocks
#: leave the worst cell at 0.028 px masked EPE over noise draws, every pixel at 0.016 px
#: (``benchmarks/noise_bound.py``), at 3-8x the default call's time. (A highlight that
#: only two views of a larger array hold keeps the blocks: not measured to gain there.)
PIXEL_SAMPLES_MAX_CAMERAS = 2


#: Points per axis on an every-pixel sample (``PIXEL_SAMPLES_MAX_CAMERAS``): its centre.
#: A pixel's area is an average too, but over a lobe many pixels wide it moves the model
#: by a second-order term: on eight stereo scenes read pixel by pixel (six sharp lobes
#: under a 15 mm lamp, two rough clipped ones), averaging each pixel over 2 x 2 points
#: moved the plane by at most 0.001 px, at three to four times the cost. Block means that
#: come out one pixel wide (a small window on a larger array: a sharp lobe, few samples,
#: little cost) keep the blocks' 2 x 2 points: read at their centres, they changed 5 of
#: the 220 several-light and faceted objects, 4 for the worse (one faceted face 0.046 ->
#: 0.068 px) and one both ways.
PIXEL_SUPPORT_POINTS = 1


#: Pixels closer than this to the object's outline are not fitted (mask warping slack).
MASK_MARGIN_PX = 2


#: Fewer samples than this, all views together, are too few to fit the model.
MIN_SAMPLES = 60


#: Fewer unsaturated samples than this above the background cannot show the lobe's flanks.
MIN_FLANK_SAMPLES = 12


#: Peak-over-background contrast (linear luminance) below which there is no highlight.
MIN_HIGHLIGHT_CONTRAST = 0.02


# Coarse grid step (pixels) and number of views used to size the window.
_SIZING_STRIDE_PX = 4
_SIZING_VIEWS = 3


# Quantile of the luminance taken as the object's background level near the highlight.
_BACKGROUND_QUANTILE = 0.2


@dataclass(frozen=True)
class HighlightSamples:
    """Samples fitted, all views stacked, unsaturated first; arrays ``(P,)`` or ``(P, 3)``.

    A sample is the mean linear luminance of a ``block x block`` pixel square, placed at
    the square's centre: averaging costs far less than fitting every pixel and keeps
    nearly all their information (the window spans about six half-maximum radii of the
    lobe, so a block is a small fraction of the lobe's width).
    """

    camera_m: np.ndarray  # (P, 3) centre of the sample's camera
    ray: np.ndarray  # (P, 3) unnormalised ray ((u - cx) / fx, (v - cy) / fy, 1)
    luminance: np.ndarray  # (P,) linear luminance
    saturated: np.ndarray  # (P,) bool: some pixel clipped, the mean is a lower bound
    view_indices: tuple[int, ...]  # the views with samples, ascending
    half_window_px: int
    block_px: int
    outline_px: int  # how far inside the object's outline the samples' pixels stay
    # Every pixel a sample (``sample_windows(pixel_samples=True)``), not block means that
    # came out one pixel wide because the window is small.
    every_pixel: bool = False

    @property
    def may_come_nearer(self) -> bool:
        """Whether samples placed for a fitted plane may come nearer the outline."""
        return self.outline_px > MASK_MARGIN_PX + self.block_px // 2

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.luminance.shape[0])


def sample_windows(views, rig: CameraRig, mask: np.ndarray, plane: Plane, centers: np.ndarray,
                    *, box=None, other_lights_m=None, further_centers=None,
                    settled: bool = False, pixel_samples: bool | None = None
                    ) -> HighlightSamples | str:
    """Block samples around each view's highlight on the object, or why there are none.

    ``box``: the mask's bounding box, if known. ``other_lights_m`` ``(M, 3)``: further
    lights whose highlights (where ``plane`` puts them) are left out of the windows, over
    the radius the window spans around its own highlight. ``further_centers``
    ``(L, N, 2)``, pixels: highlights of further modelled lights (NaN where a view has
    none); windows of the same size go around them too, in the views whose own highlight
    has a window, less the blocks an earlier window of the view already holds.
    ``settled``: ``plane`` is a fitted one, which places the outline in the other views
    to a fraction of a pixel; pixel samples may then come as near it as blocks' pixels
    (:data:`MASK_MARGIN_PX`). Otherwise they keep the blocks' own distance.
    ``pixel_samples``: every pixel a sample (True) or block means (False); by default
    every pixel on a rig of :data:`PIXEL_SAMPLES_MAX_CAMERAS` cameras or fewer.
    """
    box = mask_bbox(mask) if box is None else box
    eroded = _erode(mask, MASK_MARGIN_PX, box)
    w, h = rig.image_size
    max_half = max(MIN_WINDOW_HALF_PX, int(MAX_WINDOW_FRACTION * min(w, h)))
    usable = [i for i in range(rig.n_cameras)
              if np.all(np.isfinite(centers[i]))
              and -max_half <= centers[i, 0] <= w + max_half
              and -max_half <= centers[i, 1] <= h + max_half]
    if not usable:
        return "samples: no view has a highlight centre inside or near the image"
    maps = references_from_views(rig, plane)
    to_ref = {i: None if i == rig.reference else maps[i] for i in usable}

    # Size the window from the blob's half-maximum radius, seen on a coarse grid in a few
    # views (the reference first).
    stride = _SIZING_STRIDE_PX
    offsets = np.arange(-max_half, max_half + 1, stride)
    radii = []
    for i in sorted(usable, key=lambda j: j != rig.reference):
        if len(radii) == _SIZING_VIEWS:
            break
        uu = np.tile(offsets + int(np.rint(centers[i, 0])), len(offsets))
        vv = np.repeat(offsets + int(np.rint(centers[i, 1])), len(offsets))
        keep = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        uu, vv = uu[keep], vv[keep]
        inside = _object_lookup(eroded, to_ref[i], uu, vv)
        if inside.sum() < MIN_SAMPLES:
            continue
        y = luminance(views[i][vv[inside], uu[inside]][None], rig.image_encoding)[0]
        background, peak = low_quantile_of(y), float(y.max())
        if peak - background < MIN_HIGHLIGHT_CONTRAST:
            continue
        area_px = np.count_nonzero(y > 0.5 * (background + peak)) * stride**2
        radii.append(math.sqrt(area_px / math.pi))
    if not radii:
        return (f"samples: no view shows a highlight brighter than the object by "
                f"{MIN_HIGHLIGHT_CONTRAST:g} (linear) inside the mask")
    half = math.ceil(WINDOW_PER_BLOB_RADIUS * float(np.median(radii))) + 2
    half = min(max(half, MIN_WINDOW_HALF_PX), max_half)
    nominal = max(1, math.ceil((2 * half + 1) / SAMPLES_PER_SIDE))
    if pixel_samples is None:
        pixel_samples = rig.n_cameras <= PIXEL_SAMPLES_MAX_CAMERAS
    block = 1 if pixel_samples else nominal
    # Pixel samples keep the blocks' distance from the outline until the plane is fitted:
    # a plane from triangulation can place the outline in the other views a few pixels
    # off, which brings the background into the windows.
    outline = MASK_MARGIN_PX + (block if settled else nominal) // 2
    block_mask = _erode(mask, outline, box)
    others = None
    if other_lights_m is not None and len(other_lights_m):
        others = plane.mirror(np.asarray(other_lights_m, dtype=np.float64).reshape(-1, 3))
        exclude_px = half - 2 + block
    uvs, lum, sat, used, counts = [], [], [], [], []
    for i in usable:
        window = _block_window(views[i], rig, block_mask, to_ref[i], centers[i], half, block)
        if window is None or not window[3].any():
            continue
        uv, y, clipped, inside = window
        if further_centers is not None:
            uv, y, clipped, inside = _with_further_windows(
                views[i], rig, block_mask, to_ref[i], centers[i], further_centers[:, i], half,
                block, (uv, y, clipped, inside))
        if others is not None:
            # Other lights' highlights are not the fitted light's lobe.
            seen = project_points(rig, others, np.full(len(others), i))
            gaps = np.linalg.norm(uv[:, None, :] - seen[None, :, :], axis=2)
            inside = inside & np.all(gaps > exclude_px, axis=1)
            if not inside.any():
                continue
        uvs.append(uv[inside])
        lum.append(y[inside])
        sat.append(clipped[inside])
        used.append(i)
        counts.append(len(lum[-1]))
    if not used:
        return "samples: no object pixels in any highlight window"
    luminance_all = np.concatenate(lum)
    saturated_all = np.concatenate(sat)
    if len(luminance_all) < MIN_SAMPLES:
        return (f"samples: only {len(luminance_all)} object samples near the highlights "
                f"(< {MIN_SAMPLES})")
    unsaturated = luminance_all[~saturated_all]
    background = low_quantile_of(unsaturated) if unsaturated.size else 1.0
    flank = int(np.count_nonzero(unsaturated > background + MIN_HIGHLIGHT_CONTRAST))
    if flank < MIN_FLANK_SAMPLES:
        return (f"samples: only {flank} unsaturated samples on the highlight's flanks "
                f"(< {MIN_FLANK_SAMPLES}; {int(saturated_all.sum())} of "
                f"{len(saturated_all)} saturated); the lobe cannot be fitted")
    # Unsaturated samples first: the intensity solve then slices instead of copying.
    order = np.argsort(saturated_all, kind="stable")
    cameras_m = np.repeat(rig.centers_m[used], counts, axis=0)
    return HighlightSamples(cameras_m[order], rig.rays(np.concatenate(uvs)[order]),
                    luminance_all[order], saturated_all[order], tuple(used), half, block,
                    outline, pixel_samples)


def support_points(samples: HighlightSamples, rig: CameraRig, points: int
                   ) -> tuple[HighlightSamples, np.ndarray]:
    """Where to evaluate the model so that its mean over each block is the sample's value.

    Parameters
    ----------
    samples : HighlightSamples
        ``P`` samples, each the mean of a ``block_px`` square.
    rig : CameraRig
    points : int
        Gauss-Legendre points per axis; 1 evaluates the model at block centres only.
        Every-pixel samples take at most :data:`PIXEL_SUPPORT_POINTS`.

    Returns
    -------
    HighlightSamples
        ``S * P`` model points, ``S = points**2`` groups of ``P`` (group ``s`` holds
        every sample's ``s``-th point); the observations are repeated per group.
    numpy.ndarray, (S,)
        The quadrature weight of each group (they sum to 1).
    """
    if samples.every_pixel:
        points = min(points, PIXEL_SUPPORT_POINTS)
    if points == 1:
        return samples, np.ones(1)
    nodes, weights = _gauss_legendre(points)
    offsets_px = 0.5 * samples.block_px * nodes  # across [-block / 2, block / 2]
    k = rig.intrinsics
    rays, group_weights = [], []
    for dv, wv in zip(offsets_px, weights, strict=True):
        for du, wu in zip(offsets_px, weights, strict=True):
            rays.append(samples.ray + np.array([du / k.fx, dv / k.fy, 0.0]))
            group_weights.append(0.25 * wu * wv)  # Gauss weights sum to 2 per axis
    n = len(rays)
    expanded = HighlightSamples(np.tile(samples.camera_m, (n, 1)), np.concatenate(rays),
                                np.tile(samples.luminance, n), np.tile(samples.saturated, n),
                                samples.view_indices, samples.half_window_px, samples.block_px,
                                samples.outline_px, samples.every_pixel)
    return expanded, np.array(group_weights)


@functools.lru_cache(maxsize=8)
def _gauss_legendre(points: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1, 1], ``(points,)`` each, read-only.

    (numpy solves an eigenproblem for them on every call; every model built asks again.)
    """
    nodes, weights = np.polynomial.legendre.leggauss(points)
    nodes.flags.writeable = weights.flags.writeable = False
    return nodes, weights


def low_quantile_of(values: np.ndarray) -> float:
    """Return the background level near the highlight: a low quantile, by partition."""
    k = int(_BACKGROUND_QUANTILE * (len(values) - 1))
    return float(np.partition(values, k)[k])


@dataclass(frozen=True)
class _Eroded:
    """A shrunk reference mask, kept only over the object's box (the rest is outside)."""

    inside: np.ndarray  # (h, w) bool, the box's pixels
    origin: tuple[int, int]  # reference pixel (x, y) of inside[0, 0]


def mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box ``(x, y, width, height)`` of a bool mask's pixels, in pixels."""
    # (a bool array viewed as bytes: no copy of a full-size mask)
    return tuple(int(v) for v in cv2.boundingRect(mask.view(np.uint8)))


def _erode(mask: np.ndarray, radius_px: int, box) -> _Eroded:
    """Shrink the mask by ``radius_px`` in the chessboard metric, over its box ``box`` only.

    ``box`` is the mask's bounding box ``(x, y, width, height)`` (see :func:`mask_bbox`).
    """
    x, y, w, h = box
    side = 2 * radius_px + 1
    return _Eroded(*eroded_crop(mask, np.ones((side, side), np.uint8), (x, y, x + w, y + h)))


def views_from_reference(rig: CameraRig, plane: Plane) -> np.ndarray:
    """Affine maps ``(N, 2, 3)`` from reference pixels to each camera's pixels on the plane.

    In a rectified rig a point at depth z moves by ``-f (C_j - C_ref) / z`` between the
    reference view and camera j, and on a plane ``1 / z`` is affine in the pixel: the
    homography the plane induces is affine.
    """
    k = rig.intrinsics
    n = plane.n
    base = plane.offset_m - float(n @ rig.reference_center_m)
    # 1 / z = g . (u, v, 1) at reference pixels (u, v)
    g = np.array([n[0] / k.fx, n[1] / k.fy, n[2] - n[0] * k.cx / k.fx - n[1] * k.cy / k.fy]) / base
    d = rig.centers_m - rig.reference_center_m
    # camera pixel = A (u, v) + t with A = I - s g[:2]^T, t = -s g[2], s = f * dXY
    s = d[:, :2] * np.array([k.fx, k.fy])  # (N, 2)
    maps = np.empty((len(d), 2, 3))
    maps[:, :, :2] = np.eye(2) - s[:, :, None] * g[:2]
    maps[:, :, 2] = -g[2] * s
    return maps


def references_from_views(rig: CameraRig, plane: Plane) -> np.ndarray:
    """Affine maps ``(N, 2, 3)`` from each camera's pixels to the reference pixels."""
    forward = views_from_reference(rig, plane)
    a, t = forward[:, :, :2], forward[:, :, 2]
    det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    inverse = np.empty_like(forward)
    inverse[:, 0, 0], inverse[:, 1, 1] = a[:, 1, 1] / det, a[:, 0, 0] / det
    inverse[:, 0, 1], inverse[:, 1, 0] = -a[:, 0, 1] / det, -a[:, 1, 0] / det
    inverse[:, :, 2] = -np.einsum("nij,nj->ni", inverse[:, :, :2], t)
    return inverse


def warp_change_px(rig: CameraRig, before: Plane, after: Plane, box) -> float:
    """Largest move (px) of the object box's corners, mapped into any other camera.

    Compares where the mappings that two planes induce send the reference mask's box
    ``(x, y, width, height)``.
    """
    x, y, w, h = box
    corners = np.array([[x, x + w - 1, x, x + w - 1], [y, y, y + h - 1, y + h - 1],
                        [1.0, 1.0, 1.0, 1.0]])
    moved = (views_from_reference(rig, after) - views_from_reference(rig, before)) @ corners
    return float(np.max(np.abs(moved)))  # (the reference view's rows are 0)


def _object_lookup(eroded_ref: _Eroded, to_ref: np.ndarray | None, uu: np.ndarray,
                   vv: np.ndarray) -> np.ndarray:
    """Whether camera pixels ``uu, vv`` (any shape) land on the eroded reference mask."""
    if to_ref is not None:
        uu, vv = (to_ref[0, 0] * uu + to_ref[0, 1] * vv + to_ref[0, 2],
                  to_ref[1, 0] * uu + to_ref[1, 1] * vv + to_ref[1, 2])
    x0, y0 = eroded_ref.origin
    ru, rv = np.rint(uu).astype(np.intp) - x0, np.rint(vv).astype(np.intp) - y0
    h, w = eroded_ref.inside.shape
    ok = (ru >= 0) & (ru < w) & (rv >= 0) & (rv < h)
    inside = np.zeros(ok.shape, dtype=bool)
    inside[ok] = eroded_ref.inside[rv[ok], ru[ok]]
    return inside


def _block_window(view: np.ndarray, rig: CameraRig, block_mask: np.ndarray, to_ref, center_uv,
                  half: int, block: int):
    """Block samples of the window around ``center_uv``, or None if it misses the image.

    Returns block centres ``(M, 2)`` (pixels), mean linear luminance, saturation (a pixel
    of the block clipped) and object membership ``(M,)``; ``block_mask`` is the
    reference mask eroded so that a block centred on it lies wholly on the object.
    """
    w, h = rig.image_size
    n_side = (2 * half + 1) // block
    start = np.rint(np.asarray(center_uv)).astype(int) - (n_side * block) // 2
    # Keep whole blocks inside the image.
    lo = np.maximum(0, np.ceil(-start / block)).astype(int)
    hi = np.minimum(n_side, np.floor((np.array([w, h]) - start) / block)).astype(int)
    if np.any(hi <= lo):
        return None
    u0, v0 = start + lo * block
    nu, nv = (int(x) for x in hi - lo)
    crop = view[v0:v0 + nv * block, u0:u0 + nu * block]
    lum = to_linear(crop, rig.image_encoding)
    if lum.ndim == 3:
        lum = cv2.transform(lum, REC709_LUMA.reshape(1, 3))
    clipped = saturation_mask(crop)
    if block > 1:
        # INTER_AREA with an integer factor is the exact block mean.
        lum = cv2.resize(lum, (nu, nv), interpolation=cv2.INTER_AREA)
        # any() over block rows, then over block columns (single-axis reductions are fast)
        clipped = clipped.reshape(nv, block, nu * block).any(axis=1)
        clipped = clipped.reshape(nv, nu, block).any(axis=2)
    cu = u0 + block * np.arange(nu) + (block - 1) / 2.0
    cv = v0 + block * np.arange(nv) + (block - 1) / 2.0
    uu, vv = np.tile(cu, nv), np.repeat(cv, nu)  # row-major, like the blocks
    inside = _object_lookup(block_mask, to_ref, uu, vv)
    return (np.stack([uu, vv], axis=1), lum.ravel().astype(np.float64), clipped.ravel(),
            inside)


def _with_further_windows(view: np.ndarray, rig: CameraRig, block_mask: np.ndarray, to_ref,
                          center_uv: np.ndarray, further_uv: np.ndarray, half: int, block: int,
                          window):
    """Join the windows around further highlights ``(L, 2)`` to a view's window.

    Blocks whose centre lies in an earlier window's square (grown by half a block, so
    no pixel is sampled twice) are left out; a highlight without a finite centre or
    whose window misses the image adds nothing. Returns the joined ``window`` tuple.
    """
    taken = [np.asarray(center_uv, dtype=np.float64)]
    parts = [window]
    reach = half + 0.5 * block
    for uv in further_uv:
        if not np.all(np.isfinite(uv)):
            continue
        extra = _block_window(view, rig, block_mask, to_ref, uv, half, block)
        if extra is not None:
            inside = extra[3].copy()
            for centre in taken:
                inside &= np.max(np.abs(extra[0] - centre), axis=1) > reach
            if inside.any():
                parts.append((*extra[:3], inside))
        taken.append(np.asarray(uv, dtype=np.float64))
    if len(parts) == 1:
        return window
    return tuple(np.concatenate(a) for a in zip(*parts, strict=True))
