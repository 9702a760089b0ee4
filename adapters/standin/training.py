r"""Training, ONNX export and the ``srde-fusion train-standin`` command for the stand-in.

The stand-in learns from procedural pairs (:mod:`srde_fusion.adapters.standin.procedural`):
textured slanted planes and occluding layers with exact disparity, generated on the fly,
so training needs no data set.

Recipe of the bundled weights: a first stage with the defaults of
:class:`TrainingConfig`, then two more on larger crops at lower learning rates::

    srde-fusion train-standin --out standin_stage1.onnx --size default --steps 3000 \\
        --seed 0 --batch-size 3 --crop 128 256 --learning-rate 1e-3
    srde-fusion train-standin --out standin_stage2.onnx --init standin_stage1.onnx \\
        --size default --steps 700 --seed 1 --batch-size 2 --crop 160 320 --learning-rate 3e-4
    srde-fusion train-standin --out standin.onnx --init standin_stage2.onnx --size default \\
        --steps 1300 --seed 2 --batch-size 1 --crop 256 512 --learning-rate 2e-4

one CPU thread; AdamW steps of fresh pairs (disparities up to 96 px), one-cycle learning
rate peaking after 5 % of the steps then falling linearly, weight decay 1e-5, gradients
clipped to norm 1; loss: smooth-L1 on the initial soft-argmin disparity plus L1 on every
refined estimate (the 1/4-resolution iterates and the full-resolution census step, the
last) weighted 0.9^(steps from the last), pixels beyond the network's range left out.
``--seed`` seeds the weights and the stream of pairs. The stages took 64.5, 10.7 and
40.3 minutes on a 2-core machine shared with other jobs (about 1.0 s per first-stage step
when the machine is quiet). The second stage was kept because it was better on held-out
procedural pairs (256x512: EPE 5.94 -> 5.50 px, bad-2 27.6 -> 25.7 %) and on four
rendered scenes outside the benchmarks (textured background bad-2 16.9 -> 16.2 %). The
third (larger crops: more context for weakly textured regions, which are the stand-in's
largest source of error on a real pair after occlusions) was kept because it was better,
both with the left-right check below, on the held-out pairs that chose that check: 12
rendered scenes EPE 0.377 -> 0.348 px (better in 9), 12 procedural pairs at 384x640
5.76 -> 5.27 px (10), 6 at 480x736 3.11 -> 1.98 px (5); its own validation pairs
(256x512) 4.43 -> 4.19 px.

Measured against the previous bundled weights (the same network without the census
group and the full-resolution step, 2400 steps on the procedural pairs without 1/f
noise) with ``benchmarks/backbone_accuracy.py``, every method counted the same way:
Motorcycle 741x500 EPE (holes filled) 2.66 -> 2.42 px, bad-1 44.1 -> 27.0 %, bad-2
26.3 -> 20.3 % (SGBM: 1.92 px, 24.1 %, 22.6 %); rendered scenes' textured background
bad-1 27.4 -> 21.9 %, bad-2 15.5 -> 15.0 %, EPE 1.37 -> 1.47 px; glossy objects EPE
8.1 -> 10.0 px (no texture to match either way). The three changes (census group,
full-resolution step, 1/f textures) were trained together; which of them the gain comes
from was not measured separately.

Why procedural pairs and not the rendered scenes of :mod:`srde_fusion.synthetic`: rendering
one scene takes seconds, too slow to draw fresh pairs at every step on a CPU, and the
procedural layers give exact disparity with occlusions at any range. For the previous
architecture a variant with 30 % dark exposures (like the dim rendered scenes) was
trained the same way and measured worse (Motorcycle EPE 4.67 px vs 3.06 px, rendered
textured background 2.22 px vs 1.94 px), so it is not used.

At inference the adapters run the trained network with a left-right check
(:data:`INFERENCE`, written to the record as ``inference``; see
:mod:`srde_fusion.adapters.consistency`): the mirrored pair too, confirmed pixels averaged
with the right view, the others filled with their row's background. It was chosen on
held-out pairs outside every benchmark (12 rendered scenes, seeds 100-115 with
disparities within the training range, textured background; 12 procedural pairs at
384x640 and 6 at 480x736, disparities up to 64 px): mean EPE 0.58 -> 0.38 px, 6.87 ->
5.76 px and 3.66 -> 3.11 px, bad-2 5.7 -> 2.9 %, 35.6 -> 33.1 % and 24.2 -> 20.9 %,
better in 12 of 12, 10 of 12 and 5 of 6 pairs. Fills from
eight directions (median; Hirschmueller's second-lowest value for occlusions) and a 2 px
tolerance were no better on all three sets. After the check comes census propagation
(:mod:`srde_fusion.adapters.propagation`): a pixel takes a neighbour's disparity where
the images' census cost is clearly lower and good in itself. It and its thresholds were
chosen on other held-out pairs outside every benchmark (12 rendered scenes, seeds
2000-2011, textured background; 16 procedural pairs at 256x512, 12 at 384x640, 6 at
480x736): mean EPE 5.05 -> 4.85, 5.26 -> 5.15, 8.44 -> 8.32 and 9.19 -> 9.18 px against
the check alone, better in 8 of 12, 16 of 16, 8 of 12 and 4 of 6 pairs. Its seeds (each
pixel's own best match over a 9x9 window, where the right view confirms it) were added
later, on the same pairs: 4.86 -> 4.49, 5.15 -> 4.98, 8.33 -> 7.85 and 9.18 -> 9.16 px,
better in 8 of 12, 12 of 16, 7 of 12 and 3 of 6 (worst pair 6 % worse). Segment planes
(:mod:`srde_fusion.adapters.segment_planes`) come last, checked on the same pairs and on
12 fusion-like rendered scenes outside every benchmark (seeds 5000-5011): 4.49 -> 4.43,
4.98 -> 4.92, 7.85 -> 7.78, 9.16 -> 9.10 and 1.03 -> 0.97 px, better in 57 of the 58
pairs (one unchanged) and worse in none.

This module imports torch only inside its functions: the ``srde-fusion`` command
imports it at start-up to register the subcommand.
"""

