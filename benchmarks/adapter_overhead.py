"""Adapter overhead: ``OnnxStereo(left, right)`` against the bare onnxruntime call.

The bundled stand-in at 640 x 480 (a multiple of 32: no padding) and at 620 x 470
(padded to 640 x 480 and cropped back). The bare call feeds ready-made float32 NCHW
tensors of the padded size to the same session; the adapter call starts from uint8
RGB images and returns the cropped float32 disparity, so the difference is the whole
pre/post-processing (checks, conversion, padding, layout, output selection, crop).
Calls alternate between the two so that load from other processes hits both alike. The
stand-in runs without its left-right check here (that check runs the model a second
time, on the mirrored pair; see ``backbone_accuracy.py`` for its cost).

    python benchmarks/adapter_overhead.py [--repeats 10]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
from srde_fusion.adapters import load_backbone
from srde_fusion.adapters._pipeline import check_pair, finish_disparity, prepare_pair

RESULTS = Path(__file__).resolve().parent / "results"
SIZES_WH = ((640, 480), (620, 470))
TARGET_OVERHEAD = 0.05


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    # one model run per call: the left-right check's second run is the model's time, not
    # the adapter's
    backbone = load_backbone("default", left_right_check=False)
    session, names = backbone.session, backbone.input_names
    rng = np.random.default_rng(0)
    rows = []
    for width, height in SIZES_WH:
        left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        right = np.roll(left, -8, axis=1)
        left01, right01 = check_pair(left, right)
        left_in, right_in, geometry = prepare_pair(left01, right01, backbone.spec, None)
        feed = {names[0]: left_in, names[1]: right_in}
        backbone(left, right)  # warm-up
        bare, full, pre, post = [], [], [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            raw = session.run([backbone.output_name], feed)[0]
            bare.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            backbone(left, right)
            full.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            prepare_pair(*check_pair(left, right), backbone.spec, None)
            pre.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            finish_disparity(raw, backbone.spec, geometry)
            post.append(time.perf_counter() - t0)
        bare_ms, full_ms = 1e3 * np.median(bare), 1e3 * np.median(full)
        rows.append({
            "size": f"{width}x{height}",
            "padded": f"{geometry.padded_hw[1]}x{geometry.padded_hw[0]}",
            "bare_ms": float(bare_ms), "bare_std_ms": float(1e3 * np.std(bare)),
            "adapter_ms": float(full_ms), "adapter_std_ms": float(1e3 * np.std(full)),
            "pre_ms": float(1e3 * np.median(pre)), "post_ms": float(1e3 * np.median(post)),
            # pre + post measured on their own: free of the model's run-to-run noise
            "overhead": float((np.median(pre) + np.median(post)) / np.median(bare)),
            "ratio": float(full_ms / bare_ms),
        })

    lines = [
        "# Adapter overhead (bundled stand-in, onnxruntime CPU)\n",
        f"Median of {args.repeats} calls; overhead = (pre + post) / bare; target "
        f"<= {TARGET_OVERHEAD:.0%}.\n",
        "| image | model input | bare ORT (ms) | adapter (ms) | pre (ms) | post (ms) "
        "| overhead | adapter / bare |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['size']} | {r['padded']} | {r['bare_ms']:.0f} ± {r['bare_std_ms']:.0f} | "
            f"{r['adapter_ms']:.0f} ± {r['adapter_std_ms']:.0f} | {r['pre_ms']:.1f} | "
            f"{r['post_ms']:.1f} | {r['overhead']:.1%} | {r['ratio']:.3f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "adapter_overhead.md").write_text(text, encoding="utf-8")
    (RESULTS / "adapter_overhead.json").write_text(
        json.dumps({"rows": rows, "repeats": args.repeats, "platform": platform.platform()},
                   indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
