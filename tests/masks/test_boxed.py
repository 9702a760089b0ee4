"""Object masks held as their boxes: the same masks, a fraction of the memory."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from srde_fusion.errors import MaskError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import masks_from_labels
from srde_fusion.masks import BoxedMasks, BoxMask, UserMasks
from srde_fusion.masks.user import connected_components


def _random_labels(seed: int, shape=(60, 80), n_labels=12) -> np.ndarray:
    rng = np.random.default_rng(seed)
    labels = np.zeros(shape, np.int32)
    for _ in range(n_labels):
        v0, u0 = rng.integers(0, shape[0] - 5), rng.integers(0, shape[1] - 5)
        v1, u1 = v0 + rng.integers(1, 20), u0 + rng.integers(1, 25)
        labels[v0:v1, u0:u1] = rng.integers(0, 300)  # gaps, overwrites, label 0 cut-outs
    return labels


@pytest.mark.parametrize("seed", range(8))
def test_boxed_masks_are_the_label_masks(seed):
    labels = _random_labels(seed)
    boxed = BoxedMasks.from_labels(labels)
    expected = masks_from_labels(labels)
    assert len(boxed) == len(expected)
    for k, (got, want) in enumerate(zip(boxed, expected, strict=True)):
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(boxed[k], want)
        # the box is the tightest one
        rows, cols = np.flatnonzero(want.any(axis=1)), np.flatnonzero(want.any(axis=0))
        assert boxed.boxes[k].box == (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1)
        assert boxed.boxes[k].pixel_count == int(want.sum())


def test_labels_without_background_and_empty_labels():
    labels = np.array([[3, 3], [4, 3]])
    assert [m.astype(int).tolist() for m in BoxedMasks.from_labels(labels)] == [
        [[1, 1], [0, 1]], [[0, 0], [1, 0]]]
    assert len(BoxedMasks.from_labels(np.zeros((3, 4), np.uint8))) == 0
    assert len(BoxedMasks.from_labels(np.zeros((0, 0), np.uint8))) == 0


def test_items_are_fresh_full_masks_and_the_crops_are_frozen():
    boxed = BoxedMasks.from_labels(_random_labels(1))
    first = boxed[0]
    first[:] = True
    assert not np.array_equal(boxed[0], first)
    with pytest.raises(ValueError, match="read-only"):
        boxed.boxes[0].crop[0, 0] = False
    part = boxed[1:3]
    assert isinstance(part, BoxedMasks) and len(part) == 2
    np.testing.assert_array_equal(part[0], boxed[1])


def test_box_mask_window_and_errors():
    mask = np.zeros((10, 12), bool)
    mask[3:5, 4:9] = True
    bm = BoxMask.from_mask(mask)
    assert bm.box == (4, 3, 9, 5)
    np.testing.assert_array_equal(bm.window((2, 1, 12, 8)), mask[1:8, 2:12])
    with pytest.raises(MaskError, match="expected at least one pixel inside the mask"):
        BoxMask.from_mask(np.zeros((4, 4), bool))
    with pytest.raises(MaskError, match=r"masks\[0\]: expected a BoxMask of an image of shape"):
        BoxedMasks([bm], (11, 12))


@pytest.mark.parametrize("seed", range(4))
def test_components_of_a_box_are_those_of_the_full_mask(seed):
    rng = np.random.default_rng(seed)
    mask = cv2.dilate((rng.random((50, 70)) > 0.97).astype(np.uint8), np.ones((3, 3))) > 0
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    want = [comp == i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= 5]
    got = connected_components(BoxMask.from_mask(mask), 5)
    assert [g.full().tolist() for g in got] == [w.tolist() for w in want]
    got_full = connected_components(mask, 5)
    assert [g.full().tolist() for g in got_full] == [w.tolist() for w in want]


def test_user_masks_of_many_labels_hold_boxes_not_images():
    # 255 small objects on a 2000x1500 label image: 255 full masks would take 765 MB.
    h, w = 1500, 2000
    labels = np.zeros((h, w), np.uint8)
    for k in range(255):
        r, c = divmod(k, 16)
        labels[r * 90 + 5:r * 90 + 25, c * 120 + 5:c * 120 + 30] = k + 1
    user = UserMasks(labels, max_objects=255)
    rig = CameraRig.stereo(0.1, fx=1000.0, image_size=(w, h))
    masks = user(None, rig)
    assert isinstance(masks, BoxedMasks) and len(masks) == 255
    assert masks.nbytes == 255 * 20 * 25
    np.testing.assert_array_equal(masks[254], labels == 255)
