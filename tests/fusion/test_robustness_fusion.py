"""Fusion never loses a valid backbone pixel, and nothing modifies its inputs.

The invariant (DESIGN §2): outside the objects whose SRDE plane fusion used, every finite
non-negative backbone pixel comes out bit for bit (as float32); inside them a pixel is
either that backbone value or a finite, non-negative value of the object's SRDE map.
Checked on hand-picked edge cases and by hypothesis over random backbone maps (NaN, inf,
negative values, odd dtypes), random and overlapping masks and random SRDE outcomes
(stand-ins that succeed with wild maps or fail, and the real estimator).
"""

from __future__ import annotations

import hashlib
import pickle
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from srde_fusion.errors import DisparityError, MaskError, RigError, SRDEError
from srde_fusion.evaluation import evaluate
from srde_fusion.fusion import HybridStereo, fuse, postprocess
from srde_fusion.geometry import CameraRig, Plane
from srde_fusion.srde import SRDE, detect_highlight
from tests.support import (
    PLANE,
    H,
    W,
    box_mask,
    grid_rig,
    highlight_views,
    masked_epe,
    true_centers,
    true_disparity,
)

MASK = box_mask()
BACKBONE_FLAT = np.full((H, W), 3.0, np.float32)


@pytest.fixture(scope="module")
def rig() -> CameraRig:
    return grid_rig()


@pytest.fixture(scope="module")
def views(rig) -> list[np.ndarray]:
    return highlight_views(true_centers(rig))


@pytest.fixture(scope="module")
def srde(rig) -> SRDE:
    return SRDE(rig, refine=False)


@dataclass(frozen=True)
class FakeResult:
    """What an estimator plugged into ``fuse`` may return: a status and a map."""

    status: str
    disparity: np.ndarray
    plane: Plane | None = None
    reason: str = ""


class FakeSRDE:
    """An estimator that returns prepared outcomes, one per call, in order."""

    def __init__(self, outcomes):
        self.outcomes = list(outcomes)
        self.calls = 0

    def estimate(self, views, mask):
        outcome = self.outcomes[self.calls % len(self.outcomes)]
        self.calls += 1
        return outcome


def _fingerprint(value) -> str:
    """Hash of arrays (values, dtype, shape, flags' writeability) nested in lists."""
    h = hashlib.sha256()
    for a in value if isinstance(value, (list, tuple)) else [value]:
        a = np.asarray(a)
        h.update(pickle.dumps((a.dtype.str, a.shape)))
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _f32_bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float32).view(np.uint32)


def check_invariant(backbone_in, masks, result) -> None:
    """Assert the fusion invariant for one call (see the module docstring)."""
    backbone = np.asarray(backbone_in)
    if backbone.ndim == 3:
        backbone = backbone[0]
    with np.errstate(over="ignore", invalid="ignore"):
        b32 = backbone.astype(np.float32)
        valid = np.isfinite(b32) & (b32 >= 0)
    fused, source = result.disparity, result.source
    assert fused.dtype == np.float32 and fused.shape == b32.shape
    assert source.dtype == np.int32 and source.shape == b32.shape
    used = {o.index for o in result.objects if o.status == "srde"}
    assert set(np.unique(source)) <= {0} | used
    kept = source == 0
    # Backbone pixels kept: bit for bit where valid, NaN where not.
    np.testing.assert_array_equal(_f32_bits(fused[kept & valid]), _f32_bits(b32[kept & valid]))
    assert np.isnan(fused[kept & ~valid]).all()
    # Replaced pixels: inside their object's mask, finite and non-negative SRDE values.
    for report in result.objects:
        k = report.index
        mine = source == k
        if report.status == "fallback":
            assert report.replaced_px == 0 and not mine.any()
            continue
        assert report.status == "srde" and report.replaced_px == int(mine.sum())
        assert not (mine & ~masks[k - 1]).any()
        srde_map = np.asarray(report.srde.disparity, dtype=np.float32)
        np.testing.assert_array_equal(_f32_bits(fused[mine]), _f32_bits(srde_map[mine]))
        assert np.isfinite(fused[mine]).all() and (fused[mine] >= 0).all()
    # The backbone as fused is the input with invalid pixels as NaN.
    np.testing.assert_array_equal(_f32_bits(result.backbone_disparity[valid]),
                                  _f32_bits(b32[valid]))
    assert np.isnan(result.backbone_disparity[~valid]).all()


