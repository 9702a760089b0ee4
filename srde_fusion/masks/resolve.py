"""One answer to "which masks?": what callers say, turned into a mask stage.

The library call (``postprocess``, ``HybridStereo``), the scene commands (``fuse``,
``srde``) and the evaluation all take the same vocabulary, resolved here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import MaskError
from .segmenter import HighlightSegmenter
from .user import Masker, UserMasks

__all__ = ["MASK_SOURCES", "MaskerChoice", "resolve_masker"]

#: The named mask sources: the scene's own mask file, or the built-in segmenter.
MASK_SOURCES = ("user", "auto")

_AUTO = "auto (built-in highlight segmenter)"


@dataclass(frozen=True)
class MaskerChoice:
    """The mask stage that will run, and how a report names it.

    Attributes
    ----------
    masker : callable
        ``masker(views, rig) -> list of (H, W) bool masks``.
    description : str
        E.g. ``"user (scene mask.png)"`` or ``"auto (built-in highlight segmenter)"``.
    """

    masker: Masker
    description: str


def resolve_masker(masks: Any = None, *, scene_labels: np.ndarray | None = None,
                   where: str = "scene") -> MaskerChoice:
    """Turn a mask request into a mask stage.

    Parameters
    ----------
    masks : None, "auto", "user", path, numpy.ndarray, list of masks, or callable
        ``None``: the scene's labels if there are any, else the built-in
        :class:`~srde_fusion.masks.HighlightSegmenter`. ``"auto"``: the segmenter, even
        when the scene has labels. ``"user"``: the scene's labels, which must exist. A
        path, label array or list of masks: :class:`~srde_fusion.masks.UserMasks`. A
        callable ``masker(views, rig)`` is used as it is.
    scene_labels : numpy.ndarray, (H, W) int, optional
        The scene folder's own label image (``mask.png``), if it has one.
    where : str
        What to name in the error when ``"user"`` finds no labels (a scene folder).

    Returns
    -------
    MaskerChoice

    Raises
    ------
    MaskError
        ``"user"`` without scene labels, or masks that are not valid (as
        :class:`~srde_fusion.masks.UserMasks` says).

    Examples
    --------
    >>> resolve_masker(None).description
    'auto (built-in highlight segmenter)'
    >>> import numpy as np
    >>> resolve_masker("user", scene_labels=np.eye(3, dtype=np.uint8)).description
    'user (scene mask.png)'
    """
    if callable(masks) and not isinstance(masks, np.ndarray):
        return MaskerChoice(masks, type(masks).__name__)
    if isinstance(masks, str) and masks == "auto":
        return MaskerChoice(HighlightSegmenter(), _AUTO)
    if isinstance(masks, str) and masks == "user" and scene_labels is None:
        raise MaskError(f"{where}: expected a mask.png for --masks user, got none")
    if masks is None and scene_labels is None:
        return MaskerChoice(HighlightSegmenter(), _AUTO)
    if masks is None or (isinstance(masks, str) and masks == "user"):
        user = UserMasks(scene_labels)
        return MaskerChoice(user, "; ".join(("user (scene mask.png)", *user.notes)))
    user = UserMasks(masks)
    return MaskerChoice(user, user.describe())
