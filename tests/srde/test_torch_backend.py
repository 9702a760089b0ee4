"""BatchedSRDE (torch, batched over views) against SRDE (numpy) on rendered scenes.

The two differ only in the order of floating-point sums, so the disparity must agree
far below a pixel; the building blocks are checked against OpenCV directly.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.errors import ImageError, SRDEError
from srde_fusion.geometry import CameraRig
from srde_fusion.srde import (
    BLOB_CENTERS,
    SRDE,
    BatchedSRDE,
    DetectionRequest,
    DetectorConfig,
    NumpyBackend,
)
from srde_fusion.srde.torch_backend import TorchBackend
from srde_fusion.srde.torch_ops import extend_borders, label_components, reflect_index, smooth_at
from srde_fusion.synthetic import default_rig, random_scene, render

# The contract: torch and numpy paths agree within this much disparity on rendered scenes.
DISPARITY_TOL_PX = 0.05
# Highlight centres: only summation order differs (float32 crops, float64 centroids).
CENTER_TOL_PX = 1e-3
# Seeds whose scene succeeds with both detectors at half the paper's resolution.
SEEDS = (0, 3)


@pytest.fixture(scope="module")
def half_rig() -> CameraRig:
    """The paper's 3 x 3 array at 320 x 240: rendered quickly, highlights still sizeable."""
    return default_rig().scaled(0.5)


@pytest.fixture(scope="module")
def frames(half_rig):
    out = {}
    for seed in SEEDS:
        scene = random_scene(seed, half_rig, background="textured")
        out[seed] = (scene, render(scene, half_rig))
    return out


def _both(rig, scene, rendering, **options):
    light = scene.light.position_m
    mask = rendering.object_masks[0]
    numpy_result = SRDE(rig, light=light, **options).estimate(rendering.views, mask)
    torch_result = BatchedSRDE(rig, light=light, **options).estimate(rendering.views, mask)
    return numpy_result, torch_result


def _assert_agree(a, b):
    assert (a.status, a.reason) == (b.status, b.reason)
    np.testing.assert_array_equal(np.isnan(a.highlight_centers), np.isnan(b.highlight_centers))
    np.testing.assert_allclose(b.highlight_centers, a.highlight_centers, atol=CENTER_TOL_PX)
    np.testing.assert_array_equal(a.used_views, b.used_views)
    np.testing.assert_array_equal(np.isnan(a.disparity), np.isnan(b.disparity))
    if a.ok:
        assert np.nanmax(np.abs(a.disparity - b.disparity)) <= DISPARITY_TOL_PX
    for da, db in zip(a.detections, b.detections, strict=True):
        assert (da.found, da.reason, da.bbox) == (db.found, db.reason, db.bbox)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("options", [
    dict(refine=False),
    dict(refine=False, detector="paper"),
    dict(method="paper"),
    dict(refine=False, blob_center="core"),
    dict(refine=False, blob_center="lobe"),
], ids=["blob", "paper-detector", "paper-method", "core", "lobe"])
def test_agrees_with_numpy_on_rendered_scenes(half_rig, frames, seed, options):
    scene, rendering = frames[seed]
    a, b = _both(half_rig, scene, rendering, **options)
    assert a.ok, a.reason
    _assert_agree(a, b)


def test_default_options_with_refinement_agree(half_rig, frames):
    scene, rendering = frames[3]
    a, b = _both(half_rig, scene, rendering)
    assert a.ok and a.refinement is not None
    _assert_agree(a, b)
    assert b.refinement is not None and b.refinement.status == a.refinement.status


def test_white_references_agree(half_rig, frames):
    scene, rendering = frames[0]
    w, h = half_rig.image_size
    # Vignetting-like white images, different per camera.
    vv, uu = np.mgrid[0:h, 0:w]
    whites = [np.clip(255 * (0.9 - 0.3 * ((uu - w / 2) ** 2 + (vv - h / 2) ** 2) / (w * w)
                             + 0.01 * j), 0, 255).astype(np.uint8) for j in range(9)]
    a, b = _both(half_rig, scene, rendering, refine=False, white_references=whites)
    assert a.ok, a.reason
    _assert_agree(a, b)


