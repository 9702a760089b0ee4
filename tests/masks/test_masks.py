from __future__ import annotations

import warnings

import numpy as np
import pytest

from srde_fusion.errors import FileFormatError, MaskError, SRDEError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import write_mask
from srde_fusion.masks import HighlightSegmenter, OnnxMasker, UserMasks

H, W = 48, 64


@pytest.fixture
def rig() -> CameraRig:
    return CameraRig.stereo(0.1, fx=60.0, image_size=(W, H))


def two_box_labels() -> np.ndarray:
    labels = np.zeros((H, W), np.int32)
    labels[4:14, 6:20] = 1
    labels[25:40, 30:60] = 4
    return labels


# ---------------------------------------------------------------- UserMasks
def test_user_masks_from_label_array(rig):
    labels = two_box_labels()
    masks = UserMasks(labels)(None, rig)
    assert len(masks) == 2
    assert np.array_equal(masks[0], labels == 1) and np.array_equal(masks[1], labels == 4)
    assert all(m.dtype == bool for m in masks)


def test_user_masks_from_png_file_binary_and_labels(rig, tmp_path):
    labels = two_box_labels()
    write_mask(tmp_path / "labels.png", labels)
    assert [int(m.sum()) for m in UserMasks(tmp_path / "labels.png")(None, rig)] == [140, 450]
    binary = np.where(labels > 0, 255, 0).astype(np.uint8)
    write_mask(tmp_path / "binary.png", binary)
    # A binary mask holding two objects is two objects, and says so.
    auto = UserMasks(str(tmp_path / "binary.png"))
    assert [int(m.sum()) for m in auto(None, rig)] == [140, 450]
    assert auto.notes == ("binary mask split into 2 objects (its 8-connected components); "
                          "split_components=False (--mask-as-one) keeps one object",)
    one = UserMasks(tmp_path / "binary.png", split_components=False)(None, rig)
    assert len(one) == 1 and np.array_equal(one[0], labels > 0)
    split = UserMasks(tmp_path / "binary.png", split_components=True)(None, rig)
    assert [int(m.sum()) for m in split] == [140, 450]
    # Instance labels are taken as given: no splitting, no note.
    assert UserMasks(tmp_path / "labels.png").notes == ()


def test_binary_mask_specks_are_ignored_and_counted(rig):
    mask = np.zeros((H, W), bool)
    mask[2:4, 2:4] = True  # a 4 px speck
    mask[10:20, 10:20] = True
    mask[30:40, 30:50] = True
    masks = UserMasks(mask)
    assert [int(m.sum()) for m in masks(None, rig)] == [100, 200]
    assert "2 objects (its 8-connected components, 1 under 16 px ignored)" in masks.notes[0]
    # one object with specks stays one object, specks included
    mask[30:40, 30:50] = False
    assert [int(m.sum()) for m in UserMasks(mask)(None, rig)] == [104]


def test_lossy_mask_files_are_refused(rig, tmp_path):
    import cv2

    cv2.imwrite(str(tmp_path / "mask.jpg"), np.where(two_box_labels() > 0, 255, 0).astype(np.uint8))
    with pytest.raises(FileFormatError, match=r"mask.jpg: expected a lossless label image "
                       r"\(PNG, TIFF, BMP or .npy\), got JPG"):
        UserMasks(tmp_path / "mask.jpg")


def test_the_resolver_reports_which_masks_and_what_was_done(rig, tmp_path):
    from srde_fusion.masks import resolve_masker

    write_mask(tmp_path / "binary.png", np.where(two_box_labels() > 0, 255, 0).astype(np.uint8))
    choice = resolve_masker(tmp_path / "binary.png")
    assert choice.description.startswith(f"user ({tmp_path / 'binary.png'}, 2 object(s)); "
                                         "binary mask split into 2 objects")
    assert resolve_masker(None).description == "auto (built-in highlight segmenter)"


def test_user_masks_from_npy_and_list_and_stack(rig, tmp_path):
    labels = two_box_labels()
    np.save(tmp_path / "labels.npy", labels.astype(np.float32))  # whole numbers as floats
    assert len(UserMasks(tmp_path / "labels.npy")(None, rig)) == 2
    as_list = UserMasks([labels == 1, (labels == 4).astype(np.uint8) * 255])(None, rig)
    assert [int(m.sum()) for m in as_list] == [140, 450]
    stack = UserMasks(np.stack([labels == 4, labels == 1]))(None, rig)
    assert [int(m.sum()) for m in stack] == [450, 140]


