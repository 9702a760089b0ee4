"""The centre of a highlight cut by a straight edge, from the arc of its outline."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from srde_fusion.srde.cut_highlights import arc_center

# Sub-pixel drawing: OpenCV's ``shift`` gives coordinates in 1/16 px.
_SHIFT = 4


def _ellipse(shape, center_uv, axes_px, angle_deg) -> np.ndarray:
    """A filled ellipse drawn by OpenCV (not by the code under test), as a bool image."""
    image = np.zeros(shape, np.uint8)
    scale = 1 << _SHIFT
    cv2.ellipse(image, (round(center_uv[0] * scale), round(center_uv[1] * scale)),
                (round(axes_px[0] * scale), round(axes_px[1] * scale)), angle_deg, 0, 360,
                1, -1, cv2.LINE_8, _SHIFT)
    return image.astype(bool)


def _cut(blob: np.ndarray, point_uv, normal) -> np.ndarray:
    """``blob`` without the pixels on the far side of the line through ``point_uv``."""
    v, u = np.mgrid[:blob.shape[0], :blob.shape[1]]
    side = (u - point_uv[0]) * normal[0] + (v - point_uv[1]) * normal[1]
    return blob & (side <= 0.0)


def _centroid(blob: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(blob)
    return np.array([u.mean(), v.mean()])


CENTER = (40.3, 37.6)


@pytest.mark.parametrize(("axes", "angle", "normal", "depth"), [
    ((14.0, 14.0), 0.0, (1.0, 0.0), 6.0),   # a disc, its right third cut off
    ((18.0, 10.0), 30.0, (0.6, 0.8), 4.0),  # an ellipse cut across its tilted axes
    ((20.0, 12.0), -15.0, (-1.0, 0.2), 9.0),  # most of one half cut
])
def test_a_cut_highlight_is_centred_where_the_whole_one_was(axes, angle, normal, depth):
    whole = _ellipse((80, 80), CENTER, axes, angle)
    n = np.asarray(normal) / np.hypot(*normal)
    # The chord lies ``depth`` px from the centre (the part beyond it removed).
    cut = _cut(whole, np.asarray(CENTER) + depth * n, n)
    assert np.count_nonzero(cut) < 0.9 * np.count_nonzero(whole)
    # The cut blob's centroid is pulled well off the centre; the arc's ellipse is not.
    assert np.linalg.norm(_centroid(cut) - CENTER) > 1.5
    found = arc_center(cut)
    assert found is not None
    assert np.linalg.norm(found - CENTER) < 0.5


@pytest.mark.parametrize(("axes", "angle"), [((14.0, 14.0), 0.0), ((22.0, 9.0), 35.0),
                                             ((6.0, 5.0), 80.0)])
def test_a_whole_highlight_is_not_recentred(axes, angle):
    # A whole blob's flank is straight for a few pixels; the ellipse through the rest of
    # its outline is the blob itself, not one reaching beyond it.
    assert arc_center(_ellipse((80, 80), CENTER, axes, angle)) is None


def test_a_sliver_cut_is_not_a_cut():
    whole = _ellipse((80, 80), CENTER, (15.0, 11.0), 0.0)
    # A cut 14 px from the centre of a 15 px half-axis takes a sliver of a few pixels.
    sliver = _cut(whole, (CENTER[0] + 14.0, CENTER[1]), (1.0, 0.0))
    assert np.count_nonzero(whole) - np.count_nonzero(sliver) < 0.03 * np.count_nonzero(whole)
    assert arc_center(sliver) is None


def test_a_blob_that_is_no_cut_ellipse_gives_no_centre():
    # A rectangle: one straight side bounds it, but the rest of its outline is three more
    # straight sides, which no ellipse runs through.
    blob = np.zeros((60, 60), bool)
    blob[15:45, 10:50] = True
    assert arc_center(blob) is None
    # Too few outline points for an arc.
    tiny = np.zeros((10, 10), bool)
    tiny[4:6, 4:6] = True
    assert arc_center(tiny) is None
    assert arc_center(np.zeros((10, 10), bool)) is None


def test_the_same_blob_gives_the_same_centre():
    cut = _cut(_ellipse((80, 80), CENTER, (16.0, 11.0), 20.0),
               (CENTER[0] + 5.0, CENTER[1]), (1.0, 0.0))
    first, second = arc_center(cut), arc_center(cut.copy())
    assert first is not None and np.array_equal(first, second)
    assert all(math.isfinite(x) for x in first)
