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
from ..imaging import luminance, saturation_mask
from .config import (
    BLOB_LEVEL,
    BRIGHT_REGION_QUANTILE,
    CLIPPED_MEDIAN,
    DEFAULT_BLOB_CENTER,
    LOBE_FLOOR,
    MIN_CORE_PX,
    PEAK_SMOOTHING_SIGMA_PX,
    WHITE_FLOOR,
    WHITE_SIGMA_PX,
    DetectorConfig,
)

__all__ = [
    "HighlightDetection",
    "detect_highlight",
    "detect_in_view",
    "search_box",
    "grown_box",
    "blob_rejection",
    "paper_rejection",
    "components",
    "crop_luminance",
    "median",
    "region_background",
    "weighted_centroid",
    "lobe_center",
]

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

    def shifted(self, origin_uv) -> HighlightDetection:
        """Return the detection with crop coordinates moved by ``origin_uv = (u0, v0)`` px."""
        if not self.found:
            return self
        u0, v0 = (int(o) for o in origin_uv)
        bu0, bv0, bu1, bv1 = self.bbox
        return HighlightDetection(True, self.center_uv + np.array([u0, v0], dtype=np.float64),
                                  self.area_px, (bu0 + u0, bv0 + v0, bu1 + u0, bv1 + v0),
                                  self.score, "", self.level)


def blob_rejection(config: DetectorConfig, *, background: float, peak: float, level: float,
                   any_above: bool, area_px: int) -> str:
    """Why a blob-detector crop shows no highlight, or ``""`` if it shows one.

    Parameters
    ----------
    config : DetectorConfig
    background, peak : float
        The region's median and its smoothed maximum, linear intensity.
    level : float
        The level that delimits the blob, linear intensity.
    any_above : bool
        Whether any region pixel lies above the level.
    area_px : int
        Pixels of the brightest blob above the level.
    """
    contrast = peak - background
    if contrast < config.min_contrast:
        return (f"no bright blob: peak {peak:.4f} is only {contrast:.4f} above the region's "
                f"median {background:.4f} (min_contrast {config.min_contrast:g}, linear "
                f"intensity)")
    if not any_above:  # smoothing can lift a lone spike's surroundings above every raw pixel
        return f"no pixel above the level {level:.4f} in the search region"
    if area_px < config.min_area_px:
        return (f"brightest blob has {area_px} px above the level {level:.4f}, fewer than "
                f"min_area_px {config.min_area_px}")
    return ""


def paper_rejection(config: DetectorConfig, *, n_components: int, any_kept: bool,
                    region_px: int, largest: tuple[int, int, int]) -> str:
    """Why a paper-detector crop shows no highlight, or ``""`` if it shows one.

    Parameters
    ----------
    config : DetectorConfig
    n_components : int
        Components of pixels above the gradient threshold.
    any_kept : bool
        Whether any component reaches the minimum extent.
    region_px : int
        Pixels of the search region.
    largest : (int, int, int)
        Width, height and area of the largest component, pixels.
    """
    if n_components == 0:
        return (f"no pixel with gradient above mu + {config.k:g} sigma ({config.window}x"
                f"{config.window} window) in the search region of {region_px} px")
    if not any_kept:
        w, h, area = largest
        return (f"no gradient component with extent >= {config.min_extent_px}x"
                f"{config.min_extent_px} px among {n_components} (largest: {w}x{h} px, "
                f"{area} px)")
    return ""


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
    config = DetectorConfig(method=method, encoding=encoding, window=window, k=k,
                            min_extent_px=min_extent_px, blob_center=blob_center,
                            min_contrast=min_contrast, min_area_px=min_area_px)
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
    return detect_in_view(image, region, config, level=None if level is None else float(level),
                          white_reference=white_reference)


def search_box(region: np.ndarray, margin_px: int) -> tuple[int, int, int, int] | None:
    """Bounding box ``(u0, v0, u1, v1)`` of a search region grown by ``margin_px``, clipped.

    With the detector's margin (:attr:`DetectorConfig.margin_px`) the crop gives the same
    filter values as the whole image inside the region. None for an empty region.
    """
    # OpenCV's box of the non-zero pixels: one pass, no per-axis reductions.
    x, y, bw, bh = cv2.boundingRect(np.ascontiguousarray(region).view(np.uint8))
    if bw == 0:
        return None
    return grown_box((x, y, x + bw, y + bh), margin_px, region.shape)


