"""SRDE: a flat glossy object's plane and disparity from its specular highlight.

Owns highlight detection, the search for the highlight in every view, the
virtual-light triangulation and the photometric refinement (:mod:`.refine`). Imports
``geometry`` and ``imaging``; torch is imported only when the torch backend is asked for
(``SRDE(backend="torch")``, :class:`BatchedSRDE`).
"""

from __future__ import annotations

from .backends import (
    DetectionRequest,
    HighlightBackend,
    NumpyBackend,
)
from .batched import (
    BatchedSRDE,
)
from .config import (
    BLOB_CENTERS,
    BLOB_LEVEL,
    BLOB_MARGIN_PX,
    DEFAULT_BLOB_CENTER,
    HIGHLIGHT_METHODS,
    LOBE_FLOOR,
    MIN_BLOB_AREA_PX,
    MIN_CORE_PX,
    PEAK_SMOOTHING_SIGMA_PX,
    WHITE_FLOOR,
    WHITE_SIGMA_PX,
    DetectorConfig,
)
from .estimator import (
    SRDE,
    SRDE_METHODS,
)
from .faces import (
    FaceResult,
    Faces,
)
from .highlight import (
    HighlightDetection,
    blob_rejection,
    components,
    detect_highlight,
    detect_in_view,
    lobe_center,
    paper_rejection,
    search_box,
    weighted_centroid,
)
from .refine import DEFAULT_LOBE, LOBES, LobeFit, PlaneRefinement, refine_plane
from .result import (
    SRDE_STATUSES,
    SRDEResult,
)
from .search import (
    BaselineSearch,
    Candidates,
    shifted_window,
)

__all__ = [
    "DEFAULT_LOBE",
    "LOBES",
    "LobeFit",
    "PlaneRefinement",
    "refine_plane",
    "DetectionRequest",
    "HighlightBackend",
    "NumpyBackend",
    "BatchedSRDE",
    "DetectorConfig",
    "HIGHLIGHT_METHODS",
    "BLOB_CENTERS",
    "DEFAULT_BLOB_CENTER",
    "BLOB_LEVEL",
    "PEAK_SMOOTHING_SIGMA_PX",
    "LOBE_FLOOR",
    "BLOB_MARGIN_PX",
    "MIN_CORE_PX",
    "MIN_BLOB_AREA_PX",
    "WHITE_SIGMA_PX",
    "WHITE_FLOOR",
    "SRDE",
    "SRDE_METHODS",
    "HighlightDetection",
    "detect_highlight",
    "detect_in_view",
    "search_box",
    "blob_rejection",
    "paper_rejection",
    "components",
    "weighted_centroid",
    "lobe_center",
    "SRDEResult",
    "SRDE_STATUSES",
    "Faces",
    "FaceResult",
    "Candidates",
    "BaselineSearch",
    "shifted_window",
]