from __future__ import annotations

import json
import os
import platform
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from srde_fusion.errors import BackboneError

from .procedural import random_stereo_batch

__all__ = [
    "TrainingConfig",
    "TrainingReport",
    "train_standin",
    "export_standin_onnx",
    "evaluate_standin",
]

ONNX_OPSET = 17
ONNX_INPUT_NAMES = ("left", "right")
ONNX_OUTPUT_NAME = "disparity"
PARITY_SIZES_HW = ((96, 160), (100, 150))  # one multiple of 32 and one that is not
_VALIDATION_SEED = 1_000_003  # held-out pairs never drawn by a training seed stream
_BAD_THRESHOLD_PX = 2.0
# IGEV's loss: smooth-L1 on the initial estimate, gamma-weighted L1 on the iterates.
_INITIAL_LOSS_WEIGHT = 1.0
_ITERATION_GAMMA = 0.9
#: How the adapters run a trained stand-in (StereoSpec fields, written to its record):
#: a left-right check whose failures take the row's background, chosen on held-out
#: rendered and procedural pairs (see the module text).
INFERENCE = {"left_right_check": True, "left_right_max_diff_px": 1.0, "census_propagation": True,
             "segment_planes": True}


@dataclass(frozen=True)
class TrainingConfig:
    """How the stand-in is trained.

    Attributes
    ----------
    size : {"default", "tiny"} or StandinConfig
        Architecture: a named size (see ``STANDIN_SIZES``) or a config of its own.
    steps : int
        Optimiser steps.
    seed : int
        Seeds the weights and the stream of procedural training pairs.
    batch_size : int
        Pairs per step.
    crop_hw : (int, int)
        Training image height and width in pixels (multiples of 32).
    max_train_disparity_px : float
        Largest disparity in training pairs (at most the network's ``max_disparity_px``).
    learning_rate : float
        Peak AdamW learning rate of the one-cycle schedule.
    validation_pairs : int
        Held-out procedural pairs evaluated before and after training.
    threads : int
        torch CPU threads. One thread is the default: on a shared 2-core machine two
        threads contend with other processes and ran several times slower.
    init_onnx : str, optional
        A stand-in ONNX export of the same architecture whose weights training starts
        from (a second, fine-tuning stage); None: fresh weights from ``seed``.
    """

    size: Any = "default"
    steps: int = 3000
    seed: int = 0
    batch_size: int = 3
    crop_hw: tuple[int, int] = (128, 256)
    max_train_disparity_px: float = 96.0
    learning_rate: float = 1e-3
    validation_pairs: int = 16
    threads: int = 1
    init_onnx: str | None = None


