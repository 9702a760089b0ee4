"""Fusion: SRDE's disparity inside each object, the backbone's everywhere else.

Owns the per-object decision, its checks and the pipeline wrappers. Imports
``srde``, ``masks``, ``geometry`` and ``imaging``; never a backbone adapter.
"""

from __future__ import annotations

from .fuse import (
    DEFAULT_BORDER_CHECK,
    SOURCE_BACKBONE,
    BorderCheck,
    FusionResult,
    HybridStereo,
    ObjectReport,
    fuse,
    postprocess,
)

__all__ = [
    "BorderCheck",
    "ObjectReport",
    "FusionResult",
    "fuse",
    "postprocess",
    "HybridStereo",
    "SOURCE_BACKBONE",
    "DEFAULT_BORDER_CHECK",
]
