from __future__ import annotations

import numpy as np
import pytest

from srde_fusion._checks import (
    Views,
    check_disparity,
    check_image,
    check_mask,
    check_point3,
    check_views,
)
from srde_fusion.errors import DisparityError, ImageError, MaskError, SRDEError


# ---------------------------------------------------------------------- check_image
def test_check_image_keeps_uint8_and_converts_floats():
    rgb = np.zeros((4, 5, 3), np.uint8)
    assert check_image(rgb) is rgb
    as_float = check_image(np.full((4, 5), 0.5, np.float64))
    assert as_float.dtype == np.float32 and as_float.shape == (4, 5)
    assert float(as_float[0, 0]) == 0.5


def test_check_image_drops_single_channel_axis():
    out = check_image(np.zeros((3, 4, 1), np.uint8))
    assert out.shape == (3, 4)


@pytest.mark.parametrize(
    ("image", "match"),
    [
        ([[0, 1], [2, 3]], r"img: expected a numpy array \(H, W\) or \(H, W, 3\), got list"),
        (
            np.zeros((4, 5, 4), np.uint8),
            r"img: expected shape \(H, W\) or \(H, W, 3\), got \(4, 5, 4\)",
        ),
        (np.zeros((2, 4, 5, 3), np.uint8), r"got \(2, 4, 5, 3\)"),
        (np.zeros((1, 5), np.uint8), r"img: expected at least 2x2 pixels, got \(1, 5\)"),
        (np.zeros((4, 5), np.int32), "img: expected dtype uint8 or float in .0, 1., got int32"),
        (np.zeros((4, 5), bool), "got bool"),
        (np.zeros((4, 5), np.uint16), "got uint16"),
        (np.full((4, 5), np.nan, np.float32), "img: expected finite float values"),
        (
            np.full((4, 5), 1.5, np.float32),
            r"img: expected float values in \[0, 1\], got range \[1.5, 1.5\]",
        ),
        (np.linspace(-0.25, 1.0, 20).reshape(4, 5), r"got range \[-0.25, 1\]"),
    ],
    ids=["list", "4-channel", "4d", "tiny", "int32", "bool", "uint16", "nan", "above-1", "below-0"],
)
def test_check_image_errors(image, match):
    with pytest.raises(ImageError, match=match):
        check_image(image, "img")


# ---------------------------------------------------------------------- check_views
def test_check_views_list_and_stack():
    views = [np.zeros((4, 5, 3), np.uint8) for _ in range(3)]
    out = check_views(views, 3, (5, 4))
    assert len(out) == 3 and all(v.shape == (4, 5, 3) for v in out)
    stacked = check_views(np.zeros((3, 4, 5, 3), np.uint8), 3)
    assert isinstance(stacked, Views) and len(stacked) == 3
    grey_stack = check_views(np.zeros((2, 4, 5), np.float32), 2)
    assert [v.shape for v in grey_stack] == [(4, 5), (4, 5)]
    assert check_views(tuple(views))[0] is views[0]


def test_check_views_passes_validated_views_through_without_reading_them():
    views = check_views([np.zeros((4, 5, 3), np.uint8) for _ in range(2)], 2, (5, 4))
    assert check_views(views, 2, (5, 4)) is views
    assert check_views(views) is views
    # a different expectation is checked again, with the usual message
    with pytest.raises(ImageError, match="expected 3 images"):
        check_views(views, 3)
    with pytest.raises(ImageError, match=r"rig's size 6x4, got 5x4"):
        check_views(views, 2, (6, 4))


def test_check_views_accepts_mixed_grey_and_rgb_of_one_size():
    out = check_views([np.zeros((4, 5), np.uint8), np.zeros((4, 5, 3), np.uint8)])
    assert [v.ndim for v in out] == [2, 3]


