"""The stand-in network: it learns, its ONNX export matches torch, the bundled default works."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

from srde_fusion.adapters import (  # noqa: E402
    OnnxStereo,
    TorchStereo,
    default_model_info,
    load_backbone,
)
from srde_fusion.adapters.standin.network import (  # noqa: E402
    STANDIN_SIZES,
    SoftCensus,
    StandinConfig,
    build_standin,
    row_correlations,
)
from srde_fusion.adapters.standin.procedural import random_stereo_pair  # noqa: E402
from srde_fusion.adapters.standin.training import (  # noqa: E402
    TrainingConfig,
    load_onnx_weights,
    train_standin,
)

from srde_fusion.cli import main  # noqa: E402
from srde_fusion.errors import BackboneError  # noqa: E402

PARITY_PX = 1e-3
# Smaller than "tiny": trains in seconds on one CPU thread.
MICRO = StandinConfig(feature_channels=8, max_disparity_px=32, correlation_groups=2,
                      volume_channels=2, hidden_channels=8, lookup_radius=1, iterations=1,
                      census_radius=1, refine_channels=4, refine_radius=1)
MICRO_TRAINING = TrainingConfig(size=MICRO, steps=80, batch_size=4, crop_hw=(32, 64),
                                max_train_disparity_px=16.0, learning_rate=3e-3,
                                validation_pairs=8)
DEFAULT_EPE_RATIO = 0.8  # bundled model vs the best constant map on procedural pairs


@pytest.fixture(scope="module")
def micro(tmp_path_factory):
    return train_standin(tmp_path_factory.mktemp("micro") / "micro.onnx", MICRO_TRAINING,
                         progress=False)


def test_micro_network_learns(micro):
    assert micro.final_epe_px < 0.6 * micro.initial_epe_px, micro
    record = json.loads(micro.info_path.read_text())
    assert record["architecture"]["feature_channels"] == MICRO.feature_channels
    assert record["validation"]["final_epe_px"] == pytest.approx(micro.final_epe_px, abs=1e-3)
    assert record["onnx"]["parity_max_abs_px"] < PARITY_PX


@pytest.mark.parametrize("hw", [(64, 96), (50, 75)])  # a multiple of 32 and not
def test_torch_and_onnx_adapters_agree(micro, hw):
    sample = random_stereo_pair(11, height=hw[0], width=hw[1], max_disparity_px=16)
    via_torch = TorchStereo(micro.network, "igev")(sample.left, sample.right)
    via_onnx = OnnxStereo(micro.onnx_path, "igev")(sample.left, sample.right)
    assert via_torch.shape == via_onnx.shape == hw
    assert np.abs(via_torch - via_onnx).max() < PARITY_PX
    assert np.abs(via_onnx).max() > 1.0  # a trained network, not a constant zero map


def test_onnx_weights_load_back_into_the_network(micro):
    fresh = build_standin(MICRO).eval()
    x = torch.rand(1, 3, 32, 64) * 255
    assert not torch.allclose(fresh(x, x), micro.network(x, x))
    load_onnx_weights(fresh, micro.onnx_path)
    assert torch.allclose(fresh(x, x), micro.network(x, x), atol=1e-5)
    with pytest.raises(BackboneError, match="expected .* of shape"):
        load_onnx_weights(build_standin("tiny"), micro.onnx_path)


def test_fine_tuning_starts_from_the_given_weights(micro, tmp_path):
    # zero steps of learning rate: the network must come back as it was loaded
    stage2 = train_standin(tmp_path / "ft.onnx", TrainingConfig(
        size=MICRO, steps=1, batch_size=1, crop_hw=(32, 64), max_train_disparity_px=16.0,
        learning_rate=1e-12, validation_pairs=8, init_onnx=str(micro.onnx_path)),
        progress=False)
    assert stage2.initial_epe_px == pytest.approx(micro.final_epe_px, rel=1e-3)


def test_forward_all_returns_every_iterate():
    net = build_standin("tiny").eval()
    x = torch.rand(2, 3, 64, 96) * 255
    out = net.forward_all(x, x)
    assert out.initial.shape == (2, 1, 64, 96)
    # every 1/4-resolution iterate, then the full-resolution step (the output)
    assert len(out.refined) == STANDIN_SIZES["tiny"].iterations + 1
    assert torch.equal(net(x, x), out.refined[-1])


def test_soft_census_ignores_monotonic_intensity_changes():
    census = SoftCensus(radius=2)
    grey = torch.rand(1, 1, 24, 32) * 2 - 1
    bits = census(grey)
    assert bits.shape == (1, 24, 24, 32) and census.channels == 24
    # a gain and an offset change the differences' scale, not their signs: the clear
    # bits (well above the softness) keep their sign
    brighter = census(grey * 1.5 + 0.2)
    clear = bits.abs() > 0.9
    assert clear.float().mean() > 0.5
    assert torch.equal(torch.sign(bits[clear]), torch.sign(brighter[clear]))
    # a flat image has no bits
    assert census(torch.full((1, 1, 8, 8), 0.3)).abs().max() == 0


def _sample_rows(image: torch.Tensor, x_px: torch.Tensor) -> torch.Tensor:
    """Reference: per-pixel linear interpolation along rows, zero outside (numpy)."""
    img, x = image.numpy(), x_px.numpy()[:, 0]
    out = np.zeros_like(img)
    b, c, h, w = img.shape
    for n in range(b):
        for y in range(h):
            for col in range(w):
                lo = int(np.floor(x[n, y, col]))
                f = x[n, y, col] - lo
                for j, weight in ((lo, 1 - f), (lo + 1, f)):
                    if 0 <= j < w:
                        out[n, :, y, col] += weight * img[n, :, y, j]
    return torch.from_numpy(out)


def test_row_correlations_match_resampling_the_descriptors():
    gen = torch.Generator().manual_seed(0)
    left, right = (torch.rand(2, 5, 4, 9, generator=gen) - 0.5 for _ in range(2))
    x = torch.rand(2, 1, 4, 9, generator=gen) * 14 - 3  # some positions outside the row
    costs = row_correlations(left, right, x, radius=2)
    assert costs.shape == (2, 5, 4, 9)
    for k, offset in enumerate(range(-2, 3)):
        expected = (left * _sample_rows(right, x - offset)).mean(dim=1)
        assert torch.allclose(costs[:, k], expected, atol=1e-6)


def test_full_resolution_step_reads_the_census_costs():
    net = build_standin("tiny").eval()
    step = net.full_resolution
    sample = random_stereo_pair(3, height=64, width=96, max_disparity_px=16)
    left, right = (torch.from_numpy(v).permute(2, 0, 1)[None].float() * (2 / 255) - 1
                   for v in (sample.left, sample.right))
    census_l, census_r = (net.census(v.mean(dim=1, keepdim=True)) for v in (left, right))
    truth = torch.from_numpy(sample.disparity_px)[None, None]
    # freshly built, it starts as (almost) the identity
    assert (step(left, census_l, census_r, truth) - truth).abs().max() < 0.1
    # its census costs are higher at the true disparity than 3 px off
    columns = torch.cumsum(torch.ones_like(truth), dim=3) - 1
    at_truth = row_correlations(census_l, census_r, columns - truth, radius=1)[:, 1].mean()
    off = row_correlations(census_l, census_r, columns - truth - 3, radius=1)[:, 1].mean()
    assert at_truth > off + 0.05  # measured 0.15 against 0.05 (seed 3)


def test_bundled_default_fulfils_the_contract():
    backbone = load_backbone("default")
    info = default_model_info()
    assert info["preset"] == "igev" and backbone.spec.pad_multiple == 32
    epe, constant_epe = [], []
    for seed in range(8):
        sample = random_stereo_pair(seed, height=100, width=150, max_disparity_px=40)
        disp = backbone(sample.left, sample.right)
        assert disp.shape == (100, 150) and disp.dtype == np.float32
        assert np.isfinite(disp).all()
        epe.append(np.abs(disp - sample.disparity_px).mean())
        # the best constant map (the median) is what a network that does not match gets
        truth = sample.disparity_px
        constant_epe.append(np.abs(truth - np.median(truth)).mean())
    # measured 1.8 px against 4.3 px for the best constants (some layers are textureless)
    assert np.mean(epe) < DEFAULT_EPE_RATIO * np.mean(constant_epe)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_procedural_pair_is_consistent_with_its_disparity():
    for seed in range(4):
        s = random_stereo_pair(seed, height=64, width=128, max_disparity_px=40)
        again = random_stereo_pair(seed, height=64, width=128, max_disparity_px=40)
        assert np.array_equal(s.left, again.left)
        assert np.array_equal(s.disparity_px, again.disparity_px)
        assert 0 <= s.disparity_px.min() and s.disparity_px.max() <= 40
        ys, xs = np.mgrid[0:64, 0:128].astype(np.float32)
        scores = []
        for shift in (0.0, 3.0):
            x_right = xs - s.disparity_px - shift
            warped = cv2.remap(s.right.astype(np.float32), x_right, ys, cv2.INTER_LINEAR)
            inside = x_right >= 0
            # horizontal gradients: exposure differences between the views cancel out
            grad_warped = cv2.Sobel(warped.mean(axis=2), cv2.CV_32F, 1, 0)
            grad_left = cv2.Sobel(s.left.astype(np.float32).mean(axis=2), cv2.CV_32F, 1, 0)
            scores.append(_ncc(grad_warped[inside], grad_left[inside]))
        assert scores[0] > scores[1] + 0.15, (seed, scores)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"max_disparity_px": 60}, "multiple of 8"),
        ({"correlation_groups": 5}, "divisor of feature_channels"),
        ({"iterations": 0}, "iterations"),
    ],
)
def test_invalid_architecture(changes, message):
    with pytest.raises(BackboneError, match=message):
        StandinConfig(**changes)


def test_invalid_training_settings(tmp_path):
    with pytest.raises(BackboneError, match="multiples of 32"):
        train_standin(tmp_path / "x.onnx", TrainingConfig(size=MICRO, crop_hw=(30, 64)))
    with pytest.raises(BackboneError, match="ending in .onnx"):
        train_standin(tmp_path / "x.pt", MICRO_TRAINING)
    with pytest.raises(BackboneError, match="expected one of default, tiny"):
        build_standin("huge")


def test_cli_reports_bad_output_path(tmp_path, capsys):
    assert main(["train-standin", "--out", str(tmp_path / "model.txt"), "--steps", "1"]) == 2
    assert "ending in .onnx" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["train-standin", "--help"])
    assert exit_info.value.code == 0
    assert "procedural" in capsys.readouterr().out
