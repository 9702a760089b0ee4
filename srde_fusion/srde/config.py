"""The highlight detector's options and tuning constants, defined once for every backend.

Both detectors (``"blob"`` and ``"paper"``, see :mod:`~srde_fusion.srde.highlight`) and
both pixel backends (numpy/OpenCV and torch) read their settings from a
:class:`DetectorConfig` and the constants here, so a change is one edit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SRDEError
from ..imaging import IMAGE_ENCODINGS

__all__ = [
    "DetectorConfig",
    "HIGHLIGHT_METHODS",
    "BLOB_CENTERS",
    "DEFAULT_BLOB_CENTER",
    "BLOB_LEVEL",
    "CLIPPED_MEDIAN",
    "BRIGHT_REGION_QUANTILE",
    "PEAK_SMOOTHING_SIGMA_PX",
    "LOBE_FLOOR",
    "BLOB_MARGIN_PX",
    "MIN_CORE_PX",
    "MIN_BLOB_AREA_PX",
    "WHITE_SIGMA_PX",
    "WHITE_FLOOR",
]

#: Detector names accepted by :func:`~srde_fusion.srde.detect_highlight`.
HIGHLIGHT_METHODS = ("blob", "paper")
#: Sub-pixel centre estimators of the blob detector.
BLOB_CENTERS = ("weighted", "core", "lobe")
#: The blob centre used by default (chosen by measurement, ``benchmarks/srde_accuracy.py``).
DEFAULT_BLOB_CENTER = "weighted"

#: Blob detector: the level between background and peak that delimits the blob (half max).
BLOB_LEVEL = 0.5
#: A search region whose median luminance is at least this (linear, 1 = the clipping
#: level) and from which the peak does not stand out is mostly highlight: a clipped
#: blob larger than half the region (a very glossy object under a near light) ...
CLIPPED_MEDIAN = 0.9
#: ... and its background is read at this quantile of the region instead of the median.
BRIGHT_REGION_QUANTILE = 0.1
#: The blob's peak is read from a slightly smoothed image so one hot pixel cannot set it.
PEAK_SMOOTHING_SIGMA_PX = 1.0
#: The lobe fit uses flank pixels above this fraction of the contrast (the log of small
#: values is dominated by noise and quantisation).
LOBE_FLOOR = 0.05
#: Margin around the search region's bounding box for the blob detector (smoothing support).
BLOB_MARGIN_PX = 4
#: A core needs this many clipped pixels before its centroid is preferred.
MIN_CORE_PX = 3
#: Smallest blob (pixels above the level) SRDE takes for a highlight.
MIN_BLOB_AREA_PX = 3
#: White-reference images are smoothed with this sigma so their noise does not enter.
WHITE_SIGMA_PX = 3.0
#: Floor of the white-reference luminance, so dark corners do not blow up.
WHITE_FLOOR = 1e-3


def _is_int(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, np.integer))


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.number))


@dataclass(frozen=True)
class DetectorConfig:
    """How highlights are detected; validated on construction.

    Parameters
    ----------
    method : {"blob", "paper"}
        The detector.
    encoding : {"srgb", "linear"}
        How image values encode intensity (the rig's ``image_encoding``).
    window : int
        Paper detector: side of the square window of the local gradient statistics, px.
    k : float
        Paper detector: threshold ``mu + k * sigma`` of the gradient magnitude.
    min_extent_px : int
        Paper detector: components narrower or shorter than this are dropped.
    blob_center : {"weighted", "core", "lobe"}
        Blob detector: the sub-pixel centre estimator.
    min_contrast : float
        Blob detector: the smoothed peak must exceed the region's median by this much
        (linear intensity).
    min_area_px : int
        Blob detector: smallest blob (pixels above the level) accepted.

    Raises
    ------
    SRDEError
        An option out of range; the message names it.

    Examples
    --------
    >>> DetectorConfig(method="paper").margin_px
    9
    """

    method: str = "blob"
    encoding: str = "srgb"
    window: int = 15
    k: float = 1.5
    min_extent_px: int = 10
    blob_center: str = DEFAULT_BLOB_CENTER
    min_contrast: float = 0.05
    min_area_px: int = 3

    def __post_init__(self) -> None:
        if self.method not in HIGHLIGHT_METHODS:
            raise SRDEError(f"method: expected one of {list(HIGHLIGHT_METHODS)}, got "
                            f"{self.method!r}")
        if self.encoding not in IMAGE_ENCODINGS:
            raise SRDEError(f"encoding: expected one of {list(IMAGE_ENCODINGS)}, got "
                            f"{self.encoding!r}")
        if self.blob_center not in BLOB_CENTERS:
            raise SRDEError(f"blob_center: expected one of {list(BLOB_CENTERS)}, got "
                            f"{self.blob_center!r}")
        if not _is_int(self.window) or self.window < 3 or self.window % 2 == 0:
            raise SRDEError(f"window: expected an odd integer >= 3 (pixels), got {self.window!r}")
        if not _is_number(self.k) or not np.isfinite(self.k):
            raise SRDEError(f"k: expected a finite number, got {self.k!r}")
        for name in ("min_extent_px", "min_area_px"):
            value = getattr(self, name)
            if not _is_int(value) or value < 1:
                raise SRDEError(f"{name}: expected a positive integer (pixels), got {value!r}")
        if not _is_number(self.min_contrast) or not 0.0 <= self.min_contrast < 1.0:
            raise SRDEError(f"min_contrast: expected a number in [0, 1) (linear intensity), got "
                            f"{self.min_contrast!r}")
        # Normalise numpy scalars to plain Python numbers (hashable, printable).
        for name, kind in (("window", int), ("k", float), ("min_extent_px", int),
                           ("min_contrast", float), ("min_area_px", int)):
            object.__setattr__(self, name, kind(getattr(self, name)))

    @property
    def margin_px(self) -> int:
        """Pixels around a search region's bounding box that the filters read.

        The paper detector's gradient needs 1 px of Sobel support and the window
        statistics ``window // 2`` more; the blob detector its peak smoothing.
        """
        return self.window // 2 + 2 if self.method == "paper" else BLOB_MARGIN_PX
