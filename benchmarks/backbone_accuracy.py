"""Accuracy of the bundled stand-in backbone beside OpenCV's StereoSGBM (``load_backbone("sgbm")``).

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

SGBM is the library's backbone with its documented defaults (``SGBMSpec()``: block 5,
colour, width / 8 disparities rounded up to 16, P1/P2 = 8/32 * 3 * 25, 3-way). It leaves
pixels empty (failed uniqueness or left-right checks); the stand-in fills every pixel.
The stand-in runs as ``load_backbone`` gives it: its left-right check (the mirrored pair
too; pixels the right view contradicts, or that match outside the right image, take the
row's background, the others the mean of both views), then census propagation (a pixel
takes its own best census match over a wider window, where the right view confirms it,
or a neighbour's disparity, where the census matching cost is clearly lower), then
segment planes (a pixel takes its colour segment's robust disparity plane where the
segment is planar, the plane is within 3 px and the census cost does not prefer its own
value). It runs once more without the planes (``stand-in, no planes``), without the
propagation either (``stand-in, no propagation``) and with none of the three
(``network only``) to show what each changes; the shares of pixels the check filled, the
propagation changed and the planes changed are reported. ``EPE both`` is taken over the
pixels where every method gave a value (where SGBM did: the same pixels for every
stand-in row).
All methods are counted the same way, over the pixels with finite ground truth:

* ``EPE filled``: every pixel, each method's holes first filled by the KITTI devkit's
  background interpolation (``fill_holes_background``: a hole takes the smaller of its
  row's nearest valid disparities left and right);
* ``EPE both``: only the pixels where both methods gave a value;
* bad-1, bad-2 and D1: every pixel of the raw maps, a hole counted as wrong;
* ``invalid``: the share of holes.

Times are the median of three runs per pair after one warm-up (the 640x480 time on the
first rendered scene). The targets section checks the stand-in against SGBM on the
full-size Motorcycle pair under every counting above, and its time per 640x480 pair
(<= 1 s) and ONNX size (<= 5 MB).

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
from srde_fusion.adapters import (
    SGBMSpec,
    default_model_info,
    default_weights_path,
    load_backbone,
    propagation,
    segment_planes,
)

from srde_fusion.evaluation import evaluate, fill_holes_background, summarize
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS = Path(__file__).resolve().parent / "results"
KEYS = ("epe_filled", "epe_both", "bad1", "bad2", "d1", "invalid")
METHODS = ("stand-in", "stand-in, no planes", "stand-in, no propagation", "network only",
           "SGBM")
SGBM = SGBMSpec()
TIMING_RUNS = 3
TARGET_SECONDS_640X480 = 1.0
TARGET_ONNX_MB = 5.0


def timed(run, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, float]:
    """Prediction and median seconds of TIMING_RUNS calls after a warm-up call."""
    pred = run(left, right)
    seconds = []
    for _ in range(TIMING_RUNS):
        t0 = time.perf_counter()
        run(left, right)
        seconds.append(time.perf_counter() - t0)
    return pred, float(np.median(seconds))


def score(preds: dict[str, np.ndarray], gt: np.ndarray,
          region: np.ndarray | None = None) -> dict[str, dict]:
    """The KEYS of every method's prediction, counted the same way (see the module text)."""
    valid = np.isfinite(gt) if region is None else np.isfinite(gt) & region
    both = valid & np.logical_and.reduce([np.isfinite(p) for p in preds.values()])
    out = {}
    for method, pred in preds.items():
        raw = evaluate(pred, gt, valid)
        out[method] = {
            "epe_filled": evaluate(fill_holes_background(pred), gt, valid)["epe"],
            "epe_both": evaluate(pred, gt, both)["epe"] if both.any() else np.nan,
            "bad1": raw["bad1"], "bad2": raw["bad2"], "d1": raw["d1"],
            "invalid": float((~np.isfinite(pred[valid])).mean()) if valid.any() else np.nan,
        }
    return out


def fmt(mean_std: tuple[float, float] | float, key: str) -> str:
    mean, std = mean_std if isinstance(mean_std, tuple) else (mean_std, None)
    if key.startswith("epe"):
        text = f"{mean:.2f}" + (f" ± {std:.2f}" if std is not None else "")
    else:
        text = f"{100 * mean:.1f} %" + (f" ± {100 * std:.1f}" if std is not None else "")
    return text


