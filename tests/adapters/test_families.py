"""The published families as users hold them, through the adapters.

Each look-alike below has the forward signature, output structure, input names, shapes
and value ranges of a published family (IGEV-Stereo, RAFT-Stereo, the CREStereo PyTorch
port and its ONNX exports, FoundationStereo, HITNET's ONNX exports), written here from
their interfaces, with toy arithmetic inside: the disparity a look-alike returns is an
input channel (0..255 units), so a misread convention shows up as a wrong number. Each
records how it was called, so a preset's iteration count and ``test_mode`` are checked,
not assumed. Sizes are deliberately not multiples of 8 or 32.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

import torch.nn.functional as F  # noqa: E402
from srde_fusion.adapters import OnnxStereo, StereoSpec, TorchStereo, load_backbone  # noqa: E402
from torch import nn  # noqa: E402

from srde_fusion.errors import BackboneError  # noqa: E402

EXACT_PX = 1e-4  # float32 round-off of a pure copy through pre/post-processing
REFINED_OFF_PX = 5.0  # how far the look-alikes' unrefined outputs are from the final one
RNG = np.random.default_rng(16)


def random_image(h: int, w: int) -> np.ndarray:
    return RNG.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def constant_image(h: int, w: int, rgb) -> np.ndarray:
    return np.broadcast_to(np.asarray(rgb, np.uint8), (h, w, 3)).copy()


def require_multiple(image: torch.Tensor, multiple: int) -> None:
    """What the published networks do, less politely, on a size they cannot take."""
    if image.shape[-1] % multiple or image.shape[-2] % multiple:
        raise RuntimeError(f"sizes must be multiples of {multiple}, got {tuple(image.shape)}")


def export(module: nn.Module, path, args, input_names, output_names, dynamic=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(module.eval(), tuple(args), str(path), input_names=list(input_names),
                          output_names=list(output_names), dynamic_axes=dynamic,
                          opset_version=17, dynamo=False)
    return path


# ---------------------------------------------------------------- IGEV / IGEV++
class IGEVLike(nn.Module):
    """``forward(image1, image2, iters=12, flow_init=None, test_mode=False)``.

    Outside test mode: ``(init_disp, [disp after each iteration])``, full size, the
    initial disparity ``REFINED_OFF_PX`` off and each iteration closer; in test mode the
    final ``(B, 1, H, W)`` map only. Disparity = channel 0 of image1 (0..255).
    """

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[dict] = []

    def forward(self, image1, image2, iters=12, flow_init=None, test_mode=False):
        self.calls.append({"iters": iters, "flow_init": flow_init, "test_mode": test_mode})
        require_multiple(image1, 32)
        disp = image1[:, :1] + 0.0 * image2[:, :1]
        init_disp = disp + REFINED_OFF_PX
        disp_preds = [disp + REFINED_OFF_PX * (iters - 1 - i) / iters for i in range(iters)]
        if test_mode:
            return disp_preds[-1]
        return init_disp, disp_preds


def test_igev_module_runs_like_its_demo():
    module = IGEVLike()
    left = random_image(50, 70)
    disp = load_backbone(module, "igev")(left, random_image(50, 70))
    np.testing.assert_allclose(disp, left[:, :, 0], atol=EXACT_PX)
    assert module.calls == [{"iters": 32, "flow_init": None, "test_mode": True}]
    assert TorchStereo(IGEVLike(), "igev++")(left, left).shape == (50, 70)


def test_igev_outside_test_mode_reads_the_final_prediction_or_warns():
    left = random_image(50, 70)
    plain = StereoSpec(name="igev-train-mode", pad_multiple=32)
    # output -1 is the list of predictions: its last element is final
    adapter = TorchStereo(IGEVLike(), plain)
    np.testing.assert_allclose(adapter(left, left), left[:, :, 0], atol=EXACT_PX)
    assert "list of 12 predictions: the last (final) one is used" in adapter.describe()
    assert "tuple(tensor(1, 1, 64, 96), list[12 x tensor(1, 1, 64, 96)])" in adapter.describe()
    # a path into the nested output, written out
    path = TorchStereo(IGEVLike(), plain.replace(output=(1, -1)))(left, left)
    np.testing.assert_allclose(path, left[:, :, 0], atol=EXACT_PX)
    # output 0 is the disparity before refinement: taken as asked, but not silently
    with pytest.warns(UserWarning, match=r"output 0 of tuple\(tensor.*is used; the list after "
                      r"it usually holds the refined predictions .* test_mode=True .* "
                      r"output=\(1, -1\)"):
        before = TorchStereo(IGEVLike(), plain.replace(output=0))(left, left)
    np.testing.assert_allclose(before, left[:, :, 0] + REFINED_OFF_PX, atol=EXACT_PX)


def test_keyword_extras_accept_booleans_and_never_land_in_flow_init():
    left = random_image(50, 70)
    module = IGEVLike()
    spec = StereoSpec(pad_multiple=32, extra_inputs={"iters": 7, "test_mode": True})
    np.testing.assert_allclose(TorchStereo(module, spec)(left, left), left[:, :, 0],
                               atol=EXACT_PX)
    assert module.calls == [{"iters": 7, "flow_init": None, "test_mode": True}]
    with pytest.raises(BackboneError, match=r"spec.extra_inputs: expected keyword arguments "
                       r"of IGEVLike.forward, got 'n_steps'"):
        TorchStereo(IGEVLike(), StereoSpec(extra_inputs={"n_steps": 3}))


class FlagInput(nn.Module):
    """An export that kept ``test_mode`` as a boolean graph input."""

    def forward(self, left, right, test_mode):
        disp = left[:, :1] + 0.0 * right[:, :1]
        return torch.where(test_mode, disp, disp + REFINED_OFF_PX)


def test_boolean_extra_input_of_an_onnx_model(tmp_path):
    path = export(FlagInput(), tmp_path / "flag.onnx",
                  (torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32), torch.tensor(True)),
                  ("left", "right", "test_mode"), ("disp",))
    left = random_image(32, 32)
    disp = OnnxStereo(path, StereoSpec(extra_inputs={"test_mode": True}))(left, left)
    np.testing.assert_allclose(disp, left[:, :, 0], atol=EXACT_PX)
    off = OnnxStereo(path, StereoSpec(extra_inputs={"test_mode": False}))(left, left)
    np.testing.assert_allclose(off, left[:, :, 0] + REFINED_OFF_PX, atol=EXACT_PX)


# ---------------------------------------------------------------- RAFT-Stereo
class RAFTStereoLike(nn.Module):
    """``forward(image1, image2, iters=12, flow_init=None, test_mode=False)``.

    Test mode: ``(flow_low (B, 2, H/4, W/4), flow_up (B, 1, H, W))``; otherwise the list
    of ``flow_up`` per iteration. Flow is negative disparity; with fewer than 32
    iterations it has not converged (off by ``REFINED_OFF_PX / iters``).
    """

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[dict] = []

    def forward(self, image1, image2, iters=12, flow_init=None, test_mode=False):
        self.calls.append({"iters": iters, "test_mode": test_mode})
        require_multiple(image1, 32)
        flow = -(image1[:, :1] + 0.0 * image2[:, :1])
        preds = [flow - REFINED_OFF_PX * max(0, 32 - i - 1) / 32 for i in range(iters)]
        if test_mode:
            low = F.avg_pool2d(torch.cat([flow, torch.zeros_like(flow)], 1), 4) / 4
            return low, preds[-1]
        return preds


def test_raft_stereo_module_runs_32_iterations_in_test_mode():
    module = RAFTStereoLike()
    left = random_image(50, 70)
    np.testing.assert_allclose(TorchStereo(module, "raft-stereo")(left, left), left[:, :, 0],
                               atol=EXACT_PX)
    assert module.calls == [{"iters": 32, "test_mode": True}]
    # the forward default (12 iterations) would have been visibly unconverged
    default = TorchStereo(RAFTStereoLike(), StereoSpec(pad_multiple=32, output_sign=-1.0))
    assert np.abs(default(left, left) - left[:, :, 0]).min() > 1.0


# ---------------------------------------------------------------- CREStereo (PyTorch port)
class CREStereoLike(nn.Module):
    """``forward(image1, image2, flow_init=None, iters=10, upsample=True, test_mode=False)``.

    As in the PyTorch port, test mode is the constructor's ``self.test_mode`` (the
    keyword is accepted and ignored): then ``flow_up`` ``(B, 2, H, W)``, else the list of
    predictions, coarse (1/16 stage, off by 1.6 px) first. Channel 0 = channel 0 of
    image1 (blue for BGR input), positive. Without ``flow_init`` the estimate is 0.5 px
    off, as a one-stage run is coarser than the demo's two stages.
    """

    def __init__(self, test_mode: bool = False) -> None:
        super().__init__()
        self.test_mode = test_mode
        self.calls: list[dict] = []

    def forward(self, image1, image2, flow_init=None, iters=10, upsample=True, test_mode=False):
        self.calls.append({"hw": tuple(image1.shape[-2:]), "iters": iters,
                           "flow_init": None if flow_init is None else tuple(flow_init.shape)})
        require_multiple(image1, 8)
        if flow_init is not None:
            assert flow_init.shape[-2:] == (image1.shape[-2] // 2, image1.shape[-1] // 2)
            assert flow_init.shape[1] == 2
        disp = image1[:, :1] + 0.0 * image2[:, :1] + (0.0 if flow_init is not None else 0.5)
        flow_up = torch.cat([disp, torch.zeros_like(disp)], dim=1)
        predictions = [flow_up + 1.6, flow_up + 0.4, flow_up]
        if self.test_mode:
            return flow_up
        return predictions


@pytest.mark.parametrize("test_mode", [True, False])
def test_crestereo_module_runs_two_stages_like_its_demo(test_mode):
    module = CREStereoLike(test_mode=test_mode)
    left = random_image(50, 70)
    disp = TorchStereo(module, "crestereo")(left, random_image(50, 70))
    # BGR: the model's channel 0 is the image's blue channel; the final prediction is
    # read whether the port was built in test mode or not
    np.testing.assert_allclose(disp, left[:, :, 2], atol=EXACT_PX)
    # padded to 64x80 (a multiple of 8 at half size too), half size first, then full
    # size with the half-size flow
    assert module.calls == [{"hw": (32, 40), "iters": 20, "flow_init": None},
                            {"hw": (64, 80), "iters": 20, "flow_init": (1, 2, 32, 40)}]


def test_crestereo_positional_slots_stay_untouched():
    # an iteration count given as an extra used to be passed positionally, into flow_init
    module = CREStereoLike(test_mode=True)
    spec = StereoSpec(channel_order="BGR", pad_multiple=8, extra_inputs={"iters": 4})
    left = random_image(48, 64)
    np.testing.assert_allclose(TorchStereo(module, spec)(left, left), left[:, :, 2] + 0.5,
                               atol=EXACT_PX)
    assert module.calls == [{"hw": (48, 64), "iters": 4, "flow_init": None}]


# ---------------------------------------------------------------- FoundationStereo
class FoundationStereoLike(nn.Module):
    """``forward(image1, image2, iters=12, flow_init=None, test_mode=False,
    low_memory=False, init_disp=None)``: ``(init_disp, disp_preds)`` or, in test mode,
    ``disp_up``."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[dict] = []

    def forward(self, image1, image2, iters=12, flow_init=None, test_mode=False,
                low_memory=False, init_disp=None):
        self.calls.append({"iters": iters, "test_mode": test_mode})
        require_multiple(image1, 32)
        disp = image1[:, :1] + 0.0 * image2[:, :1]
        preds = [disp + REFINED_OFF_PX * (iters - 1 - i) / iters for i in range(iters)]
        if test_mode:
            return preds[-1]
        return disp + REFINED_OFF_PX, preds