# ------------------------------------------------------------------ backbone edge cases
def _sprinkled(seed=0, dtype=np.float32):
    rng = np.random.default_rng(seed)
    b = rng.uniform(0.0, 60.0, (H, W))
    for value, fraction in ((np.nan, 0.1), (np.inf, 0.05), (-np.inf, 0.05), (-3.0, 0.1),
                            (0.0, 0.02), (-0.0, 0.02)):
        b[rng.random((H, W)) < fraction] = value
    return b.astype(dtype)


@pytest.mark.parametrize("backbone", [
    _sprinkled(0), _sprinkled(1, np.float64), _sprinkled(2, np.float16),
    np.full((H, W), np.nan, np.float32), np.full((H, W), -1.0), np.full((H, W), np.inf),
    np.full((H, W), 1e300),  # finite in float64, inf as float32: invalid
    _sprinkled(3)[None],  # (1, H, W), as a network returns it
])
def test_backbone_with_invalid_values(rig, views, srde, backbone):
    before = _fingerprint(backbone)
    result = fuse(backbone, views, rig, [MASK], srde)
    assert _fingerprint(backbone) == before
    assert result.objects[0].status == "srde"
    check_invariant(backbone, [MASK], result)
    # SRDE fills the object whatever the backbone held there.
    assert masked_epe(result.disparity, true_disparity(rig), MASK) < 0.1


@pytest.mark.parametrize("backbone, match", [
    (np.zeros((H, W - 1), np.float32), r"backbone_disparity: expected shape \(150, 200\), "
     r"got \(150, 199\)"),
    (np.zeros((W, H), np.float32), r"backbone_disparity: expected shape \(150, 200\), got "
     r"\(200, 150\)"),
    (np.zeros((H, W, 2), np.float32), r"backbone_disparity: expected shape \(H, W\), got "
     r"\(150, 200, 2\)"),
    (np.zeros((H, W), bool), "backbone_disparity: expected a float array, got dtype bool"),
    # Fixed-point maps (OpenCV SGBM's int16 x 16) must be scaled by the caller.
    (np.arange(H * W, dtype=np.int16).reshape(H, W), "expected float disparity in pixels, got "
     "dtype int16; fixed-point maps need scaling first"),
    (np.zeros((H, W), complex), "expected a float array, got dtype complex128"),
    ([[1.0]], "backbone_disparity: expected a numpy array"),
])
def test_backbone_of_the_wrong_kind(rig, views, srde, backbone, match):
    with pytest.raises(DisparityError, match=match):
        fuse(backbone, views, rig, [MASK], srde)


# ------------------------------------------------------------------ masks
def test_no_masks_keeps_the_backbone(rig, views):
    backbone = _sprinkled(4)
    for masks in ([], np.zeros((0, H, W), bool)):
        result = fuse(backbone, views, rig, masks)
        assert result.objects == () and (result.source == 0).all()
        check_invariant(backbone, [], result)


@pytest.mark.parametrize("masks, match", [
    ([MASK, np.zeros((H, W), bool)], r"masks\[1\]: expected at least one pixel inside"),
    ([MASK[:, :-1]], r"masks\[0\]: expected shape \(150, 200\), got \(150, 199\)"),
    (np.zeros((2, 2, H, W), bool), r"masks: expected a list of \(H, W\) masks"),
    ("mask.png", "masks: expected a list of (H, W) bool masks, got str"),
    ([MASK.astype(complex)], r"masks\[0\]: expected a bool or integer mask"),
])
def test_bad_masks(rig, views, srde, masks, match):
    with pytest.raises(MaskError, match=match.replace("(H, W)", r"\(H, W\)")):
        fuse(np.zeros((H, W), np.float32), views, rig, masks, srde)


