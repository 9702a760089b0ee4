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

__all__ = ["DetectionRequest", "HighlightBackend", "HostFrame", "NumpyBackend", "block_means",
           "gaussian_ksize", "smooth_at"]


#: From this smoothing scale on, the brightness search smooths a reduced image: the
#: kernel is then wide enough that block means lose nothing it would keep.
REDUCED_SMOOTHING_SIGMA_PX = 6.0


def gaussian_ksize(sigma: float) -> int:
    """OpenCV's Gaussian kernel size for float images: ``round(8 sigma + 1)``, made odd."""
    return int(round(sigma * 8 + 1)) | 1


def smooth_at(lum: np.ndarray, points_uv: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian smoothing of an image at the blob's scale, read at some of its pixels.

    Below :data:`REDUCED_SMOOTHING_SIGMA_PX` this is OpenCV's ``GaussianBlur`` (reflected
    borders) read at the points. Above it the blur's cost would grow with the kernel
    (``8 sigma + 1`` taps per pixel: a large clipped highlight costs tens of
    milliseconds per view), so the image is first reduced by a power of two ``f`` to
    block means, blurred there with what remains of the Gaussian (a block mean has
    variance ``(f^2 - 1) / 12``), and read bilinearly at the points: a cost of about one
    read of the image, whatever the blob's size. The two agree to a small part of the
    smoothed values' spread, and the search only ranks candidates by them.

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
    u, v = points_uv[:, 0], points_uv[:, 1]
    if sigma_px < REDUCED_SMOOTHING_SIGMA_PX:
        smooth = cv2.GaussianBlur(lum, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
        return smooth[v, u]
    factor = 2 ** int(math.floor(math.log2(sigma_px / 3.0)))
    h, w = lum.shape
    rows, cols = -(-h // factor), -(-w // factor)
    padded = cv2.copyMakeBorder(lum, 0, rows * factor - h, 0, cols * factor - w,
                                cv2.BORDER_REFLECT)
    small = block_means(padded, factor)
    residual = math.sqrt(sigma_px ** 2 - (factor ** 2 - 1) / 12.0) / factor
    small = cv2.GaussianBlur(small, (0, 0), residual, borderType=cv2.BORDER_REFLECT)
    # Pixel centre u of the image sits at (u + 0.5) / f - 0.5 on the reduced one.
    map_u = ((u + 0.5) / factor - 0.5).astype(np.float32)[None, :]
    map_v = ((v + 0.5) / factor - 0.5).astype(np.float32)[None, :]
    return cv2.remap(small, map_u, map_v, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REFLECT)[0]


# numpy sums up to this many contiguous float32 values with 8 running partial sums; longer
# runs are split in halves first (its pairwise summation), which block_means does not mimic.
_PAIRWISE_BLOCK = 128


def block_means(image: np.ndarray, factor: int) -> np.ndarray:
    """Means of the ``factor x factor`` blocks of an image, ``(h / f, w / f)`` float32.

    The same sums in the same order as
    ``image.reshape(h // f, f, w // f, f).mean(axis=(1, 3), dtype=np.float32)``: each
    block row's ``f`` values summed as numpy sums a contiguous run (one after the other
    below 8, else in 8 running partial sums added as a tree), then the ``f`` row sums
    one after the other, then divided by ``f * f``. numpy's own reduction over two
    non-adjacent axes runs a loop per ``f`` values; here each step is one operation on
    a strided view of the whole image.

    Parameters
    ----------
    image : numpy.ndarray, (h, w) float32
        ``h`` and ``w`` multiples of ``factor``.
    factor : int
        Block side, pixels (a power of two).

    Returns
    -------
    numpy.ndarray, (h // factor, w // factor) float32
    """
    h, w = image.shape
    rows, cols = h // factor, w // factor
    if (factor < 2 or factor > _PAIRWISE_BLOCK or factor & (factor - 1)
            or rows < 2 or cols < 2):  # numpy orders these sums differently: let it
        return image.reshape(rows, factor, cols, factor).mean(axis=(1, 3), dtype=np.float32)
    runs = image.reshape(h, cols, factor)
    if factor < 8:
        row_sums = runs[..., 0] + runs[..., 1]
        for i in range(2, factor):
            row_sums += runs[..., i]
    else:
        eights = runs.reshape(h, cols, factor // 8, 8)
        partial = eights[:, :, 0]                                         # (h, cols, 8)
        if factor > 8:
            partial = partial + eights[:, :, 1]
            for i in range(2, factor // 8):
                partial += eights[:, :, i]
        pairs = partial[..., 0::2] + partial[..., 1::2]
        quads = pairs[..., 0::2] + pairs[..., 1::2]
        row_sums = quads[..., 0] + quads[..., 1]
    # A reduction over a middle axis adds the rows one after the other, as numpy's does.
    total = row_sums.reshape(rows, factor, cols).sum(axis=1, dtype=np.float32)
    total /= np.float32(factor * factor)
    return total


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
    brightness search computes and the detection in the same view then reads instead
    of converting the pixels again. A frame lives for one estimate.
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

        The smoothing is evaluated at the candidates only (:func:`smooth_at`).
        """
        best = []
        known = getattr(frame, "luminance_crops", None)
        for j, cand in searches:
            (u0, v0), (u1, v1) = cand.lo, cand.hi
            lum = luminance(frame[j][v0:v1, u0:u1], self.config.encoding)
            if known is not None:
                known[j] = ((u0, v0, u1, v1), lum)
            brightness = np.full(cand.w_v.size, -np.inf)
            brightness[cand.ok] = smooth_at(lum, cand.pix[cand.ok] - np.array([u0, v0]),
                                            cand.sigma_px)
            best.append(int(np.argmax(brightness)))
        return best