def test_tensor_views_give_the_numpy_views_result(half_rig, frames):
    scene, rendering = frames[0]
    srde = BatchedSRDE(half_rig, light=scene.light.position_m, refine=False)
    mask = rendering.object_masks[0]
    from_numpy = srde.estimate(rendering.views, mask)
    stacked = torch.from_numpy(np.stack(rendering.views))
    from_tensor = srde.estimate(stacked, mask)
    from_floats = srde.estimate([torch.from_numpy(v).float() / 255.0 for v in rendering.views],
                                mask)
    assert from_numpy.ok and from_tensor.ok and from_floats.ok
    np.testing.assert_array_equal(from_tensor.disparity, from_numpy.disparity)
    assert np.nanmax(np.abs(from_floats.disparity - from_numpy.disparity)) <= DISPARITY_TOL_PX


def test_failures_match_numpy_reasons():
    rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    light = [0.05, -0.3, 0.2]
    views = [np.zeros((64, 96), np.uint8)] * 2
    mask = np.ones((64, 96), bool)
    a = SRDE(rig, light=light).estimate(views, mask)
    b = BatchedSRDE(rig, light=light).estimate(views, mask)
    assert b.status == "no_highlight" and (a.status, a.reason) == (b.status, b.reason)
    tiny = np.zeros((64, 96), bool)
    tiny[10:13, 10:13] = True
    assert BatchedSRDE(rig, light=light).estimate(views, tiny).status == "mask_too_small"


@pytest.fixture(scope="module")
def stereo():
    rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    return BatchedSRDE(rig, light=[0.05, -0.3, 0.2]), np.ones((64, 96), bool)


@pytest.mark.parametrize(("views", "match"), [
    (torch.zeros(3, 64, 96, 3, dtype=torch.uint8), "expected 2 images"),
    (torch.zeros(2, 64, 90, 3, dtype=torch.uint8), r"rig's size 96x64, got 90x64"),
    (torch.zeros(2, 64, 96, 4, dtype=torch.uint8), r"expected shape \(H, W\) or \(H, W, 3\)"),
    (torch.full((2, 64, 96), 1.5), r"float values in \[0, 1\], got \[1.5, 1.5\]"),
    (torch.full((2, 64, 96), float("nan")), "finite float values"),
    (torch.zeros(2, 64, 96, dtype=torch.int32), "expected uint8 or float"),
    ([np.zeros((64, 96), np.uint8)], "expected 2 images"),
])
def test_bad_views_raise(stereo, views, match):
    srde, mask = stereo
    with pytest.raises(ImageError, match=match):
        srde.estimate(views, mask)


def test_bad_device_raises():
    rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    with pytest.raises(SRDEError, match="device: expected a torch device"):
        BatchedSRDE(rig, light=[0.0, 0.0, 0.0], device="abacus")
    if not torch.cuda.is_available():
        with pytest.raises(SRDEError, match="CUDA is not available"):
            BatchedSRDE(rig, light=[0.0, 0.0, 0.0], device="cuda")


def _partition(labels: np.ndarray) -> set[frozenset]:
    flat = labels.ravel()
    return {frozenset(np.flatnonzero(flat == v).tolist()) for v in np.unique(flat) if v}


@given(seed=st.integers(0, 2**16), density=st.floats(0.2, 0.7))
def test_label_components_matches_opencv(seed, density):
    binary = np.random.default_rng(seed).random((3, 17, 23)) < density
    labels = label_components(torch.from_numpy(binary)).numpy()
    for image, got in zip(binary, labels, strict=True):
        _, expected = cv2.connectedComponents(image.view(np.uint8), connectivity=8)
        assert _partition(got) == _partition(expected)
        assert np.array_equal(got > 0, image)


@pytest.mark.parametrize("mode, border", [("symmetric", cv2.BORDER_REFLECT),
                                          ("reflect101", cv2.BORDER_REFLECT_101)])