def test_a_mask_covering_the_whole_image(rig, views, srde):
    everything = np.ones((H, W), bool)
    backbone = _sprinkled(5)
    result = fuse(backbone, views, rig, [everything], srde)
    report = result.objects[0]
    # No outline to check against: SRDE is used, and the report says it went unchecked.
    assert report.status == "srde"
    assert report.reason.startswith("SRDE used unchecked: only 0 textured px")
    assert (result.source == 1).all()
    check_invariant(backbone, [everything], result)


def test_overlapping_masks_first_object_wins(rig, views):
    first, second = box_mask((40, 30, 120, 100)), box_mask((90, 60, 170, 130))
    overlap = first & second
    assert overlap.any()
    maps = [np.full((H, W), 11.0, np.float32), np.full((H, W), 22.0, np.float32)]
    fake = FakeSRDE([FakeResult("ok", m) for m in maps])
    backbone = _sprinkled(6)
    result = fuse(backbone, views, rig, [first, second], fake)
    assert (result.source[overlap] == 1).all() and (result.disparity[overlap] == 11.0).all()
    assert (result.disparity[second & ~first] == 22.0).all()
    assert result.objects[1].replaced_px == int((second & ~first).sum())
    check_invariant(backbone, [first, second], result)


def test_instance_labels_as_masks(rig, views):
    labels = np.zeros((H, W), np.int32)
    labels[30:60, 40:80] = 2
    labels[90:120, 100:150] = 7
    fake = FakeSRDE([FakeResult("ok", np.full((H, W), 9.0, np.float32))])
    result = fuse(_sprinkled(7), views, rig, labels, fake)
    assert [o.pixel_count for o in result.objects] == [30 * 40, 30 * 50]


@pytest.mark.parametrize("not_a_rig", [None, "rig.json", {"reference": 4}])
def test_a_rig_that_is_not_one(views, srde, not_a_rig):
    with pytest.raises(RigError, match="rig: expected a CameraRig, got"):
        fuse(BACKBONE_FLAT, views, not_a_rig, [MASK], srde)


@pytest.mark.parametrize("check", [True, {"width_px": 4}, "strict"])
def test_a_border_check_that_is_not_one(rig, views, srde, check):
    with pytest.raises(SRDEError, match="border_check: expected a BorderCheck or None, got"):
        fuse(BACKBONE_FLAT, views, rig, [MASK], srde, border_check=check)


# ------------------------------------------------------------------ estimators plugged in
def test_srde_values_that_are_not_valid_disparity_are_not_used(rig, views):
    srde_map = np.full((H, W), 12.0, np.float32)
    srde_map[40:50] = np.nan
    srde_map[50:60] = np.inf
    srde_map[60:70] = -4.0
    backbone = _sprinkled(8)
    result = fuse(backbone, views, rig, [MASK], FakeSRDE([FakeResult("ok", srde_map)]))
    check_invariant(backbone, [MASK], result)
    assert (result.disparity[MASK & (result.source == 1)] == 12.0).all()


@pytest.mark.parametrize("disparity", [np.zeros((H, W - 1), np.float32),
                                       np.zeros((H, W, 3), np.float32)])
def test_an_estimator_returning_a_map_of_the_wrong_shape(rig, views, disparity):
    with pytest.raises(SRDEError, match=r"srde: expected estimate\(\) to return an \(150, 200\) "
                       "disparity map"):
        fuse(_sprinkled(9), views, rig, [MASK], FakeSRDE([FakeResult("ok", disparity)]))


