"""Fusion: SRDE's disparity inside each object, the backbone's everywhere else.

Owns the per-object decision, its checks and the pipeline wrappers. Imports
``srde``, ``masks``, ``geometry`` and ``imaging``; never a backbone adapter.
"""

from __future__ import annotations

from .checks import (
    DEFAULT_BORDER_CHECK,
    BorderCheck,
    border_band,
    textured_mask,
)
from .estimate import (
    ObjectEstimate,
    PlaneEstimator,
    read_estimate,
)
from .fuse import (
    fuse,
)
from .lamps import (
    LampTally,
)
from .pipeline import (
    HybridStereo,
    postprocess,
)
from .report import (
    SOURCE_BACKBONE,
    FusionResult,
    ObjectReport,
)
from .stream import (
    FrameTiming,
    FusionStream,
    StreamStats,
)

__all__ = [
    "border_band",
    "textured_mask",
    "BorderCheck",
    "DEFAULT_BORDER_CHECK",
    "PlaneEstimator",
    "ObjectEstimate",
    "read_estimate",
    "fuse",
    "postprocess",
    "HybridStereo",
    "ObjectReport",
    "FusionResult",
    "SOURCE_BACKBONE",
    "FusionStream",
    "StreamStats",
    "FrameTiming",
    "LampTally",
]