def grown_box(bbox: tuple[int, int, int, int], margin_px: int, shape: tuple[int, int]
              ) -> tuple[int, int, int, int]:
    """Grow a bounding box ``(u0, v0, u1, v1)`` by ``margin_px``, clipped to ``shape``.

    :func:`search_box` of a region is ``grown_box`` of its bounding box.
    """
    u0, v0, u1, v1 = bbox
    h, w = shape
    return (max(u0 - margin_px, 0), max(v0 - margin_px, 0), min(u1 + margin_px, w),
            min(v1 + margin_px, h))


def detect_in_view(image: np.ndarray, region: np.ndarray, config: DetectorConfig, *,
                   level: float | None = None, white_reference: np.ndarray | None = None,
                   region_bbox: tuple[int, int, int, int] | None = None,
                   luminance_crop=None) -> HighlightDetection:
    """Detect the highlight of one validated view inside ``region`` (numpy and OpenCV).

    Only the region's bounding box plus the filters' margin is read.

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3), uint8 or float32
        A validated view.
    region : numpy.ndarray, (H, W) bool
    config : DetectorConfig
    level : float, optional
        Blob detector: the level that delimits the blob (see :func:`detect_highlight`).
    white_reference : numpy.ndarray, optional
        The camera's white image, validated, same size.
    region_bbox : (int, int, int, int), optional
        ``region``'s bounding box ``(u0, v0, u1, v1)``, inclusive-exclusive, if known;
        found from ``region`` otherwise.
    luminance_crop : ((int, int, int, int), numpy.ndarray), optional
        ``(box, lum)``: the image's linear luminance over ``box = (u0, v0, u1, v1)``,
        already computed; read where it overlaps the detection's crop instead of
        converting those pixels again (see :func:`crop_luminance`).

    Returns
    -------
    HighlightDetection
    """
    box = (search_box(region, config.margin_px) if region_bbox is None
           else grown_box(region_bbox, config.margin_px, region.shape))
    if box is None:
        return HighlightDetection.missing("search region is empty")
    u0, v0, u1, v1 = box
    crop = (slice(v0, v1), slice(u0, u1))
    lum = crop_luminance(image, box, config.encoding, luminance_crop)
    if white_reference is not None:
        white = luminance(white_reference[crop], config.encoding)
        white = cv2.GaussianBlur(white, (0, 0), WHITE_SIGMA_PX, borderType=cv2.BORDER_REFLECT)
        lum = lum / np.maximum(white, WHITE_FLOOR)
    sub_region = region[crop]
    if config.method == "paper":
        det = _detect_paper(lum, sub_region, config)
    else:
        # Only the core and lobe centres look at clipping.
        saturated = None if config.blob_center == "weighted" else saturation_mask(image[crop])
        det = _detect_blob(lum, saturated, sub_region, config, level)
    return det.shifted((u0, v0))


def crop_luminance(image: np.ndarray, box: tuple[int, int, int, int], encoding: str,
                   known=None) -> np.ndarray:
    """Linear luminance of ``image`` over ``box = (u0, v0, u1, v1)``, ``(v1 - v0, u1 - u0)``.

    ``known = (known_box, lum)``, the luminance already computed over another box, is
    read where the boxes overlap (a slice when it holds ``box``); only the rest of the
    pixels are converted. Luminance is per pixel, so the values are those of
    ``luminance(image[v0:v1, u0:u1], encoding)``.
    """
    u0, v0, u1, v1 = box
    if known is None:
        return luminance(image[v0:v1, u0:u1], encoding)
    (ku0, kv0, ku1, kv1), lum = known
    if ku0 <= u0 and kv0 <= v0 and u1 <= ku1 and v1 <= kv1:
        return lum[v0 - kv0:v1 - kv0, u0 - ku0:u1 - ku0]
    # The overlap's rows span the box's width only if it does; the rest are strips.
    ou0, ov0, ou1, ov1 = max(u0, ku0), max(v0, kv0), min(u1, ku1), min(v1, kv1)
    if ou0 >= ou1 or ov0 >= ov1 or 2 * (ou1 - ou0) * (ov1 - ov0) < (u1 - u0) * (v1 - v0):
        return luminance(image[v0:v1, u0:u1], encoding)  # too little to reuse
    out = np.empty((v1 - v0, u1 - u0), dtype=np.float32)
    out[ov0 - v0:ov1 - v0, ou0 - u0:ou1 - u0] = lum[ov0 - kv0:ov1 - kv0, ou0 - ku0:ou1 - ku0]
    strips = [(u0, v0, u1, ov0), (u0, ov1, u1, v1), (u0, ov0, ou0, ov1), (ou1, ov0, u1, ov1)]
    for su0, sv0, su1, sv1 in strips:  # above, below, left, right of the overlap
        if su1 > su0 and sv1 > sv0:
            out[sv0 - v0:sv1 - v0, su0 - u0:su1 - u0] = luminance(image[sv0:sv1, su0:su1],
                                                                 encoding)
    return out