@pytest.mark.parametrize("status", ["no_highlight", "grazing", "whatever"])
def test_failed_estimates_fall_back_with_their_reason(rig, views, status):
    fake = FakeSRDE([FakeResult(status, np.full((H, W), 5.0, np.float32),
                                reason="because")])
    backbone = _sprinkled(10)
    result = fuse(backbone, views, rig, [MASK], fake)
    assert result.objects[0].status == "fallback"
    assert result.objects[0].reason == f"SRDE failed ({status}): because"
    check_invariant(backbone, [MASK], result)


# ------------------------------------------------------------------ inputs stay untouched
def test_no_public_step_modifies_its_inputs(rig, views, srde, tmp_path):
    backbone = _sprinkled(11)
    masks = [MASK.copy(), box_mask((10, 10, 30, 30))]
    labels = np.zeros((H, W), np.int32)
    labels[MASK] = 3
    gt = true_disparity(rig).astype(np.float32)
    inputs = [backbone, masks, labels, views, gt]
    before = [_fingerprint(x) for x in inputs]
    srde.estimate(views, masks[0])
    detect_highlight(views[4], masks[0])
    fuse(backbone, views, rig, masks, srde)
    fuse(backbone, views, rig, labels, srde)
    postprocess(backbone, views, rig, masks)
    postprocess(backbone, views, rig, labels)
    postprocess(backbone, views, rig)  # the built-in segmenter
    HybridStereo(lambda left, right: backbone, rig, masker=lambda v, r: masks)(views)
    evaluate(backbone, gt, masks[0])
    assert [_fingerprint(x) for x in inputs] == before


def test_read_only_inputs_are_accepted(rig, views, srde):
    frozen_views = [v.copy() for v in views]
    for v in frozen_views:
        v.setflags(write=False)
    backbone, mask = _sprinkled(12), MASK.copy()
    backbone.setflags(write=False)
    mask.setflags(write=False)
    result = fuse(backbone, frozen_views, rig, [mask], srde)
    check_invariant(backbone, [mask], result)
    assert srde.estimate(frozen_views, mask).ok


# ------------------------------------------------------------------ the invariant, at random
@st.composite
def backbones(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    b = rng.uniform(draw(st.sampled_from([-10.0, 0.0])), 80.0, (H, W))
    for value in (np.nan, np.inf, -np.inf, -1.0, 0.0, -0.0, 1e300, 5e-324):
        b[rng.random((H, W)) < draw(st.sampled_from([0.0, 0.01, 0.2, 1.0]))] = value
    dtype = draw(st.sampled_from([np.float32, np.float64, np.float16]))
    with np.errstate(invalid="ignore", over="ignore"):
        return b.astype(dtype)


@st.composite
def rect_masks(draw):
    masks = []
    for _ in range(draw(st.integers(1, 4))):
        u0, v0 = draw(st.integers(0, W - 2)), draw(st.integers(0, H - 2))
        u1, v1 = draw(st.integers(u0 + 1, W)), draw(st.integers(v0 + 1, H))
        masks.append(box_mask((u0, v0, u1, v1)))
    return masks


@st.composite
def outcomes(draw, n):
    out = []
    for _ in range(n):
        kind = draw(st.sampled_from(["ok", "ok plane", "failed"]))
        rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
        disparity = rng.uniform(-5.0, 60.0, (H, W)).astype(np.float32)
        disparity[rng.random((H, W)) < 0.1] = np.nan
        disparity[rng.random((H, W)) < 0.05] = np.inf
        plane = None
        if kind == "ok plane":
            # A plane for the outline check: the true one or one grossly off.
            factor = draw(st.sampled_from([1.0, 0.3, 3.0]))
            plane = Plane(PLANE.normal, PLANE.offset_m / factor)
        out.append(FakeResult("failed" if kind == "failed" else "ok", disparity, plane))
    return out


_FAST = settings(max_examples=25, suppress_health_check=[HealthCheck.too_slow])


def _fuzz_fusion(rig, views, srde, backbone, masks, fake_outcomes, real):
    estimator = srde if real else FakeSRDE(fake_outcomes)
    snapshot = [_fingerprint(x) for x in (backbone, masks, views)]
    result = fuse(backbone, views, rig, masks, estimator)
    assert [_fingerprint(x) for x in (backbone, masks, views)] == snapshot
    check_invariant(backbone, masks, result)


@_FAST
@given(data=st.data(), backbone=backbones(), masks=rect_masks(), real=st.booleans())
def test_fusion_never_loses_a_valid_backbone_pixel(rig, views, srde, data, backbone, masks,
                                                   real):
    _fuzz_fusion(rig, views, srde, backbone, masks, data.draw(outcomes(len(masks))), real)


@pytest.mark.slow
@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), backbone=backbones(), masks=rect_masks(), real=st.booleans())
def test_fusion_never_loses_a_valid_backbone_pixel_many(rig, views, srde, data, backbone,
                                                        masks, real):
    _fuzz_fusion(rig, views, srde, backbone, masks, data.draw(outcomes(len(masks))), real)


