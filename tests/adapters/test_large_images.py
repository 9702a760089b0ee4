"""Pairs over an adapter's max_pixels: run in strips or downscaled, said and recorded."""

from __future__ import annotations

import logging
import warnings

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

from srde_fusion.adapters import (  # noqa: E402
    OnnxStereo,
    StereoSpec,
    TorchStereo,
    default_weights_path,
    load_backbone,
)
from srde_fusion.adapters.large_images import (  # noqa: E402
    TILE_OVERLAP_ROWS,
    default_max_pixels,
    plan_large_image,
)
from srde_fusion.adapters.loading import STANDIN_BYTES_PER_PX  # noqa: E402
from torch import nn  # noqa: E402

from srde_fusion.errors import BackboneError  # noqa: E402

EXACT_PX = 1e-4
RNG = np.random.default_rng(14)


class Pointwise(nn.Module):
    """Disparity = left's first channel; records the input sizes it was given."""

    def __init__(self, multiple: int = 1) -> None:
        super().__init__()
        self.multiple = multiple
        self.sizes: list[tuple[int, int]] = []

    def forward(self, left, right):
        self.sizes.append(tuple(left.shape[-2:]))
        if left.shape[-1] % self.multiple or left.shape[-2] % self.multiple:
            raise RuntimeError("size must be a multiple")
        return left[:, :1] + 0.0 * right[:, :1]


class RunsOutOfMemory(Pointwise):
    """Fails like an allocator above ``limit`` input pixels."""

    def __init__(self, limit: int) -> None:
        super().__init__()
        self.limit = limit

    def forward(self, left, right):
        if left.shape[-1] * left.shape[-2] > self.limit:
            raise RuntimeError("CPU out of memory: tried to allocate 3.5 GiB")
        return super().forward(left, right)


def image(h: int, w: int) -> np.ndarray:
    return RNG.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def test_a_pair_over_max_pixels_runs_in_overlapping_strips(caplog):
    module = Pointwise(multiple=32)
    adapter = TorchStereo(module, "igev", max_pixels=160 * 192)
    left = image(300, 170)
    with caplog.at_level(logging.WARNING, logger="srde_fusion.adapters"):
        disp = adapter(left, left)
    # a pointwise model makes the blend exact: every row is the image's own value
    np.testing.assert_allclose(disp, left[:, :, 0], atol=EXACT_PX)
    plan = adapter.last_plan
    assert plan.strategy == "tiles" and plan.run_hw == (160, 170)
    assert all(h * w <= 160 * 192 for h, w in module.sizes)  # padded run sizes
    starts = [r[0] for r in plan.rows]
    stops = [r[1] for r in plan.rows]
    assert starts[0] == 0 and stops[-1] == 300
    assert all(stop - nxt >= TILE_OVERLAP_ROWS for stop, nxt in zip(stops, starts[1:],
                                                                      strict=False))
    assert "exceeds max_pixels 30,720" in caplog.text and "strips of 170x160" in caplog.text


def test_downscale_rescales_disparity_by_the_width_ratio():
    adapter = TorchStereo(Pointwise(), "generic", max_pixels=100 * 100,
                          large_images="downscale")
    left = np.broadcast_to(np.asarray([60, 0, 0], np.uint8), (200, 300, 3)).copy()
    disp = adapter(left, left)
    plan = adapter.last_plan
    run_h, run_w = plan.run_hw
    assert plan.strategy == "downscale" and run_h * run_w <= 100 * 100
    assert abs(run_w / run_h - 1.5) < 0.05  # same aspect ratio
    # 60 px measured on run_w-wide images is 60 * 300 / run_w px on the caller's
    np.testing.assert_allclose(disp, 60.0 * 300 / run_w, rtol=1e-5)


def test_too_wide_for_a_strip_falls_back_to_downscale():
    plan = plan_large_image((2000, 4000), 4000 * 64, multiple=32, strategy="tile")
    assert plan.strategy == "downscale" and "downscaled" in plan.reason
    assert plan.run_hw[0] * plan.run_hw[1] <= 4000 * 64


