"""Census propagation: the census, what a seed and a neighbour's offer must beat, the pixels
it leaves alone, strips against the whole image, and the switch on the adapters and the
stand-in; with segment planes, the stand-in's defaults and the input checks of both."""

from __future__ import annotations

import numpy as np
import pytest
from srde_fusion.adapters import StereoSpec, load_backbone, propagation
from srde_fusion.adapters.propagation import census_pair, census_transform, propagate_disparity
from srde_fusion.adapters.segment_planes import fit_segment_planes

from srde_fusion.errors import BackboneError, DisparityError, ImageError

TRUE_PX = 6.0


def textured_pair(height: int = 48, width: int = 96, seed: int = 0):
    """A fronto-parallel random texture at TRUE_PX: ``left[x] = right[x - TRUE_PX]``."""
    rng = np.random.default_rng(seed)
    right = rng.random((height, width)).astype(np.float32)
    left = np.roll(right, int(TRUE_PX), axis=1)
    return left, right


def test_census_sets_one_bit_per_darker_neighbour():
    grey = np.arange(25, dtype=np.float32).reshape(5, 5)
    bits = census_transform(grey, 2)
    # the centre of a ramp: the 12 neighbours before it in raster order are darker
    assert int(bits[2, 2]).bit_count() == 12
    # the first 12 bits (raster order, centre skipped) are those neighbours
    assert int(bits[2, 2]) == (1 << 12) - 1
    assert bits.dtype == np.uint32 and bits.shape == (5, 5)
    assert not census_transform(np.ones((4, 4), np.float32)).any()  # nothing is darker


def test_bit_counts_fallback_matches_numpy():
    values = np.random.default_rng(1).integers(0, 2**24, (7, 9)).astype(np.uint32)
    expected = np.array([[bin(int(v)).count("1") for v in row] for row in values])
    np.testing.assert_array_equal(propagation._bit_counts(values), expected)


def test_a_wrong_band_takes_its_neighbours_value():
    left, right = textured_pair()
    wrong = np.full(left.shape, TRUE_PX, np.float32)
    wrong[:, 40:60] = 14.0  # fattened foreground, 20 px wide: needs more than one round
    result = propagate_disparity(left, right, wrong)
    inner = result.disparity_px[4:-4, 40:60]
    np.testing.assert_array_equal(inner, TRUE_PX)
    assert result.changed_fraction == pytest.approx(
        np.mean(result.disparity_px != wrong))
    assert result.changed_fraction > 0.15


def wrong_throughout():
    """A pair at TRUE_PX and a map wrong (14 px) everywhere but its first column (2 px).

    The wrong band is wider than propagation can cross: no neighbour within reach holds
    the right value. The map's range, 2-14 px, holds the right level.
    """
    left, right = textured_pair(width=200)
    wrong = np.full(left.shape, 14.0, np.float32)
    wrong[:, 0] = 2.0
    return left, right, wrong


def test_a_region_wrong_throughout_takes_the_seeds_value():
    # The seeds' local match over the wider window holds the right value.
    result = propagate_disparity(*wrong_throughout()).disparity_px
    inner = result[6:-6, 30:-6]
    assert np.all(np.abs(inner - TRUE_PX) < 0.25)


def test_seeds_must_beat_the_network_by_a_margin(monkeypatch):
    monkeypatch.setattr(propagation, "SEED_MARGIN_BITS", 25.0)  # more than a window can lose
    kept = propagate_disparity(*wrong_throughout()).disparity_px
    assert np.all(kept[6:-6, 30:-6] == 14.0)


def test_right_values_stay():
    left, right = textured_pair()
    truth = np.full(left.shape, TRUE_PX, np.float32)
    truth[:, ::7] += 0.25  # sub-pixel values are kept as they are
    result = propagate_disparity(left, right, truth)
    np.testing.assert_array_equal(result.disparity_px, truth)
    assert result.changed_fraction == 0.0


def test_untextured_images_change_nothing():
    flat = np.full((30, 60), 0.5, np.float32)
    disparity = np.where(np.arange(60) < 30, 3.0, 9.0).astype(np.float32)[None].repeat(30, 0)
    result = propagate_disparity(flat, flat, disparity)
    np.testing.assert_array_equal(result.disparity_px, disparity)


