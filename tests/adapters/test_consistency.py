"""Left-right check with background fill: the rule, its agreement with the scoring fill, the
adapters' mirrored run, and the switch on the bundled stand-in."""

from __future__ import annotations

import numpy as np
import pytest
from srde_fusion.adapters import StereoSpec, load_backbone
from srde_fusion.adapters.consistency import fill_left_right, mirrored_pair

from srde_fusion.errors import BackboneError
from srde_fusion.evaluation import fill_holes_background

# One row of a fronto-parallel scene: background at 2 px, a foreground at 4 px from
# column 6. LEFT_ROW is the left view's disparity spread ("fattened") over the two
# background pixels the foreground hides in the right view; RIGHT_ROW is the right
# view's exact disparity (its columns 2..7 show the foreground).
LEFT_ROW = [2, 2, 2, 2, 4, 4, 4, 4, 4, 4, 4, 4]
RIGHT_ROW = [2, 2, 4, 4, 4, 4, 4, 4, 2, 2, 2, 2]
TRUE_ROW = [2, 2, 2, 2, 2, 2, 4, 4, 4, 4, 4, 4]
# columns 0-1 match outside the right image, 4-5 are contradicted
FILLED_ROW = [1, 1, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0]


def test_fattened_occlusion_and_left_band_take_the_background():
    left = np.tile(np.array(LEFT_ROW, np.float32), (3, 1))
    right = np.tile(np.array(RIGHT_ROW, np.float32), (3, 1))
    checked = fill_left_right(left, right)
    np.testing.assert_array_equal(checked.disparity_px, np.tile(TRUE_ROW, (3, 1)))
    np.testing.assert_array_equal(checked.filled, np.tile(FILLED_ROW, (3, 1)).astype(bool))
    assert checked.filled_fraction == pytest.approx(4 / 12)
    # the true left map keeps its values: its occluded pixels are not confirmed either,
    # but their background fill is what they hold
    truth = fill_left_right(np.tile(np.array(TRUE_ROW, np.float32), (3, 1)), right)
    np.testing.assert_array_equal(truth.filled[0], FILLED_ROW)
    np.testing.assert_array_equal(truth.disparity_px[0], TRUE_ROW)


def test_tolerance_decides_what_is_contradicted():
    left = np.full((2, 10), 3.0, np.float32)
    right = np.full((2, 10), 4.5, np.float32)
    right[:, :3] = 3.0  # seen by left columns 3..5
    assert fill_left_right(left, right, max_diff_px=1.0).filled[:, 6:].all()
    assert not fill_left_right(left, right, max_diff_px=2.0).filled[:, 3:].any()


def test_fill_is_the_scoring_background_fill_of_the_replaced_pixels():
    rng = np.random.default_rng(3)
    left = rng.uniform(0, 12, (40, 80)).astype(np.float32)
    right = np.where(rng.random((40, 80)) < 0.6, left, left + 5).astype(np.float32)
    checked = fill_left_right(left, right)
    assert 0.1 < checked.filled_fraction < 0.9
    holes = np.where(checked.filled, np.nan, left)
    expected = fill_holes_background(holes)
    np.testing.assert_array_equal(checked.disparity_px[checked.filled],
                                  expected[checked.filled])


def test_trusted_pixels_hold_the_mean_of_both_views():
    # a plane at 3.4 px seen as 3.0 from the left and 3.6 from the right
    left = np.full((2, 20), 3.0, np.float32)
    right = np.full((2, 20), 3.6, np.float32)
    checked = fill_left_right(left, right)
    np.testing.assert_allclose(checked.disparity_px[:, 3:], 3.3, atol=1e-6)
    # where the right view's interpolated value is off by more than the tolerance, the
    # left value stays (here the right pixel's neighbour belongs to another surface)
    right[:, 5] = 9.0
    left[:, 8] = 3.6  # x - d = 4.4: rounded, right_px[4] agrees; interpolated, 5.76
    checked = fill_left_right(left, right)
    assert not checked.filled[0, 8]
    assert checked.disparity_px[0, 8] == pytest.approx(3.6)
    assert checked.disparity_px[0, 7] == pytest.approx(3.3)  # x - d = 4: right_px[4]


def test_pixels_without_disparity_stay_empty_and_rows_without_trust_stay():
    left = np.array([[np.nan, 2, 2, 2, 2], [9, 9, 9, 9, 9]], np.float32)
    right = np.array([[2, 2, 2, 2, 2], [1, 1, 1, 1, 1]], np.float32)
    checked = fill_left_right(left, right)
    assert np.isnan(checked.disparity_px[0, 0]) and not checked.filled[0, 0]
    np.testing.assert_array_equal(checked.disparity_px[1], left[1])  # nothing to fill from


def test_mirrored_pair_swaps_and_mirrors():
    left, right = np.arange(6).reshape(2, 3), 10 + np.arange(6).reshape(2, 3)
    m_left, m_right = mirrored_pair(left, right)
    np.testing.assert_array_equal(m_left, right[:, ::-1])
    np.testing.assert_array_equal(m_right, left[:, ::-1])


def test_adapter_runs_the_mirrored_pair_and_fills():
    torch = pytest.importorskip("torch")

    class ChannelZero(torch.nn.Module):
        """Disparity = the left input's channel 0 (0..255 units)."""

        def forward(self, left, right):
            return left[:, :1] + 0.0 * right.mean()

    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (3, 12, 3), dtype=np.uint8)
    right = rng.integers(0, 255, (3, 12, 3), dtype=np.uint8)
    left[:, :, 0], right[:, :, 0] = LEFT_ROW, RIGHT_ROW
    checked = load_backbone(ChannelZero(), "generic", left_right_check=True)
    np.testing.assert_allclose(checked(left, right), np.tile(TRUE_ROW, (3, 1)), atol=1e-4)
    assert checked.last_filled_fraction == pytest.approx(4 / 12)
    assert "left-right check: on" in checked.describe()
    plain = load_backbone(ChannelZero(), "generic")
    np.testing.assert_allclose(plain(left, right), np.tile(LEFT_ROW, (3, 1)), atol=1e-4)
    assert plain.last_filled_fraction is None and "left-right check: off" in plain.describe()


def test_bundled_standin_checks_by_default_and_can_be_switched_off():
    pytest.importorskip("onnxruntime")
    assert load_backbone("default").spec.left_right_check
    assert load_backbone("default", "igev").spec.left_right_check
    assert not load_backbone("default", left_right_check=False).spec.left_right_check
    # a full spec of one's own is taken as given
    own = StereoSpec(name="mine", pad_multiple=32)
    assert not load_backbone("default", own).spec.left_right_check


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"left_right_check": "yes"}, "left_right_check: expected True or False, got 'yes'"),
        ({"left_right_max_diff_px": -1.0},
         r"left_right_max_diff_px: expected a number >= 0 \(px\), got -1.0"),
    ],
)
def test_bad_left_right_settings(changes, message):
    with pytest.raises(BackboneError, match=message):
        StereoSpec(**changes)
