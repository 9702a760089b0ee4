"""Photometric refinement of an SRDE plane: a lobe model fitted to every view.

:func:`refine_plane` (``plane``) fits the lobe model (``model``: the lobe families and
the closed-form intensities; ``reflection``: the shading geometry of a plane hypothesis)
to block-averaged samples around the highlights (``samples``) with Levenberg-Marquardt
(``solver``). Imports ``geometry`` and ``imaging`` only.
"""

from __future__ import annotations

from .model import DEFAULT_LOBE, LOBES, LobeFit
from .plane import PlaneRefinement, refine_plane

__all__ = [
    "LOBES",
    "DEFAULT_LOBE",
    "LobeFit",
    "PlaneRefinement",
    "refine_plane",
]