@dataclass(frozen=True)
class TrainingReport:
    """What a training run produced and measured.

    Attributes
    ----------
    onnx_path : pathlib.Path
        The exported model.
    info_path : pathlib.Path
        The JSON record next to it (config, command, metrics).
    initial_epe_px, final_epe_px : float
        Mean absolute disparity error on the held-out procedural pairs before and after.
    final_bad2 : float
        Fraction of held-out pixels with error above 2 px after training.
    parity_max_abs_px : float
        Largest |torch - onnxruntime| disparity difference over the parity sizes.
    seconds : float
        Wall time of the training loop.
    network : StandinStereo
        The trained torch module, in eval mode.
    """

    onnx_path: Path
    info_path: Path
    initial_epe_px: float
    final_epe_px: float
    final_bad2: float
    parity_max_abs_px: float
    seconds: float
    network: Any = field(repr=False)


def _to_tensors(samples: list, device: Any) -> tuple[Any, Any, Any]:
    import torch

    # (B, H, W, 3) uint8 -> (B, 3, H, W) float in 0..255, the IGEV input convention
    left = torch.from_numpy(np.stack([s.left for s in samples])).permute(0, 3, 1, 2).float()
    right = torch.from_numpy(np.stack([s.right for s in samples])).permute(0, 3, 1, 2).float()
    disp = torch.from_numpy(np.stack([s.disparity_px for s in samples]))[:, None]
    return left.to(device), right.to(device), disp.to(device)


def evaluate_standin(net: Any, samples: list, *, batch_size: int = 8) -> dict[str, float]:
    """Mean EPE and bad-2 of a stand-in network on procedural samples.

    Parameters
    ----------
    net : StandinStereo
    samples : list of StereoSample
        Sizes must be multiples of 32.

    Returns
    -------
    dict
        ``{"epe": px, "bad2": fraction}`` over all pixels.
    """
    import torch

    was_training = net.training
    net.eval()
    abs_sum, bad_sum, count = 0.0, 0.0, 0
    with torch.inference_mode():
        for i in range(0, len(samples), batch_size):
            left, right, gt = _to_tensors(samples[i:i + batch_size], "cpu")
            err = (net(left, right) - gt).abs()
            abs_sum += float(err.sum())
            bad_sum += float((err > _BAD_THRESHOLD_PX).sum())
            count += err.numel()
    net.train(was_training)
    return {"epe": abs_sum / count, "bad2": bad_sum / count}


def _loss(outputs: Any, gt: Any, max_disparity_px: float) -> Any:
    import torch.nn.functional as F

    valid = (gt < max_disparity_px).float()
    norm = valid.sum().clamp(min=1.0)
    loss = _INITIAL_LOSS_WEIGHT * (
        F.smooth_l1_loss(outputs.initial, gt, reduction="none") * valid
    ).sum() / norm
    n = len(outputs.refined)
    for i, pred in enumerate(outputs.refined):
        weight = _ITERATION_GAMMA ** (n - i - 1)
        loss = loss + weight * ((pred - gt).abs() * valid).sum() / norm
    return loss


