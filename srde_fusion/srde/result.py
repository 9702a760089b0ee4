"""What one SRDE estimate returns: the disparity, the plane, and what happened on the way.

A geometric failure is a result with a ``status`` and a ``reason`` naming the step, the
view and the numbers, never an exception (DESIGN §2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._json import json_safe
from ..geometry import (
    Plane,
)
from .assignment import LightsSolution
from .highlight import HighlightDetection
from .refine import PlaneRefinement

if TYPE_CHECKING:
    from .faces import Faces

__all__ = [
    "SRDEResult",
    "SRDE_STATUSES",
]

#: Every ``status`` an :class:`SRDEResult` can carry.
SRDE_STATUSES = (
    "ok",
    "mask_too_small",    # the eroded mask (or the given region) leaves nothing to search
    "no_highlight",      # the reference view, or too many views, show no highlight
    "inconsistent",      # the centres do not fit one 3D point; or cameras behind the plane
    "too_few_views",     # fewer agreeing views than min_views
    "at_infinity",       # V's image barely moves across the rig (delta ~ 0)
    "behind_cameras",    # V triangulates behind the cameras
    "light_on_plane",    # V ~ L: the light lies (nearly) on the plane, the normal is undefined
    "light_behind_plane",  # L on the far side of the plane from the cameras
    "grazing",           # some mask pixel rays meet the plane (nearly) edge-on, or behind
    "ambiguous",         # several lights: two different planes explain the highlights alike
    "face_split",        # faces: the faces' planes do not split the mask as their highlights say
)


@dataclass(frozen=True)
class SRDEResult:
    """The outcome of one SRDE estimate.

    Parameters
    ----------
    status : str
        ``"ok"`` or a failure code from :data:`SRDE_STATUSES`.
    reason : str
        ``""`` if ok; else the failed step, the view(s) and the numbers.
    disparity_box : (v1 - v0, u1 - u0) float32
        Reference-camera disparity of the stereo pair inside ``box``, pixels; NaN outside
        the mask. Kept to the object's box so that many objects of a large image do not
        each hold a full-image map; :attr:`disparity` is the full map.
    box : (int, int, int, int)
        ``(u0, v0, u1, v1)`` of ``disparity_box`` in the image, inclusive-exclusive (the
        mask's bounding box; empty if the estimate failed).
    image_shape : (int, int)
        ``(H, W)`` of the image.
    plane : Plane or None
        The object's plane in the array frame.
    virtual_light_m : (3,) float64 or None
        The triangulated virtual light, array frame, metres.
    highlight_centers : (N, 2) float64
        Highlight centre ``(u, v)`` per view, pixels; NaN where none was found.
    used_views : (N,) bool
        Views used in the final solve.
    residual_px : float
        RMS reprojection residual of the virtual light over the used views, pixels
        (NaN if not available).
    method : str
        ``"default"`` or ``"paper"``.
    notes : tuple of str
        What was left out of an ``ok`` result and why (views without a highlight, views
        dropped as outliers, pairs dropped by the paper method).
    detections : tuple of HighlightDetection
        The per-view detections (empty if the reference view already failed).
    refinement : PlaneRefinement or None
        The photometric refinement of the plane (default method), refined or not; None
        if it did not run. ``virtual_light_m`` is the light mirrored across the returned
        plane; ``residual_px`` stays the triangulation's.
    lights : LightsSolution or None
        With several lights: which highlight belongs to which light, the evidence, and the
        joint plane (:func:`~srde_fusion.srde.assignment.assign_lights`); None with one light.
    faces : Faces or None
        A faceted object (``SRDE(max_faces=2 or 3)``): the split rule, the faces' label map
        over ``box`` and each face's plane (:mod:`~srde_fusion.srde.faces`); ``plane`` and
        the fields above are then the largest face's, and ``disparity_box`` holds every
        face's plane on its part. None for a single plane.
    """

    status: str
    reason: str
    disparity_box: np.ndarray
    box: tuple[int, int, int, int]
    image_shape: tuple[int, int]
    plane: Plane | None
    virtual_light_m: np.ndarray | None
    highlight_centers: np.ndarray
    used_views: np.ndarray
    residual_px: float
    method: str
    notes: tuple[str, ...] = ()
    detections: tuple[HighlightDetection, ...] = field(default=(), repr=False)
    refinement: PlaneRefinement | None = field(default=None, repr=False)
    lights: LightsSolution | None = field(default=None, repr=False)
    faces: Faces | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """Whether the estimate succeeded."""
        return self.status == "ok"

    @property
    def disparity_sigma_px(self) -> float:
        """Standard error of the disparity from the images' noise, px; NaN if not refined.

        The refined plane's (:attr:`PlaneRefinement.disparity_sigma_px`, the largest over
        the object box's corners); on a faceted object, the largest of its refined faces'.
        It does not count a model that does not fit the images.
        """
        faces = () if self.faces is None else self.faces.faces
        refinements = [f.refinement for f in faces] or [self.refinement]
        sigmas = [r.disparity_sigma_px for r in refinements if r is not None and r.ok]
        return max(sigmas) if sigmas else math.nan

    @property
    def disparity(self) -> np.ndarray:
        """The disparity as a full map, ``(H, W)`` float32, pixels; NaN outside the mask.

        Built from ``disparity_box`` on every access (all NaN if the estimate failed).
        """
        out = np.full(self.image_shape, np.nan, dtype=np.float32)
        u0, v0, u1, v1 = self.box
        out[v0:v1, u0:u1] = self.disparity_box
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary (no pixel maps): status, reason, plane, virtual light, centres.

        Non-finite numbers become ``None``.
        """
        return json_safe({
            "status": self.status,
            "reason": self.reason,
            "method": self.method,
            "plane": None if self.plane is None else {
                "normal": self.plane.normal, "offset_m": self.plane.offset_m},
            "virtual_light_m": self.virtual_light_m,
            "highlight_centers_px": np.asarray(self.highlight_centers, dtype=np.float64),
            "used_views": np.asarray(self.used_views, dtype=bool).ravel(),
            "residual_px": self.residual_px,
            "disparity_sigma_px": self.disparity_sigma_px,
            **({} if self.lights is None else {"lights": self.lights.to_dict()}),
            **({} if self.faces is None else {"faces": self.faces.to_dict()}),
        })

    def __bool__(self) -> bool:
        return self.ok
