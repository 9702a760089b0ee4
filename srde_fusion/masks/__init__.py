"""Mask stages: which reference-view pixels belong to which reflective object.

Owns user-given masks, the built-in highlight segmenter and ONNX segmentation models.
Imports ``srde`` (the blob primitives), ``geometry`` (triangulation) and ``io``.
"""

from __future__ import annotations

from .boxed import (
    BoxedMasks,
    BoxMask,
)
from .onnx import (
    OnnxMasker,
)
from .resolve import (
    MASK_SOURCES,
    MaskerChoice,
    resolve_masker,
)
from .segmenter import (
    HighlightSegmenter,
    SegmenterDiagnostics,
)
from .user import (
    Masker,
    UserMasks,
)

__all__ = [
    "BoxedMasks",
    "BoxMask",
    "OnnxMasker",
    "MASK_SOURCES",
    "MaskerChoice",
    "resolve_masker",
    "HighlightSegmenter",
    "SegmenterDiagnostics",
    "Masker",
    "UserMasks",
]
