"""Detector backends: where the pixel work of highlight detection runs.

SRDE's steps that read pixels -- the brightness search along each baseline and the
highlight detection in a search region -- go through a :class:`HighlightBackend`. The
algorithm, its options (:class:`~srde_fusion.srde.config.DetectorConfig`) and its accept
and reject rules (:func:`~srde_fusion.srde.highlight.blob_rejection`,
:func:`~srde_fusion.srde.highlight.paper_rejection`) are the same for every backend;
backends differ in where the arrays live. :class:`NumpyBackend` runs OpenCV on host
arrays, one view at a time; the torch backend
(:class:`~srde_fusion.srde.torch_backend.TorchBackend`) batches the views on a device.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np

from .._checks import Views, check_views
from ..geometry import CameraRig
from ..imaging import luminance
from .config import DetectorConfig
from .highlight import HighlightDetection, detect_in_view
from .search import Candidates

__all__ = ["DetectionRequest", "HighlightBackend", "HostFrame", "NumpyBackend", "gaussian_ksize",
           "sample_grid", "smooth_at", "smooth_samples_at"]


#: From this smoothing scale on, the brightness search reads a grid of the pixels
#: (:func:`sample_grid`): the kernel is then wide enough that the grid loses nothing it
#: would keep.
REDUCED_SMOOTHING_SIGMA_PX = 6.0


def gaussian_ksize(sigma: float) -> int:
    """OpenCV's Gaussian kernel size for float images: ``round(8 sigma + 1)``, made odd."""
    return int(round(sigma * 8 + 1)) | 1


