"""Specular highlight detection: where the image of the light sits in one view.

Two detectors share one result type:

``method="paper"``
    The paper's adaptive gradient thresholding (Methods, eqs. 1-4): Sobel gradient magnitude
    ``G`` of the luminance, a local threshold ``mu + k * sigma`` of ``G`` over a square
    window, 8-connected components of ``G > threshold`` with a minimum bounding-box
    extent, the largest one kept; the centre is the centroid of that component, which is
    the highlight's *edge ring*. It is only as good as the ring is symmetric.
``method="blob"`` (default)
    The bright blob itself, on linear intensity: pixels above the half-maximum level
    between the local background and the (smoothed) peak, the 8-connected component with
    the most light kept, and a sub-pixel centre from it. ``blob_center`` picks the
    estimator: ``"weighted"`` (intensity-weighted centroid of the light above the level;
    clipped pixels weigh as much as the clip allows, which keeps a symmetric blob
    symmetric), ``"core"`` (plain centroid of the saturated core, weighted centroid if
    nothing is clipped) or ``"lobe"`` (a Gaussian fitted to the unclipped flanks through
    a weighted log-quadratic least-squares fit, saturation-aware). The default was
    chosen by measuring each against the projected virtual light on rendered scenes
    (``benchmarks/srde_accuracy.py``).

Both work only inside a search region (the object's eroded mask in the reference
view); the region's bounding box, plus the margin the filters need, is all that is
computed, so the cost scales with the object and not with the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._checks import check_image, check_mask
from ..errors import SRDEError
from ..imaging import IMAGE_ENCODINGS, luminance, saturation_mask

__all__ = [
    "HighlightDetection",
    "detect_highlight",
    "HIGHLIGHT_METHODS",
    "BLOB_CENTERS",
    "DEFAULT_BLOB_CENTER",
]

#: Detector names accepted by :func:`detect_highlight`.
HIGHLIGHT_METHODS = ("blob", "paper")
#: Sub-pixel centre estimators of the blob detector.
BLOB_CENTERS = ("weighted", "core", "lobe")
#: The blob centre used by default (chosen by measurement, see the module docstring).
DEFAULT_BLOB_CENTER = "weighted"

# Blob detector: the level between background and peak that delimits the blob (half max).
_BLOB_LEVEL = 0.5
# The blob's peak is read from a slightly smoothed image so one hot pixel cannot set it.
_PEAK_SMOOTHING_SIGMA_PX = 1.0
# The lobe fit uses flank pixels above this fraction of the contrast (log of small values
# is dominated by noise and quantisation).
_LOBE_FLOOR = 0.05
# Margin around the region's bounding box for the blob detector (smoothing support).
_BLOB_MARGIN_PX = 4
# A core needs this many clipped pixels before its centroid is preferred.
_MIN_CORE_PX = 3
# White-reference images are smoothed with this sigma so their noise does not enter.
_WHITE_SIGMA_PX = 3.0
# Floor of the white-reference luminance, so dark corners do not blow up.
_WHITE_FLOOR = 1e-3


@dataclass(frozen=True)
class HighlightDetection:
    """Where the highlight is in one view, or why none was found.

    Parameters
    ----------
    found : bool
        Whether a highlight was detected.
    center_uv : (2,) float64 or None
        Sub-pixel centre ``(u, v)`` in pixels (pixel centres at integers).
    area_px : int
        Number of pixels of the component the centre was computed from (0 if none).
    bbox : (int, int, int, int) or None
        ``(u0, v0, u1, v1)`` of that component, inclusive-exclusive, pixels.
    score : float
        Strength of the detection: for the blob detector the peak's linear luminance
        above the background; for the paper detector the mean gradient magnitude over
        the component divided by the mean local threshold there. 0 if nothing found.
    reason : str
        ``""`` when found, else why not, with the numbers.
    level : float
        Blob detector: the linear intensity level that delimited the blob (pass it as
        ``level`` to detect the same highlight in other views consistently); NaN for
        the paper detector and when nothing was found.
    """

    found: bool
    center_uv: np.ndarray | None
    area_px: int
    bbox: tuple[int, int, int, int] | None
    score: float
    reason: str
    level: float = float("nan")

    def __bool__(self) -> bool:
        return self.found

    @classmethod
    def missing(cls, reason: str) -> HighlightDetection:
        """Build a failed detection carrying ``reason``."""
        return cls(False, None, 0, None, 0.0, reason)


def _check_options(method, encoding, window, k, min_extent_px, blob_center, min_contrast,
                   min_area_px) -> None:
    if method not in HIGHLIGHT_METHODS:
        raise SRDEError(f"method: expected one of {list(HIGHLIGHT_METHODS)}, got {method!r}")
    if encoding not in IMAGE_ENCODINGS:
        raise SRDEError(f"encoding: expected one of {list(IMAGE_ENCODINGS)}, got {encoding!r}")
    if blob_center not in BLOB_CENTERS:
        raise SRDEError(f"blob_center: expected one of {list(BLOB_CENTERS)}, got {blob_center!r}")
    if (isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 3
            or window % 2 == 0):
        raise SRDEError(f"window: expected an odd integer >= 3 (pixels), got {window!r}")
    if not isinstance(k, (int, float, np.number)) or isinstance(k, bool) or not np.isfinite(k):
        raise SRDEError(f"k: expected a finite number, got {k!r}")
    for name, value in (("min_extent_px", min_extent_px), ("min_area_px", min_area_px)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise SRDEError(f"{name}: expected a positive integer (pixels), got {value!r}")
    if (not isinstance(min_contrast, (int, float, np.number)) or isinstance(min_contrast, bool)
            or not 0.0 <= min_contrast < 1.0):
        raise SRDEError(f"min_contrast: expected a number in [0, 1) (linear intensity), got "
                        f"{min_contrast!r}")


def detect_highlight(image, region=None, *, method: str = "blob", encoding: str = "srgb",
                     window: int = 15, k: float = 1.5, min_extent_px: int = 10,
                     blob_center: str = DEFAULT_BLOB_CENTER, min_contrast: float = 0.05,
                     min_area_px: int = 3, level: float | None = None,
                     white_reference=None) -> HighlightDetection:
    """Find the specular highlight of one view inside a search region.

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3), uint8 or float32 in [0, 1]
        One camera image.
    region : numpy.ndarray, (H, W) bool, optional
        Where to search (the object's eroded mask in the reference view). The whole
        image by default. An empty region gives a failed detection, not an error.
    method : {"blob", "paper"}
        Detector; see the module docstring.
    encoding : {"srgb", "linear"}
        How the image values encode intensity (the rig's ``image_encoding``).
    window : int
        Paper detector: side of the square window of the local gradient statistics, px.
    k : float
        Paper detector: threshold ``mu + k * sigma`` of the gradient magnitude.
    min_extent_px : int
        Paper detector: components whose bounding box is narrower or shorter than this
        are dropped (the paper's 10 x 10 px rule).
    blob_center : {"weighted", "core", "lobe"}
        Blob detector: the sub-pixel centre estimator.
    min_contrast : float
        Blob detector: the smoothed peak must exceed the region's median by this much
        (linear intensity, after white normalisation if any).
    min_area_px : int
        Blob detector: smallest blob (pixels above the level) accepted.
    level : float, optional
        Blob detector: the linear intensity that delimits the blob. By default halfway
        between the region's median and its smoothed peak. Centroids of an asymmetric
        lobe depend on the level, so views of one highlight are best measured at one
        level: pass the reference view's ``HighlightDetection.level`` to the others.
    white_reference : numpy.ndarray, (H, W) or (H, W, 3), optional
        An image of a white reference target taken by the same camera, same encoding.
        Linear intensity is divided by its smoothed luminance before detection, which
        evens out vignetting and per-camera gain (the paper normalises with reflection
        standards). Saturation is still judged on ``image``.

    Returns
    -------
    HighlightDetection
        Falsy when nothing was found; ``reason`` then says why.

    Raises
    ------
    ImageError
        ``image`` or ``white_reference`` is not a valid image, or their sizes differ.
    MaskError
        ``region`` has the wrong shape or dtype.
    SRDEError
        An option is out of range.

    References
    ----------
    Kossira et al., SRDE, Methods: "Specular Reflection Detection" (eqs. 1-4).

    Examples
    --------
    >>> import numpy as np
    >>> v, u = np.mgrid[0:40, 0:60]
    >>> blob = np.exp(-((u - 31.3) ** 2 + (v - 17.6) ** 2) / (2 * 2.0 ** 2))
    >>> det = detect_highlight((0.1 + 0.8 * blob).astype(np.float32), encoding="linear")
    >>> det.found, np.round(det.center_uv, 1).tolist()
    (True, [31.3, 17.6])
    """
    image = check_image(image)
    _check_options(method, encoding, window, k, min_extent_px, blob_center, min_contrast,
                   min_area_px)
    if level is not None and (isinstance(level, bool)
                              or not isinstance(level, (int, float, np.number))
                              or not np.isfinite(level)):
        raise SRDEError(f"level: expected a finite number (linear intensity), got {level!r}")
    shape = image.shape[:2]
    if region is None:
        region = np.ones(shape, dtype=bool)
    else:
        region = check_mask(region, shape, "region", allow_empty=True)
    if white_reference is not None:
        white_reference = check_image(white_reference, "white_reference")
        if white_reference.shape[:2] != shape:
            raise SRDEError(
                f"white_reference: expected the image's size {shape[1]}x{shape[0]}, got "
                f"{white_reference.shape[1]}x{white_reference.shape[0]}")
    return _detect(image, region, method=method, encoding=encoding, window=int(window),
                   k=float(k), min_extent_px=int(min_extent_px), blob_center=blob_center,
                   min_contrast=float(min_contrast), min_area_px=int(min_area_px),
                   level=None if level is None else float(level), white_reference=white_reference)


def _detect(image, region, *, method, encoding, window, k, min_extent_px, blob_center,
            min_contrast, min_area_px, level, white_reference) -> HighlightDetection:
    """:func:`detect_highlight` on validated input (used by SRDE without re-checking)."""
    rows = np.flatnonzero(region.any(axis=1))
    if rows.size == 0:
        return HighlightDetection.missing("search region is empty")
    cols = np.flatnonzero(region.any(axis=0))
    # Paper: G needs 1 px of Sobel support and the window statistics window // 2 more, so
    # with this margin the crop gives the same values as the full image inside the region.
    margin = window // 2 + 2 if method == "paper" else _BLOB_MARGIN_PX
    h, w = region.shape
    v0, v1 = max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, h)
    u0, u1 = max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, w)
    crop = (slice(v0, v1), slice(u0, u1))
    lum = luminance(image[crop], encoding)
    if white_reference is not None:
        white = luminance(white_reference[crop], encoding)
        white = cv2.GaussianBlur(white, (0, 0), _WHITE_SIGMA_PX, borderType=cv2.BORDER_REFLECT)
        lum = lum / np.maximum(white, _WHITE_FLOOR)
    sub_region = region[crop]
    if method == "paper":
        det = _detect_paper(lum, sub_region, window=window, k=k, min_extent_px=min_extent_px)
    else:
        # Only the core and lobe centres look at clipping.
        saturated = None if blob_center == "weighted" else saturation_mask(image[crop])
        det = _detect_blob(lum, saturated, sub_region, center=blob_center,
                           min_contrast=min_contrast, min_area_px=min_area_px, level=level)
    if not det.found:
        return det
    bu0, bv0, bu1, bv1 = det.bbox
    return HighlightDetection(True, det.center_uv + np.array([u0, v0], dtype=np.float64),
                              det.area_px, (bu0 + u0, bv0 + v0, bu1 + u0, bv1 + v0), det.score, "",
                              det.level)


def _components(binary: np.ndarray):
    """8-connected components: ``(n, labels, stats)`` as OpenCV returns them."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary.view(np.uint8), connectivity=8)
    return n, labels, stats


def _bbox(stats_row) -> tuple[int, int, int, int]:
    x, y, bw, bh = (int(s) for s in stats_row[:4])
    return (x, y, x + bw, y + bh)


def _detect_paper(lum, region, *, window, k, min_extent_px) -> HighlightDetection:
    """Adaptive gradient thresholding (paper eqs. 1-4) on a crop."""
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3)
    grad = np.sqrt(gx * gx + gy * gy)
    mean = cv2.boxFilter(grad, cv2.CV_32F, (window, window))
    mean_sq = cv2.boxFilter(grad * grad, cv2.CV_32F, (window, window))
    # E[G^2] - E[G]^2 can dip below 0 by rounding; a local std is never negative.
    std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    threshold = mean + k * std
    candidates = region & (grad > threshold)
    n, labels, stats = _components(candidates)
    if n <= 1:
        return HighlightDetection.missing(
            f"no pixel with gradient above mu + {k:g} sigma ({window}x{window} window) in the "
            f"search region of {int(region.sum())} px")
    widths, heights, areas = stats[1:, 2], stats[1:, 3], stats[1:, 4]
    keep = (widths >= min_extent_px) & (heights >= min_extent_px)
    if not keep.any():
        big = int(np.argmax(areas))
        return HighlightDetection.missing(
            f"no gradient component with extent >= {min_extent_px}x{min_extent_px} px among "
            f"{n - 1} (largest: {int(widths[big])}x{int(heights[big])} px, {int(areas[big])} px)")
    label = 1 + int(np.argmax(np.where(keep, areas, -1)))
    x, y, bw, bh = (int(s) for s in stats[label, :4])
    ring = labels[y:y + bh, x:x + bw] == label
    vv, uu = np.nonzero(ring)
    center = np.array([uu.mean() + x, vv.mean() + y], dtype=np.float64)
    box = (slice(y, y + bh), slice(x, x + bw))
    score = float(grad[box][ring].mean()) / max(float(threshold[box][ring].mean()),
                                                float(np.finfo(np.float32).tiny))
    return HighlightDetection(True, center, int(stats[label, 4]), _bbox(stats[label]), score, "")


def _detect_blob(lum, saturated, region, *, center, min_contrast, min_area_px, level
                 ) -> HighlightDetection:
    """Half-maximum blob on linear intensity and its sub-pixel centre, on a crop."""
    smooth = cv2.GaussianBlur(lum, (0, 0), _PEAK_SMOOTHING_SIGMA_PX, borderType=cv2.BORDER_REFLECT)
    inside = lum[region]
    background = float(np.median(inside))
    peak = float(smooth[region].max())
    contrast = peak - background
    if contrast < min_contrast:
        return HighlightDetection.missing(
            f"no bright blob: peak {peak:.4f} is only {contrast:.4f} above the region's median "
            f"{background:.4f} (min_contrast {min_contrast:g}, linear intensity)")
    if level is None:
        level = background + _BLOB_LEVEL * contrast
    excess = np.where(region, lum - level, 0.0).astype(np.float32)
    n, labels, stats = _components(excess > 0)
    if n <= 1:  # smoothing can lift a lone spike's surroundings above every raw pixel
        return HighlightDetection.missing(
            f"no pixel above the level {level:.4f} in the search region")
    light = np.bincount(labels.ravel(), weights=np.maximum(excess, 0.0).ravel(), minlength=n)
    label = 1 + int(np.argmax(light[1:]))
    area = int(stats[label, 4])
    if area < min_area_px:
        return HighlightDetection.missing(
            f"brightest blob has {area} px above the level {level:.4f}, fewer than "
            f"min_area_px {min_area_px}")
    x, y, bw, bh = (int(s) for s in stats[label, :4])
    box = (slice(y, y + bh), slice(x, x + bw))
    blob = labels[box] == label
    weights = np.where(blob, excess[box], 0.0)
    center_uv = _weighted_centroid(weights) + np.array([x, y], dtype=np.float64)
    if center == "core":
        core = blob & saturated[box]
        if int(core.sum()) >= _MIN_CORE_PX:
            center_uv = _weighted_centroid(core.astype(np.float64)) + np.array([x, y], np.float64)
    elif center == "lobe":
        fitted = _lobe_center(lum, saturated, region, labels == label, background, contrast)
        if fitted is not None:
            center_uv = fitted
    return HighlightDetection(True, center_uv, area, _bbox(stats[label]), contrast, "", level)


def _weighted_centroid(weights: np.ndarray) -> np.ndarray:
    """``(u, v)`` centroid of a non-negative weight image (pixel centres at integers)."""
    total = float(weights.sum())
    vv, uu = np.indices(weights.shape, dtype=np.float64)
    return np.array([(weights * uu).sum() / total, (weights * vv).sum() / total])


def _lobe_center(lum, saturated, region, blob, background, contrast) -> np.ndarray | None:
    """Peak of a Gaussian fitted to the blob's unclipped flanks, or None if ill-posed.

    ``log(I - b)`` of a Gaussian lobe is a quadratic in (u, v); it is fitted by weighted
    least squares with weights ``(I - b)^2`` (log-domain noise scales as ``1 / (I - b)``)
    on the blob grown by its own half-width, dropping clipped pixels, whose true value is
    unknown. The peak is where the quadratic's gradient vanishes.
    """
    grow = max(2, int(np.sqrt(blob.sum() / np.pi)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    support = cv2.dilate(blob.view(np.uint8), kernel).view(bool)
    excess = lum - background
    use = support & region & ~saturated & (excess > _LOBE_FLOOR * contrast)
    vv, uu = np.nonzero(use)
    if uu.size < 6:
        return None
    u_ref, v_ref = uu.mean(), vv.mean()
    du, dv = uu - u_ref, vv - v_ref
    values = excess[vv, uu].astype(np.float64)
    design = np.stack([np.ones_like(du), du, dv, du * du, du * dv, dv * dv], axis=1)
    sqrt_w = values  # sqrt of the (I - b)^2 weights
    coef, *_ = np.linalg.lstsq(design * sqrt_w[:, None], np.log(values) * sqrt_w, rcond=None)
    hessian = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
    if np.any(np.linalg.eigvalsh(hessian) >= 0):  # not a peak
        return None
    offset = np.linalg.solve(hessian, -coef[1:3])
    center = np.array([u_ref + offset[0], v_ref + offset[1]])
    vb, ub = np.nonzero(blob)
    inside_u = ub.min() - 1 <= center[0] <= ub.max() + 1
    if not (inside_u and vb.min() - 1 <= center[1] <= vb.max() + 1):
        return None  # a fit that leaves its own blob is not to be trusted
    return center
