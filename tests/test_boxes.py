"""A boolean image held over a box reads as the whole array it stands for."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.boxes import BoxMask
from srde_fusion.errors import MaskError


@given(st.integers(0, 2**32 - 1))
def test_a_box_mask_reads_as_the_whole_array(seed):
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 30)), int(rng.integers(1, 30)))
    u0, u1 = sorted(int(x) for x in rng.integers(0, shape[1] + 1, 2))
    v0, v1 = sorted(int(x) for x in rng.integers(0, shape[0] + 1, 2))
    crop = rng.random((v1 - v0, u1 - u0)) < 0.5
    boxed = BoxMask.from_crop((u0, v0, u1, v1), crop, shape)
    whole = np.asarray(boxed)
    assert whole.shape == shape and whole.dtype == bool
    assert whole[v0:v1, u0:u1].sum() == whole.sum() == boxed.pixel_count
    for _ in range(10):
        a0, a1 = sorted(int(x) for x in rng.integers(0, shape[1] + 1, 2))
        b0, b1 = sorted(int(x) for x in rng.integers(0, shape[0] + 1, 2))
        np.testing.assert_array_equal(boxed[b0:b1, a0:a1], whole[b0:b1, a0:a1])
        np.testing.assert_array_equal(boxed.window((a0, b0, a1, b1)), whole[b0:b1, a0:a1])
    np.testing.assert_array_equal(boxed[::2, 1:], whole[::2, 1:])  # not a window: the array's


def test_slices_inside_the_box_are_views_and_windows_are_new():
    mask = np.zeros((10, 12), bool)
    mask[3:6, 4:9] = True
    mask[4, 6] = False
    boxed = BoxMask.from_mask(mask)
    assert boxed.box == (4, 3, 9, 6) and boxed.ndim == 2 and boxed.dtype == bool
    inside = boxed[3:5, 5:8]
    assert np.shares_memory(inside, boxed.crop) and not inside.flags.writeable
    window = boxed.window((4, 3, 9, 6))
    assert not np.shares_memory(window, boxed.crop) and window.flags.writeable
    np.testing.assert_array_equal(boxed.window((2, 1, 12, 8)), mask[1:8, 2:12])
    np.testing.assert_array_equal(boxed.window((0, 0, 5, 4)), mask[0:4, 0:5])  # overlaps
    assert not BoxMask.empty((10, 12)).full().any()
    with pytest.raises(MaskError, match="expected at least one pixel inside the mask"):
        BoxMask.from_mask(np.zeros((4, 4), bool))


def test_a_callers_crop_is_never_frozen():
    image = np.zeros((6, 6), bool)
    BoxMask.from_crop((1, 1, 4, 4), image[1:4, 1:4], image.shape)
    assert image.flags.writeable