def test_fixed_size_and_small_pairs_run_whole(tmp_path):
    assert plan_large_image((480, 640), None, multiple=32).strategy == "whole"
    assert plan_large_image((480, 640), 640 * 480, multiple=32).strategy == "whole"
    # 470 rows pad to 480: counted after padding
    assert plan_large_image((470, 640), 640 * 470, multiple=32).strategy == "tiles"
    fixed = plan_large_image((3000, 4000), 10, multiple=32, fixed_size=True)
    assert fixed.strategy == "whole" and "fixed-size" in fixed.reason


def test_running_out_of_memory_is_retried_on_fewer_pixels(caplog):
    module = RunsOutOfMemory(limit=200 * 120)
    adapter = TorchStereo(module, "generic", max_pixels=None)
    left = image(300, 120)
    with caplog.at_level(logging.WARNING, logger="srde_fusion.adapters"):
        disp = adapter(left, left)
    np.testing.assert_allclose(disp, left[:, :, 0], atol=EXACT_PX)
    assert adapter.last_plan.strategy == "tiles"
    assert "after running out of memory" in adapter.last_plan.reason
    assert "out of memory" in caplog.text and "retrying with max_pixels" in caplog.text
    # a model that fails even on the smallest run says so as a BackboneError
    with pytest.raises(BackboneError, match="out of memory"):
        TorchStereo(RunsOutOfMemory(limit=0), "generic", max_pixels=None)(left, left)


def test_onnx_adapter_tiles_too(tmp_path):
    path = tmp_path / "pointwise.onnx"
    args = (torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(Pointwise(), args, str(path), input_names=["left", "right"],
                          output_names=["disp"], opset_version=17, dynamo=False,
                          dynamic_axes={n: {2: "h", 3: "w"} for n in ("left", "right")})
    model = OnnxStereo(path, "igev", max_pixels=200 * 256)
    left = image(500, 230)
    np.testing.assert_allclose(model(left, left), left[:, :, 0], atol=EXACT_PX)
    assert model.last_plan.strategy == "tiles"
    assert "max_pixels 51,200 (given); beyond it: strips of full width" in model.describe()


def test_default_budgets():
    # the stand-in's budget follows from its measured memory per pixel and the machine
    standin = load_backbone("default")
    assert standin.max_pixels == default_max_pixels(STANDIN_BYTES_PER_PX)
    assert standin.spec.bytes_per_px == STANDIN_BYTES_PER_PX
    assert "B/px" in standin.describe()
    # 12 MP needs ~8 GB: inside the budget of a 24 GiB machine (about 19 MP), run whole;
    # on a 4 GiB machine (about 3 MP) it is tiled
    budget = default_max_pixels(STANDIN_BYTES_PER_PX, memory_bytes=24 * 2**30)
    assert 1.5e7 < budget < 2.5e7
    assert plan_large_image((3000, 4000), budget, multiple=32).strategy == "whole"
    small = default_max_pixels(STANDIN_BYTES_PER_PX, memory_bytes=4 * 2**30)
    assert plan_large_image((3000, 4000), small, multiple=32).strategy == "tiles"
    # a model of unknown memory per pixel gets no budget, and says so
    unknown = OnnxStereo(default_weights_path(), "igev")
    assert unknown.max_pixels is None and "memory per pixel of this model unknown" in (
        unknown.describe())
    assert OnnxStereo(default_weights_path(), StereoSpec(pad_multiple=32, bytes_per_px=1e3),
                      max_pixels="auto").max_pixels == default_max_pixels(1e3)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"max_pixels": 0}, "max_pixels: expected None, 'auto' or a positive integer, got 0"),
        ({"max_pixels": "lots"}, "max_pixels: expected None, 'auto' or a positive integer"),
        ({"large_images": "crop"}, "large_images: expected one of tile, downscale, got 'crop'"),
    ],
)
def test_invalid_large_image_options(options, message):
    with pytest.raises(BackboneError, match=message):
        TorchStereo(Pointwise(), "generic", **options)