def test_user_masks_returns_fresh_copies(rig):
    source = UserMasks(two_box_labels())
    first = source(None, rig)
    first[0][:] = False
    assert source(None, rig)[0].sum() == 140


def test_split_components_drops_small_ones(rig):
    mask = np.zeros((H, W), bool)
    mask[2:4, 2:4] = True  # 4 px
    mask[20:30, 20:30] = True
    masks = UserMasks(mask, split_components=True, min_area_px=10)(None, rig)
    assert [int(m.sum()) for m in masks] == [100]


@pytest.mark.parametrize("source, error, match", [
    (np.zeros((H, W), np.uint8), MaskError, r"expected at least one object"),
    (np.full((H, W), 0.5), MaskError, r"masks: expected integer labels"),
    (np.full((H, W), -1), MaskError, r"masks: expected labels >= 0"),
    (np.zeros((2, 2, H, W)), MaskError, r"masks: expected \(H, W\) labels or a \(K, H, W\) stack"),
    ([np.zeros((H, W), bool)], MaskError, r"masks\[0\]: expected at least one pixel"),
    ([np.ones(5)], MaskError, r"masks\[0\]: expected an \(H, W\) mask"),
    (42, MaskError, r"masks: expected a mask file path, a label array or a list of masks"),
    ("no/such/mask.png", FileFormatError, r"mask file: expected an existing file"),
])
def test_user_masks_bad_sources(source, error, match):
    with pytest.raises(error, match=match):
        UserMasks(source)