def table(rows: list[tuple[str, str, dict]], first: str) -> str:
    header = f"| {first} | method | " + " | ".join(
        {"epe_filled": "EPE filled (px)", "epe_both": "EPE both (px)", "bad1": "bad-1",
         "bad2": "bad-2", "d1": "D1", "invalid": "invalid"}[k]
        for k in KEYS) + " |"
    lines = [header, "|" + "---|" * (len(KEYS) + 2)]
    for name, method, values in rows:
        lines.append(f"| {name} | {method} | " + " | ".join(fmt(values[k], k) for k in KEYS) + " |")
    return "\n".join(lines) + "\n"


def rendered_scenes(runs: dict, n_scenes: int) -> tuple[list, dict, dict, list, list, list]:
    rig = default_rig()
    pair_rig = rig.subset(list(rig.stereo_pair))
    per = {(region, method): [] for region in ("all", "textured", "glossy")
           for method in METHODS}
    seconds = {method: [] for method in METHODS}
    seconds_640 = {}  # median of TIMING_RUNS on the first scene
    filled = []  # share of pixels the stand-in's left-right check filled, per scene
    changed = []  # ... and its census propagation changed
    planar = []  # ... and its segment planes changed
    for seed in range(n_scenes):
        scene = random_scene(seed, rig, background="textured")
        rendering = render(scene, pair_rig)
        left, right = (rendering.views[i] for i in pair_rig.stereo_pair)
        gt = np.where(rendering.disparity_px > 0, rendering.disparity_px, np.nan)
        regions = {"all": None, "textured": rendering.instance_mask == 0,
                   "glossy": rendering.instance_mask > 0}
        preds = {}
        for method, run in runs.items():
            t0 = time.perf_counter()
            preds[method] = run(left, right)
            seconds[method].append(time.perf_counter() - t0)
            if method == METHODS[0]:
                filled.append(run.last_filled_fraction)
                changed.append(run.last_propagated_fraction)
                planar.append(run.last_planes_fraction)
            if seed == 0:
                _, seconds_640[method] = timed(run, left, right)
        for region, mask in regions.items():
            for method, values in score(preds, gt, mask).items():
                per[(region, method)].append(values)
    rows = [(region, method, summarize(values)) for (region, method), values in per.items()]
    return (rows, {m: float(np.mean(s)) for m, s in seconds.items()}, seconds_640, filled,
            changed, planar)


