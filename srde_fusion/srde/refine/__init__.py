"""Photometric refinement of an SRDE plane: a lobe model fitted to every view.

Imports ``geometry`` and ``imaging`` only.
"""

from __future__ import annotations

from .plane import (
    DEFAULT_LOBE,
    LOBES,
    LobeFit,
    PlaneRefinement,
    refine_plane,
)

__all__ = [
    "LOBES",
    "DEFAULT_LOBE",
    "LobeFit",
    "PlaneRefinement",
    "refine_plane",
]
