"""Mask stages: which reference-view pixels belong to which reflective object.

Owns user-given masks, the built-in highlight segmenter and ONNX segmentation models.
Imports ``srde`` (the detector and triangulation), ``io`` and ``geometry``.
"""

from __future__ import annotations

from .resolve import MASK_SOURCES, MaskerChoice, resolve_masker
from .stages import (
    HighlightSegmenter,
    Masker,
    OnnxMasker,
    SegmenterDiagnostics,
    UserMasks,
)

__all__ = [
    "MASK_SOURCES",
    "MaskerChoice",
    "resolve_masker",
    "Masker",
    "UserMasks",
    "HighlightSegmenter",
    "SegmenterDiagnostics",
    "OnnxMasker",
]
