"""Bounded memory for large images: run a model on fewer pixels than the pair has.

A stereo network's memory grows with the pixels it is fed (an earlier bundled stand-in needed
about 1.75 GB per megapixel on a CPU), so a 12 MP pair can exhaust a machine that runs
640x480 pairs with ease. Rather than fail inside the runtime, an adapter given
``max_pixels`` plans each call (:func:`plan_large_image`):

- ``"whole"``: the (padded) pair fits, run it as it is;
- ``"tiles"``: run horizontal strips of full width with overlapping rows and blend them.
  Rectified stereo matches along rows, so full-width strips keep every disparity; the
  overlap gives each strip context above and below what it contributes;
- ``"downscale"``: run the pair shrunk to fit and scale the disparity back up by the
  width ratio (also the fallback when even a thin strip of full width would not fit).

The chosen plan is returned to the adapter, logged, and kept as ``adapter.last_plan``.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np

from srde_fusion.errors import BackboneError

__all__ = ["LargeImagePlan", "plan_large_image", "run_plan", "default_max_pixels",
           "check_max_pixels", "LARGE_IMAGE_STRATEGIES", "MEMORY_FRACTION"]

logger = logging.getLogger(__name__)

Strategy = Literal["whole", "downscale", "tiles"]
LARGE_IMAGE_STRATEGIES = ("tile", "downscale")
#: Share of the machine's memory one model run may plan to use by default.
MEMORY_FRACTION = 0.5
TILE_OVERLAP_ROWS = 32  # rows shared by neighbouring strips (context, then blended)
_MIN_STRIP_ROWS = 4 * TILE_OVERLAP_ROWS  # thinner strips would be mostly overlap
_SHRINK_STEP = 0.98  # downscale search: shrink by 2 % until the padded size fits


@dataclass(frozen=True)
class LargeImagePlan:
    """How one pair is run under a pixel budget.

    Attributes
    ----------
    strategy : {"whole", "downscale", "tiles"}
    image_hw : (int, int)
        Height and width of the caller's pair.
    run_hw : (int, int)
        Height and width of what one model call sees before padding: the image, the
        downscaled image, or one strip.
    rows : tuple of (int, int)
        ``(start, stop)`` image rows of each strip (one entry unless tiled).
    max_pixels : int or None
        The budget, in model-input pixels (after padding).
    reason : str
        Why this plan, with the numbers.
    """

    strategy: Strategy
    image_hw: tuple[int, int]
    run_hw: tuple[int, int]
    rows: tuple[tuple[int, int], ...]
    max_pixels: int | None
    reason: str

    @property
    def width_scale(self) -> float:
        """Run width over image width (1 unless downscaled)."""
        return self.run_hw[1] / self.image_hw[1]


def check_max_pixels(max_pixels: Any, large_images: Any) -> tuple[int | None, str]:
    """Validate the adapters' ``max_pixels`` and ``large_images`` options."""
    if max_pixels is not None and (isinstance(max_pixels, bool)
                                   or not isinstance(max_pixels, (int, np.integer))
                                   or max_pixels < 1):
        raise BackboneError(
            f"max_pixels: expected None, 'auto' or a positive integer, got {max_pixels!r}"
        )
    if large_images not in LARGE_IMAGE_STRATEGIES:
        raise BackboneError(
            f"large_images: expected one of {', '.join(LARGE_IMAGE_STRATEGIES)}, got "
            f"{large_images!r}"
        )
    return (None if max_pixels is None else int(max_pixels)), large_images


