"""What fusion reports: the fused map, where each pixel came from, and why."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._json import json_safe
from .estimate import ObjectEstimate

__all__ = [
    "ObjectReport",
    "FusionResult",
    "SOURCE_BACKBONE",
]

#: Value of :attr:`FusionResult.source` where the backbone's disparity is kept.
SOURCE_BACKBONE = 0


@dataclass(frozen=True)
class ObjectReport:
    """What happened to one object during fusion.

    Attributes
    ----------
    index : int
        The object's number k (1-based); its pixels carry ``k`` in the source map when
        SRDE was used.
    status : {"srde", "fallback"}
        Whether SRDE's disparity replaced the backbone's inside the mask.
    reason : str
        Why, in words with the numbers behind the decision.
    estimate : ObjectEstimate
        The estimator's result for this object as fusion read it; ``srde`` is the
        result itself (an ``SRDEResult`` with plane, virtual light, highlight centres).
    pixel_count : int
        Pixels in the object's mask.
    replaced_px : int
        Pixels whose disparity now comes from SRDE (0 on fallback).
    border_px : int
        Band pixels the check used (0 when it did not run).
    border_ratio_low, border_ratio_high : float
        The tested low and high quantiles of ``backbone / srde`` over the band (NaN when
        the check did not run).
    border_median_diff_px : float
        Median of ``srde - backbone`` over the band, pixels (NaN when not run); for
        information, not used in the decision.
    trimmed_px : int
        Mask pixels found not to belong to the object (textured, contradicting SRDE,
        better explained by the backbone, connected to the mask's edge); they keep the
        backbone's disparity.
    photo_px : int
        Ring pixels the photometric check used (0 when it did not run).
    photo_cost_srde, photo_cost_backbone : float
        Mean photometric cost on the ring with SRDE's and with the backbone's disparity,
        grey values in [0, 1] (NaN when the check did not run).
    """

    index: int
    status: str
    reason: str
    estimate: ObjectEstimate
    pixel_count: int
    replaced_px: int
    border_px: int = 0
    border_ratio_low: float = math.nan
    border_ratio_high: float = math.nan
    border_median_diff_px: float = math.nan
    trimmed_px: int = 0
    photo_px: int = 0
    photo_cost_srde: float = math.nan
    photo_cost_backbone: float = math.nan

    @property
    def srde(self) -> Any:
        """The estimator's result as it returned it (an ``SRDEResult`` for SRDE)."""
        return self.estimate.result

    @property
    def used_srde(self) -> bool:
        """True when SRDE's disparity was used for this object."""
        return self.status == "srde"

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable summary (NaN becomes None)."""
        return {
            "index": self.index,
            "status": self.status,
            "reason": self.reason,
            "pixel_count": self.pixel_count,
            "replaced_px": self.replaced_px,
            "border": {
                "px": self.border_px,
                "ratio_low": json_safe(self.border_ratio_low),
                "ratio_high": json_safe(self.border_ratio_high),
                "median_diff_px": json_safe(self.border_median_diff_px),
            },
            "trimmed_px": self.trimmed_px,
            "photo": {
                "px": self.photo_px,
                "cost_srde": json_safe(self.photo_cost_srde),
                "cost_backbone": json_safe(self.photo_cost_backbone),
            },
            "srde": self.estimate.record,
        }


@dataclass(frozen=True)
class FusionResult:
    """The fused disparity map and where each pixel came from.

    Attributes
    ----------
    disparity : numpy.ndarray, (H, W), float32, pixels
        Fused stereo-pair disparity; NaN where neither source is valid.
    source : numpy.ndarray, (H, W), int32
        0 where the backbone's value is kept, ``k`` where object ``k``'s SRDE plane is used.
    objects : tuple of ObjectReport
        One report per object, in mask order.
    backbone_disparity : numpy.ndarray, (H, W), float32, pixels
        The backbone's map as fused (non-finite and negative values turned into NaN).
    """

    disparity: np.ndarray
    source: np.ndarray
    objects: tuple[ObjectReport, ...]
    backbone_disparity: np.ndarray = field(repr=False)

    @property
    def srde_disparity(self) -> np.ndarray:
        """SRDE alone: every object's SRDE disparity, fallbacks included, NaN elsewhere.

        Returns
        -------
        numpy.ndarray, (H, W), float32, pixels
        """
        out = np.full(self.disparity.shape, np.nan, dtype=np.float32)
        for obj in self.objects:
            srde_disp = obj.estimate.disparity_box
            if srde_disp is None or obj.estimate.image_shape != out.shape:
                continue
            u0, v0, u1, v1 = obj.estimate.box
            part = out[v0:v1, u0:u1]
            fill = np.isfinite(srde_disp) & np.isnan(part)
            part[fill] = srde_disp[fill]
        return out

    def report(self) -> dict[str, Any]:
        """Return a JSON-serialisable summary of the fusion."""
        valid = np.isfinite(self.disparity)
        return {
            "image_size": [int(self.disparity.shape[1]), int(self.disparity.shape[0])],
            "n_objects": len(self.objects),
            "n_srde": sum(o.status == "srde" for o in self.objects),
            "n_fallback": sum(o.status == "fallback" for o in self.objects),
            "pixels_from_srde": int(np.count_nonzero(self.source != SOURCE_BACKBONE)),
            "pixels_from_backbone": int(np.count_nonzero(valid & (self.source == SOURCE_BACKBONE))),
            "invalid_px": int(np.count_nonzero(~valid)),
            "objects": [o.to_dict() for o in self.objects],
        }
