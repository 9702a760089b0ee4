"""Segment planes: a slanted wall's wandering values made planar, what the images keep (a
curved surface, a depth edge, pixels without a value), and the switch on the adapters
(the stand-in's default, a bad setting and bad inputs are tested with census
propagation's)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from srde_fusion.adapters import load_backbone, segment_planes
from srde_fusion.adapters.segment_planes import fit_segment_planes

HEIGHT, WIDTH = 96, 160
MEASURED = np.s_[:, 40:]  # right of every match that leaves the right image


def pair_for(disparity_px: np.ndarray, seed: int = 0, contrast: float = 1.0):
    """A left view made from a random right texture and a true left disparity map.

    ``left[y, x] = right[y, x - d(y, x)]``, bilinear; the texture is smoothed over a few
    pixels so that the sub-pixel shifts are well defined.
    """
    rng = np.random.default_rng(seed)
    right = cv2.GaussianBlur(rng.random((HEIGHT, WIDTH)).astype(np.float32), (0, 0), 1.2)
    right = 0.5 + contrast * (right - right.mean())
    x, y = np.meshgrid(np.arange(WIDTH, dtype=np.float32), np.arange(HEIGHT, dtype=np.float32))
    left = cv2.remap(right, x - disparity_px.astype(np.float32), y, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REFLECT_101)
    return np.clip(left, 0, 1), np.clip(right, 0, 1)


def slanted_wall():
    """A slanted plane, 20 px at the left edge to about 27 px at the bottom right."""
    y, x = np.mgrid[:HEIGHT, :WIDTH].astype(np.float32)
    return (20.0 + 0.03 * x + 0.02 * y).astype(np.float32)


def blotches(seed: int = 1, amplitude_px: float = 1.5) -> np.ndarray:
    """Smooth errors of up to ``amplitude_px`` in blobs a few pixels across, like a
    network's on a weak texture."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.standard_normal((HEIGHT, WIDTH)).astype(np.float32), (0, 0), 2)
    return (amplitude_px * noise / np.abs(noise).max()).astype(np.float32)


def test_a_faint_slanted_wall_becomes_its_plane():
    truth = slanted_wall()
    # A faint texture: the census still reads it, but the window costs of nearby values
    # are too close to pick one.
    left, right = pair_for(truth, contrast=0.05)
    wandering = truth + blotches()
    result = fit_segment_planes(left, right, wandering)
    before = np.abs(wandering - truth)[MEASURED].mean()
    after = np.abs(result.disparity_px - truth)[MEASURED].mean()
    assert before > 0.3
    assert after < 0.4 * before
    assert result.changed_fraction == pytest.approx(np.mean(result.disparity_px != wandering))
    assert result.changed_fraction > 0.5 and result.planar_fraction > 0.8


def test_a_curved_surface_keeps_the_values_its_texture_tells():
    y, x = np.mgrid[:HEIGHT, :WIDTH].astype(np.float32)
    # A corrugated sheet: within 1 px of a plane over most of a segment (so its segments
    # count as planar), up to 2 px off it elsewhere.
    truth = (20.0 + 2.0 * np.sin(2 * np.pi * x / 48)).astype(np.float32)
    left, right = pair_for(truth, seed=2)
    kept = fit_segment_planes(left, right, truth)
    # Without the images' say, the planes would flatten it: the check is what keeps it
    # (to the level it can tell: values within half a pixel cost the same).
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(segment_planes, "COST_TOLERANCE_BITS", 1e6)
        flattened = fit_segment_planes(left, right, truth)
    assert flattened.planar_fraction == 1.0
    error_flattened = np.abs(flattened.disparity_px - truth)[MEASURED].mean()
    error_kept = np.abs(kept.disparity_px - truth)[MEASURED].mean()
    assert error_flattened > 0.4
    assert error_kept < 0.3 * error_flattened


def test_a_depth_edge_is_not_bridged_even_where_the_images_are_indifferent():
    truth = np.full((HEIGHT, WIDTH), 12.0, np.float32)
    truth[30:70, 70:120] = 30.0  # a box in front of a wall
    left, right = pair_for(truth, seed=3, contrast=0.05)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(segment_planes, "COST_TOLERANCE_BITS", 1e6)  # only the distance rule
        result = fit_segment_planes(left, right, truth + 0.5 * blotches(seed=4)).disparity_px
    # A segment straddling the edge fits one side's plane; the other side's values are
    # further from it than REPLACE_PX and stay.
    assert np.abs(result - truth).max() < 0.5 + 3.0
    assert np.all(result[30:70, 70:120] > 26.0) and np.all(result[:, :60] < 16.0)


