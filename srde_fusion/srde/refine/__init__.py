"""Photometric refinement of an SRDE plane: a lobe model fitted to every view.

:func:`refine_plane` (``plane``: the attempts, their verdict and the restarts) fits the
lobe model (``model``) to block-averaged luminance samples around the highlights
(``samples``) with Levenberg-Marquardt (``solver``). The model is assembled from the
shading geometry of a plane hypothesis (``reflection``), the lobe families (``lobes``),
the closed-form intensities (``intensities``) and analytic derivatives (``slopes``);
``layout`` names the entries of its parameter vector. Imports ``geometry`` and
``imaging`` (and the package's ``errors`` and ``_checks``) only.
"""

from __future__ import annotations

from .lobes import DEFAULT_LOBE, LOBES
from .model import LobeFit
from .plane import PlaneRefinement, refine_plane
from .radius import RadiusFit, refine_plane_and_radius

__all__ = [
    "LOBES",
    "DEFAULT_LOBE",
    "LobeFit",
    "PlaneRefinement",
    "RadiusFit",
    "refine_plane",
    "refine_plane_and_radius",
]
