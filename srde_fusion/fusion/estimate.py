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
    disparity_box : numpy.ndarray, (v1 - v0, u1 - u0) float32 or None
        The object's disparity inside ``box``, pixels (NaN where it has none); None when
        the estimator gave none.
    box : (int, int, int, int)
        ``(u0, v0, u1, v1)`` of ``disparity_box``: the mask's box for SRDE, the box of the
        finite values for another estimator.
    image_shape : tuple of int
        Shape of the map the estimator returned (``(H, W)`` unless it is broken).
    plane : Plane or None
        The object's plane, if the estimator reports one.
    kept_initial_plane : bool
        The estimator's own photometric refinement ran and kept its initial plane: weak
        evidence, so fusion checks it more strictly.
    record : dict
        JSON-ready summary for the fusion report.
    result : object
        The estimator's result as it returned it.
    face_planes : tuple of Plane
        A faceted object's faces' planes (``SRDEResult.faces``), array frame; empty for
        one plane.
    face_labels_box : numpy.ndarray, (v1 - v0, u1 - u0) uint8 or None
        Over ``box``: 0 outside the mask, k on ``face_planes[k - 1]``'s part; None for
        one plane.
    """

    ok: bool
    status: str
    reason: str
    disparity_box: np.ndarray | None
    box: tuple[int, int, int, int]
    image_shape: tuple[int, ...]
    plane: Plane | None
    kept_initial_plane: bool
    record: dict = field(repr=False)
    result: Any = field(repr=False)
    face_planes: tuple[Plane, ...] = ()
    face_labels_box: np.ndarray | None = field(default=None, repr=False)

    @property
    def disparity(self) -> np.ndarray | None:
        """The full ``(H, W)`` float32 map (NaN outside ``box``), built on access; or None."""
        if self.disparity_box is None:
            return None
        out = np.full(self.image_shape, np.nan, dtype=np.float32)
        u0, v0, u1, v1 = self.box
        out[v0:v1, u0:u1] = self.disparity_box
        return out

    def window(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """Return the disparity over ``box = (u0, v0, u1, v1)``, float32, NaN elsewhere."""
        u0, v0, u1, v1 = box
        out = np.full((v1 - v0, u1 - u0), np.nan, dtype=np.float32)
        return _paste(out, self.disparity_box, self.box, box)

    def face_labels(self, box: tuple[int, int, int, int]) -> np.ndarray | None:
        """Return the face labels over ``box = (u0, v0, u1, v1)``, uint8, 0 elsewhere.

        None for an object of one plane.
        """
        if self.face_labels_box is None:
            return None
        u0, v0, u1, v1 = box
        out = np.zeros((v1 - v0, u1 - u0), dtype=np.uint8)
        return _paste(out, self.face_labels_box, self.box, box)


def _paste(out: np.ndarray, values: np.ndarray | None, values_box, box) -> np.ndarray:
    """Copy ``values`` (over ``values_box``) into ``out`` (over ``box``) where they overlap."""
    if values is None:
        return out
    u0, v0, u1, v1 = box
    a0, b0, a1, b1 = values_box
    # The overlap of the two boxes, in image coordinates.
    c0, d0, c1, d1 = max(a0, u0), max(b0, v0), min(a1, u1), min(b1, v1)
    if c1 > c0 and d1 > d0:
        out[d0 - v0:d1 - v0, c0 - u0:c1 - u0] = values[d0 - b0:d1 - b0, c0 - a0:c1 - a0]
    return out


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
        faces = result.faces.faces if result.faces is not None else ()
        # A faceted object's evidence is as weak as its weakest face's.
        refinements = [f.refinement for f in faces] or [result.refinement]
        kept = any(r is not None and not r.ok for r in refinements)
        return ObjectEstimate(
            result.ok, result.status, result.reason,
            np.asarray(result.disparity_box, np.float32), tuple(result.box),
            tuple(result.image_shape), result.plane, kept, result.to_dict(), result,
            tuple(f.plane for f in faces),
            None if result.faces is None else np.asarray(result.faces.labels_box, np.uint8))
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
    crop, box, shape = None, (0, 0, 0, 0), ()
    if disparity is not None:
        full = np.asarray(disparity, dtype=np.float32)
        shape = full.shape
        # A map of the wrong shape is refused by fuse, which knows the image's.
        if full.ndim == 2:
            box, crop = _finite_box(full)
        else:
            crop = np.zeros((0, 0), np.float32)
    return ObjectEstimate(
        status == "ok", status, reason, crop, box, shape, plane,
        refinement is not None and not refinement.ok, record, result)


def _finite_box(full: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """Crop a map to the box of its finite values (a copy; empty box if none)."""
    finite = np.isfinite(full)
    rows = np.flatnonzero(finite.any(axis=1))
    cols = np.flatnonzero(finite.any(axis=0))
    if rows.size == 0:
        return (0, 0, 0, 0), np.zeros((0, 0), np.float32)
    v0, v1, u0, u1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return (u0, v0, u1, v1), full[v0:v1, u0:u1].copy()
