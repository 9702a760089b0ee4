"""Accuracy and speed of the photometric plane refinement on rendered scenes.

SRDE's geometric plane comes from highlight centroids, which rough lobes bias (irradiance
falloff, foreshortening, clipping). ``srde_fusion.srde.refine.plane.refine_plane`` fits a lobe model
to the highlights of all views to remove that bias. This benchmark measures it against
the geometric plane and against another way to de-bias the centres, on scenes rendered
by ``srde_fusion.synthetic`` under the paper's conditions:

* rigs: the paper's 3 x 3 array and a two-camera stereo rig (85 mm baselines,
  640 x 480 px, fx = 600 px);
* lobes rendered: GGX and Blinn-Phong (the renderer's conventions: Cook-Torrance for
  GGX, a Phong-style BRDF without ``1 / (4 cos cos)`` for Blinn-Phong), spherical lights
  of 2-10 mm radius (which widen the lobe), clipped highlights, sensor noise;
* roughness bins: alpha < 0.03, 0.03-0.055, 0.055-0.08.

Methods: ``none`` (SRDE's default plane, the refinement's input); ``per-view Gaussian
centre`` (SRDE with ``blob_center="lobe"``: each view's centre from a Gaussian fit to its
lobe, another way to de-bias); and ``refine_plane`` with three lobe models: ``gtr`` (the
default: free tail and foreshortening exponent, a model other than either rendered
one), ``ggx, k=0`` and ``blinn_phong, k=1`` (fixed shapes and conventions: matched to one
rendered lobe, mismatched to the other). Metrics: masked EPE and bmp0.1 (paper), mean ±
std over scenes; the refinement's plane is evaluated whether it was refined or kept.

Run: ``python benchmarks/refinement_accuracy.py [--scenes 8]``; writes
``benchmarks/results/refinement_accuracy.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from srde_fusion.evaluation import evaluate
from srde_fusion.geometry import CameraRig, plane_disparity
from srde_fusion.srde import SRDE, refine_plane
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "refinement_accuracy"

RENDER_LOBES = ("ggx", "blinn_phong")
#: (low, high, label): roughness drawn uniformly in [low, high).
BINS = ((0.005, 0.03, "a < 0.03"), (0.03, 0.055, "0.03-0.055"), (0.055, 0.08, "0.055-0.08"))
#: Keyword arguments of refine_plane per method.
REFINE_METHODS = {
    "refine: gtr (default)": {},
    "refine: ggx, k=0": {"lobe": "ggx", "foreshortening": 0.0},
    "refine: blinn_phong, k=1": {"lobe": "blinn_phong", "foreshortening": 1.0},
}
NONE = "none (SRDE default plane)"
GAUSSIAN = "per-view Gaussian centre"
METHODS = (NONE, GAUSSIAN, *REFINE_METHODS)
#: Which rendered lobe each fixed-lobe method matches.
MATCHES = {"refine: ggx, k=0": "ggx", "refine: blinn_phong, k=1": "blinn_phong"}
TARGET_EPE_PX = {"3x3": 0.01, "2-camera": 0.03}
TARGET_MS = 20.0
REPEATS = 3
STEREO_BASELINE_M = 0.085


def rigs() -> dict[str, CameraRig]:
    return {"3x3": default_rig(),
            "2-camera": CameraRig.stereo(STEREO_BASELINE_M, fx=600.0, image_size=(640, 480))}


def run_scene(rig: CameraRig, seed: int, lobe: str, roughness: tuple[float, float]) -> dict:
    """Render one scene; evaluate every method. Plain numbers only."""
    scene = random_scene(seed, rig, lobe=lobe, roughness=roughness)
    out = render(scene, rig)
    mask = out.object_masks[0]
    lit = rig.with_light(scene.light.position_m)
    record = {"seed": seed, "lobe": lobe, "roughness": scene.objects[0].material.roughness,
              "light_radius_m": scene.light.radius_m, "mask_px": int(mask.sum()), "runs": {}}
    base = SRDE(lit, refine=False).estimate(out.views, mask)
    record["srde_status"] = base.status
    if not base.ok:
        return record

    def metrics(plane) -> dict:
        disparity = np.full(mask.shape, np.nan, dtype=np.float32)
        disparity[mask] = plane_disparity(plane, lit)[mask]
        m = evaluate(disparity, out.disparity_px, mask)
        return {"epe": float(m["epe"]), "bmp0.1": float(m["bmp0.1"])}

    record["runs"][NONE] = metrics(base.plane)
    centers = np.where(base.used_views[:, None], base.highlight_centers, np.nan)
    for name, options in REFINE_METHODS.items():
        walls, cpus = [], []
        for _ in range(REPEATS):  # best of three, as the paper times its runs
            wall, cpu = time.perf_counter(), time.process_time()
            result = refine_plane(out.views, lit, lit.light, mask, base.plane,
                                  centers_uv=centers, **options)
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
        run = metrics(result.plane)
        run.update(time_ms=1000 * min(walls), cpu_ms=1000 * min(cpus),
                   first_call_ms=1000 * walls[0], status=result.status,
                   reason=result.reason, iterations=result.iterations,
                   n_samples=result.n_samples, residual=result.residual)
        if result.params is not None:
            run["params"] = {k: float(v) for k, v in vars(result.params).items()}
        record["runs"][name] = run
    # After the timed runs: the refinement follows SRDE's default estimate, as in SRDE's
    # default mode, and not the Gaussian fits' least squares, whose BLAS worker threads
    # keep spinning for a while after the call.
    gaussian = SRDE(lit, blob_center="lobe", refine=False).estimate(out.views, mask)
    if gaussian.ok:
        record["runs"][GAUSSIAN] = metrics(gaussian.plane)
    return record


def relation(method: str, lobe: str) -> str:
    if method in MATCHES:
        return "matched" if MATCHES[method] == lobe else "mismatched"
    return "other model" if method.startswith("refine") else "-"


def cell(records: list[dict], method: str, key: str) -> tuple[float, float, int]:
    values = [r["runs"][method][key] for r in records if method in r["runs"]]
    if not values:
        return float("nan"), float("nan"), 0
    return float(np.mean(values)), float(np.std(values)), len(values)


def accuracy_table(records: list[dict]) -> tuple[str, dict]:
    """Markdown table (method x rendered lobe rows, bins as columns) and its numbers."""
    header = ["method", "rendered", "relation"]
    for _, _, label in BINS:
        header += [f"EPE {label}", f"bmp0.1 {label}"]
    header += ["kept", "n"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * 3 + "---:|" * (len(header) - 3)]
    numbers: dict = {}
    for method in METHODS:
        for lobe in RENDER_LOBES:
            row = [method, lobe, relation(method, lobe)]
            kept = n = 0
            for low, high, label in BINS:
                chosen = [r for r in records if r["lobe"] == lobe and low <= r["roughness"] < high]
                epe_m, epe_s, count = cell(chosen, method, "epe")
                bmp_m, _, _ = cell(chosen, method, "bmp0.1")
                n += count
                kept += sum(r["runs"][method].get("status") == "kept_initial"
                            for r in chosen if method in r["runs"])
                row += [f"{epe_m:.4f} ± {epe_s:.4f}", f"{bmp_m:.3f}"]
                numbers.setdefault(method, {}).setdefault(lobe, {})[label] = {
                    "epe": [epe_m, epe_s], "bmp0.1": bmp_m, "n": count}
            row += [str(kept) if method in REFINE_METHODS else "-", str(n)]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n", numbers


def timing(records: list[dict], method: str) -> dict:
    wall = [r["runs"][method]["time_ms"] for r in records if method in r["runs"]]
    cpu = [r["runs"][method]["cpu_ms"] for r in records if method in r["runs"]]
    if not wall:
        return {}
    first = [r["runs"][method]["first_call_ms"] for r in records if method in r["runs"]]
    return {"median_ms": float(np.median(wall)), "p90_ms": float(np.percentile(wall, 90)),
            "median_cpu_ms": float(np.median(cpu)), "median_first_call_ms": float(np.median(first)),
            "n": len(wall)}


def worse_lines(records: list[dict]) -> list[str]:
    """Per refinement method: scenes whose refined plane is worse than the initial one."""
    out = []
    for method in REFINE_METHODS:
        pairs = [(r["runs"][NONE]["epe"], r["runs"][method]["epe"]) for r in records
                 if method in r["runs"]]
        worse = [after - before for before, after in pairs if after > before]
        worst = f", by up to {max(worse):.4f} px" if worse else ""
        out.append(f"- {method}: worse than the initial plane on {len(worse)} of {len(pairs)} "
                   f"scenes{worst}; largest EPE {max(a for _, a in pairs):.4f} px")
    return out


def target_lines(numbers: dict, rig_name: str) -> list[str]:
    """The brief's targets: the default lobe model (other than either rendered one)."""
    target = TARGET_EPE_PX[rig_name]
    out = []
    for lobe in RENDER_LOBES:
        bins = numbers["refine: gtr (default)"][lobe]
        worst = max(v["epe"][0] for v in bins.values())
        verdict = "met" if worst <= target else "NOT met"
        out.append(f"- {rig_name}, rendered {lobe}, fitted gtr: worst bin mean EPE "
                   f"{worst:.4f} px (target <= {target} px): {verdict}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8,
                        help="scenes per (rig, rendered lobe, roughness bin)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    load_before = os.getloadavg()[0]
    results: dict[str, list[dict]] = {}
    for rig_name, rig in rigs().items():
        records = results[rig_name] = []
        for b, (low, high, _) in enumerate(BINS):
            for lobe in RENDER_LOBES:
                for i in range(args.scenes):
                    records.append(run_scene(rig, 1000 * b + i, lobe, (low, high)))
    total_s = time.perf_counter() - start
    load_after = os.getloadavg()[0]

    n = args.scenes
    lines = [
        "# Photometric plane refinement on rendered scenes",
        "",
        f"{n} scenes per rig, rendered lobe and roughness bin (`random_scene(seed, lobe=..., "
        "roughness=bin)`, seeds 1000 b + i; the same seeds for both lobes). One flat glossy "
        "object at 0.6-1.4 m, tilted up to 30 deg, light radius 2-10 mm, highlight core "
        "1.5-4x the clipping level, sensor noise 0.002. Masked EPE (px, mean ± std over "
        "scenes) and bmp0.1 (mean); `kept`: scenes where the refinement kept the initial "
        "plane; scenes where SRDE itself failed are left out.",
        "",
    ]
    summary: dict = {}
    for rig_name, records in results.items():
        table, numbers = accuracy_table(records)
        failed = sum(r["srde_status"] != "ok" for r in records)
        times = {m: timing(records, m) for m in REFINE_METHODS}
        summary[rig_name] = {"accuracy": numbers, "timing": times, "srde_failed": failed}
        views = rigs()[rig_name].n_cameras
        lines += [f"## {rig_name} rig ({views} views)", "", table,
                  f"SRDE failed on {failed} of {len(records)} scenes.", "",
                  *target_lines(numbers, rig_name), "", *worse_lines(records), "",
                  "Refinement time per frame, best of three calls right after SRDE's default "
                  "estimate (median and p90 over frames, wall; median CPU; median of the first "
                  "call alone), ms:", ""]
        for method, t in times.items():
            if t:
                lines.append(f"- {method}: {t['median_ms']:.1f} / {t['p90_ms']:.1f} wall, "
                             f"{t['median_cpu_ms']:.1f} CPU, first call "
                             f"{t['median_first_call_ms']:.1f} (n = {t['n']})")
        lines.append("")
    t9 = summary["3x3"]["timing"]["refine: gtr (default)"]
    lines += [
        "## Time target",
        "",
        f"- 9 views, 640 x 480, default lobe, best of three: median {t9['median_ms']:.1f} ms "
        f"wall, {t9['median_cpu_ms']:.1f} ms CPU (target <= {TARGET_MS:g} ms): "
        + ("met" if t9["median_ms"] <= TARGET_MS else "NOT met on this run"),
        f"- machine: {os.cpu_count()} CPU(s), {platform.machine()}, Python "
        f"{platform.python_version()}; 1-min load average {load_before:.1f} before, "
        f"{load_after:.1f} after (shared machine: wall times include waiting for a core).",
        "",
        "## Reading the tables",
        "",
        "- The geometric plane's error grows with roughness: centroids drift towards the "
        "part of the lobe nearest the light, the same way in every view.",
        "- A per-view Gaussian fit of the lobe (`blob_center=\"lobe\"`) is a local cure; it "
        "cannot know the falloff, so its centres stay biased.",
        "- Fitting a fixed lobe of the wrong shape or foreshortening convention leaves an "
        "error of its own: the misfit's asymmetry moves the plane (mismatched rows), at "
        "times beyond the initial error; the guard rails catch only the grossest misfits.",
        "- `gtr` fits the lobe's tail and the foreshortening exponent as well; it recovers "
        "GGX (tail 1/2, k = 0) and the renderer's Blinn-Phong (tail ~0, k = 1) alike, which "
        "is why it is the default.",
        "",
        f"Total run time {total_s:.0f} s.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{NAME}.md").write_text(text)
    payload = {"scenes_per_cell": n, "summary": summary, "records": results,
               "load_average": [load_before, load_after], "total_s": total_s}
    (args.out / f"{NAME}.json").write_text(json.dumps(payload, indent=1, default=_json))
    return 0


def _json(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value).__name__)


if __name__ == "__main__":
    raise SystemExit(main())
