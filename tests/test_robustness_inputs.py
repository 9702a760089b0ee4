"""Robustness of the public entry points to bad arrays: views, masks, disparity, metrics.

Every case is either an SRDEError subclass whose message names the argument and the
problem, or a result whose ``status``/``reason`` explains it. Random arrays of odd
dtypes and shapes (hypothesis) raise nothing but SRDEError.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from srde_fusion.errors import DisparityError, ImageError, LightError, MaskError, SRDEError
from srde_fusion.evaluation import evaluate
from srde_fusion.fusion import fuse, postprocess
from srde_fusion.geometry import CameraRig
from srde_fusion.srde import SRDE, SRDE_STATUSES, detect_highlight
from tests.support import H, W, box_mask, grid_rig, highlight_views, true_centers


@pytest.fixture(scope="module")
def rig() -> CameraRig:
    return grid_rig()


@pytest.fixture(scope="module")
def views(rig) -> list[np.ndarray]:
    return highlight_views(true_centers(rig))


@pytest.fixture(scope="module")
def srde(rig) -> SRDE:
    return SRDE(rig, refine=False)


MASK = box_mask()
BACKBONE = np.full((H, W), 7.5, np.float32)


def _replace(views, index, image):
    out = list(views)
    out[index] = image
    return out


# ------------------------------------------------------------------ views
@pytest.mark.parametrize("make, match", [
    (lambda v: v[:8], r"views: expected 9 images \(one per rig camera\), got 8"),
    (lambda v: [*v, v[0]], r"views: expected 9 images \(one per rig camera\), got 10"),
    (lambda v: [], r"views: expected 9 images \(one per rig camera\), got 0"),
    (lambda v: _replace(v, 3, v[3][:-1]), r"views\[3\]: expected the same size as views\[0\] "
     r"\(200x150\), got 200x149"),
    (lambda v: [x[:, :-2] for x in v], "views: expected images of the rig's size 200x150, "
     "got 198x150"),
    (lambda v: _replace(v, 0, v[0].astype(np.uint16) * 257),
     r"views\[0\]: expected dtype uint8 or float in \[0, 1\], got uint16"),
    (lambda v: _replace(v, 1, v[1].astype(np.int64)),
     r"views\[1\]: expected dtype uint8 or float in \[0, 1\], got int64"),
    (lambda v: _replace(v, 2, v[2] > 128), r"views\[2\]: expected dtype uint8 .* got bool"),
    (lambda v: _replace(v, 2, v[2].astype(np.float32)),  # float 0..255, not 0..1
     r"views\[2\]: expected float values in \[0, 1\], got range \[.*, 255\]"),
    (lambda v: _replace(v, 2, np.where(v[2] > 200, 3.5e38, 0.0)),  # beyond float32's range
     r"views\[2\]: expected float values in \[0, 1\], got range \[0, 3.5e\+38\]"),
    (lambda v: _replace(v, 5, np.where(v[5] > 200, np.nan, v[5] / 255.0)),
     r"views\[5\]: expected finite float values in \[0, 1\], got NaN or inf"),
    (lambda v: _replace(v, 4, np.dstack([v[4], v[4][:, :, :1]])),
     r"views\[4\]: expected shape \(H, W\) or \(H, W, 3\), got \(150, 200, 4\)"),
    (lambda v: _replace(v, 4, v[4][None]), r"views\[4\]: expected shape \(H, W\) or \(H, W, 3\)"),
    (lambda v: _replace(v, 6, v[6].tolist()), r"views\[6\]: expected a numpy array"),
    (lambda v: "cam0.png", "views: expected a sequence of images, got str"),
    (lambda v: None, "views: expected a sequence of images, got NoneType"),
])
def test_bad_views(rig, views, srde, make, match):
    bad = make(views)
    with pytest.raises(ImageError, match=match):
        srde.estimate(bad, MASK)
    with pytest.raises(ImageError, match=match):
        fuse(BACKBONE, bad, rig, [MASK], srde)
    with pytest.raises(ImageError, match=match):
        postprocess(BACKBONE, bad, rig, [MASK])


def test_grey_and_colour_views_may_be_mixed(rig, views, srde):
    # A grey view is the luminance of its RGB twin: the estimate does not change.
    mixed = [v[:, :, 0] if j % 2 else v for j, v in enumerate(views)]
    colour, grey = srde.estimate(views, MASK), srde.estimate(mixed, MASK)
    assert colour.ok and grey.ok
    np.testing.assert_allclose(grey.highlight_centers, colour.highlight_centers, atol=1e-6)
    np.testing.assert_allclose(grey.disparity, colour.disparity, atol=1e-5, equal_nan=True)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float_views_in_unit_range_match_8_bit(views, srde, dtype):
    as_float = [(v / 255.0).astype(dtype) for v in views]
    a, b = srde.estimate(views, MASK), srde.estimate(as_float, MASK)
    assert a.ok and b.ok
    np.testing.assert_allclose(b.highlight_centers, a.highlight_centers, atol=1e-3)


@pytest.mark.parametrize("value, name", [(0, "black"), (255, "saturated"), (128, "flat grey")])
def test_featureless_views_have_no_highlight(rig, srde, value, name):
    flat = [np.full((H, W, 3), value, np.uint8)] * rig.n_cameras
    result = srde.estimate(flat, MASK)
    assert result.status == "no_highlight" and not result
    assert result.reason.startswith("view 4 (cam4, reference): no bright blob")
    assert np.isnan(result.disparity).all()
    fused = fuse(BACKBONE, flat, rig, [MASK], srde)
    assert fused.objects[0].status == "fallback"
    assert "SRDE failed (no_highlight)" in fused.objects[0].reason
    np.testing.assert_array_equal(fused.disparity, BACKBONE)


def test_saturated_everywhere_but_the_object(rig, views, srde):
    # A blown-out background must not be taken for the highlight: the search stays in
    # the (eroded) mask.
    bright = [np.where(MASK[:, :, None], v, 255).astype(np.uint8) for v in views]
    assert srde.estimate(bright, MASK).ok


# ------------------------------------------------------------------ masks and regions
@pytest.mark.parametrize("mask, error, match", [
    (np.zeros((H, W), bool), MaskError, "mask: expected at least one pixel inside the mask"),
    (MASK[:-1], MaskError, r"mask: expected shape \(150, 200\), got \(149, 200\)"),
    (MASK.T, MaskError, r"mask: expected shape \(150, 200\), got \(200, 150\)"),
    (MASK.astype(complex), MaskError, "mask: expected a bool or integer mask, got dtype "
     "complex128"),
    (MASK.tolist(), MaskError, "mask: expected a numpy array of shape"),
    (None, MaskError, "mask: expected a numpy array of shape"),
])
def test_bad_mask_for_srde(views, srde, mask, error, match):
    with pytest.raises(error, match=match):
        srde.estimate(views, mask)


def test_float_labels_beyond_the_integer_range(rig, views):
    labels = np.zeros((H, W), np.float16)
    labels[MASK] = 6e4
    assert len(postprocess(BACKBONE, views, rig, labels).objects) == 1
    labels = labels.astype(np.float64) * 1e15
    with pytest.raises(MaskError, match=r"masks: expected integer labels \(0 = background\), "
                       "got values up to 6e\\+19"):
        postprocess(BACKBONE, views, rig, labels)


def test_integer_and_float_masks_mean_non_zero(views, srde):
    expected = srde.estimate(views, MASK)
    for mask in (MASK.astype(np.uint8) * 255, MASK.astype(np.int64), MASK.astype(np.float32)):
        result = srde.estimate(views, mask)
        assert result.ok
        np.testing.assert_array_equal(result.disparity, expected.disparity)


def test_a_mask_smaller_than_its_erosion(views, srde):
    tiny = np.zeros((H, W), bool)
    tiny[50:53, 90:93] = True
    result = srde.estimate(views, tiny)
    assert result.status == "mask_too_small"
    assert result.reason == ("mask: nothing left to search after eroding the 9-px mask by 3 px")


def test_detect_highlight_with_an_empty_region_is_a_result(views):
    result = detect_highlight(views[4], np.zeros((H, W), bool))
    assert not result and result.reason == "search region is empty"


# ------------------------------------------------------------------ light
@pytest.mark.parametrize("light, match", [
    ([0.1, 0.2], r"light: expected 3 finite numbers \(x, y, z\) in metres"),
    ([0.1, np.nan, 0.2], "light: expected 3 finite numbers"),
    ([0.1, np.inf, 0.2], "light: expected 3 finite numbers"),
    ("above", r"light: expected 3 numbers \(x, y, z\) in metres, got 'above'"),
    ([[0.1, 0.2], [0.3, 0.4]], r"light: expected \(x, y, z\) in metres or \(K, 3\)"),
    ([0.0, -1e200, 0.0], r"light: expected a position within 1e\+12 m of the reference camera, "
     r"got one 1e\+200 m away"),
])
def test_bad_light(rig, views, light, match):
    with pytest.raises(LightError, match=match):
        SRDE(rig, light=light)


def test_a_light_beyond_any_use_is_refused_at_every_entry(rig, views):
    far = [1e300, 1e300, 1e300]
    with pytest.raises(LightError, match="expected a position within"):
        postprocess(BACKBONE, views, rig, [MASK], light=far)
    with pytest.raises(LightError, match="expected a position within"):
        fuse(BACKBONE, views, rig.with_light(far), [MASK])


def test_no_light_anywhere(views):
    rig = grid_rig(light_m=None)
    with pytest.raises(LightError, match="expected a light position .* got neither"):
        SRDE(rig)
    with pytest.raises(LightError, match="given here or in the rig, got None"):
        postprocess(BACKBONE, views, rig, [MASK])


# ------------------------------------------------------------------ metrics
@pytest.mark.parametrize("pred, gt, region, error, match", [
    (BACKBONE[:-1], BACKBONE, None, DisparityError, r"pred: expected the shape of gt"),
    (BACKBONE[None, None], BACKBONE, None, DisparityError, r"pred: expected shape \(H, W\)"),
    (BACKBONE.astype(complex), BACKBONE, None, DisparityError,
     "pred: expected a float disparity map, got dtype complex128"),
    (BACKBONE, "gt.pfm", None, DisparityError, "gt: expected a numpy array"),
    (BACKBONE, BACKBONE, MASK[:, :-1], MaskError, r"region: expected shape \(150, 200\)"),
])
def test_bad_metric_inputs(pred, gt, region, error, match):
    with pytest.raises(error, match=match):
        evaluate(pred, gt, region)


def test_metrics_of_nothing_are_nan():
    m = evaluate(BACKBONE, np.full((H, W), np.nan, np.float32))
    assert m["valid_px"] == 0 and np.isnan(m["epe"]) and np.isnan(m["bad1"])
    m = evaluate(np.full((H, W), np.inf, np.float32), BACKBONE)
    assert np.isnan(m["epe"]) and m["bad1"] == 1.0 and m["invalid_pred_px"] == H * W


# ------------------------------------------------------------------ random arrays (hypothesis)
_DTYPES = st.sampled_from([np.uint8, np.int8, np.uint16, np.int32, np.int64, np.float16,
                           np.float32, np.float64, np.bool_, np.complex64, np.uint64])
# Shapes near the valid ones (the rig's, transposed, with odd channel counts) and random.
_NEAR_SHAPES = st.sampled_from([(H, W), (H, W, 3), (H, W, 1), (H, W, 4), (W, H), (1, H, W),
                                (H, W - 1), (3, H, W), (H, W, 3, 1), (0, W), ()])
_SHAPES = _NEAR_SHAPES | hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=6)


@st.composite
def odd_arrays(draw):
    dtype = np.dtype(draw(_DTYPES))
    shape = draw(_SHAPES)
    if int(np.prod(shape)) > 4 * H * W:
        shape = (H, W)
    # Cheap, value-varied fills: one random element value broadcast plus a random patch,
    # rather than drawing every element (hypothesis would be too slow on images).
    fill = draw(hnp.from_dtype(dtype))
    array = np.full(shape, fill, dtype=dtype)
    if array.size:
        array.flat[draw(st.integers(0, array.size - 1))] = draw(hnp.from_dtype(dtype))
    return array


def _only_srde_errors(call):
    try:
        return call()
    except SRDEError:
        return None


_SETTINGS = settings(max_examples=40, suppress_health_check=[HealthCheck.too_slow])


@_SETTINGS
@given(array=odd_arrays(), slot=st.sampled_from(["views", "one view", "mask"]))
def test_random_arrays_into_srde_estimate(rig, views, srde, array, slot):
    if slot == "views":
        args = ([array] * rig.n_cameras, MASK)
    elif slot == "one view":
        args = (_replace(views, 4, array), MASK)
    else:
        args = (views, array)
    result = _only_srde_errors(lambda: srde.estimate(*args))
    if result is not None:
        assert result.status in SRDE_STATUSES
        assert result.disparity.shape == (H, W) and result.disparity.dtype == np.float32


@_SETTINGS
@given(array=odd_arrays(), slot=st.sampled_from(["backbone", "masks", "mask list", "view"]))
def test_random_arrays_into_fuse_and_postprocess(rig, views, srde, array, slot):
    backbone, masks, vs = BACKBONE, [MASK], views
    if slot == "backbone":
        backbone = array
    elif slot == "masks":
        masks = array
    elif slot == "mask list":
        masks = [MASK, array]
    else:
        vs = _replace(views, 0, array)
    for call in (lambda: fuse(backbone, vs, rig, masks, srde),
                 lambda: postprocess(backbone, vs, rig, masks, srde_method="default")):
        result = _only_srde_errors(call)
        if result is not None:
            assert result.disparity.shape == (H, W) and result.disparity.dtype == np.float32
            assert all(o.status in ("srde", "fallback") for o in result.objects)


@_SETTINGS
@given(image=odd_arrays(), region=odd_arrays())
def test_random_arrays_into_detect_highlight(views, image, region):
    _only_srde_errors(lambda: detect_highlight(image))
    _only_srde_errors(lambda: detect_highlight(views[4], region))
    result = _only_srde_errors(lambda: detect_highlight(image, region))
    if result is not None:
        assert bool(result) == result.found and (result.found or result.reason)


@_SETTINGS
@given(pred=odd_arrays(), gt=odd_arrays(), region=st.none() | odd_arrays())
def test_random_arrays_into_evaluate(pred, gt, region):
    metrics = _only_srde_errors(lambda: evaluate(pred, gt, region))
    if metrics is not None:
        for key in ("bad1", "bmp0.1", "d1"):
            assert np.isnan(metrics[key]) or 0.0 <= metrics[key] <= 1.0
        assert metrics["valid_px"] >= 0


# ------------------------------------------------------------------ longer runs (-m slow)
_MANY = settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.slow
@_MANY
@given(array=odd_arrays(), slot=st.sampled_from(["views", "one view", "mask"]))
def test_random_arrays_into_srde_estimate_many(rig, views, srde, array, slot):
    test_random_arrays_into_srde_estimate.hypothesis.inner_test(
        rig=rig, views=views, srde=srde, array=array, slot=slot)


@pytest.mark.slow
@_MANY
@given(array=odd_arrays(), slot=st.sampled_from(["backbone", "masks", "mask list", "view"]))
def test_random_arrays_into_fuse_and_postprocess_many(rig, views, srde, array, slot):
    test_random_arrays_into_fuse_and_postprocess.hypothesis.inner_test(
        rig=rig, views=views, srde=srde, array=array, slot=slot)
