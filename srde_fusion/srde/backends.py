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

__all__ = ["DetectionRequest", "HighlightBackend", "NumpyBackend"]


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
    """

    view: int
    region: np.ndarray
    level: float | None = None


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

    def prepare(self, views: Any) -> Views:
        """Validate the views (no copy; a validated ``Views`` passes straight through)."""
        return check_views(views, self.rig.n_cameras, self.rig.image_size)

    def detect(self, frame: Views, requests: Sequence[DetectionRequest]
               ) -> list[HighlightDetection]:
        """Detect the highlight for each request (see :func:`detect_in_view`)."""
        whites = self.white_references
        return [detect_in_view(frame[r.view], r.region, self.config, level=r.level,
                               white_reference=None if whites is None else whites[r.view])
                for r in requests]

    def brightest(self, frame: Views, searches: Sequence[tuple[int, Candidates]]) -> list[int]:
        """Brightest candidate of each view: luminance smoothed at the blob's scale."""
        best = []
        for j, cand in searches:
            (u0, v0), (u1, v1) = cand.lo, cand.hi
            lum = luminance(frame[j][v0:v1, u0:u1], self.config.encoding)
            lum = cv2.GaussianBlur(lum, (0, 0), cand.sigma_px, borderType=cv2.BORDER_REFLECT)
            brightness = np.full(cand.w_v.size, -np.inf)
            brightness[cand.ok] = lum[cand.pix[cand.ok, 1] - v0, cand.pix[cand.ok, 0] - u0]
            best.append(int(np.argmax(brightness)))
        return best