@pytest.mark.parametrize("size, pad", [(7, 3), (4, 9), (2, 5)])
def test_extension_is_opencvs_border(mode, border, size, pad):
    row = np.arange(size, dtype=np.float32)[None, :]
    expected = cv2.copyMakeBorder(row, 0, 0, pad, pad, border)[0]
    np.testing.assert_array_equal(row[0, reflect_index(-pad, size + pad, size, mode)], expected)
    crops = torch.from_numpy(np.random.default_rng(1).random((2, 6, 8)).astype(np.float32))
    sizes = np.array([[6, 8], [4, 5]])
    ext = extend_borders(crops, sizes, pad, mode).numpy()
    small = crops[1, :4, :5].numpy()
    want = cv2.copyMakeBorder(small, pad, pad, pad, pad, border)
    np.testing.assert_array_equal(ext[1, :4 + 2 * pad, :5 + 2 * pad], want)


@pytest.mark.parametrize("direction", [(1, 0), (0, 1), (1, 1), (2, -1)])
def test_smoothing_at_points_is_opencvs_blur(direction):
    rng = np.random.default_rng(4)
    crop = cv2.GaussianBlur(rng.random((60, 70)).astype(np.float32), (0, 0), 2.0)
    sigma = 5.0
    kernel = cv2.getGaussianKernel(int(round(8 * sigma + 1)) | 1, sigma, cv2.CV_32F)[:, 0]
    pad = kernel.size // 2
    t = np.arange(20)
    points = np.stack([10 + direction[0] * t, 30 + direction[1] * t], axis=1)
    ext = torch.from_numpy(cv2.copyMakeBorder(crop, pad, pad, pad, pad, cv2.BORDER_REFLECT))
    got = smooth_at(ext, points, torch.from_numpy(kernel)).numpy()
    blurred = cv2.GaussianBlur(crop, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    np.testing.assert_allclose(got, blurred[points[:, 1], points[:, 0]], rtol=1e-5)


# ------------------------------------------------------------ one detector, two backends
@pytest.mark.parametrize("options", [{"method": "blob", "blob_center": c} for c in BLOB_CENTERS]
                         + [{"method": "paper"}], ids=[*BLOB_CENTERS, "paper"])
def test_numpy_and_torch_backends_detect_the_same_highlights(options):
    rig = default_rig()
    scene = random_scene(5, rig, n_objects=2, background="textured")
    out = render(scene, rig)
    config = DetectorConfig(encoding=rig.image_encoding, **options)
    numpy_backend, torch_backend = NumpyBackend(rig, config), TorchBackend(rig, config)
    flat = np.zeros(out.instance_mask.shape, bool)
    flat[5:40, 5:60] = True  # a corner of the room: no highlight, a failure with a reason
    regions = [out.instance_mask == 1, out.instance_mask == 2, flat]
    requests = [DetectionRequest(j, region) for j in range(rig.n_cameras) for region in regions]
    expected = numpy_backend.detect(numpy_backend.prepare(out.views), requests)
    got = torch_backend.detect(torch_backend.prepare(out.views), requests)
    assert sum(d.found for d in expected) >= len(requests) // 2
    for e, g in zip(expected, got, strict=True):
        assert (e.found, e.area_px, e.bbox) == (g.found, g.area_px, g.bbox)
        if e.found:
            np.testing.assert_allclose(g.center_uv, e.center_uv, atol=CENTER_TOL_PX)
        else:
            assert g.reason.split(":")[0] == e.reason.split(":")[0]


@pytest.mark.parametrize("bad", [{"method": "ring"}, {"window": 4}, {"min_contrast": 1.0}])
def test_detector_config_is_checked_once_with_its_message(bad):
    with pytest.raises(SRDEError, match=f"{next(iter(bad))}: expected"):
        DetectorConfig(**bad)


def test_srde_takes_a_backend_by_name_or_instance():
    rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    light = [0.05, -0.3, 0.2]
    assert isinstance(SRDE(rig, light, backend="torch").backend, TorchBackend)
    custom = NumpyBackend(rig, DetectorConfig())
    assert SRDE(rig, light, backend=custom).backend is custom
    with pytest.raises(SRDEError, match="backend: expected 'numpy', 'torch' or an object"):
        SRDE(rig, light, backend="jax")
    with pytest.raises(SRDEError, match="device: expected None or 'cpu' for the numpy backend"):
        SRDE(rig, light, device="cuda")

