"""SRDE: a flat glossy object's plane and disparity from its specular highlight.

Owns highlight detection, the search for the highlight in every view, the
virtual-light triangulation and the photometric refinement (:mod:`.refine`). Imports
``geometry`` and ``imaging``; torch is imported only by the batched backend.
"""

from __future__ import annotations

from .estimator import (
    SRDE,
    SRDE_METHODS,
    SRDE_STATUSES,
    SRDEResult,
)
from .highlight import (
    BLOB_CENTERS,
    DEFAULT_BLOB_CENTER,
    HIGHLIGHT_METHODS,
    HighlightDetection,
    detect_highlight,
)
from .refine import PlaneRefinement, refine_plane


def __getattr__(name: str):
    # torch is imported only when the batched estimator is asked for.
    if name == "BatchedSRDE":
        from .batched import BatchedSRDE

        return BatchedSRDE
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BatchedSRDE",
    "PlaneRefinement",
    "refine_plane",
    "SRDE",
    "SRDEResult",
    "SRDE_METHODS",
    "SRDE_STATUSES",
    "HighlightDetection",
    "detect_highlight",
    "HIGHLIGHT_METHODS",
    "BLOB_CENTERS",
    "DEFAULT_BLOB_CENTER",
]