# ------------------------------------------------------------------ a model around the user's
@pytest.mark.parametrize("output, error, match", [
    (np.zeros((H, W - 1), np.float32), DisparityError,
     r"backbone_disparity: expected shape \(150, 200\), got \(150, 199\)"),
    (None, DisparityError, "backbone_disparity: expected a numpy array .* got NoneType"),
    ([[1.0] * W] * H, DisparityError, "backbone_disparity: expected a numpy array .* got list"),
    (np.zeros((2, H, W), np.float32), DisparityError, r"expected shape \(H, W\)"),
])
def test_a_backbone_that_breaks_the_contract(rig, views, output, error, match):
    model = HybridStereo(lambda left, right: output, rig, masker=lambda v, r: [MASK])
    with pytest.raises(error, match=match):
        model(views)


@pytest.mark.parametrize("masks, match", [
    (None, "masks: expected a list of (H, W) bool masks, got NoneType"),
    ([MASK[:-1]], r"masks\[0\]: expected shape \(150, 200\)"),
    ([np.zeros((H, W), bool)], r"masks\[0\]: expected at least one pixel"),
])
def test_a_masker_that_breaks_the_contract(rig, views, masks, match):
    model = HybridStereo(lambda left, right: np.full((H, W), 4.0, np.float32), rig,
                         masker=lambda v, r: masks)
    with pytest.raises(MaskError, match=match.replace("(H, W)", r"\(H, W\)")):
        model(views)


def test_a_backbone_with_no_valid_pixel(rig, views):
    model = HybridStereo(lambda left, right: np.full((H, W), -1.0, np.float32), rig,
                         masker=lambda v, r: [MASK])
    result = model(views)
    # Nothing to check SRDE against along the outline: used, and said so.
    assert result.objects[0].status == "srde"
    assert "unchecked" in result.objects[0].reason
    assert np.isnan(result.disparity[~MASK]).all()
    assert masked_epe(result.disparity, true_disparity(rig), MASK) < 0.1


# ------------------------------------------------------------------ sign conventions
def test_a_flow_convention_backbone_is_refused_with_the_fix(rig, views):
    flow = -true_disparity(rig).astype(np.float32)  # RAFT-Stereo's negative flow
    with pytest.raises(DisparityError, match=r"^disparity: expected positive disparity"
                       r".* 100% of the .* finite values negative .* output_sign=-1"):
        postprocess(flow, views, rig, [MASK])
    with pytest.raises(DisparityError, match=r"^backbone_disparity: .*output_sign=-1"):
        HybridStereo(lambda left, right: flow, rig, masker=lambda v, r: [MASK])(views)
    # a constant sentinel is invalid pixels, not a convention
    result = postprocess(np.full((H, W), -1.0, np.float32), views, rig, [MASK])
    assert np.isnan(result.disparity[~MASK]).all()