def test_unmeasured_and_empty_pixels_keep_their_value():
    left, right = textured_pair()
    wrong = np.full(left.shape, TRUE_PX, np.float32)
    wrong[:, 30:50] = 14.0
    wrong[:, 5] = 40.0  # matches left of the right image: no cost, kept
    wrong[10:20, 30:50] = np.nan  # no value: kept, and never offered
    wrong[30, 60:62] = (-0.25, np.inf)  # no value either: returned as given
    result = propagate_disparity(left, right, wrong).disparity_px
    assert np.all(result[:, 5] == 40.0)
    assert np.all(np.isnan(result[10:20, 30:50]))
    assert not np.isnan(np.delete(result, np.s_[10:20], axis=0)).any()
    assert result[30, 60] == -0.25 and result[30, 61] == np.inf
    empty = propagate_disparity(left, right, np.full(left.shape, np.nan))
    assert np.isnan(empty.disparity_px).all()


def test_strips_give_the_whole_image_answer(monkeypatch):
    left, right = textured_pair(height=200, width=64, seed=3)
    rng = np.random.default_rng(4)
    noisy = (TRUE_PX + rng.choice([0.0, 0.0, 5.0, -3.0], size=left.shape)).astype(np.float32)
    whole = propagate_disparity(left, right, noisy)
    levels = int(np.ceil(noisy.max()) - np.floor(noisy.min())) + 1
    reach = propagation.ITERATIONS * max(propagation.OFFSETS_PX) + 4
    monkeypatch.setattr(propagation, "MAX_VOLUME_BYTES", 2 * levels * 64 * (2 * reach + 10))
    stripped = propagate_disparity(left, right, noisy)
    np.testing.assert_array_equal(stripped.disparity_px, whole.disparity_px)
    assert stripped.changed_fraction == whole.changed_fraction > 0.0


def test_rgb_and_grey_pairs_agree():
    left, right = textured_pair(seed=5)
    wrong = np.full(left.shape, TRUE_PX, np.float32)
    wrong[:, 50:58] = 2.0
    grey = propagate_disparity(left, right, wrong).disparity_px
    rgb = propagate_disparity(np.repeat(left[..., None], 3, -1),
                              np.repeat(right[..., None], 3, -1), wrong).disparity_px
    np.testing.assert_array_equal(rgb, grey)


def test_adapter_propagates_after_the_model():
    torch = pytest.importorskip("torch")

    class Constant(torch.nn.Module):
        """A disparity of 14 px in a band of columns, 6 px elsewhere."""

        def forward(self, left, right):
            out = torch.full_like(left[:, :1], TRUE_PX) + 0.0 * right.mean()
            out[..., 40:60] = 14.0
            return out

    left, right = textured_pair()

    def to_u8(image):
        return np.repeat((image * 255).astype(np.uint8)[..., None], 3, -1)

    on = load_backbone(Constant(), "generic", census_propagation=True)
    fixed = on(to_u8(left), to_u8(right))
    assert np.all(fixed[4:-4, 40:60] == TRUE_PX)
    assert on.last_propagated_fraction > 0.15
    assert "census propagation: on" in on.describe()
    off = load_backbone(Constant(), "generic")
    assert np.all(off(to_u8(left), to_u8(right))[:, 40:60] == 14.0)
    assert off.last_propagated_fraction is None and "census propagation: off" in off.describe()


@pytest.mark.parametrize("switch", ["census_propagation", "segment_planes"])
def test_bundled_standin_has_its_image_stages_on_and_each_can_be_switched_off(switch):
    pytest.importorskip("onnxruntime")
    assert getattr(load_backbone("default").spec, switch)
    assert not getattr(load_backbone("default", **{switch: False}).spec, switch)
    assert not getattr(load_backbone("default", StereoSpec(name="mine")).spec, switch)


@pytest.mark.parametrize(("switch", "value"), [("census_propagation", 1),
                                               ("segment_planes", "yes")])
def test_bad_image_stage_setting(switch, value):
    with pytest.raises(BackboneError, match=f"{switch}: expected True or False, got {value!r}"):
        StereoSpec(**{switch: value})