def machine_memory_bytes() -> int | None:
    """Physical memory of this machine in bytes, or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, OSError, ValueError):
        return None


def default_max_pixels(bytes_per_px: float | None, memory_bytes: int | None = None
                       ) -> int | None:
    """Pixel budget from a per-pixel memory estimate and a memory size.

    Parameters
    ----------
    bytes_per_px : float or None
        Peak memory of one model run per input pixel; None (unknown) gives no budget.
    memory_bytes : int, optional
        Memory the run may use in full; default: this machine's physical memory.

    Returns
    -------
    int or None
        ``MEMORY_FRACTION * memory_bytes / bytes_per_px``, or None when either is unknown.

    Examples
    --------
    >>> default_max_pixels(1750.0, memory_bytes=24 * 2**30)  # 1.75 GB per MP, 24 GiB
    7362801
    """
    if bytes_per_px is None:
        return None
    memory = machine_memory_bytes() if memory_bytes is None else memory_bytes
    if memory is None:
        return None
    return int(MEMORY_FRACTION * memory / bytes_per_px)


def _padded(size: int, multiple: int) -> int:
    return size + (-size) % multiple


def plan_large_image(image_hw: tuple[int, int], max_pixels: int | None, *, multiple: int,
                     strategy: str = "tile", fixed_size: bool = False) -> LargeImagePlan:
    """Choose how to run one pair within ``max_pixels`` model-input pixels.

    Parameters
    ----------
    image_hw : (int, int)
        Height and width of the pair.
    max_pixels : int or None
        Budget in model-input pixels, padding included; None: no budget.
    multiple : int
        The model's padding multiple (sizes are counted after padding to it).
    strategy : {"tile", "downscale"}
        What to do when the pair does not fit.
    fixed_size : bool
        The model has a fixed input size: it is fed that size whatever the image, so the
        budget does not apply.

    Returns
    -------
    LargeImagePlan
    """
    h, w = image_hw
    whole = ((0, h),)
    if fixed_size:
        return LargeImagePlan("whole", image_hw, image_hw, whole, max_pixels,
                              "fixed-size model: its input size does not depend on the image")
    padded = _padded(h, multiple) * _padded(w, multiple)
    if max_pixels is None or padded <= max_pixels:
        reason = ("no pixel budget" if max_pixels is None
                  else f"{padded:,} model pixels within max_pixels {max_pixels:,}")
        return LargeImagePlan("whole", image_hw, image_hw, whole, max_pixels, reason)
    over = f"{w}x{h} ({padded:,} model pixels after padding) exceeds max_pixels {max_pixels:,}"
    if strategy == "tile":
        strip_rows = (max_pixels // _padded(w, multiple)) // multiple * multiple
        if strip_rows >= _MIN_STRIP_ROWS:
            step = strip_rows - TILE_OVERLAP_ROWS
            n_strips = max(2, math.ceil((h - TILE_OVERLAP_ROWS) / step))
            # spread the strips evenly so every overlap is at least TILE_OVERLAP_ROWS
            starts = np.linspace(0, h - strip_rows, n_strips).round().astype(int)
            rows = tuple((int(s), int(s) + strip_rows) for s in starts)
            return LargeImagePlan(
                "tiles", image_hw, (strip_rows, w), rows, max_pixels,
                f"{over}: {len(rows)} strips of {w}x{strip_rows} overlapping by at least "
                f"{TILE_OVERLAP_ROWS} rows",
            )
        over += (f"; a strip of full width needs at least {_MIN_STRIP_ROWS} rows "
                 f"({_MIN_STRIP_ROWS * _padded(w, multiple):,} pixels), so downscaled")
    scale = math.sqrt(max_pixels / padded)
    while True:
        run_h, run_w = max(1, int(h * scale)), max(1, int(w * scale))
        if _padded(run_h, multiple) * _padded(run_w, multiple) <= max_pixels or run_h == 1:
            break
        scale *= _SHRINK_STEP
    if _padded(run_h, multiple) * _padded(run_w, multiple) > max_pixels:
        raise BackboneError(
            f"max_pixels: expected a budget of at least one padded block "
            f"({multiple}x{multiple}), got {max_pixels:,}"
        )
    return LargeImagePlan(
        "downscale", image_hw, (run_h, run_w), whole, max_pixels,
        f"{over}: run at {run_w}x{run_h}, disparity scaled by {w / run_w:.3f}",
    )


def _strip_weights(start: int, stop: int, h: int) -> np.ndarray:
    """Blending weights of a strip's rows: ramps inside the overlaps, 1 at image edges."""
    rows = np.arange(start, stop, dtype=np.float32)
    up = np.ones_like(rows) if start == 0 else (rows - start + 0.5) / TILE_OVERLAP_ROWS
    down = np.ones_like(rows) if stop == h else (stop - rows - 0.5) / TILE_OVERLAP_ROWS
    return np.clip(np.minimum(up, down), 0.0, 1.0)


def run_plan(plan: LargeImagePlan, left: np.ndarray, right: np.ndarray,
             disparity: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Run ``disparity(left, right)`` as the plan says and return the full-size map.

    Parameters
    ----------
    plan : LargeImagePlan
    left, right : numpy.ndarray, (H, W, 3) float32 in [0, 1]
    disparity : callable
        The model on one (sub)pair: ``(h, w, 3), (h, w, 3) -> (h, w)`` float32 px.

    Returns
    -------
    numpy.ndarray, (H, W), float32, pixels
    """
    h, w = plan.image_hw
    if plan.strategy == "whole":
        return disparity(left, right)
    if plan.strategy == "downscale":
        run_h, run_w = plan.run_hw
        small = [cv2.resize(x, (run_w, run_h), interpolation=cv2.INTER_AREA)
                 for x in (left, right)]
        disp = disparity(*small)
        # Disparity is in run pixels: back to image pixels by the width ratio.
        disp = cv2.resize(disp, (w, h), interpolation=cv2.INTER_LINEAR)
        return (disp * np.float32(w / run_w)).astype(np.float32)
    total = np.zeros((h, w), np.float64)
    weight = np.zeros((h, w), np.float64)
    for start, stop in plan.rows:
        strip = disparity(left[start:stop], right[start:stop])
        rows_w = _strip_weights(start, stop, h)[:, None] * np.isfinite(strip)
        total[start:stop] += np.where(np.isfinite(strip), strip, 0.0) * rows_w
        weight[start:stop] += rows_w
    with np.errstate(invalid="ignore", divide="ignore"):  # 0/0 -> NaN where none is finite
        return (total / weight).astype(np.float32)


def log_plan(plan: LargeImagePlan, name: str) -> None:
    """Say, once per call that needed it, how a large pair was run."""
    if plan.strategy != "whole":
        logger.warning("%s: %s", name, plan.reason)
