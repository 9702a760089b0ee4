"""Per-object results keep to the object's box: memory follows the objects, not the image."""

from __future__ import annotations

import tracemalloc

import numpy as np

from srde_fusion.fusion import fuse, postprocess
from srde_fusion.masks import BoxedMasks
from srde_fusion.srde import SRDE
from tests.support import MASK_BOX, box_mask, grid_rig, highlight_views, true_centers

BACKBONE_PX = 3.0


def _scene():
    rig = grid_rig()
    views = highlight_views(true_centers(rig))
    backbone = np.full((rig.height, rig.width), BACKBONE_PX, np.float32)
    return rig, views, backbone


def test_srde_result_holds_the_mask_box_only():
    rig, views, _ = _scene()
    mask = box_mask()
    result = SRDE(rig).estimate(views, mask)
    assert result.ok, result.reason
    u0, v0, u1, v1 = MASK_BOX
    assert result.box == MASK_BOX and result.disparity_box.shape == (v1 - v0, u1 - u0)
    full = result.disparity
    assert full.shape == (rig.height, rig.width) and full.dtype == np.float32
    assert np.all(np.isnan(full[~mask])) and np.all(np.isfinite(full[mask]))
    np.testing.assert_array_equal(full[v0:v1, u0:u1], result.disparity_box)
    failed = SRDE(rig).estimate([v * 0 for v in views], mask)
    assert not failed.ok and failed.disparity_box.size == 0
    assert np.all(np.isnan(failed.disparity)) and failed.disparity.shape == (rig.height, rig.width)


def test_labels_lists_and_boxed_masks_fuse_alike_and_keep_boxes():
    rig, views, backbone = _scene()
    labels = np.zeros((rig.height, rig.width), np.uint8)
    labels[box_mask()] = 7
    labels[5:20, 5:30] = 2  # a second object, without a highlight: it falls back
    srde = SRDE(rig)
    from_labels = fuse(backbone, views, rig, labels, srde)
    from_list = fuse(backbone, views, rig, [labels == 2, labels == 7], srde)
    from_boxes = fuse(backbone, views, rig, BoxedMasks.from_labels(labels), srde)
    via_postprocess = postprocess(backbone, views, rig, labels)
    for other in (from_list, from_boxes, via_postprocess):
        np.testing.assert_array_equal(other.disparity, from_labels.disparity)
        np.testing.assert_array_equal(other.source, from_labels.source)
        assert [o.reason for o in other.objects] == [o.reason for o in from_labels.objects]
    assert [o.status for o in from_labels.objects] == ["fallback", "srde"]
    for obj in from_labels.objects:
        box = obj.estimate.disparity_box
        u0, v0, u1, v1 = obj.estimate.box
        assert box.shape == (v1 - v0, u1 - u0)
        assert box.size <= obj.pixel_count  # (boxes of rectangles: equal)
    # SRDE alone is still a full map made from the boxes
    srde_only = from_labels.srde_disparity
    assert srde_only.shape == (rig.height, rig.width)
    np.testing.assert_array_equal(np.isfinite(srde_only), labels == 7)


def test_what_fusion_keeps_does_not_grow_with_the_image():
    """Retained memory of a result: the fused maps and one box per object."""
    rig, views, backbone = _scene()
    masks = [box_mask()] + [box_mask((5 + 6 * i, 5, 9 + 6 * i, 9)) for i in range(20)]
    tracemalloc.start()
    try:
        result = fuse(backbone, views, rig, masks, SRDE(rig))
        kept, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    full_maps = 3 * backbone.nbytes  # fused, source, backbone as fused
    boxes = sum(o.estimate.disparity_box.nbytes for o in result.objects)
    assert boxes <= 2 * box_mask().sum() * 4
    # 21 objects with full-image maps would keep 21 x 120 kB more than this
    assert kept < full_maps + 2 * boxes + 21 * backbone.nbytes // 4