def smooth_at(lum: np.ndarray, points_uv: np.ndarray, sigma_px: float) -> np.ndarray:
    """OpenCV's Gaussian blur of an image (reflected borders), read at some of its pixels.

    The brightness search's smoothing below :data:`REDUCED_SMOOTHING_SIGMA_PX`; above
    it the search reads a grid of the pixels instead (:func:`sample_grid`,
    :func:`smooth_samples_at`).

    Parameters
    ----------
    lum : numpy.ndarray, (h, w) float32
    points_uv : numpy.ndarray, (n, 2) int
        Pixels ``(u, v)`` of ``lum``.
    sigma_px : float
        Standard deviation of the Gaussian, pixels.

    Returns
    -------
    numpy.ndarray, (n,) float32
    """
    smooth = cv2.GaussianBlur(lum, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    return smooth[points_uv[:, 1], points_uv[:, 0]]


def sample_grid(box: tuple[int, int, int, int], sigma_px: float
                ) -> tuple[slice, slice, int] | None:
    """Return the pixels of a box the brightness search reads to smooth at ``sigma_px``.

    From :data:`REDUCED_SMOOTHING_SIGMA_PX` on, the search ranks its candidates by the
    luminance smoothed at the reference blob's scale, and a Gaussian that wide is
    integrated as well by one pixel in every ``step x step`` block: ``step`` is the
    power of two at most ``sigma_px / 3``, so at least three samples per sigma. The box
    (candidates plus three sigmas around them) is then read at ``1 / step^2`` of its
    pixels: a large clipped highlight costs about what a small one does, instead of a
    colour conversion and ``8 sigma + 1`` taps per pixel of a crop that grows with it.

    Parameters
    ----------
    box : (int, int, int, int)
        ``(u0, v0, u1, v1)``, inclusive-exclusive, pixels.
    sigma_px : float

    Returns
    -------
    (rows, cols, step) or None
        Slices of the image (every ``step``-th row and column from ``step // 2`` into
        the box), and the step; None below the reduced scale or when the grid would
        have fewer than two rows or columns (the search then smooths every pixel).
    """
    if sigma_px < REDUCED_SMOOTHING_SIGMA_PX:
        return None
    step = 2 ** int(math.floor(math.log2(sigma_px / 3.0)))
    u0, v0, u1, v1 = box
    offset = step // 2
    if min(u1 - u0, v1 - v0) < offset + step + 1:
        return None
    return slice(v0 + offset, v1, step), slice(u0 + offset, u1, step), step


def smooth_samples_at(samples: np.ndarray, grid: tuple[slice, slice, int],
                      points_uv: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing of a grid of pixel samples, read at some pixels of the image.

    Parameters
    ----------
    samples : numpy.ndarray, (rows, cols) float32
        Luminance at the pixels of ``grid``.
    grid : (slice, slice, int)
        The grid's rows, columns and spacing, pixels (:func:`sample_grid`).
    points_uv : numpy.ndarray, (n, 2) int
        Image pixels ``(u, v)``, read bilinearly between the samples.
    sigma_px : float
        Standard deviation of the Gaussian, image pixels.

    Returns
    -------
    numpy.ndarray, (n,) float32
    """
    rows, cols, step = grid
    smooth = cv2.GaussianBlur(samples, (0, 0), sigma_px / step, borderType=cv2.BORDER_REFLECT)
    # image pixel u sits at (u - first sample's u) / step on the grid
    map_u = ((points_uv[:, 0] - cols.start) / step).astype(np.float32)[None, :]
    map_v = ((points_uv[:, 1] - rows.start) / step).astype(np.float32)[None, :]
    return cv2.remap(smooth, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)[0]


@dataclass(frozen=True)
class DetectionRequest:
    """Detect the highlight of view ``view`` inside ``region``.

    Attributes
    ----------
    view : int
        Camera index.
    region : numpy.ndarray, (H, W) bool
        Where to search; not empty.
    level : float or None
        Blob detector: the linear intensity that delimits the blob (the reference
        view's, so that every view of one highlight is measured at one level).
    bbox : (int, int, int, int) or None
        The region's bounding box ``(u0, v0, u1, v1)``, inclusive-exclusive, pixels, when
        the caller knows it (backends then skip finding it); None to let them find it.
    """

    view: int
    region: np.ndarray
    level: float | None = None
    bbox: tuple[int, int, int, int] | None = None


class HighlightBackend(Protocol):
    """The pixel work of SRDE's highlight detection, on some kind of array."""

    def prepare(self, views: Any) -> Sequence[np.ndarray]:
        """Validate a frame's views and hold them as this backend reads them.

        The returned sequence indexes host ``numpy`` images (what the photometric
        refinement reads).
        """

    def detect(self, frame: Sequence[np.ndarray], requests: Sequence[DetectionRequest]
               ) -> list[HighlightDetection]:
        """Detect the highlight for each request, in order."""

    def brightest(self, frame: Sequence[np.ndarray],
                  searches: Sequence[tuple[int, Candidates]]) -> list[int]:
        """Return, for each ``(view, candidates)``, the index of its brightest candidate."""


class HostFrame(Views):
    """One frame's validated views, and the luminance crops computed from them so far.

    ``luminance_crops`` maps a view to ``((u0, v0, u1, v1), lum)``: its linear luminance
    over that box (:func:`~srde_fusion.imaging.luminance`, float32), which the
    brightness search computes when it smooths every pixel of its crop (not when it
    reads a grid of them, :func:`sample_grid`) and the detection in the same view then
    reads instead of converting the pixels again. A frame lives for one estimate.
    """

    def __init__(self, views) -> None:
        self.luminance_crops: dict[int, tuple[tuple[int, int, int, int], np.ndarray]] = {}


class NumpyBackend:
    """Highlight detection with numpy and OpenCV on host images, one view at a time.

    Parameters
    ----------
    rig : CameraRig
    config : DetectorConfig
    white_references : Views, optional
        Validated white-reference images, one per camera.
    """

    def __init__(self, rig: CameraRig, config: DetectorConfig,
                 white_references: Views | None = None) -> None:
        self.rig = rig
        self.config = config
        self.white_references = white_references

    def prepare(self, views: Any) -> HostFrame:
        """Validate the views (no copy of the images; a validated ``Views`` is not re-read)."""
        return HostFrame(check_views(views, self.rig.n_cameras, self.rig.image_size))

    def detect(self, frame: Views, requests: Sequence[DetectionRequest]
               ) -> list[HighlightDetection]:
        """Detect the highlight for each request (see :func:`detect_in_view`).

        A view whose luminance the brightness search of this frame computed over a box
        holding the detection's crop is not converted again.
        """
        whites = self.white_references
        known = getattr(frame, "luminance_crops", {})
        return [detect_in_view(frame[r.view], r.region, self.config, level=r.level,
                               white_reference=None if whites is None else whites[r.view],
                               region_bbox=r.bbox, luminance_crop=known.get(r.view))
                for r in requests]

    def brightest(self, frame: Views, searches: Sequence[tuple[int, Candidates]]) -> list[int]:
        """Brightest candidate of each view: luminance smoothed at the blob's scale.

        The smoothing is evaluated at the candidates only: on every pixel of their crop
        (:func:`smooth_at`, the luminance kept for the frame's detection), or, for a large
        blob, on a grid of its pixels (:func:`sample_grid`).
        """
        best = []
        known = getattr(frame, "luminance_crops", None)
        encoding = self.config.encoding
        for j, cand in searches:
            (u0, v0), (u1, v1) = cand.lo, cand.hi
            points = cand.pix[cand.ok]
            grid = sample_grid((u0, v0, u1, v1), cand.sigma_px)
            brightness = np.full(cand.w_v.size, -np.inf)
            if grid is None:
                lum = luminance(frame[j][v0:v1, u0:u1], encoding)
                if known is not None:
                    known[j] = ((u0, v0, u1, v1), lum)
                brightness[cand.ok] = smooth_at(lum, points - np.array([u0, v0]), cand.sigma_px)
            else:
                rows, cols, _ = grid
                samples = luminance(np.ascontiguousarray(frame[j][rows, cols]), encoding)
                brightness[cand.ok] = smooth_samples_at(samples, grid, points, cand.sigma_px)
            best.append(int(np.argmax(brightness)))
        return best