def test_foundationstereo_preset_reads_the_refined_disparity():
    module = FoundationStereoLike()
    left = random_image(50, 70)
    np.testing.assert_allclose(TorchStereo(module, "foundationstereo")(left, left),
                               left[:, :, 0], atol=EXACT_PX)
    assert module.calls == [{"iters": 32, "test_mode": True}]


class FoundationStereoOnnxLike(nn.Module):
    """Its ONNX export's wrapper: ``forward(left, right)`` -> ``disp``, test mode inside."""

    def __init__(self) -> None:
        super().__init__()
        self.net = FoundationStereoLike()

    def forward(self, left, right):
        return self.net(left, right, iters=4, test_mode=True)


def test_foundationstereo_fixed_size_export(tmp_path):
    path = export(FoundationStereoOnnxLike(), tmp_path / "fs.onnx",
                  (torch.rand(1, 3, 64, 96), torch.rand(1, 3, 64, 96)), ("left", "right"),
                  ("disp",))
    model = OnnxStereo(path, "foundationstereo")
    text = model.describe()
    assert "fixed input size 96x64" in text and "pad_multiple (32) is not applied" in text
    left = constant_image(48, 72, (40, 0, 0))  # same aspect ratio: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(model(left, left), 40.0 * 72 / 96, atol=1e-3)
    left = constant_image(50, 70, (40, 0, 0))
    with pytest.warns(UserWarning, match=r"70x50 images are resized to the model's fixed 96x64 "
                      r"\(x by 1.371, y by 1.280: the aspect ratio changes\)"):
        np.testing.assert_allclose(model(left, left), 40.0 * 70 / 96, atol=1e-3)