def motorcycle(runs: dict) -> tuple[list, dict, dict, dict, dict]:
    left, right, gt = skdata.stereo_motorcycle()
    gt = gt.astype(np.float32)
    rows, seconds, filled, changed, planar = [], {}, {}, {}, {}
    for label, factor in (("741x500 (full)", 1), ("370x250 (1/2)", 2)):
        if factor == 1:
            l_img, r_img, g = left, right, gt
        else:
            size = (left.shape[1] // factor, left.shape[0] // factor)
            l_img = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            r_img = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
            # nearest keeps inf (unknown) pixels unknown; disparity scales with width
            g = cv2.resize(gt, size, interpolation=cv2.INTER_NEAREST) / factor
        preds = {}
        for method, run in runs.items():
            preds[method], seconds[f"{method} {label}"] = timed(run, l_img, r_img)
        filled[label] = runs[METHODS[0]].last_filled_fraction
        changed[label] = runs[METHODS[0]].last_propagated_fraction
        planar[label] = runs[METHODS[0]].last_planes_fraction
        rows += [(label, method, values) for method, values in score(preds, g).items()]
    return rows, seconds, filled, changed, planar


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6, help="rendered scenes")
    parser.add_argument("--model", default="default",
                        help="'default' or a stand-in .onnx file (igev preset)")
    args = parser.parse_args()
    runs = dict(zip(METHODS, (
        load_backbone(args.model, "igev", left_right_check=True, census_propagation=True,
                      segment_planes=True),
        load_backbone(args.model, "igev", left_right_check=True, census_propagation=True,
                      segment_planes=False),
        load_backbone(args.model, "igev", left_right_check=True, census_propagation=False,
                      segment_planes=False),
        load_backbone(args.model, "igev", left_right_check=False, census_propagation=False,
                      segment_planes=False),
        load_backbone("sgbm", SGBM)), strict=True))
    (scene_rows, scene_seconds, seconds_640, scene_filled, scene_changed,
     scene_planar) = rendered_scenes(runs, args.scenes)
    moto_rows, moto_seconds, moto_filled, moto_changed, moto_planar = motorcycle(runs)
    full = "741x500 (full)"
    ratio = moto_seconds[f"stand-in {full}"] / moto_seconds[f"SGBM {full}"]
    ratio_640 = seconds_640["stand-in"] / seconds_640["SGBM"]
    model_path = default_weights_path() if args.model == "default" else Path(args.model)
    onnx_mb = model_path.stat().st_size / 1e6
    moto = {m: v for s, m, v in moto_rows if s == full}
    checks = [(f"Motorcycle {full}: {name}", moto["stand-in"][key], moto["SGBM"][key],
               moto["stand-in"][key] < moto["SGBM"][key])
              for key, name in (("epe_filled", "EPE filled (px)"), ("epe_both", "EPE both (px)"),
                                ("bad2", "bad-2"))]
    checks += [("seconds per 640x480 pair", seconds_640["stand-in"], seconds_640["SGBM"],
                seconds_640["stand-in"] <= TARGET_SECONDS_640X480),
               ("ONNX size (MB)", onnx_mb, None, onnx_mb <= TARGET_ONNX_MB)]
    target_lines = ["| check | stand-in | SGBM | target | met |", "|---|---|---|---|---|"]
    for name, mine, theirs, met in checks:
        goal = ("< SGBM" if "Motorcycle" in name else
                f"<= {TARGET_SECONDS_640X480:g} s" if "seconds" in name else
                f"<= {TARGET_ONNX_MB:g} MB")
        theirs_text = "-" if theirs is None else f"{theirs:.3f}"
        target_lines.append(f"| {name} | {mine:.3f} | {theirs_text} | {goal} | "
                            f"{'yes' if met else 'no'} |")

    info = default_model_info() if args.model == "default" else {}
    name = "bundled stand-in" if args.model == "default" else f"`{Path(args.model).name}`"
    training = info.get("training", {})
    stages = [training.get("first_stage", {}).get("steps"),
              training.get("second_stage", {}).get("steps"), training.get("steps")]
    steps = " + ".join(str(n) for n in stages if n is not None) or "?"
    text = (
        "# Stand-in backbone accuracy\n\n"
        f"The {name} (trained {steps} steps on "
        "procedural pairs, igev preset) beside "
        f"OpenCV StereoSGBM as `load_backbone(\"sgbm\")` (block {SGBM.block_size}, "
        f"{'colour' if SGBM.colour else 'luminance'}, width / 8 disparities rounded up to 16, "
        f"{SGBM.mode}). "
        "The stand-in runs as `load_backbone` gives it: its left-right check (the "
        "mirrored pair too; pixels the right view contradicts by more than 1 px, or that "
        "match outside the right image, take the smaller of their row's nearest confirmed "
        "disparities: the output stays dense; the others the mean of both views' "
        "disparities), then census propagation (first each pixel's best census match "
        f"averaged over a {propagation.SEED_WINDOW_PX}x{propagation.SEED_WINDOW_PX} "
        "window, confirmed by the right view's, replaces its value where that cost is "
        f"lower by {propagation.SEED_MARGIN_BITS:g} bits per pixel and at most "
        f"{propagation.SEED_MATCH_BITS:g}; then each pixel is offered its neighbours' "
        f"disparities {', '.join(map(str, propagation.OFFSETS_PX))} px along its row and "
        f"column, {propagation.ITERATIONS} rounds, and takes one whose census cost "
        f"({2 * propagation.CENSUS_RADIUS_PX + 1}x{2 * propagation.CENSUS_RADIUS_PX + 1} "
        f"census, {propagation.WINDOW_PX}x{propagation.WINDOW_PX} window) is lower by "
        f"{propagation.MARGIN_BITS:g} bits per pixel and at most "
        f"{propagation.MATCH_BITS:g}), then segment planes (each pixel takes the robust "
        f"disparity plane of its colour segment, about {segment_planes.SEGMENT_PX} px "
        "across, where at least "
        f"{100 * segment_planes.MIN_INLIER_SHARE:.0f} % of the segment lies within "
        f"{segment_planes.INLIER_PX:g} px of it, the plane is within "
        f"{segment_planes.REPLACE_PX:g} px of the pixel's value and its census cost is at "
        f"most {segment_planes.COST_TOLERANCE_BITS:g} bit per pixel above the value's); "
        "once more without the planes (`stand-in, no planes`), without the propagation "
        "either (`stand-in, no propagation`) and with none of them (`network only`). "
        "All methods are counted the same way over the pixels with ground truth: "
        "`EPE filled` over every pixel after filling each method's holes with the KITTI "
        "devkit's background interpolation (a hole takes the smaller of its row's nearest "
        "valid disparities), `EPE both` over the pixels where every method gave a value "
        "(where SGBM did); "
        "bad-1, bad-2 and D1 over every pixel of the raw maps, a hole counted as wrong. "
        "SGBM leaves holes (`invalid`); the stand-in fills every pixel.\n\n"
        f"## Rendered scenes ({args.scenes} scenes, 640x480, textured background, one glossy "
        "object; mean ± std over scenes)\n\n"
        + table(scene_rows, "region")
        + "\nMean time per pair: "
        + ", ".join(f"{m} {s:.2f} s" for m, s in scene_seconds.items())
        + f". Pixels filled by the left-right check: {100 * np.mean(scene_filled):.1f} % "
        f"(per scene {', '.join(f'{100 * f:.1f}' for f in scene_filled)} %); changed by "
        f"the census propagation: {100 * np.mean(scene_changed):.1f} % (per scene "
        f"{', '.join(f'{100 * f:.1f}' for f in scene_changed)} %); by the segment planes: "
        f"{100 * np.mean(scene_planar):.1f} % (per scene "
        f"{', '.join(f'{100 * f:.1f}' for f in scene_planar)} %)."
        + "\n\n## Middlebury 2014 Motorcycle (scikit-image copy)\n\n"
        + table(moto_rows, "size")
        + "\nTime per pair (median of 3 after a warm-up): "
        + ", ".join(f"{m} {s:.3f} s" for m, s in moto_seconds.items())
        + f"; stand-in / SGBM at full size: {ratio:.1f}x. Pixels filled by the left-right "
        "check: " + ", ".join(f"{s} {100 * f:.1f} %" for s, f in moto_filled.items())
        + "; changed by the census propagation: "
        + ", ".join(f"{s} {100 * f:.1f} %" for s, f in moto_changed.items())
        + "; by the segment planes: "
        + ", ".join(f"{s} {100 * f:.1f} %" for s, f in moto_planar.items()) + "\n"
        + "\n## Targets\n\n"
        + "\n".join(target_lines)
        + f"\n\nTime per 640x480 pair (first rendered scene, median of {TIMING_RUNS} after a "
        f"warm-up): stand-in {seconds_640['stand-in']:.3f} s, SGBM {seconds_640['SGBM']:.3f} s "
        f"({ratio_640:.1f}x).\n"
    )
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "backbone_accuracy.md").write_text(text, encoding="utf-8")
    payload = {
        "scenes": [{"region": r, "method": m, **{k: list(v[k]) for k in KEYS}}
                   for r, m, v in scene_rows],
        "motorcycle": [{"size": s, "method": m, **v} for s, m, v in moto_rows],
        "seconds": {**scene_seconds, **moto_seconds},
        "standin_over_sgbm_time_full": ratio,
        "seconds_640x480": seconds_640,
        "left_right_filled": {"scenes": scene_filled, "motorcycle": moto_filled},
        "propagation_changed": {"scenes": scene_changed, "motorcycle": moto_changed},
        "planes_changed": {"scenes": scene_planar, "motorcycle": moto_planar},
        "standin_over_sgbm_time_640x480": ratio_640,
        "onnx_mb": onnx_mb,
        "targets": [{"check": n, "standin": a, "sgbm": b, "met": bool(m)}
                    for n, a, b, m in checks],
        "sgbm_spec": {f: getattr(SGBM, f) for f in SGBM.__dataclass_fields__},
        "model": info.get("validation"),
        "platform": platform.platform(),
    }
    (RESULTS / "backbone_accuracy.json").write_text(json.dumps(payload, indent=2) + "\n",
                                                    encoding="utf-8")


if __name__ == "__main__":
    main()