def load_onnx_weights(net: Any, path: str | os.PathLike) -> None:
    """Copy the weights of a stand-in ONNX export into a network of the same architecture.

    The exporter keeps parameter names as initializer names, so every entry of the
    network's ``state_dict`` is looked up by name.

    Parameters
    ----------
    net : StandinStereo
    path : str or os.PathLike
        A ``.onnx`` file written by :func:`export_standin_onnx`.

    Raises
    ------
    BackboneError
        Missing file, or a weight missing or of another shape (another architecture).
    """
    import onnx
    import torch
    from onnx import numpy_helper

    if not Path(path).is_file():
        raise BackboneError(f"init_onnx: expected an existing .onnx file, got {str(path)!r}")
    weights = {i.name: i for i in onnx.load(str(path)).graph.initializer}
    state = {}
    for name, tensor in net.state_dict().items():
        if name not in weights:
            raise BackboneError(f"init_onnx {path}: expected a weight named {name!r}, got none "
                                f"(another architecture?)")
        value = torch.from_numpy(numpy_helper.to_array(weights[name]).copy())
        if value.shape != tensor.shape:
            raise BackboneError(f"init_onnx {path}: expected {name} of shape "
                                f"{tuple(tensor.shape)}, got {tuple(value.shape)}")
        state[name] = value
    net.load_state_dict(state)