# ---------------------------------------------------------------- CREStereo ONNX exports
class CREStereoCombinedLike(nn.Module):
    """The combined two-stage export: ``(init_left, init_right)`` at half size and
    ``(next_left, next_right)`` at full size -> ``(1, 2, H, W)`` flow, channel 0 positive.

    Channel 0 = blue of next_left (BGR input) plus 10x the difference of the coarse and
    full left means: exact for the right coarse pair, far off for a wrong one.
    """

    def forward(self, init_left, init_right, next_left, next_right):
        coarse_check = init_left[:, :1].mean() - next_left[:, :1].mean()
        disp = next_left[:, :1] + 10.0 * coarse_check + 0.0 * (init_right.mean()
                                                               + next_right.mean())
        return torch.cat([disp, torch.zeros_like(disp)], dim=1)


def combined_export(path, dynamic: bool):
    full = (torch.rand(1, 3, 64, 96), torch.rand(1, 3, 64, 96))
    half = (torch.rand(1, 3, 32, 48), torch.rand(1, 3, 32, 48))
    names = ("init_left", "init_right", "next_left", "next_right")
    axes = {n: {2: f"h_{n[:4]}", 3: f"w_{n[:4]}"} for n in names} if dynamic else None
    return export(CREStereoCombinedLike(), path, (*half, *full), names, ("output",), axes)


