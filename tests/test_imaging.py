from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from srde_fusion.errors import ImageError
from srde_fusion.imaging import (
    REC709_LUMA,
    linear_to_srgb,
    luminance,
    saturation_mask,
    srgb_to_linear,
    to_float,
)

# float32 arithmetic on both sides of the sRGB curve.
ROUND_TRIP_ATOL = 2e-6


def test_srgb_known_values():
    encoded = np.array([0.0, 0.04045, 0.5, 1.0])
    expected = [0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0]
    np.testing.assert_allclose(srgb_to_linear(encoded), expected, rtol=1e-6)
    assert srgb_to_linear(encoded).dtype == np.float32
    # Mid grey 0.5 encoded is about 21.4 % linear intensity.
    assert float(srgb_to_linear(0.5)) == pytest.approx(0.21404, abs=1e-5)


def test_srgb_curve_is_continuous_at_the_knee():
    below, above = srgb_to_linear(np.array([0.04045, 0.04046]))
    assert above > below and above - below < 1e-5


@given(arrays(np.float32, 16, elements=st.floats(0.0, 1.0, width=32)))
def test_srgb_round_trip(encoded):
    np.testing.assert_allclose(
        linear_to_srgb(srgb_to_linear(encoded)), encoded, atol=ROUND_TRIP_ATOL
    )


@given(arrays(np.float32, 16, elements=st.floats(0.0, 1.0, width=32)))
def test_srgb_decoding_is_monotone_and_darkens(encoded):
    lin = srgb_to_linear(np.sort(encoded))
    assert np.all(np.diff(lin) >= 0)
    assert np.all(lin <= np.sort(encoded) + 1e-7)


def test_linear_to_srgb_clips():
    np.testing.assert_allclose(linear_to_srgb(np.array([-0.5, 2.0])), [0.0, 1.0], atol=1e-6)


def test_to_float():
    np.testing.assert_array_equal(to_float(np.array([[0, 255]], np.uint8)), [[0.0, 1.0]])
    out = to_float(np.array([[0.25]], np.float64))
    assert out.dtype == np.float32 and out[0, 0] == 0.25


@pytest.mark.parametrize("value", [0, 1, 17, 128, 200, 255])
def test_luminance_of_grey_is_the_decoded_grey(value):
    grey = np.full((2, 3), value, np.uint8)
    rgb = np.repeat(grey[..., None], 3, axis=2)
    expected = srgb_to_linear(np.float32(value / 255.0))
    # The Rec. 709 weights sum to one, so grey keeps its intensity.
    np.testing.assert_allclose(luminance(rgb), expected, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(luminance(grey), expected, rtol=1e-6, atol=1e-9)
    assert luminance(rgb).shape == (2, 3) and luminance(rgb).dtype == np.float32


def test_luminance_weights_primaries():
    primaries = np.eye(3, dtype=np.uint8)[None] * 255  # (1, 3, 3): red, green, blue pixels
    np.testing.assert_allclose(luminance(primaries)[0], REC709_LUMA, rtol=1e-6)


def test_luminance_uint8_table_matches_float_path():
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (5, 6, 3), dtype=np.uint8)
    np.testing.assert_allclose(luminance(image), luminance(to_float(image)), atol=1e-6)


def test_luminance_linear_encoding():
    image = np.array([[[0.5, 0.5, 0.5], [1.0, 0.0, 0.0]]], np.float32)
    np.testing.assert_allclose(luminance(image, "linear"), [[0.5, 0.2126]], rtol=1e-6)
    grey = np.array([[0, 51]], np.uint8)
    np.testing.assert_allclose(luminance(grey, "linear"), [[0.0, 0.2]], rtol=1e-6)


def test_luminance_unknown_encoding():
    with pytest.raises(
        ImageError, match=r"encoding: expected one of \['srgb', 'linear'\], got 'sRGB'"
    ):
        luminance(np.zeros((2, 2), np.uint8), "sRGB")


def test_saturation_mask():
    rgb = np.zeros((1, 4, 3), np.uint8)
    rgb[0, 1, 0] = 254
    rgb[0, 2] = 255
    rgb[0, 3] = 253
    np.testing.assert_array_equal(saturation_mask(rgb), [[False, True, True, False]])
    grey = np.array([[0.999, 0.99, 1.0]], np.float32)
    np.testing.assert_array_equal(saturation_mask(grey), [[True, False, True]])


@given(st.integers(0, 2 ** 31), st.sampled_from([np.uint8, np.float32]),
       st.sampled_from(["srgb", "linear"]))
def test_luminance_of_a_crop_is_the_same_pixels_in_the_whole_image(seed, dtype, encoding):
    # Crops of any size, single columns and rows included: the detector reuses one
    # crop's luminance for another and relies on per-pixel arithmetic.
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 256, (23, 31, 3), dtype=np.uint8)
    if dtype is np.float32:
        image = (image / 255.0).astype(np.float32)
    u0, v0 = int(rng.integers(0, 31)), int(rng.integers(0, 23))
    u1, v1 = int(rng.integers(u0 + 1, 32)), int(rng.integers(v0 + 1, 24))
    np.testing.assert_array_equal(luminance(image[v0:v1, u0:u1], encoding),
                                  luminance(image, encoding)[v0:v1, u0:u1])