def test_user_masks_of_the_wrong_size_for_the_rig(rig):
    masks = UserMasks(np.ones((H // 2, W // 2), bool))
    with pytest.raises(MaskError, match=r"masks\[0\]: expected shape \(48, 64\) \(the rig's image "
                                        r"size 64x48\), got \(24, 32\)"):
        masks(None, rig)


@pytest.mark.parametrize("data", [
    b"not numpy", b"",  # garbage, empty (EOFError inside numpy)
    b"\x93NUMPY\x01\x00\x10\x00{'descr': '<f4', 'fortran_o",  # damaged header (SyntaxError)
    b"\x93NUMPY\x01\x00\x10\x00{'descr': \"<f4\" \\\n   ",  # header the tokenizer rejects
], ids=["garbage", "empty", "cut-header", "bad-token"])
def test_user_masks_bad_npy_file(tmp_path, data):
    (tmp_path / "bad.npy").write_bytes(data)
    with pytest.raises(FileFormatError, match=r"bad.npy: expected a numpy .npy array, got an "
                       r"unreadable file"):
        UserMasks(tmp_path / "bad.npy")


# ---------------------------------------------------------------- OnnxMasker
def export(model, path, input_hw=(24, 32), dynamic=False):
    import torch

    kwargs = {}
    if dynamic:
        kwargs["dynamic_axes"] = {"image": {2: "h", 3: "w"}, "out": {2: "h", 3: "w"}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter announces its deprecation
        torch.onnx.export(model.eval(), torch.zeros(1, 3, *input_hw), str(path),
                          input_names=["image"], output_names=["out"], dynamo=False, **kwargs)
    return path


def brightness_model(scale=20.0):
    """Foreground logit = (mean RGB in [0, 1] - 0.5) * scale."""
    import torch

    class Bright(torch.nn.Module):
        def forward(self, x):
            return (x.mean(dim=1, keepdim=True) - 0.5) * scale

    return Bright()


def channel_model():
    """Three class logits: background, 'red' objects, 'green' objects."""
    import torch

    class Channels(torch.nn.Module):
        def forward(self, x):
            r, g = x[:, 0:1], x[:, 1:2]
            background = torch.full_like(r, 0.3)
            return torch.cat([background, r - g, g - r], dim=1) * 10.0

    return Channels()


def scene_image():
    image = np.zeros((H, W, 3), np.uint8)
    image[4:20, 4:24] = (250, 30, 30)  # red box
    image[28:44, 36:60] = (30, 250, 30)  # green box
    return image


def iou(a, b):
    return np.logical_and(a, b).sum() / np.logical_or(a, b).sum()


def test_onnx_binary_output_with_resize_and_components(rig, tmp_path):
    path = export(brightness_model(), tmp_path / "bright.onnx", input_hw=(24, 32))
    masker = OnnxMasker(path, min_area_px=20)
    assert masker.input_size == (32, 24)  # read from the model's static input
    image = np.zeros((H, W, 3), np.uint8)
    image[4:20, 4:24] = 255
    image[28:44, 36:60] = 255
    masks = masker([image, image], rig)
    assert len(masks) == 2
    expected = [np.zeros((H, W), bool), np.zeros((H, W), bool)]
    expected[0][4:20, 4:24] = True
    expected[1][28:44, 36:60] = True
    assert iou(masks[0], expected[0]) > 0.85 and iou(masks[1], expected[1]) > 0.85


def test_onnx_class_layout_splits_classes(rig, tmp_path):
    path = export(channel_model(), tmp_path / "classes.onnx", input_hw=(H, W))
    masks = OnnxMasker(path, layout="classes")([scene_image()] * 2, rig)
    assert len(masks) == 2
    assert masks[0][10, 10] and not masks[0][35, 45]
    assert masks[1][35, 45] and not masks[1][10, 10]
    assert int(masks[0].sum()) == 16 * 20 and int(masks[1].sum()) == 16 * 24


def test_onnx_instance_layout_with_probabilities(rig, tmp_path):
    import torch

    class Probabilities(torch.nn.Module):
        def forward(self, x):
            return torch.cat([x[:, 0:1], x[:, 1:2]], dim=1)  # already in [0, 1]

    path = export(Probabilities(), tmp_path / "inst.onnx", input_hw=(H, W), dynamic=True)
    masker = OnnxMasker(path, layout="instances", output="probabilities", threshold=0.6,
                        min_area_px=10)
    masks = masker([scene_image()] * 2, rig)
    assert [int(m.sum()) for m in masks] == [16 * 20, 16 * 24]


def test_onnx_dynamic_model_runs_at_image_size(rig, tmp_path):
    path = export(brightness_model(), tmp_path / "dyn.onnx", dynamic=True)
    masker = OnnxMasker(path)
    assert masker.input_size is None
    image = np.zeros((H, W, 3), np.uint8)
    image[10:30, 10:40] = 200
    (mask,) = masker([image, image], rig)
    assert int(mask.sum()) == 20 * 30


@pytest.mark.parametrize("kwargs, match", [
    ({"output": "softmax"}, r"output: expected 'logits' or 'probabilities'"),
    ({"layout": "semantic"}, r"layout: expected 'classes' or 'instances'"),
    ({"threshold": 1.0}, r"threshold: expected a probability in \(0, 1\)"),
])
def test_onnx_bad_options(tmp_path, kwargs, match):
    path = export(brightness_model(), tmp_path / "m.onnx")
    with pytest.raises(SRDEError, match=match):
        OnnxMasker(path, **kwargs)


def test_onnx_bad_files(tmp_path):
    with pytest.raises(FileFormatError, match=r"segmentation model: expected an existing .onnx"):
        OnnxMasker(tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"\x00junk")
    with pytest.raises(FileFormatError, match=r"junk.onnx: expected a valid ONNX model"):
        OnnxMasker(tmp_path / "junk.onnx")


# ---------------------------------------------------------------- HighlightSegmenter
SW, SH = 160, 120


def synthetic_views(rig, *, object_depth_m=1.0, virtual_depth_m=2.0, off_epipolar=None,
                    texture_seed=0):
    """A grey disc (object) with a clipped highlight in front of strong texture.

    The disc's image shifts with its own depth across the views, the highlight with the
    virtual light's depth: exactly the geometry the segmenter checks.
    """
    rng = np.random.default_rng(texture_seed)
    k = rig.intrinsics
    vv, uu = np.mgrid[0:SH, 0:SW].astype(np.float64)
    views = []
    for j in range(rig.n_cameras):
        d = rig.centers_m[j] - rig.reference_center_m
        texture = rng.integers(20, 230, (SH // 4, SW // 4)).astype(np.float32)
        image = np.kron(texture, np.ones((4, 4), np.float32))  # blocky, strong texture
        ou, ov = 80 - k.fx * d[0] / object_depth_m, 60 - k.fy * d[1] / object_depth_m
        disc = (uu - ou) ** 2 + (vv - ov) ** 2 <= 35.0**2
        image[disc] = 90.0
        hu, hv = 80 - k.fx * d[0] / virtual_depth_m, 60 - k.fy * d[1] / virtual_depth_m
        if off_epipolar is not None and j == off_epipolar:
            hv += 9.0 if d[1] == 0 else 0.0
            hu += 9.0 if d[1] != 0 else 0.0
        blob = 600.0 * np.exp(-((uu - hu) ** 2 + (vv - hv) ** 2) / (2 * 3.5**2))
        image = np.where(disc, image + blob, image)
        image += rng.normal(0.0, 1.0, image.shape)
        views.append(np.repeat(np.clip(image, 0, 255).astype(np.uint8)[:, :, None], 3, axis=2))
    truth = (uu - 80) ** 2 + (vv - 60) ** 2 <= 35.0**2
    return views, truth


@pytest.fixture
def small_array() -> CameraRig:
    return CameraRig.grid(3, 3, baseline_m=0.05, fx=150.0, image_size=(SW, SH))


def test_segmenter_finds_a_glossy_disc(small_array):
    views, truth = synthetic_views(small_array)
    segmenter = HighlightSegmenter()
    masks = segmenter(views, small_array)
    assert len(masks) == 1
    # Where a background block has the disc's grey the outline is invisible and the
    # boundary may drift into that block; the disc itself must be covered.
    assert iou(masks[0], truth) > 0.9
    assert np.count_nonzero(truth & ~masks[0]) < 0.01 * truth.sum()
    diag = segmenter.last_diagnostics
    assert diag.kept == (True,)
    np.testing.assert_allclose(diag.seeds_uv[0], [80, 60], atol=0.5)
    assert diag.inverse_depth_per_m[0] == pytest.approx(1 / 2.0, abs=0.02)


def test_segmenter_drops_a_highlight_the_other_views_contradict(small_array):
    views, _ = synthetic_views(small_array, off_epipolar=5)  # the right neighbour
    masks, diag = HighlightSegmenter().segment(views, small_array)
    assert masks == []
    assert diag.kept == (False,)
    assert diag.reasons[0].startswith("views [5] show no highlight where")
    relaxed = HighlightSegmenter(min_consistent_views=7).segment(views, small_array)[0]
    assert len(relaxed) == 1


def test_segmenter_drops_a_bright_spot_in_texture(small_array):
    rng = np.random.default_rng(1)
    texture = np.kron(rng.integers(20, 230, (SH // 4, SW // 4)), np.ones((4, 4))).astype(np.uint8)
    views = [np.repeat(texture[:, :, None], 3, axis=2) for _ in range(9)]
    for v in views:  # a white square at the same place in every view: a point at infinity
        v[50:60, 70:80] = 255
    masks, diag = HighlightSegmenter().segment(views, small_array)
    assert masks == []
    assert diag.reasons[0].startswith(("textured surroundings", "region of"))


def test_segmenter_on_a_rendered_scene():
    from srde_fusion.synthetic import default_rig, random_scene, render

    rig = default_rig()  # the segmenter's scales are set for 640x480
    scene = random_scene(3, rig, n_objects=2, background="textured")
    rendering = render(scene, rig.with_light(scene.light.position_m), noise_seed=3)
    masks = HighlightSegmenter()(rendering.views, rig)
    truth = rendering.object_masks
    assert len(masks) == len(truth) == 2
    for t in truth:
        assert max(iou(m, t) for m in masks) > 0.95


def test_segmenter_options_are_validated():
    with pytest.raises(SRDEError, match=r"seed_luminance: expected a value in \(0, 1\]"):
        HighlightSegmenter(seed_luminance=0.0)
    with pytest.raises(SRDEError, match=r"contrast_sigmas_px: expected 0 < s1 < s2"):
        HighlightSegmenter(contrast_sigmas_px=(3.0, 1.0))
    with pytest.raises(SRDEError, match=r"max_region_fraction: expected a value in \(0, 1\]"):
        HighlightSegmenter(max_region_fraction=2.0)


def test_the_number_of_objects_is_bounded_before_masks_are_built(rig, tmp_path):
    labels = (np.arange(H * W).reshape(H, W) % 300).astype(np.uint16)  # 299 labels
    np.save(tmp_path / "many.npy", labels)
    with pytest.raises(MaskError, match=r"many.npy: expected at most 64 objects \(max_objects\), "
                       r"got 299 labels"):
        UserMasks(tmp_path / "many.npy")
    assert len(UserMasks(labels, max_objects=300)(None, rig)) == 299
    with pytest.raises(MaskError, match="expected at most 2 objects"):
        UserMasks([labels == 1, labels == 2, labels == 3], max_objects=2)