@pytest.mark.parametrize("dynamic", [False, True])
def test_crestereo_combined_two_stage_export(tmp_path, dynamic):
    model = OnnxStereo(combined_export(tmp_path / "combined.onnx", dynamic), "crestereo")
    assert model.input_names == ("next_left", "next_right") and model.uses_coarse
    assert "two-stage export: coarse inputs ['init_left', 'init_right']" in model.describe()
    left, right = constant_image(50, 70, (40, 20, 30)), constant_image(50, 70, (5, 6, 7))
    if dynamic:
        disp = model(left, right)
    else:
        with pytest.warns(UserWarning, match="the aspect ratio changes"):
            disp = model(left, right)
    if dynamic:
        # padded to 64x80 (multiple of 16), coarse pair 32x40; no resize
        assert model.pad_multiple == 16
        np.testing.assert_allclose(disp, 30.0, atol=1e-3)
    else:
        # resized to the export's 96x64 (coarse 48x32), rescaled by the width ratio
        np.testing.assert_allclose(disp, 30.0 * 70 / 96, atol=1e-3)


class CREStereoFlowInputLike(nn.Module):
    """The export with a ``flow_init`` input ``(1, 2, H/2, W/2)``; zeros leave it exact."""

    def forward(self, left, right, flow_init):
        disp = left[:, :1] + 0.0 * right[:, :1]
        disp = disp + F.interpolate(flow_init[:, :1], scale_factor=2.0)
        return torch.cat([disp, torch.zeros_like(disp)], dim=1)


def test_crestereo_export_with_flow_init_is_fed_zeros(tmp_path):
    path = export(CREStereoFlowInputLike(), tmp_path / "cre_flow.onnx",
                  (torch.rand(1, 3, 64, 96), torch.rand(1, 3, 64, 96),
                   torch.rand(1, 2, 32, 48)), ("left", "right", "flow_init"), ("output",))
    with pytest.warns(UserWarning, match=r"'flow_init' \(initial flow\) is fed zeros"):
        model = OnnxStereo(path, "crestereo")
    assert not model.uses_coarse and "fed zeros" in model.describe()
    left = constant_image(64, 96, (1, 2, 3))
    np.testing.assert_allclose(model(left, left), 3.0, atol=EXACT_PX)


# ---------------------------------------------------------------- HITNET
class HitnetLike(nn.Module):
    """One stacked input in 0..1: ``(1, 6, H, W)`` RGB or ``(1, 2, H, W)`` grey.

    Disparity (px) = 255 * (left's first channel + 2 x right's first channel), so a
    swapped or missing half of the stack shows.
    """

    def __init__(self, channels_per_image: int) -> None:
        super().__init__()
        self.c = channels_per_image

    def forward(self, x):
        return 255.0 * (x[:, :1] + 2.0 * x[:, self.c:self.c + 1])