@pytest.mark.parametrize(
    ("views", "kwargs", "match"),
    [
        ("cam0.png", {}, "views: expected a sequence of images, got str"),
        (np.zeros((4, 5), np.uint8), {}, "views: expected a sequence of images, got array"),
        ([], {}, "views: expected at least one image, got none"),
        ([np.zeros((4, 5), np.uint8)] * 2, {"n_cameras": 9}, "expected 9 images .*, got 2"),
        (
            [np.zeros((4, 5), np.uint8), np.zeros((4, 6), np.uint8)],
            {},
            r"views\[1\]: expected the same size as views\[0\] \(5x4\), got 6x4",
        ),
        (
            [np.zeros((4, 5), np.uint8)],
            {"image_size": (640, 480)},
            "views: expected images of the rig's size 640x480, got 5x4",
        ),
        (
            [np.zeros((4, 5), np.uint8), np.zeros((4, 5), np.int8)],
            {},
            r"views\[1\]: expected dtype",
        ),
    ],
    ids=["string", "single-image", "empty", "count", "sizes", "rig-size", "dtype"],
)
def test_check_views_errors(views, kwargs, match):
    with pytest.raises(ImageError, match=match):
        check_views(views, **kwargs)


# ---------------------------------------------------------------------- check_mask
def test_check_mask_normalises_to_bool():
    mask = np.array([[0, 2], [0, 0]], np.uint8)
    out = check_mask(mask, (2, 2))
    assert out.dtype == bool
    np.testing.assert_array_equal(out, [[False, True], [False, False]])
    as_float = check_mask(np.array([[np.nan, 0.5], [0.0, 0.0]]), (2, 2))
    np.testing.assert_array_equal(as_float, [[False, True], [False, False]])
    boolean = np.eye(2, dtype=bool)
    assert check_mask(boolean, (2, 2)) is boolean
    assert not check_mask(np.zeros((2, 2), bool), (2, 2), allow_empty=True).any()


@pytest.mark.parametrize(
    ("mask", "match"),
    [
        ([[1, 0]], r"m: expected a numpy array of shape \(2, 2\), got list"),
        (np.ones((2, 3), bool), r"m: expected shape \(2, 2\), got \(2, 3\)"),
        (np.ones((2, 2), complex), "m: expected a bool or integer mask, got dtype complex128"),
        (np.zeros((2, 2), np.uint8), "m: expected at least one pixel inside the mask"),
    ],
    ids=["list", "shape", "dtype", "empty"],
)
def test_check_mask_errors(mask, match):
    with pytest.raises(MaskError, match=match):
        check_mask(mask, (2, 2), "m")


# ---------------------------------------------------------------------- check_disparity
def test_check_disparity_marks_invalid_as_nan_in_a_copy():
    d = np.array([[1.0, -2.0], [np.inf, 0.0]])
    out = check_disparity(d)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[1.0, np.nan], [np.nan, 0.0]])
    assert d[0, 1] == -2.0  # the input is untouched
    assert check_disparity(np.zeros((1, 3, 4), np.float32)).shape == (3, 4)


@pytest.mark.parametrize(
    ("disparity", "shape", "match"),
    [
        ([[1.0]], None, r"d: expected a numpy array \(H, W\), got list"),
        (np.zeros((2, 3, 4)), None, r"d: expected shape \(H, W\), got \(2, 3, 4\)"),
        (np.zeros(5), None, r"got \(5,\)"),
        (np.zeros((3, 4), bool), None, "d: expected a float array, got dtype bool"),
        (np.zeros((3, 4)), (4, 3), r"d: expected shape \(4, 3\), got \(3, 4\)"),
        (np.zeros((3, 4), np.int16), None, r"d: expected float disparity .* divide by 16"),
        (np.zeros((3, 4), np.uint16), None, r"got dtype uint16.*read_kitti_disparity"),
    ],
    ids=["list", "3d", "1d", "bool", "shape", "sgbm-int16", "kitti-uint16"],
)
def test_check_disparity_errors(disparity, shape, match):
    with pytest.raises(DisparityError, match=match):
        check_disparity(disparity, shape, "d")


# ---------------------------------------------------------------------- check_point3
def test_check_point3():
    out = check_point3([1, 2, 3], "light")
    assert out.dtype == np.float64 and out.tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(SRDEError, match=r"light: expected 3 finite numbers \(x, y, z\) in metres"):
        check_point3([1.0, 2.0], "light")
    with pytest.raises(SRDEError, match="light: expected 3 finite numbers"):
        check_point3([1.0, np.nan, 2.0], "light")
    with pytest.raises(SRDEError, match=r"light: expected 3 numbers \(x, y, z\)"):
        check_point3(["a", 2, 3], "light")
