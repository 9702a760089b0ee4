"""OpenCV SGBM as a backbone: known disparities recovered, empty pixels NaN, spec checks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from srde_fusion.adapters import SGBMSpec, SGBMStereo, load_backbone
from srde_fusion.adapters.sgbm import _left_right_consistent

from srde_fusion.cli.backbones import backbone_from
from srde_fusion.errors import BackboneError, ImageError

SUBPIXEL_PX = 0.25  # SGBM's parabola fit on a 4-bit fixed-point grid, on clean texture
H, W = 120, 200


def texture(seed: int, h: int = H, w: int = W) -> np.ndarray:
    """Blurred noise: texture at a few pixels' scale, which block matching can lock onto."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, size=(h, w, 3)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 1.2) * 2.0 - 127.0, 0, 255).astype(np.uint8)


def warp_left(right: np.ndarray, disparity_px: np.ndarray) -> np.ndarray:
    """The left view of ``right`` for a left-view disparity map: left(x) = right(x - d)."""
    h, w = disparity_px.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(right, xs - disparity_px.astype(np.float32), ys,
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def step_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured wall at 9 px and a textured square in front of it at 21 px.

    Both views are cut from two wide textures at integer offsets, so every visible point
    is exact, and the wall strip just left of the square (x 78..89) is hidden from the
    right camera by the square: an occlusion, as a real pair has.
    """
    wall, square = texture(1, w=W + 32), texture(3, w=W + 32)
    rows, cols = slice(35, 85), slice(90, 150)
    truth = np.full((H, W), 9.0, np.float32)
    truth[rows, cols] = 21.0
    left = wall[:, :W].copy()
    left[rows, cols] = square[rows, cols]
    right = wall[:, 9:W + 9].copy()  # right(x) = left-view point x + d
    right[rows, cols.start - 21:cols.stop - 21] = square[rows, cols]
    return left, right, truth


def test_recovers_a_known_step_of_disparity():
    left, right, truth = step_scene()
    disparity_px = load_backbone("sgbm")(left, right)
    assert disparity_px.shape == (H, W) and disparity_px.dtype == np.float32
    filled = np.isfinite(disparity_px)
    assert np.all(disparity_px[filled] >= 0)  # sign: positive, never OpenCV's -1 sentinel
    # inside each region, away from the step and the unmatched left border
    inner = np.zeros((H, W), bool)
    inner[5:-5, 40:-5] = True
    inner[30:90, 75:155] = False
    inner[40:80, 95:145] = True
    assert filled[inner].mean() > 0.95
    error = np.abs(disparity_px - truth)[inner & filled]
    assert np.median(error) < SUBPIXEL_PX and (error > 1.0).mean() < 0.02


def test_recovers_a_subpixel_shift():
    right = texture(2)
    truth = np.full((H, W), 7.5, np.float32)
    disparity_px = SGBMStereo(block_size=7)(warp_left(right, truth), right)
    inner = disparity_px[5:-5, 40:-5]
    assert np.abs(np.nanmedian(inner) - 7.5) < SUBPIXEL_PX


def test_fixed_point_output_is_converted_and_empty_pixels_are_nan():
    left, right, _ = step_scene()
    backbone = SGBMStereo()
    disparity_px = backbone(left, right)
    raw = backbone.matcher(W).compute(left, right)  # int16, disparity * 16, -16 = none
    empty = raw < 0
    assert empty.any() and np.array_equal(np.isnan(disparity_px), empty)
    np.testing.assert_array_equal(disparity_px[~empty], raw[~empty] / 16.0)
    # the left border has no match within the searched range
    range_px = SGBMSpec().num_disparities_for(W)
    assert np.isnan(disparity_px[:, : range_px - 1]).all()


def test_left_right_check_only_empties_pixels():
    left, right, truth = step_scene()
    plain = SGBMStereo(disp12_max_diff=-1)(left, right)
    checked = SGBMStereo(disp12_max_diff=-1, left_right_check=True)(left, right)
    assert np.isnan(checked).sum() > np.isnan(plain).sum()
    both = np.isfinite(checked)
    assert np.isfinite(plain[both]).all()
    np.testing.assert_array_equal(checked[both], plain[both])
    # in the wall strip the square hides from the right camera, most wrong values go
    occluded = (slice(35, 85), slice(78, 90))
    wrong_before = (np.abs(plain - truth)[occluded] > 1.0).sum()
    wrong_after = (np.abs(checked - truth)[occluded] > 1.0).sum()
    assert wrong_before > 10 and wrong_after < 0.5 * wrong_before


def test_left_right_consistency_rule():
    left_px = np.array([[np.nan, 5.0, 2.0, 2.0, 3.0]], np.float32)
    right_px = np.array([[2.0, 2.0, 9.0, np.nan, 3.0]], np.float32)
    # x=1: 1 - 5 < 0 falls outside (kept); x=2 -> right 0 (2, agrees); x=3 -> right 1
    # (2, agrees); x=4 -> right 1 (2 vs 3, contradicted at 0.5 px, kept at 1 px)
    np.testing.assert_array_equal(_left_right_consistent(left_px, right_px, 0.5),
                                  [[np.nan, 5.0, 2.0, 2.0, np.nan]])
    np.testing.assert_array_equal(_left_right_consistent(left_px, right_px, 1.0), left_px)
    right_px[0, 0] = 7.0  # x=2 now contradicted
    assert np.isnan(_left_right_consistent(left_px, right_px, 1.0)[0, 2])


def test_float_grey_and_uint8_inputs():
    left, right, _ = step_scene()
    from_uint8 = SGBMStereo()(left, right)
    from_float = SGBMStereo()(left.astype(np.float32) / 255, right.astype(np.float32) / 255)
    np.testing.assert_array_equal(from_float, from_uint8)
    grey = SGBMStereo(colour=False)(left, right)
    assert np.nanmedian(np.abs(grey - from_uint8)) < SUBPIXEL_PX
    with pytest.raises(ImageError, match="same size"):
        SGBMStereo()(left, right[:, :-1])


def test_defaults_scale_with_the_image():
    spec = SGBMSpec()
    assert [spec.num_disparities_for(w) for w in (50, 640, 741, 1280)] == [16, 80, 96, 160]
    assert spec.penalties() == (8 * 3 * 25, 32 * 3 * 25)
    assert SGBMSpec(colour=False, block_size=3).penalties() == (72, 288)
    assert SGBMSpec(num_disparities=128).num_disparities_for(50) == 128
    text = SGBMStereo(block_size=7).describe()
    assert "block_size = 7" in text and "P1 = 1176" in text and "NaN" in text


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"num_disparities": 40}, "num_disparities: expected None or a positive multiple of 16"),
        ({"block_size": 4}, "block_size: expected an odd integer >= 1, got 4"),
        ({"p1": 100, "p2": 50}, "p2: expected a penalty larger than p1"),
        ({"p1": 5000}, r"p2: expected a penalty larger than p1 \(5000\), got 2400"),
        ({"mode": "fast"}, "mode: expected one of sgbm, hh, 3way, hh4, got 'fast'"),
        ({"uniqueness_ratio": -1}, "uniqueness_ratio: expected an integer >= 0"),
        ({"left_right_check": 1}, "left_right_check: expected True or False"),
        ({"left_right_max_diff_px": -0.5}, "left_right_max_diff_px: expected a number >= 0"),
        ({"colour_space": "lab"}, "got unknown colour_space"),
    ],
)
def test_invalid_parameters(changes, message):
    with pytest.raises(BackboneError, match=message):
        SGBMStereo(**changes)


def test_load_backbone_and_the_command_name_it():
    assert load_backbone("SGBM", block_size=3).spec.block_size == 3
    assert load_backbone("sgbm", SGBMSpec(uniqueness_ratio=5)).spec.uniqueness_ratio == 5
    assert isinstance(backbone_from("sgbm"), SGBMStereo)
    with pytest.raises(BackboneError, match="expected an SGBMSpec .* for the 'sgbm' backbone"):
        load_backbone("sgbm", "igev")
    with pytest.raises(BackboneError, match="it goes with source 'sgbm'"):
        load_backbone("default", SGBMSpec())


@pytest.mark.parametrize(("mode", "changes", "widest_refused"), [
    ("3way", {}, 18), ("sgbm", {}, 18), ("hh", {"block_size": 11}, 21),
    ("3way", {"num_disparities": 32}, 34), ("sgbm", {"min_disparity": 8}, 26),
])
def test_images_too_narrow_for_the_range_are_refused_before_opencv(mode, changes,
                                                                   widest_refused):
    # OpenCV fails on these with an allocation of a negative size (and may leave the
    # process corrupt); the widths just above the limit run.
    rng = np.random.default_rng(3)
    stereo = SGBMStereo(mode=mode, **changes)
    for width in (2, widest_refused):
        image = rng.integers(0, 256, (24, width, 3), dtype=np.uint8)
        with pytest.raises(ImageError, match=f"expected a width above {widest_refused} px "
                                             f"for SGBM .*got {width} px"):
            stereo(image, image)
    image = rng.integers(0, 256, (24, widest_refused + 1, 3), dtype=np.uint8)
    assert stereo(image, image).shape == (24, widest_refused + 1)