@pytest.mark.parametrize("grey", [False, True])
def test_hitnet_stacked_input(tmp_path, grey):
    c = 1 if grey else 3
    path = export(HitnetLike(c), tmp_path / "hitnet.onnx", (torch.rand(1, 2 * c, 48, 64),),
                  ("input",), ("reference_output_disparity",))
    model = OnnxStereo(path, "hitnet")
    assert model.input_names == ("input",)
    assert model.spec.channel_order == ("grey" if grey else "RGB")
    left, right = random_image(48, 64), random_image(48, 64)
    if grey:
        first = [cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float32) for x in (left, right)]
        assert "a grey pair" in model.describe()
    else:
        first = [x[:, :, 0].astype(np.float32) for x in (left, right)]
    # grey: OpenCV's uint8 conversion rounds, the adapter's float one does not
    tolerance = 0.5 * 3 if grey else 1e-3
    np.testing.assert_allclose(model(left, right), first[0] + 2 * first[1], atol=tolerance)
    # the same look-alike as a torch module
    torch_disp = TorchStereo(HitnetLike(c), preset_for_torch(grey))(left, right)
    np.testing.assert_allclose(torch_disp, first[0] + 2 * first[1], atol=tolerance)


def preset_for_torch(grey: bool) -> StereoSpec:
    from srde_fusion.adapters import preset

    return preset("hitnet").replace(channel_order="grey") if grey else preset("hitnet")


def test_stacked_and_grey_channel_counts_are_checked(tmp_path):
    path = export(HitnetLike(3), tmp_path / "hitnet6.onnx", (torch.rand(1, 6, 32, 32),),
                  ("input",), ("disp",))
    with pytest.raises(BackboneError, match=r"expected 2 channels .* left and right stacked, "
                       r"grey\), got shape \[1, 6, 32, 32\]"):
        OnnxStereo(path, StereoSpec(input_mode="stacked", channel_order="grey"))
    with pytest.raises(BackboneError, match="model inputs: expected two image inputs"):
        OnnxStereo(path, "generic")
    with pytest.raises(BackboneError, match="input_names: expected one name"):
        StereoSpec(input_mode="stacked", input_names=("left", "right"))


# ---------------------------------------------------------------- sizes and assumptions
class NeedsEvenSizes(nn.Module):
    """A dynamic export whose skip connection only fits even sizes (a Concat in ONNX)."""

    def forward(self, left, right):
        up = F.interpolate(F.avg_pool2d(left[:, :1], 2), scale_factor=2.0)
        return torch.cat([up, left[:, :1] + 0.0 * right[:, :1]], dim=1)[:, 1:]


def test_size_failures_point_at_pad_multiple(tmp_path):
    args = (torch.rand(1, 3, 64, 96), torch.rand(1, 3, 64, 96))
    axes = {n: {2: "h", 3: "w"} for n in ("left", "right")}
    path = export(NeedsEvenSizes(), tmp_path / "even.onnx", args, ("left", "right"), ("disp",),
                  axes)
    with pytest.warns(UserWarning, match="no spec or preset given, 'generic' assumed"):
        model = load_backbone(path)
    assert "set pad_multiple or use its preset" in model.describe()
    with pytest.raises(BackboneError, match=r"set spec.pad_multiple \(now 1\) or use its "
                       r"preset"):
        model(random_image(51, 71), random_image(51, 71))
    left = random_image(51, 71)
    padded = OnnxStereo(path, StereoSpec(pad_multiple=2))(left, left)
    np.testing.assert_allclose(padded, left[:, :, 0], atol=EXACT_PX)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"forward_kwargs": {"iters": [1, 2]}}, r"forward_kwargs\['iters'\]: expected a bool"),
        ({"forward_kwargs": {"iters": 3}, "extra_inputs": {"iters": 3}},
         "expected names not also in extra_inputs, got iters in both"),
        ({"extra_inputs": {"flag": None}}, r"extra_inputs\['flag'\]: expected a bool, int"),
        ({"output": ()}, "output: expected an index, a name or a non-empty path"),
        ({"output": (1, 2.5)}, "output: expected an index, a name or a non-empty path"),
        ({"input_mode": "side-by-side"}, "input_mode: expected one of pair, stacked"),
        ({"coarse_factor": 0}, "coarse_factor: expected an integer >= 1"),
        ({"coarse_input_names": ("a",)}, "coarse_input_names: expected two names"),
        ({"bytes_per_px": -1.0}, "bytes_per_px: expected None or a positive number"),
    ],
)
def test_invalid_family_fields(changes, message):
    with pytest.raises(BackboneError, match=message):
        StereoSpec(**changes)


def test_output_paths_are_for_torch_only(tmp_path):
    path = export(FoundationStereoOnnxLike(), tmp_path / "fs.onnx",
                  (torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)), ("left", "right"),
                  ("disp",))
    with pytest.raises(BackboneError, match=r"expected an index or a name for an ONNX model "
                       r"\(its outputs are a flat list \['disp'\]\), got the path \(1, -1\)"):
        OnnxStereo(path, StereoSpec(output=(1, -1)))
