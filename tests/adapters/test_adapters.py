"""Backbone adapters: every convention a spec declares is undone exactly.

Each test builds a small torch "probe" model with one convention (sign, channel order,
output structure, resolution, fixed size, extra input), exports it to ONNX in tmp_path,
and checks that the adapter returns the disparity the probe encodes: the probe returns
an input channel as disparity, so misplaced padding, a wrong channel or a missed rescale
shows up as a numeric difference, not just a shape.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

import torch.nn.functional as F  # noqa: E402
from srde_fusion.adapters import (  # noqa: E402
    PRESETS,
    OnnxStereo,
    StereoSpec,
    TorchStereo,
    load_backbone,
    preset,
)
from torch import nn  # noqa: E402

from srde_fusion.errors import BackboneError, ImageError  # noqa: E402

EXACT_PX = 1e-4  # float32 round-off of a pure copy through pre/post-processing
RNG = np.random.default_rng(7)


class Probe(nn.Module):
    """Disparity = input channel ``channel`` (0..255 units) with a declared convention.

    ``sign`` negates it, ``stride`` returns it at 1/stride resolution in low-resolution
    pixels, ``flow`` adds a zero second channel, ``crop`` drops the last column (an
    output that fits no spec), ``tuple_out`` returns ``(low_res, full)``.
    """

    def __init__(self, *, channel: int = 0, sign: float = 1.0, stride: int = 1,
                 flow: bool = False, crop: bool = False, tuple_out: bool = False,
                 multiple: int = 1) -> None:
        super().__init__()
        self.channel, self.sign, self.stride = channel, sign, stride
        self.flow, self.crop, self.tuple_out, self.multiple = flow, crop, tuple_out, multiple

    def forward(self, left, right):
        if self.multiple > 1 and (left.shape[-1] % self.multiple or left.shape[-2] % self.multiple):
            raise RuntimeError("input size must be a multiple of the stride")
        d = left[:, self.channel:self.channel + 1] * self.sign + 0.0 * right.mean()
        if self.stride > 1:
            d = F.avg_pool2d(d, self.stride) / self.stride
        if self.flow:
            d = torch.cat([d, torch.zeros_like(d)], dim=1)
        if self.crop:
            d = d[..., :-1]
        if self.tuple_out:
            return F.avg_pool2d(d, 4), d
        return d


class DictProbe(nn.Module):
    """NMRF-style: called with a dict of images, returns a dict whose "disp" is (B, H, W)."""

    def forward(self, sample):
        left = sample["img1"]
        return {"prob": sample["img2"].mean(dim=1), "disp": left[:, 0]}


class DictOutputProbe(nn.Module):
    """Positional images, dict output (what an ONNX export of a dict model looks like)."""

    def forward(self, img1, img2):
        return {"prob": img2.mean(dim=1), "disp": img1[:, 0]}


class ExtraInputProbe(nn.Module):
    """Takes an iteration count as a third input and adds it to the disparity."""

    def forward(self, left, right, iters):
        return left[:, :1] + torch.as_tensor(iters, dtype=left.dtype) + 0.0 * right.mean()


def export(module: nn.Module, path, *, hw=(64, 96), dynamic: bool = True,
           input_names=("left", "right"), output_names=("disparity",), extra=()):
    h, w = hw
    args = (torch.rand(1, 3, h, w) * 255, torch.rand(1, 3, h, w) * 255, *extra)
    axes = None
    if dynamic:
        axes = {name: {2: "height", 3: "width"} for name in input_names[:2]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module.eval(), args, str(path), input_names=list(input_names),
                          output_names=list(output_names), dynamic_axes=axes,
                          opset_version=17, dynamo=False)
    return path


def random_image(h: int, w: int) -> np.ndarray:
    return RNG.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def constant_image(h: int, w: int, rgb=(10, 20, 30)) -> np.ndarray:
    return np.broadcast_to(np.asarray(rgb, np.uint8), (h, w, 3)).copy()


@pytest.fixture(scope="module")
def probe_path(tmp_path_factory):
    return export(Probe(), tmp_path_factory.mktemp("probe") / "probe.onnx")


# ---------------------------------------------------------------- padding and values
@pytest.mark.parametrize("pad_side", ["both", "after", "before"])
@pytest.mark.parametrize("pad_mode", ["replicate", "constant"])
def test_padding_is_removed_exactly(probe_path, pad_side, pad_mode):
    spec = StereoSpec(pad_multiple=32, pad_side=pad_side, pad_mode=pad_mode)
    left = random_image(50, 70)
    disp = OnnxStereo(probe_path, spec)(left, random_image(50, 70))
    assert disp.shape == (50, 70) and disp.dtype == np.float32
    np.testing.assert_allclose(disp, left[:, :, 0].astype(np.float32), atol=EXACT_PX)


def test_uint8_float_and_grey_inputs_agree(probe_path):
    model = OnnxStereo(probe_path, "igev")
    left = random_image(40, 60)
    from_uint8 = model(left, left)
    from_float = model(left.astype(np.float32) / 255.0, left.astype(np.float32) / 255.0)
    np.testing.assert_allclose(from_float, from_uint8, atol=EXACT_PX)
    grey = left[:, :, 1]
    np.testing.assert_allclose(model(grey, grey), grey.astype(np.float32), atol=EXACT_PX)


def test_mean_std_normalisation(probe_path):
    spec = StereoSpec(mean=(1.0, 2.0, 3.0), std=(2.0, 4.0, 8.0))
    left = random_image(32, 32)
    disp = OnnxStereo(probe_path, spec)(left, left)
    np.testing.assert_allclose(disp, (left[:, :, 0] - 1.0) / 2.0, atol=EXACT_PX)


def test_torch_model_that_requires_a_multiple_gets_padded_input():
    model = TorchStereo(Probe(multiple=32), "igev")
    left = random_image(50, 70)
    np.testing.assert_allclose(model(left, left), left[:, :, 0], atol=EXACT_PX)
    # the module's own error comes back as the adapter contract's, naming the module
    with pytest.raises(BackboneError, match=r"Probe \(torch, spec generic\): expected the "
                       r"module to run on inputs of shape \(1, 3, 50, 70\), got RuntimeError: "
                       r".*multiple") as info:
        TorchStereo(Probe(multiple=32), "generic")(left, left)
    assert isinstance(info.value.__cause__, RuntimeError)


class FixedReshape(nn.Module):
    """Dynamic axes declared, but a reshape baked to the export size: fails at run time."""

    def forward(self, left, right):
        return (left[:, :1] + 0 * right[:, :1]).reshape(1, 1, 64, 96)


def test_an_onnx_model_failing_while_running_is_a_backbone_error(tmp_path):
    path = export(FixedReshape(), tmp_path / "fixed.onnx")
    with pytest.raises(BackboneError, match=r"generic model: expected onnxruntime to run it on "
                       r"inputs of shape \(1, 3, 50, 70\), got"):
        OnnxStereo(path, "generic")(random_image(50, 70), random_image(50, 70))


# ---------------------------------------------------------------- sign, channel, scale
def test_raft_stereo_negative_flow_in_tuple(tmp_path):
    path = export(Probe(sign=-1.0, tuple_out=True), tmp_path / "raft.onnx",
                  output_names=("flow_low", "flow_up"))
    left = random_image(64, 96)
    np.testing.assert_allclose(OnnxStereo(path, "raft-stereo")(left, left), left[:, :, 0],
                               atol=EXACT_PX)
    torch_disp = TorchStereo(Probe(sign=-1.0, tuple_out=True), "raft-stereo")(left, left)
    np.testing.assert_allclose(torch_disp, left[:, :, 0], atol=EXACT_PX)
    # without the sign flip the disparity would be negative: refused, naming the fix
    with pytest.raises(BackboneError, match=r"model output \(raft-stereo\): expected positive "
                       r"disparity .* negative .* needs output_sign=-1"):
        OnnxStereo(path, preset("raft-stereo").replace(output_sign=1.0))(left, left)
    with pytest.raises(BackboneError, match="output_sign=-1"):
        TorchStereo(Probe(sign=-1.0, tuple_out=True), "generic")(left, left)


def test_crestereo_bgr_two_channel_flow(tmp_path):
    path = export(Probe(channel=0, flow=True), tmp_path / "cre.onnx")
    left = constant_image(48, 64, rgb=(10, 20, 30))
    # the model reads BGR, so its channel 0 is the blue channel of the RGB image
    np.testing.assert_allclose(OnnxStereo(path, "crestereo")(left, left), 30.0, atol=EXACT_PX)
    np.testing.assert_allclose(OnnxStereo(path, "generic")(left, left), 10.0, atol=EXACT_PX)


def test_output_scale_and_channel(tmp_path):
    path = export(Probe(channel=2, flow=True), tmp_path / "flow.onnx")
    left = constant_image(32, 32, rgb=(10, 20, 30))
    spec = StereoSpec(output_channel=0, output_scale=0.5)
    np.testing.assert_allclose(OnnxStereo(path, spec)(left, left), 15.0, atol=EXACT_PX)
    np.testing.assert_allclose(OnnxStereo(path, spec.replace(output_channel=1))(left, left), 0.0)


def test_negative_quarter_resolution_output_is_upsampled_and_scaled(tmp_path):
    path = export(Probe(sign=-1.0, stride=4), tmp_path / "quarter.onnx")
    h, w = 40, 70
    ramp = 2.0 + 0.25 * np.arange(w, dtype=np.float32)  # linear in x: bilinear is exact
    left = np.zeros((h, w, 3), np.float32)
    left[:, :, 0] = ramp / 255.0
    spec = StereoSpec(pad_multiple=32, output_sign=-1.0)
    disp = OnnxStereo(path, spec)(left, left)
    assert disp.shape == (h, w)
    # near the border the pooled blocks mix in padding; 8 px inside the ramp is exact
    np.testing.assert_allclose(disp[:, 8:-8], np.broadcast_to(ramp[8:-8], (h, w - 16)), atol=1e-3)
    # an explicit stride gives the same, a wrong one is refused
    np.testing.assert_allclose(OnnxStereo(path, spec.replace(output_stride=4))(left, left), disp)
    with pytest.raises(BackboneError, match="expected disparity of size"):
        OnnxStereo(path, spec.replace(output_stride=2))(left, left)


# ---------------------------------------------------------------- structure
def test_nmrf_dict_input_and_output_torch():
    left = random_image(36, 50)
    disp = TorchStereo(DictProbe(), "nmrf")(left, random_image(36, 50))
    np.testing.assert_allclose(disp, left[:, :, 0], atol=EXACT_PX)


def test_nmrf_dict_output_onnx_by_name(tmp_path):
    path = export(DictOutputProbe(), tmp_path / "nmrf.onnx", input_names=("img1", "img2"),
                  output_names=("prob", "disp"))
    model = OnnxStereo(path, "nmrf")
    assert model.output_name == "disp" and model.input_names == ("img1", "img2")
    left = random_image(36, 50)
    np.testing.assert_allclose(model(left, left), left[:, :, 0], atol=EXACT_PX)


def test_fixed_size_model_is_resized_and_rescaled(tmp_path):
    path = export(Probe(), tmp_path / "fixed.onnx", hw=(64, 96), dynamic=False,
                  output_names=("disp",))
    model = OnnxStereo(path, "foundationstereo")
    assert model.model_size == (96, 64)
    assert "fixed input size 96x64" in model.describe()
    left = constant_image(50, 75, rgb=(40, 0, 0))
    disp = model(left, left)
    assert disp.shape == (50, 75)
    # disparity measured in 96-px-wide model pixels, reported in 75-px-wide image pixels
    np.testing.assert_allclose(disp, 40.0 * 75 / 96, atol=1e-3)


def test_dynamic_model_run_at_declared_input_size(probe_path):
    model = OnnxStereo(probe_path, StereoSpec(input_size=(64, 32)))
    left = constant_image(40, 80, rgb=(16, 0, 0))
    np.testing.assert_allclose(model(left, left), 16.0 * 80 / 64, atol=1e-3)


def test_extra_constant_input(tmp_path):
    path = export(ExtraInputProbe(), tmp_path / "iters.onnx",
                  input_names=("left", "right", "iters"), extra=(torch.tensor(3),))
    left = constant_image(32, 32, rgb=(10, 0, 0))
    model = OnnxStereo(path, StereoSpec(extra_inputs={"iters": 5}))
    np.testing.assert_allclose(model(left, left), 15.0, atol=EXACT_PX)
    # torch modules get the constant as a Python number (RAFT-Stereo's iters=32)
    torch_model = TorchStereo(ExtraInputProbe(), StereoSpec(extra_inputs={"iters": 7}))
    np.testing.assert_allclose(torch_model(left, left), 17.0, atol=EXACT_PX)
    with pytest.raises(BackboneError, match="unfed"):
        OnnxStereo(path, "generic")


def test_nhwc_layout():
    class NHWCProbe(nn.Module):
        def forward(self, left, right):
            return left[..., 1:2]  # (B, H, W, 3) -> (B, H, W, 1)

    left = random_image(20, 30)
    disp = TorchStereo(NHWCProbe(), StereoSpec(layout="NHWC"))(left, left)
    np.testing.assert_allclose(disp, left[:, :, 1], atol=EXACT_PX)


def test_describe_lists_inferred_and_unknown(probe_path):
    text = OnnxStereo(probe_path, "igev").describe()
    assert "dynamic height and width" in text and "pad_multiple = 32" in text
    assert "not inferable" in text and "sign and scale" in text
    assert "cannot reveal" not in TorchStereo(Probe(), "igev").describe()
    assert "not inferable from a torch module" in TorchStereo(Probe(), "igev").describe()


def test_presets_follow_published_conventions():
    assert set(PRESETS) == {"generic", "igev", "igev++", "raft-stereo", "crestereo", "nmrf",
                            "foundationstereo", "hitnet"}
    assert preset("IGEV").pad_multiple == 32 and preset("foundationstereo").pad_multiple == 32
    assert preset("crestereo").pad_multiple == 8 and preset("nmrf").pad_multiple == 8
    assert preset("raft-stereo").output_sign == -1.0 and preset("raft-stereo").output == -1
    assert preset("crestereo").channel_order == "BGR" and preset("nmrf").output == "disp"
    assert all(p.value_scale == 255.0 and p.mean is None for p in PRESETS.values()
               if p.name != "hitnet")
    assert preset("hitnet").value_scale == 1.0 and preset("hitnet").input_mode == "stacked"
    # the demos' iteration counts, in test mode
    for name in ("igev", "igev++", "raft-stereo", "foundationstereo"):
        assert dict(preset(name).forward_kwargs) == {"iters": 32, "test_mode": True}
    assert dict(preset("crestereo").forward_kwargs) == {"iters": 20, "test_mode": True}
    spec = StereoSpec(pad_multiple=8)
    assert preset(spec) is spec


# ---------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("left", "right", "message"),
    [
        (np.zeros((20, 30, 4), np.uint8), np.zeros((20, 30, 4), np.uint8), "shape"),
        (np.zeros((20, 30, 3), np.int16), np.zeros((20, 30, 3), np.int16), "dtype"),
        (np.zeros((20, 30, 3), np.uint8), np.zeros((20, 31, 3), np.uint8), "same size"),
        (np.full((20, 30, 3), 2.0, np.float32), np.zeros((20, 30, 3), np.float32), r"\[0, 1\]"),
        ([[0, 1], [2, 3]], np.zeros((2, 2), np.uint8), "numpy array"),
    ],
)
def test_bad_images_raise_image_error(probe_path, left, right, message):
    with pytest.raises(ImageError, match=message):
        OnnxStereo(probe_path, "generic")(left, right)


def test_file_that_is_not_a_model(tmp_path):
    bogus = tmp_path / "model.onnx"
    bogus.write_text("this is not a network")
    with pytest.raises(BackboneError, match="cannot load"):
        OnnxStereo(bogus)
    with pytest.raises(BackboneError, match="existing .onnx file"):
        OnnxStereo(tmp_path / "missing.onnx")
    with pytest.raises(BackboneError, match="expected 'default', 'sgbm', a .onnx file"):
        load_backbone(tmp_path / "weights.pth")
    with pytest.raises(BackboneError, match="got int"):
        load_backbone(42)


def test_outputs_that_do_not_fit_the_spec(tmp_path, probe_path):
    with pytest.raises(BackboneError, match="expected one of the model outputs"):
        OnnxStereo(probe_path, StereoSpec(output="disp"))
    with pytest.raises(BackboneError, match="expected an index into the 1 model outputs"):
        OnnxStereo(probe_path, StereoSpec(output=3))
    flow = export(Probe(flow=True), tmp_path / "flow.onnx")
    with pytest.raises(BackboneError, match="expected at least 3 channels"):
        OnnxStereo(flow, StereoSpec(output_channel=2))
    cropped = export(Probe(crop=True), tmp_path / "crop.onnx")
    with pytest.raises(BackboneError, match="expected disparity of size 32x32"):
        OnnxStereo(cropped)(random_image(32, 32), random_image(32, 32))
    with pytest.raises(BackboneError, match="keys"):
        TorchStereo(DictProbe(), preset("nmrf").replace(output=-1))(
            random_image(8, 8), random_image(8, 8))
    with pytest.raises(BackboneError, match="expected names among the model inputs"):
        OnnxStereo(probe_path, StereoSpec(input_names=("img1", "img2")))


def test_model_inputs_that_are_not_images(tmp_path):
    class OneChannel(nn.Module):
        def forward(self, left, right):
            return left + right

    h, w = 16, 16
    path = tmp_path / "grey.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(OneChannel(), (torch.rand(1, 1, h, w), torch.rand(1, 1, h, w)),
                          str(path), input_names=["left", "right"], dynamo=False)
    with pytest.raises(BackboneError, match="expected 3 channels"):
        OnnxStereo(path)
    with pytest.raises(BackboneError, match="torch.nn.Module"):
        TorchStereo(lambda left, right: left)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"output_sign": 2.0}, "output_sign"),
        ({"pad_multiple": 0}, "pad_multiple"),
        ({"channel_order": "RGBA"}, "channel_order"),
        ({"input_names": ("left",)}, "input_names"),
        ({"std": (1.0, 0.0, 1.0)}, "std"),
        ({"extra_inputs": {"iters": "many"}}, "extra_inputs"),
        ({"input_size": (640,)}, "input_size"),
        ({"output_stride": 0}, "output_stride"),
    ],
)
def test_invalid_spec_fields(changes, message):
    with pytest.raises(BackboneError, match=message):
        StereoSpec(**changes)


def test_unknown_preset_and_field():
    with pytest.raises(BackboneError, match="expected one of the presets"):
        preset("psmnet")
    with pytest.raises(BackboneError, match="unknown colour"):
        StereoSpec().replace(colour="red")


def test_a_device_this_machine_lacks_fails_at_construction(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(BackboneError, match=r"device: expected an available device, got "
                       r"'cuda' \(this torch build or machine has no CUDA\)"):
        TorchStereo(Probe(), "generic", device="cuda")
    with pytest.raises(BackboneError, match="device: expected a torch device"):
        TorchStereo(Probe(), "generic", device="gpu please")
    path = export(Probe(), tmp_path / "m.onnx")
    with pytest.raises(BackboneError, match=r"providers: expected onnxruntime execution "
                       r"providers this installation has .*got \['NoSuchExecutionProvider'\]"):
        OnnxStereo(path, "generic", providers=("NoSuchExecutionProvider",))
