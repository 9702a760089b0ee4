"""What fusion reads of an object's plane estimate, read once per object.

:func:`~srde_fusion.fusion.fuse` takes any estimator with ``estimate(views, mask)``;
:class:`~srde_fusion.srde.SRDE` is the default. Its :class:`~srde_fusion.srde.SRDEResult`
is read field by field. Another estimator's result needs only ``status`` (``"ok"`` when
its disparity may be used) and ``disparity`` (``(H, W)`` pixels, NaN where it has no
value); ``reason``, ``plane`` and ``refinement`` are read when it has them. This module is
the one place that looks at a foreign result; the rest of fusion takes
:class:`ObjectEstimate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .._checks import Views
from .._json import json_safe
from ..geometry import Plane
from ..srde import SRDEResult

__all__ = ["PlaneEstimator", "ObjectEstimate", "read_estimate"]


class PlaneEstimator(Protocol):
    """Anything that estimates one object's disparity from the views and its mask."""

    def estimate(self, views: Views, mask: np.ndarray) -> Any:
        """Return an ``SRDEResult``, or a result with ``status`` and ``disparity``."""


@dataclass(frozen=True)
class ObjectEstimate:
    """One object's estimate as fusion uses it.

    Attributes
    ----------
    ok : bool
        Whether the estimator succeeded (``status == "ok"``).
    status, reason : str
        The estimator's outcome and why.
    disparity : numpy.ndarray, (H, W) float32 or None
        The object's disparity, pixels; None when the estimator gave none.
    plane : Plane or None
        The object's plane, if the estimator reports one.
    kept_initial_plane : bool
        The estimator's own photometric refinement ran and kept its initial plane: weak
        evidence, so fusion checks it more strictly.
    record : dict
        JSON-ready summary for the fusion report.
    result : object
        The estimator's result as it returned it.
    """

    ok: bool
    status: str
    reason: str
    disparity: np.ndarray | None
    plane: Plane | None
    kept_initial_plane: bool
    record: dict = field(repr=False)
    result: Any = field(repr=False)


def read_estimate(result: Any) -> ObjectEstimate:
    """Read an estimator's result once (see the module docstring).

    Parameters
    ----------
    result : SRDEResult or object with ``status`` and ``disparity``

    Returns
    -------
    ObjectEstimate
    """
    if isinstance(result, SRDEResult):
        refinement = result.refinement
        return ObjectEstimate(
            result.ok, result.status, result.reason,
            None if result.disparity is None else np.asarray(result.disparity, np.float32),
            result.plane, refinement is not None and not refinement.ok, result.to_dict(),
            result)
    status = str(getattr(result, "status", "unknown"))
    reason = str(getattr(result, "reason", ""))
    disparity = getattr(result, "disparity", None)
    plane = getattr(result, "plane", None)
    refinement = getattr(result, "refinement", None)
    record = json_safe({
        "status": status,
        "reason": reason,
        "method": getattr(result, "method", None),
        "plane": None if plane is None else {
            "normal": plane.normal, "offset_m": plane.offset_m},
        "virtual_light_m": None,
        "highlight_centers_px": None,
        "used_views": None,
        "residual_px": None,
    })
    return ObjectEstimate(
        status == "ok", status, reason,
        None if disparity is None else np.asarray(disparity, dtype=np.float32), plane,
        refinement is not None and not refinement.ok, record, result)
