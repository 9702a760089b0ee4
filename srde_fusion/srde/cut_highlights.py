"""Highlights cut by a straight edge: the whole highlight's centre from what is left.

A highlight that reaches the edge between two faces (or a straight stretch of the
outline) loses the part beyond it: what the camera sees is the blob up to a straight
chord. Its light-weighted centroid then lies pixels inside the part left, toward the
face's middle, and a plane proposed from such centres is pixels off the face's own. The
rest of the blob's outline is still the whole highlight's: an ellipse through it (away
from the chord) has the whole highlight's centre.

:func:`arc_center` tells a cut blob from a whole one by the ellipse: a whole blob's
outline minus a straight-looking flank gives back about the blob itself, a cut blob's
gives an ellipse that reaches well beyond the chord.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["arc_center"]

#: Contour points within this distance of a line lie on it, pixels (a binary outline
#: steps by whole pixels; its straight runs wobble by half of one).
LINE_TOLERANCE_PX = 0.75

#: A chord shorter than this is no cut (a blob's flank is straight over a few pixels).
MIN_CHORD_PX = 6.0

#: The ellipse through the arc must exceed the area inside the blob's outline by this
#: fraction (the part the chord cut off) for the blob to count as cut ... (Whole
#: highlights of faceted renders gave 0.94-1.03, cut ones mostly 1.1-2.3.)
MIN_MISSING_FRACTION = 0.08

#: ... and at most this many times the blob's area (an ellipse through a short, nearly
#: straight arc can be any size).
MAX_AREA_RATIO = 3.0

#: The arc's points must lie within this RMS distance of the ellipse, pixels.
MAX_ARC_RMS_PX = 0.75

#: Fewest arc points the ellipse is fitted to.
MIN_ARC_POINTS = 12

#: Lines tried through pairs of outline points (a fixed seed: the same blob, the same
#: answer).
_LINE_TRIES = 200


def arc_center(blob: np.ndarray) -> np.ndarray | None:
    """Return the centre of a blob cut by a straight chord, from its outline's arc.

    Parameters
    ----------
    blob : numpy.ndarray, (h, w) bool
        One highlight's pixels (those above its half-maximum level), in any crop.

    Returns
    -------
    numpy.ndarray, (2,) float64, or None
        Centre ``(u, v)`` of the ellipse through the outline away from its longest
        straight side, in the crop's pixels; None when the blob is not cut (no straight
        side bounding it, or the ellipse gives back about the blob) or the arc fits no
        ellipse.
    """
    contours, _ = cv2.findContours(blob.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    outline = max(contours, key=len)
    points = outline.reshape(-1, 2).astype(np.float64)
    if len(points) < MIN_ARC_POINTS + 2:
        return None
    signed = _bounding_chord(points)
    if signed is None:
        return None
    arc = points[np.abs(signed) > 2.0 * LINE_TOLERANCE_PX]
    if len(arc) < MIN_ARC_POINTS:
        return None
    (cu, cv), (width, height), angle_deg = cv2.fitEllipse(arc.astype(np.float32))
    a, b = 0.5 * width, 0.5 * height
    if not (math.isfinite(a) and math.isfinite(b)) or min(a, b) <= 0.5:
        return None
    # (The outline runs through the boundary pixels' centres, as the ellipse fitted to
    # it: the area inside it, not the pixel count, is what a whole blob's ellipse gives.)
    area = float(cv2.contourArea(outline))
    ellipse_area = math.pi * a * b
    if not (1.0 + MIN_MISSING_FRACTION) * area <= ellipse_area <= MAX_AREA_RATIO * area:
        return None
    # Distance of the arc's points from the ellipse, to first order: the normalised
    # radius' excess times the local radius.
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    d = arc - (cu, cv)
    x, y = d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c
    r = np.hypot(x / a, y / b)
    gap = (r - 1.0) * np.hypot(x, y) / np.maximum(r, 1e-9)
    if float(np.sqrt(np.mean(gap * gap))) > MAX_ARC_RMS_PX:
        return None
    return np.array([cu, cv], dtype=np.float64)


def _bounding_chord(points: np.ndarray) -> np.ndarray | None:
    """Signed distances of ``points`` from the longest straight side bounding them.

    The side is the line through the most outline points (within
    :data:`LINE_TOLERANCE_PX`) over at least :data:`MIN_CHORD_PX`, with every outline
    point on one side of it; None if there is none.
    """
    rng = np.random.default_rng(0)
    i = rng.integers(0, len(points), _LINE_TRIES)
    j = rng.integers(0, len(points), _LINE_TRIES)
    direction = points[j] - points[i]
    length = np.hypot(direction[:, 0], direction[:, 1])
    usable = length >= MIN_CHORD_PX
    if not usable.any():
        return None
    i, direction, length = i[usable], direction[usable], length[usable]
    normal = np.stack([-direction[:, 1], direction[:, 0]], axis=1) / length[:, None]
    signed = points @ normal.T - np.sum(points[i] * normal, axis=1)  # (P, tries)
    on_line = np.abs(signed) <= LINE_TOLERANCE_PX
    one_side = (signed >= -LINE_TOLERANCE_PX).all(axis=0) \
        | (signed <= LINE_TOLERANCE_PX).all(axis=0)
    count = np.where(one_side, on_line.sum(axis=0), 0)
    best = int(np.argmax(count))
    if count[best] == 0:
        return None
    along = points[on_line[:, best]] @ (direction[best] / length[best])
    if float(along.max() - along.min()) < MIN_CHORD_PX:
        return None
    return signed[:, best]
