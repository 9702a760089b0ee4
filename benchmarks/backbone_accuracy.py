"""Accuracy of the bundled stand-in backbone beside OpenCV's StereoSGBM.

Two data sets:

* rendered scenes (``srde_fusion.synthetic``, textured background, one glossy planar
  object each) on the paper's rig, stereo pair only, evaluated over the whole image,
  the textured background and the glossy objects separately;
* the Middlebury 2014 "Motorcycle" pair bundled with scikit-image
  (``skimage.data.stereo_motorcycle``: 741 x 500, a quarter of the original resolution).
  Its ground truth is positive disparity with ``x_right = x_left - d`` (checked by
  warping; the docstring's example reads the other way round) and ``inf`` where
  unknown; ``evaluate`` skips non-finite ground truth. It is run at full size and
  downscaled by 2 (ground truth halved with it).

StereoSGBM leaves pixels empty (failed uniqueness or left-right checks); ``evaluate``
leaves them out of EPE and counts them as wrong for bad-2 and D1, and the ``invalid``
column gives their share.

    python benchmarks/backbone_accuracy.py [--scenes 6] [--model default]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import cv2
import numpy as np
from skimage import data as skdata
from srde_fusion.adapters import default_model_info, load_backbone

from srde_fusion.evaluation import evaluate, summarize
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS = Path(__file__).resolve().parent / "results"
KEYS = ("epe", "bad1", "bad2", "d1", "invalid")
SGBM_BLOCK = 5
SGBM_NUM_DISPARITIES = 128  # covers the scenes (25..70 px) and Motorcycle (7..60 px)
SGBM_FIXED_POINT = 16.0  # StereoSGBM returns disparity * 16 as int16


def sgbm(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """OpenCV semi-global block matching, empty pixels as NaN."""
    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=SGBM_NUM_DISPARITIES, blockSize=SGBM_BLOCK,
        P1=8 * 3 * SGBM_BLOCK**2, P2=32 * 3 * SGBM_BLOCK**2, disp12MaxDiff=1,
        uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    raw = matcher.compute(cv2.cvtColor(left, cv2.COLOR_RGB2GRAY),
                          cv2.cvtColor(right, cv2.COLOR_RGB2GRAY))
    disp = raw.astype(np.float32) / SGBM_FIXED_POINT
    disp[raw < 0] = np.nan
    return disp


def score(pred: np.ndarray, gt: np.ndarray, region: np.ndarray | None = None) -> dict:
    result = evaluate(pred, gt, region)
    valid = np.isfinite(gt) if region is None else np.isfinite(gt) & region
    result["invalid"] = float((~np.isfinite(pred[valid])).mean()) if valid.any() else np.nan
    return {k: result[k] for k in KEYS}


def fmt(mean_std: tuple[float, float] | float, key: str) -> str:
    mean, std = mean_std if isinstance(mean_std, tuple) else (mean_std, None)
    if key == "epe":
        text = f"{mean:.2f}" + (f" ± {std:.2f}" if std is not None else "")
    else:
        text = f"{100 * mean:.1f} %" + (f" ± {100 * std:.1f}" if std is not None else "")
    return text


def table(rows: list[tuple[str, str, dict]], first: str) -> str:
    header = f"| {first} | method | " + " | ".join(
        {"epe": "EPE (px)", "bad1": "bad-1", "bad2": "bad-2", "d1": "D1", "invalid": "invalid"}[k]
        for k in KEYS) + " |"
    lines = [header, "|" + "---|" * (len(KEYS) + 2)]
    for name, method, values in rows:
        lines.append(f"| {name} | {method} | " + " | ".join(fmt(values[k], k) for k in KEYS) + " |")
    return "\n".join(lines) + "\n"


def rendered_scenes(backbone, n_scenes: int) -> tuple[list, dict]:
    rig = default_rig()
    pair_rig = rig.subset(list(rig.stereo_pair))
    per = {(region, method): [] for region in ("all", "textured", "glossy")
           for method in ("stand-in", "SGBM")}
    seconds = {"stand-in": [], "SGBM": []}
    for seed in range(n_scenes):
        scene = random_scene(seed, rig, background="textured")
        rendering = render(scene, pair_rig)
        left, right = (rendering.views[i] for i in pair_rig.stereo_pair)
        gt = np.where(rendering.disparity_px > 0, rendering.disparity_px, np.nan)
        regions = {"all": None, "textured": rendering.instance_mask == 0,
                   "glossy": rendering.instance_mask > 0}
        for method, run in (("stand-in", backbone), ("SGBM", sgbm)):
            t0 = time.perf_counter()
            pred = run(left, right)
            seconds[method].append(time.perf_counter() - t0)
            for region, mask in regions.items():
                per[(region, method)].append(score(pred, gt, mask))
    rows = [(region, method, summarize(values)) for (region, method), values in per.items()]
    return rows, {m: float(np.mean(s)) for m, s in seconds.items()}


def motorcycle(backbone) -> tuple[list, dict]:
    left, right, gt = skdata.stereo_motorcycle()
    gt = gt.astype(np.float32)
    rows, seconds = [], {}
    for label, factor in (("741x500 (full)", 1), ("370x250 (1/2)", 2)):
        if factor == 1:
            l_img, r_img, g = left, right, gt
        else:
            size = (left.shape[1] // factor, left.shape[0] // factor)
            l_img = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            r_img = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
            # nearest keeps inf (unknown) pixels unknown; disparity scales with width
            g = cv2.resize(gt, size, interpolation=cv2.INTER_NEAREST) / factor
        for method, run in (("stand-in", backbone), ("SGBM", sgbm)):
            t0 = time.perf_counter()
            pred = run(l_img, r_img)
            seconds[f"{method} {label}"] = time.perf_counter() - t0
            rows.append((label, method, score(pred, g)))
    return rows, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6, help="rendered scenes")
    parser.add_argument("--model", default="default",
                        help="'default' or a stand-in .onnx file (igev preset)")
    args = parser.parse_args()
    backbone = load_backbone(args.model, "igev")
    scene_rows, scene_seconds = rendered_scenes(backbone, args.scenes)
    moto_rows, moto_seconds = motorcycle(backbone)

    info = default_model_info() if args.model == "default" else {}
    name = "bundled stand-in" if args.model == "default" else f"`{Path(args.model).name}`"
    text = (
        "# Stand-in backbone accuracy\n\n"
        f"The {name} (trained {info.get('training', {}).get('steps', '?')} steps on "
        "procedural pairs, igev preset) beside "
        f"OpenCV StereoSGBM (block {SGBM_BLOCK}, {SGBM_NUM_DISPARITIES} disparities, 3-way). "
        "SGBM's EPE covers only the pixels it filled (see `invalid`); bad-1, bad-2 and D1 "
        "count its empty pixels as wrong. The stand-in fills every pixel.\n\n"
        f"## Rendered scenes ({args.scenes} scenes, 640x480, textured background, one glossy "
        "object; mean ± std over scenes)\n\n"
        + table(scene_rows, "region")
        + "\nMean time per pair: "
        + ", ".join(f"{m} {s:.2f} s" for m, s in scene_seconds.items())
        + "\n\n## Middlebury 2014 Motorcycle (scikit-image copy)\n\n"
        + table(moto_rows, "size")
        + "\nTime: " + ", ".join(f"{m} {s:.2f} s" for m, s in moto_seconds.items()) + "\n"
    )
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "backbone_accuracy.md").write_text(text, encoding="utf-8")
    payload = {
        "scenes": [{"region": r, "method": m, **{k: list(v[k]) for k in KEYS}}
                   for r, m, v in scene_rows],
        "motorcycle": [{"size": s, "method": m, **v} for s, m, v in moto_rows],
        "seconds": {**scene_seconds, **moto_seconds},
        "model": info.get("validation"),
        "platform": platform.platform(),
    }
    (RESULTS / "backbone_accuracy.json").write_text(json.dumps(payload, indent=2) + "\n",
                                                    encoding="utf-8")


if __name__ == "__main__":
    main()