def components(binary: np.ndarray):
    """8-connected components: ``(n, labels, stats)`` as OpenCV returns them."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary.view(np.uint8), connectivity=8)
    return n, labels, stats


def bbox_of(stats_row) -> tuple[int, int, int, int]:
    x, y, bw, bh = (int(s) for s in stats_row[:4])
    return (x, y, x + bw, y + bh)


def _detect_paper(lum, region, config: DetectorConfig) -> HighlightDetection:
    """Adaptive gradient thresholding (paper eqs. 1-4) on a crop."""
    window = config.window
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3)
    grad = np.sqrt(gx * gx + gy * gy)
    mean = cv2.boxFilter(grad, cv2.CV_32F, (window, window))
    mean_sq = cv2.boxFilter(grad * grad, cv2.CV_32F, (window, window))
    # E[G^2] - E[G]^2 can dip below 0 by rounding; a local std is never negative.
    std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    threshold = mean + config.k * std
    candidates = region & (grad > threshold)
    n, labels, stats = components(candidates)
    widths, heights, areas = stats[1:, 2], stats[1:, 3], stats[1:, 4]
    keep = (widths >= config.min_extent_px) & (heights >= config.min_extent_px)
    big = int(np.argmax(areas)) if n > 1 else 0
    reason = paper_rejection(
        config, n_components=n - 1, any_kept=bool(keep.any()), region_px=int(region.sum()),
        largest=(int(widths[big]), int(heights[big]), int(areas[big])) if n > 1 else (0, 0, 0))
    if reason:
        return HighlightDetection.missing(reason)
    label = 1 + int(np.argmax(np.where(keep, areas, -1)))
    x, y, bw, bh = (int(s) for s in stats[label, :4])
    ring = labels[y:y + bh, x:x + bw] == label
    vv, uu = np.nonzero(ring)
    center = np.array([uu.mean() + x, vv.mean() + y], dtype=np.float64)
    box = (slice(y, y + bh), slice(x, x + bw))
    score = float(grad[box][ring].mean()) / max(float(threshold[box][ring].mean()),
                                                float(np.finfo(np.float32).tiny))
    return HighlightDetection(True, center, int(stats[label, 4]), bbox_of(stats[label]), score, "")


def _detect_blob(lum, saturated, region, config: DetectorConfig, level: float | None
                 ) -> HighlightDetection:
    """Half-maximum blob on linear intensity and its sub-pixel centre, on a crop."""
    smooth = cv2.GaussianBlur(lum, (0, 0), PEAK_SMOOTHING_SIGMA_PX, borderType=cv2.BORDER_REFLECT)
    background = median(lum[region])
    # The region's largest smoothed value: OpenCV's masked search, several times faster
    # than numpy's gather of the region's pixels.
    peak = float(cv2.minMaxLoc(smooth, np.ascontiguousarray(region).view(np.uint8))[1])
    contrast = peak - background
    if level is None:
        level = background + BLOB_LEVEL * contrast
    # The level in the luminance's precision: float32 ``lum - level`` is positive exactly
    # where ``lum > level``, so the blob's pixels are found without the excess image.
    level_f32 = np.float32(level)
    above = (lum > level_f32) & region
    # Components are labelled only over the box of the pixels above the level: outside
    # it there is nothing to label, and inside it raster order is the crop's.
    ax, ay, aw, ah = cv2.boundingRect(above.view(np.uint8))
    ox, oy = ax, ay  # where the labelled box sits in the crop
    above_box = np.ascontiguousarray(above[ay:ay + ah, ax:ax + aw])
    excess = lum[ay:ay + ah, ax:ax + aw] - level_f32  # read only where above_box is True
    n = 1
    if aw:
        n, labels = cv2.connectedComponents(above_box.view(np.uint8), connectivity=8)
    label = area = 0
    blob_mask = above_box  # the brightest blob's pixels over the box, once it is known
    if n == 2:
        label = 1
    elif n > 2:
        # Only pixels above the level carry light (the rest weigh 0 in label 0); summing
        # just them, in the same raster order, gives the same float sums.
        light = np.bincount(labels[above_box], weights=excess[above_box], minlength=n)
        label = 1 + int(np.argmax(light[1:]))
        blob_mask = labels == label
    if label:
        area = cv2.countNonZero(blob_mask.view(np.uint8))
    reason = blob_rejection(config, background=background, peak=peak, level=level,
                            any_above=n > 1, area_px=area)
    if reason:
        return HighlightDetection.missing(reason)
    # connectedComponentsWithStats would give the box too, at several times the cost.
    x, y, bw, bh = cv2.boundingRect(blob_mask.view(np.uint8))
    blob = blob_mask[y:y + bh, x:x + bw]
    weights = np.where(blob, excess[y:y + bh, x:x + bw], 0.0)
    x, y = x + ox, y + oy
    box = (slice(y, y + bh), slice(x, x + bw))
    center_uv = weighted_centroid(weights) + np.array([x, y], dtype=np.float64)
    if config.blob_center == "core":
        core = blob & saturated[box]
        if int(core.sum()) >= MIN_CORE_PX:
            center_uv = weighted_centroid(core.astype(np.float64)) + np.array([x, y], np.float64)
    elif config.blob_center == "lobe":
        whole = np.zeros(lum.shape, dtype=bool)
        whole[box] = blob
        fitted = lobe_center(lum, saturated, region, whole, background, contrast)
        if fitted is not None:
            center_uv = fitted
    return HighlightDetection(True, center_uv, area, (x, y, x + bw, y + bh), contrast, "",
                              level)


def median(values: np.ndarray, *, overwrite: bool = False) -> float:
    """``float(np.median(values))`` of a non-empty 1-D float array, bit for bit, faster.

    One partition instead of numpy's two-index one; for an even count the lower middle
    value is the largest of the lower half, and the two are averaged in the array's
    precision as ``np.median`` does. NaN if any value is NaN, as ``np.median``.
    ``overwrite``: partition ``values`` in place (a copy the caller no longer needs)
    instead of a copy of it.
    """
    n = values.size
    half = n // 2
    if overwrite:
        values.partition(half)
        part = values
    else:
        part = np.partition(values, half)
    upper = part[half]
    if np.isnan(part[-1]):  # partition moves NaN to the end
        return float("nan")
    if n % 2:
        return float(upper)
    lower = part[:half].max()
    return float((lower + upper) / 2)


def region_background(values: np.ndarray, peak: float, min_contrast: float) -> float:
    """Return the level a highlight must stand out from in a search region (linear).

    The region's median, unless the median is at least :data:`CLIPPED_MEDIAN` and
    ``peak`` lies less than ``min_contrast`` above it: then a clipped highlight covers
    more than half of the region (a very glossy object close to its lights fills most of
    the mask with one blob), the median is the blob's own level, and the background is
    read at the :data:`BRIGHT_REGION_QUANTILE` quantile of the region instead. A region
    that is bright all over (an overexposed object) still shows no contrast there.

    Only the several-lights candidates of the reference view use it
    (:func:`~.candidates.find_candidates` with ``object_region``), where no blob centre is
    taken for a measurement before the lobes of every light are fitted on one plane. The
    single-light detector keeps the median: its geometric plane is the blob's centre
    triangulated, and the centre of a blob that fills the object is cut by the outline
    (a scene's plane came out 22 px off, and the refinement did not recover it).

    Parameters
    ----------
    values : numpy.ndarray, (n,) float
        The region's luminance, non-empty.
    peak : float
        The region's (smoothed) maximum.
    min_contrast : float
        The detector's ``min_contrast``.
    """
    background = median(values)
    if background >= CLIPPED_MEDIAN and peak - background < min_contrast:
        background = float(np.quantile(values, BRIGHT_REGION_QUANTILE))
    return background


def weighted_centroid(weights: np.ndarray) -> np.ndarray:
    """``(u, v)`` centroid of a non-negative weight image (pixel centres at integers)."""
    total = float(weights.sum())
    h, w = weights.shape
    # Broadcast coordinates make the same products as full index grids, without them.
    uu = np.arange(w, dtype=np.float64)[None, :]
    vv = np.arange(h, dtype=np.float64)[:, None]
    return np.array([(weights * uu).sum() / total, (weights * vv).sum() / total])


def lobe_center(lum, saturated, region, blob, background, contrast) -> np.ndarray | None:
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
    use = support & region & ~saturated & (excess > LOBE_FLOOR * contrast)
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