def test_a_segment_that_is_no_plane_keeps_its_values():
    rng = np.random.default_rng(5)
    scattered = rng.uniform(18.0, 24.0, (HEIGHT, WIDTH)).astype(np.float32)
    left, right = pair_for(np.full((HEIGHT, WIDTH), 21.0, np.float32), seed=6, contrast=0.05)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(segment_planes, "COST_TOLERANCE_BITS", 1e6)  # only the planarity rule
        result = fit_segment_planes(left, right, scattered)
    assert result.planar_fraction == 0.0 and result.changed_fraction == 0.0
    np.testing.assert_array_equal(result.disparity_px, scattered)


def test_pixels_without_a_value_are_returned_as_given_and_never_fitted():
    truth = slanted_wall()
    left, right = pair_for(truth, contrast=0.05)
    wandering = truth + blotches()
    holes = wandering.copy()
    holes[20:40, 60:100] = np.nan
    holes[50, 80:83] = (-1.0, np.inf, -np.inf)
    holes[60:64, 100:104] = 1e4  # one wild value: outweighed in its segment's fit
    result = fit_segment_planes(left, right, holes).disparity_px
    assert np.isnan(result[20:40, 60:100]).all()
    assert result[50, 80] == -1.0 and result[50, 81] == np.inf and result[50, 82] == -np.inf
    assert np.all(result[60:64, 100:104] == 1e4)  # far from every plane: kept
    rest = np.isfinite(holes) & (holes >= 0) & (holes < 1e3)
    rest[:, :40] = False
    assert np.abs(result - truth)[rest].mean() < 0.5 * np.abs(wandering - truth)[rest].mean()
    empty = fit_segment_planes(left, right, np.full(left.shape, np.nan, np.float32))
    assert np.isnan(empty.disparity_px).all() and empty.changed_fraction == 0.0


def test_rgb_uint8_and_float_pairs_are_accepted():
    truth = slanted_wall()
    left, right = pair_for(truth, contrast=0.05)
    wandering = truth + blotches()
    for pair in ((left, right),
                 tuple(np.repeat(np.rint(v * 255).astype(np.uint8)[..., None], 3, -1)
                       for v in (left, right))):
        result = fit_segment_planes(*pair, wandering).disparity_px
        assert result.dtype == np.float32 and result.shape == truth.shape
        assert np.abs(result - truth)[MEASURED].mean() < 0.5 * np.abs(wandering - truth)[
            MEASURED].mean()


def test_adapter_runs_the_planes_last():
    torch = pytest.importorskip("torch")
    truth = slanted_wall()
    left, right = pair_for(truth, contrast=0.05)
    wandering = truth + blotches()

    class Wandering(torch.nn.Module):
        """The slanted wall's disparity with its blotches, whatever the images."""

        def forward(self, left, right):
            return torch.from_numpy(wandering)[None, None] + 0.0 * (left + right).mean()

    def to_u8(image):
        return np.repeat(np.rint(image * 255).astype(np.uint8)[..., None], 3, -1)

    on = load_backbone(Wandering(), "generic", segment_planes=True)
    planar = on(to_u8(left), to_u8(right))
    assert np.abs(planar - truth)[MEASURED].mean() < 0.5 * np.abs(wandering - truth)[
        MEASURED].mean()
    assert on.last_planes_fraction > 0.5
    assert "segment planes: on" in on.describe()
    off = load_backbone(Wandering(), "generic")
    np.testing.assert_array_equal(off(to_u8(left), to_u8(right)), wandering)
    assert off.last_planes_fraction is None and "segment planes: off" in off.describe()


def test_a_strip_too_thin_to_fix_a_tilt_keeps_its_values():
    rng = np.random.default_rng(7)
    image = rng.random((4, 60)).astype(np.float32)
    values = (5.0 + rng.uniform(-0.5, 0.5, (4, 60))).astype(np.float32)
    result = fit_segment_planes(image, image, values)
    assert result.planar_fraction == 0.0
    np.testing.assert_array_equal(result.disparity_px, values)