def test_uint8_and_float_pairs_agree():
    left, right = textured_pair(seed=6)
    wrong = np.full(left.shape, TRUE_PX, np.float32)
    wrong[:, 50:58] = 2.0
    as_u8 = [np.rint(image * 255).astype(np.uint8) for image in (left, right)]
    from_u8 = propagate_disparity(*as_u8, wrong).disparity_px
    from_float = propagate_disparity(*(image / np.float32(255) for image in as_u8),
                                     wrong).disparity_px
    np.testing.assert_array_equal(from_u8, from_float)


@pytest.mark.parametrize(
    ("args", "error", "message"),
    [
        ((np.zeros((8, 8)), np.zeros((8, 9)), np.zeros((8, 8), np.float32)), ImageError,
         r"right: expected the left image's size \(8, 8\), got \(8, 9\)"),
        ((np.full((8, 8), 2.0), np.zeros((8, 8)), np.zeros((8, 8), np.float32)), ImageError,
         r"left: expected float values in \[0, 1\]"),
        ((np.zeros((8, 8)), np.zeros((8, 8)), np.zeros((8, 7), np.float32)), DisparityError,
         r"disparity_px: expected shape \(8, 8\), got \(8, 7\)"),
        ((np.zeros((8, 8)), np.zeros((8, 8)), np.zeros((8, 8), np.int16)), DisparityError,
         "disparity_px: expected float disparity in pixels"),
    ],
)
@pytest.mark.parametrize("stage", [propagate_disparity, fit_segment_planes])
def test_bad_inputs_say_what_was_expected(args, error, message, stage):
    with pytest.raises(error, match=message):
        stage(*args)


def test_a_seed_the_right_view_contradicts_is_not_taken():
    # A foreground band at 14 px over a background at 6 px: the background just left of
    # the band is hidden in the right view. There a 9x9 window that reaches the band
    # matches best at the foreground's disparity, but the right view's best at that match
    # is the background: the seed is refused and the truth stays.
    rng = np.random.default_rng(7)
    height, width, fg_px, bg_px = 48, 160, 14, int(TRUE_PX)
    background = rng.random((height, width + 40)).astype(np.float32)
    foreground = rng.random((height, width + 40)).astype(np.float32)
    band = slice(80, 110)  # the band's columns in the left image
    left = background[:, 20 - bg_px:20 - bg_px + width].copy()
    left[:, band] = foreground[:, band]
    right = background[:, 20:20 + width].copy()
    right[:, band.start - fg_px:band.stop - fg_px] = foreground[:, band]
    truth = np.full((height, width), TRUE_PX, np.float32)
    truth[:, band] = fg_px
    result = propagate_disparity(left, right, truth).disparity_px
    # seen in the left view only (the column beside the band is either's)
    hidden = slice(band.start - (fg_px - bg_px), band.start - 1)
    assert np.all(result[6:-6, hidden] == TRUE_PX)


@pytest.mark.parametrize("shape", [(2, 2), (5, 200), (200, 5), (9, 9), (20, 60)])
def test_images_smaller_than_the_offsets_run(shape):
    # Offsets (up to 24 px) and the seed window (9 px) reach past such maps' edges.
    rng = np.random.default_rng(8)
    left, right = (rng.random(shape).astype(np.float32) for _ in range(2))
    disparity = rng.uniform(0.0, 30.0, shape).astype(np.float32)
    disparity[0, 0] = np.nan
    result = propagate_disparity(left, right, disparity).disparity_px
    assert result.shape == shape
    np.testing.assert_array_equal(np.isnan(result), np.isnan(disparity))


@pytest.mark.parametrize("stage", [propagate_disparity, fit_segment_planes])
def test_a_census_computed_once_gives_the_same_answer(stage):
    left, right = textured_pair(seed=7)
    wrong = np.full(left.shape, TRUE_PX, np.float32)
    wrong[:, 50:58] = 2.0
    census = census_pair(left, right)
    np.testing.assert_array_equal(stage(left, right, wrong, census=census).disparity_px,
                                  stage(left, right, wrong).disparity_px)
    with pytest.raises(ImageError, match=r"census: expected census_pair's two \(H, W\) uint32"):
        stage(left, right, wrong, census=(census[0], census[1][:, 1:]))
