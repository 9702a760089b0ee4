"""Accuracy of SRDE on rendered scenes: the paper's method against the default one.

A fixed set of scenes under the paper's conditions (3 x 3 array, 85 mm baselines,
640 x 480 px, fx = 600 px; one flat glossy object, one small light of varied size;
varied roughness, tilt and distance; sensor noise; clipped highlights) is rendered with
``srde_fusion.synthetic``, and every configuration estimates the object's disparity from
the views and its mask. Metrics are the paper's (masked EPE, RMSE, bmp0.1/0.01/0.001) as
mean ± std over the scenes a configuration succeeded on; ``ok`` counts those scenes.

Also measured: the same on a two-camera stereo rig, the error of each highlight detector
against the projected virtual light (the comparison that chose the default blob
centre), the error's spread across the views of one scene (what moves the triangulated
depth), and the time per estimate.

Run: ``python benchmarks/srde_accuracy.py [--scenes 60]``; writes
``benchmarks/results/srde_accuracy.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from srde_fusion.evaluation import PAPER_KEYS, evaluate, format_markdown_table, summarize
from srde_fusion.geometry import CameraRig
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "srde_accuracy"

#: Configurations on the 3 x 3 array: name -> SRDE keyword arguments.
GEOMETRIC = "default, geometric only (refine=False)"
CONFIGS = {
    "paper": {"method": "paper"},
    "default": {},
    GEOMETRIC: {"refine": False},
    "ring centre + joint LS": {"detector": "paper", "refine": False},
    "blob centre + pair median": {"method": "paper", "detector": "blob"},
    "default, blob_center=core": {"blob_center": "core", "refine": False},
    "default, blob_center=lobe": {"blob_center": "lobe", "refine": False},
}
#: Which configuration's centres stand for each detector in the centre-error table.
DETECTORS = {
    "paper ring centroid": "paper",
    "blob, weighted (default)": "default",
    "blob, saturated core": "default, blob_center=core",
    "blob, Gaussian lobe fit": "default, blob_center=lobe",
}
STEREO_CONFIGS = {
    "default": {},
    GEOMETRIC: {"refine": False},
    "paper (one pair)": {"method": "paper"},
}
#: Roughness bins for the breakdown: (low, high, label).
ROUGHNESS_BINS = ((0.0, 0.01, "sharp, r < 0.01"), (0.01, 0.02, "mid, 0.01 <= r < 0.02"),
                  (0.02, 1.0, "rough, r >= 0.02"))
STEREO_BASELINE_M = 0.085
#: The refinement fits its own lobe family; scenes are rendered with both of the
#: renderer's lobes so that the fitted model is never exactly the rendered one.
LOBES = ("ggx", "blinn_phong")


def run_scene(rig: CameraRig, seed: int, configs: dict, lobe: str = "ggx") -> dict:
    """Render one scene and run every configuration; return plain numbers."""
    scene = random_scene(seed, rig, lobe=lobe)
    out = render(scene, rig)
    mask = out.object_masks[0]
    lit = rig.with_light(scene.light.position_m)
    truth_uv = out.highlight_uv[0]
    record = {"seed": seed, "roughness": scene.objects[0].material.roughness,
              "light_radius_m": scene.light.radius_m, "mask_px": int(mask.sum()),
              "runs": {}}
    for name, options in configs.items():
        srde = SRDE(lit, **options)
        start = time.perf_counter()
        result = srde.estimate(out.views, mask)
        elapsed = time.perf_counter() - start
        error_uv = result.highlight_centers - truth_uv
        run = {"status": result.status, "reason": result.reason, "time_s": elapsed,
               "center_error_uv": error_uv.tolist(), "used_views": result.used_views.tolist()}
        if result.ok:
            metrics = evaluate(result.disparity, out.disparity_px, mask)
            run["metrics"] = {k: float(metrics[k]) for k in PAPER_KEYS}
        if result.refinement is not None:
            run["refine_status"] = result.refinement.status
        record["runs"][name] = run
    record["lobe"] = lobe
    return record


def metric_rows(records: list[dict], names, *, subset=None) -> dict:
    """name -> {ok, metric: (mean, std)} over the records where the run succeeded."""
    rows = {}
    for name in names:
        chosen = [r for r in records if subset is None or subset(r)]
        good = [r["runs"][name]["metrics"] for r in chosen if "metrics" in r["runs"][name]]
        row = {"ok": len(good), "of": len(chosen)}
        summary = summarize(good) if good else {k: (float("nan"), float("nan")) for k in PAPER_KEYS}
        row.update(summary)
        rows[name] = row
    return rows


def center_rows(records: list[dict]) -> dict:
    """Highlight-centre error per detector, pooled over views and scenes."""
    rows = {}
    for label, config in DETECTORS.items():
        errors, spreads, found, total = [], [], 0, 0
        for r in records:
            err = np.array(r["runs"][config]["center_error_uv"], dtype=np.float64)
            ok = np.all(np.isfinite(err), axis=1)
            total += len(err)
            found += int(ok.sum())
            if ok.any():
                errors.extend(np.linalg.norm(err[ok], axis=1))
            if ok.sum() >= 2:
                # What triangulation sees: the error's deviation from its mean over views.
                spreads.append(float(np.sqrt(np.mean(np.sum((err[ok] - err[ok].mean(0)) ** 2,
                                                            axis=1)))))
        errors = np.array(errors)
        rows[label] = {
            "found": found / total if total else float("nan"),
            "median_px": float(np.median(errors)) if errors.size else float("nan"),
            "mean_px": float(np.mean(errors)) if errors.size else float("nan"),
            "p90_px": float(np.percentile(errors, 90)) if errors.size else float("nan"),
            "spread_px": float(np.median(spreads)) if spreads else float("nan"),
        }
    return rows


def timing_rows(records: list[dict], names) -> dict:
    return {name: {"median_ms": 1000 * float(np.median([r["runs"][name]["time_s"]
                                                       for r in records]))} for name in names}


def table_with_counts(rows: dict) -> str:
    """The paper's columns plus ``ok`` (scenes the configuration succeeded on)."""
    return format_markdown_table(rows, ["ok", "of", *PAPER_KEYS], digits=4)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=60, help="number of scenes (seeds 0..N-1)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    array = default_rig()
    stereo = CameraRig.stereo(STEREO_BASELINE_M, fx=600.0, image_size=(640, 480))
    # Even seeds render a GGX lobe, odd seeds a Blinn-Phong lobe.
    records = [run_scene(array, seed, CONFIGS, LOBES[seed % 2]) for seed in range(args.scenes)]
    stereo_records = [run_scene(stereo, seed, STEREO_CONFIGS, LOBES[seed % 2])
                      for seed in range(args.scenes)]
    total_s = time.perf_counter() - start

    both = lambda r: all("metrics" in r["runs"][n] for n in ("paper", "default"))  # noqa: E731
    names = list(CONFIGS)
    main_rows = metric_rows(records, names)
    common_rows = metric_rows(records, ("paper", "default"), subset=both)
    bins = {}
    for low, high, label in ROUGHNESS_BINS:
        in_bin = lambda r, lo=low, hi=high: lo <= r["roughness"] < hi  # noqa: E731
        for name in ("paper", GEOMETRIC, "default"):
            bins[f"{name}, {label}"] = metric_rows(records, [name], subset=in_bin)[name]
    for lobe in LOBES:
        of_lobe = lambda r, lb=lobe: r["lobe"] == lb  # noqa: E731
        for name in (GEOMETRIC, "default"):
            bins[f"{name}, rendered {lobe}"] = metric_rows(records, [name], subset=of_lobe)[name]
    stereo_rows = metric_rows(stereo_records, STEREO_CONFIGS)
    centers = center_rows(records)
    timing = timing_rows(records, names)

    failures: dict[str, dict[str, int]] = {}
    for r in records + stereo_records:
        for name, run in r["runs"].items():
            if run["status"] != "ok":
                kind = f"{run['status']} ({_reason_kind(run['reason'])})"
                failures.setdefault(name, {}).setdefault(kind, 0)
                failures[name][kind] += 1

    n = args.scenes
    lines = [
        "# SRDE accuracy on rendered scenes",
        "",
        f"{n} scenes (`random_scene(seed)`, seeds 0-{n - 1}): 3 x 3 array, 85 mm baselines, "
        "640 x 480 px, fx = 600 px; one flat glossy object at 0.6-1.4 m, tilted up to 30 deg; "
        "roughness 0.005-0.03 (even seeds GGX, odd seeds Blinn-Phong), light radius "
        "2-10 mm, clipped highlights, sensor noise. "
        "Metrics inside the object mask, mean ± std over the scenes a configuration "
        "succeeded on (`ok` of `of`). The paper reports EPE 0.0290 ± 0.020, bmp0.1 "
        "0.0852 ± 0.049, bmp0.01 0.1168, bmp0.001 0.1190, RMSE 0.0954 on its own data.",
        "",
        "## 3 x 3 array, all scenes",
        "",
        table_with_counts(main_rows),
        "`paper`: edge-ring centroid, V per neighbouring pair, pixel-wise median of the pair "
        "maps. `default`: intensity-weighted blob centroid on linear intensity at one level "
        "for all views, joint least-squares triangulation, outlier views dropped, then the "
        "plane refined photometrically (`srde_fusion.srde.refine.plane`: a lobe family with free "
        "width, tail and falloff fitted to the highlights of all views; GGX is one member "
        "of that family, so the Blinn-Phong scenes are the mismatched case). "
        f"`{GEOMETRIC}`: the same without the refinement. The "
        "ablation rows swap one part of the geometric pipeline each.",
        "",
        "## Head to head, scenes where both succeed",
        "",
        table_with_counts(common_rows),
        "## By roughness",
        "",
        table_with_counts(bins),
        "Centroids of a rough lobe are biased: irradiance falloff and foreshortening make the "
        "lobe asymmetric, and the bias changes smoothly from camera to camera, which "
        "triangulation reads as a change of depth. The photometric refinement "
        "(`srde_fusion.srde.refine.plane`) models the lobe to remove it.",
        "",
        f"## Stereo rig (2 cameras, {STEREO_BASELINE_M * 1000:.0f} mm baseline)",
        "",
        table_with_counts(stereo_rows),
        "`paper (one pair)`: the paper's ring detector and its per-pair solve, which on a "
        "stereo rig is a single pair (no median).",
        "",
        "## Highlight centre error against the projected virtual light (3 x 3)",
        "",
        format_markdown_table(centers, ["found", "median_px", "mean_px", "p90_px", "spread_px"],
                              digits=3, name_header="detector"),
        "`found`: fraction of views with a detection. `spread_px`: per scene, the RMS of the "
        "error's deviation from its mean over the views (a common offset hardly moves the "
        "plane; a varying one moves the depth), median over scenes.",
        "",
        "## Time per estimate (3 x 3, median)",
        "",
        format_markdown_table(timing, ["median_ms"], digits=1),
        "## Failures",
        "",
        "\n".join(f"- {name}: " + ", ".join(f"{k} x{v}" for k, v in sorted(counts.items()))
                  for name, counts in failures.items()) or "none",
        "",
        f"Total run time {total_s:.0f} s on {platform.machine()} ({platform.python_version()}).",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{NAME}.md").write_text(text)
    payload = {"scenes": n, "array": main_rows, "common": common_rows, "by_roughness": bins,
               "stereo": stereo_rows, "centers": centers, "timing": timing,
               "failures": failures, "per_scene": [_compact(r) for r in records],
               "per_scene_stereo": [_compact(r) for r in stereo_records]}
    (args.out / f"{NAME}.json").write_text(json.dumps(_plain(payload), allow_nan=False))
    return 0


def _reason_kind(reason: str) -> str:
    """The words of a failure reason after its view label, up to the first number."""
    text = reason.split("): ", 1)[-1]
    for i, ch in enumerate(text):
        if ch.isdigit():
            return text[:i].rstrip(" (,:=>+") or text
    return text


def _compact(record: dict) -> dict:
    """One scene for the JSON file: its parameters and each run's status and EPE."""
    return {"seed": record["seed"], "roughness": round(record["roughness"], 5),
            "light_radius_m": round(record["light_radius_m"], 5),
            "status": {name: run["status"] for name, run in record["runs"].items()},
            "epe": {name: float(f"{run['metrics']['epe']:.4g}") if "metrics" in run else None
                    for name, run in record["runs"].items()}}


def _plain(value):
    """JSON-safe copy: tuples to lists, numpy to Python, NaN to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return None if np.isnan(value) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


if __name__ == "__main__":
    raise SystemExit(main())