def export_standin_onnx(net: Any, path: str | os.PathLike) -> float:
    """Export a stand-in network to ONNX with dynamic batch, height and width.

    Uses the TorchScript-based exporter (``dynamo=False``): the dynamo exporter needs
    the optional ``onnxscript`` package. Afterwards the model is run with onnxruntime
    at two sizes and compared with torch.

    Parameters
    ----------
    net : StandinStereo
    path : str or os.PathLike
        Output ``.onnx`` file.

    Returns
    -------
    float
        Largest absolute disparity difference (px) between torch and onnxruntime.
    """
    import onnxruntime as ort
    import torch

    net = net.eval()
    h, w = PARITY_SIZES_HW[0]
    example = (torch.zeros(1, 3, h, w), torch.zeros(1, 3, h, w))
    dynamic = {0: "batch", 2: "height", 3: "width"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's deprecation and tracer notices
        torch.onnx.export(
            net, example, str(path), input_names=list(ONNX_INPUT_NAMES),
            output_names=[ONNX_OUTPUT_NAME], opset_version=ONNX_OPSET, dynamo=False,
            dynamic_axes={ONNX_INPUT_NAMES[0]: dynamic, ONNX_INPUT_NAMES[1]: dynamic,
                          ONNX_OUTPUT_NAME: dynamic},
        )
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = 0.0
    for i, (ph, pw) in enumerate(PARITY_SIZES_HW):
        sample = random_stereo_batch(_VALIDATION_SEED + i, 1, height=ph + (-ph) % 32,
                                     width=pw + (-pw) % 32, max_disparity_px=32.0)
        left, right, _ = _to_tensors(sample, "cpu")
        with torch.inference_mode():
            expected = net(left, right).numpy()
        got = session.run(None, {ONNX_INPUT_NAMES[0]: left.numpy(),
                                 ONNX_INPUT_NAMES[1]: right.numpy()})[0]
        worst = max(worst, float(np.abs(expected - got).max()))
    return worst


def train_standin(out: str | os.PathLike, config: TrainingConfig | None = None, *,
                  progress: bool = True, command: str | None = None) -> TrainingReport:
    """Train the stand-in on procedural pairs, export it to ONNX and write its record.

    Parameters
    ----------
    out : str or os.PathLike
        Output ``.onnx`` path; the record goes next to it with suffix ``.json``.
    config : TrainingConfig, optional
        Defaults to ``TrainingConfig()`` (the bundled default's settings).
    progress : bool
        Show a tqdm progress bar.
    command : str, optional
        The command line to store in the record.

    Returns
    -------
    TrainingReport

    Raises
    ------
    BackboneError
        Invalid settings (unknown size, crop not a multiple of 32, ...).
    """
    # torch (and the network built on it) load only when training runs.
    import torch

    from .network import INPUT_MULTIPLE, STANDIN_SIZES, StandinConfig, build_standin

    config = config or TrainingConfig()
    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise BackboneError(f"out: expected a path ending in .onnx, got {str(out)!r}")
    if isinstance(config.size, StandinConfig):
        arch = config.size
    elif config.size in STANDIN_SIZES:
        arch = STANDIN_SIZES[config.size]
    else:
        raise BackboneError(
            f"size: expected one of {', '.join(STANDIN_SIZES)} or a StandinConfig, "
            f"got {config.size!r}"
        )
    if config.steps < 1 or config.batch_size < 1:
        raise BackboneError(
            f"steps, batch_size: expected integers >= 1, got {config.steps}, {config.batch_size}"
        )
    crop_h, crop_w = config.crop_hw
    if crop_h % INPUT_MULTIPLE or crop_w % INPUT_MULTIPLE:
        raise BackboneError(
            f"crop_hw: expected multiples of {INPUT_MULTIPLE}, got {config.crop_hw}"
        )
    max_train_disp = min(config.max_train_disparity_px, float(arch.max_disparity_px))

    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    net = build_standin(arch)
    if config.init_onnx is not None:
        load_onnx_weights(net, config.init_onnx)
    net.train()
    val_samples = random_stereo_batch(_VALIDATION_SEED, config.validation_pairs,
                                      height=crop_h, width=crop_w,
                                      max_disparity_px=max_train_disp)
    initial = evaluate_standin(net, val_samples)

    optimiser = torch.optim.AdamW(net.parameters(), lr=config.learning_rate, weight_decay=1e-5)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, max_lr=config.learning_rate, total_steps=config.steps, pct_start=0.05,
        anneal_strategy="linear",
    )
    seeds = np.random.SeedSequence(config.seed)
    start = time.perf_counter()
    bar = tqdm(range(config.steps), desc="train-standin", disable=not progress,
               dynamic_ncols=True)
    running = None
    for _ in bar:
        batch_seed = int(seeds.spawn(1)[0].generate_state(1)[0])
        samples = random_stereo_batch(batch_seed, config.batch_size, height=crop_h,
                                      width=crop_w, max_disparity_px=max_train_disp)
        left, right, gt = _to_tensors(samples, "cpu")
        loss = _loss(net.forward_all(left, right), gt, float(arch.max_disparity_px))
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        optimiser.step()
        schedule.step()
        value = float(loss.detach())
        running = value if running is None else 0.95 * running + 0.05 * value
        bar.set_postfix(loss=f"{running:.3f}")
    seconds = time.perf_counter() - start
    final = evaluate_standin(net, val_samples)

    out.parent.mkdir(parents=True, exist_ok=True)
    parity = export_standin_onnx(net, out)
    info_path = out.with_suffix(".json")
    record = {
        "format": "srde-standin/1",
        "model": out.name,
        "preset": "igev",
        "inference": dict(INFERENCE),
        "architecture": asdict(arch),
        "training": {**asdict(config), "crop_hw": list(config.crop_hw),
                     "size": config.size if isinstance(config.size, str) else "custom",
                     "data": "procedural textured planes with occluding layers",
                     "seconds": round(seconds, 1), "command": command},
        "validation": {
            "pairs": config.validation_pairs, "size_hw": [crop_h, crop_w],
            "max_disparity_px": max_train_disp,
            "initial_epe_px": round(initial["epe"], 4),
            "final_epe_px": round(final["epe"], 4),
            "final_bad2": round(final["bad2"], 4),
        },
        "onnx": {"opset": ONNX_OPSET, "inputs": list(ONNX_INPUT_NAMES),
                 "output": ONNX_OUTPUT_NAME, "dynamic_axes": ["batch", "height", "width"],
                 "parity_max_abs_px": float(f"{parity:.3g}")},
        "versions": {"torch": torch.__version__, "python": platform.python_version()},
    }
    info_path.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return TrainingReport(out, info_path, initial["epe"], final["epe"], final["bad2"], parity,
                          seconds, net.eval())
