"""SRDE with several known lights: assignments, objects solved, accuracy and time against k.

Scenes: one flat glossy object before the paper's 3 x 3 array (640 x 480 px, fx 600 px),
lit by k = 1-4 lights (the first one's highlight on the object in every view, the others
placed around it), rendered with ``Physics.faithful()`` (exact Fresnel, sampled sphere
lights, Smith masking, diffuse transmittance, photon and read noise, 2 x 2 samples per
pixel). Every scene is estimated three ways:

* ``all lights``: ``SRDE`` with a rig that knows every light: highlights matched to
  lights by geometry, one plane fitted to all of them (``SRDEResult.lights``);
* ``first light only``: ``SRDE`` told only of the first light, as before this existed:
  it takes the brightest blob, which may belong to another light;
* ``best single light``: ``SRDE`` told of one light at a time, the lowest EPE among
  them -- an oracle that knows which answer is right, the bar for "no worse".

An assignment is wrong when an ``ok`` result gives a light a candidate that is not the
blob nearest to that light's true highlight, or a highlight the renderer says is not on
the object (failed results use no assignment). A plane is wrong when an ``ok`` result's
masked EPE exceeds 1 px (an object whose blobs are all merged has no assignment to be
wrong, but its plane can be). Times, median over scenes: the whole ``estimate`` call
geometric only (the refinement off, so that the assignment's own growth with k shows),
beside the single-light estimate on the same images, and the median over scenes of each
scene's ratio of the two (timed one after the other, so the machine's drift between
scenes and runs mostly cancels); and the default call (with the photometric refinement,
which renders the lobes of lights whose highlights come near each other and solves
objects whose blobs are all merged), with the same ratio to the default call told of the
first light only.

Fusion: each object the all-lights estimate solves goes through ``fuse`` with the default
border check, the backbone being OpenCV SGBM on the rig's stereo pair (the fusion
benchmark's). Its fused masked EPE is set beside SRDE's own over the same objects: fusion
should hand back only what is not the object, and every pixel of these masks is.

Run: ``python benchmarks/multi_light.py [--scenes 40] [--repeat 3]``; writes
``benchmarks/results/multi_light.md`` and ``.json``. ``--light-samples N [--lights 2]``
renders each sphere light with N samples (a multiple of 4) instead of the faithful
physics' 64 (each render takes several times longer) and writes
``multi_light_samples_N.md``: whether the lamps' sampling, the same pattern in every
pixel and noise draw, decides a comparison. ``--seed0 S --name NAME`` runs other seeds
(scene i with k lights: seed ``S + 100 k + i``) into ``NAME.md``: scenes the code was
never tuned on.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from faceted import Estimated  # fusion of a result already computed (run from this folder)
from fusion_eval import sgbm_backbone
from results_files import write_results

from srde_fusion.fusion import fuse
from srde_fusion.geometry import plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.srde.lights import estimate_with_lights
from srde_fusion.synthetic import RandomSceneConfig, default_rig, random_scene, render
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "multi_light"
LIGHT_COUNTS = (1, 2, 3, 4)
WRONG_PLANE_PX = 1.0
#: "Worse than the best single light" is also counted beyond this margin, px: the
#: several-light and a single-light estimate often end on the same plane to 1e-5 px.
WORSE_MARGIN_PX = 0.001
SEED0 = 12000
#: The backbone of the fused maps: the fusion benchmark's SGBM.
SGBM = sgbm_backbone()
#: A fused object counts as worse than SRDE's own when its masked EPE exceeds SRDE's by
#: more than this, px.
FUSED_WORSE_PX = 0.01


def masked_epe(result, rig, rendering, mask) -> float:
    if not result.ok:
        return float("nan")
    disparity = plane_disparity(result.plane, rig)[mask]
    return float(np.mean(np.abs(disparity - rendering.disparity_px[mask])))


def wrong_assignments(result, rendering, dark: int | None = None) -> int:
    """Assigned candidates that are not the blob nearest to their light's true highlight.

    ``dark``: a light the rig knows that ``rendering`` does not hold (switched off):
    every candidate given to it is wrong.
    """
    if result.lights is None or result.lights.plane is None:
        return 0
    on = rendering.highlight_on_object[:, 0, :]
    wrong = 0
    for a in result.lights.assignments:
        views = np.flatnonzero(np.isfinite(a.centers_uv[:, 0]))
        if a.light == dark:
            wrong += len(views)
            continue
        for j in views:
            truth = rendering.highlight_uv_by_light[a.light, 0, j]
            cands = result.lights.candidates_uv[j]
            nearest = cands[np.argmin(np.linalg.norm(cands - truth, axis=1))]
            if not (on[a.light, j] and np.allclose(nearest, a.centers_uv[j])):
                wrong += 1
    return wrong


def timed(fn, repeat: int = 1):
    """The first call's result and the shortest of ``repeat`` calls' times, seconds."""
    times = []
    for i in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
        if i == 0:
            out = result
    return out, min(times)


def fused_record(result, rig, rendering, mask, *, backbone_epe: bool = False) -> dict:
    """The fused map's masked EPE and fusion's decision for an ``ok`` result.

    EPEs over the mask's pixels that have a disparity (the backbone's holes stay holes
    where fusion hands them back); ``backbone_epe`` adds the backbone's own.
    """
    if not result.ok:
        return {}
    backbone = SGBM(*(rendering.views[j] for j in rig.stereo_pair))
    fused = fuse(backbone, rendering.views, rig, [mask], Estimated(result))
    truth = rendering.disparity_px[mask]
    record = {"fused_status": fused.objects[0].status,
              "trimmed_px": fused.objects[0].trimmed_px,
              "srde_map_epe": float(np.nanmean(np.abs(result.disparity[mask] - truth))),
              "fused_epe": float(np.nanmean(np.abs(fused.disparity[mask] - truth)))}
    if backbone_epe:
        record["backbone_epe"] = float(np.nanmean(np.abs(backbone[mask] - truth)))
    return record


def correspondence_time(srde: SRDE, views, mask, repeat: int) -> float:
    """Seconds of the several-light path (band scan, assignment) with ``srde``'s lights.

    ``SRDE.estimate`` takes that path only for two or more lights; told of one, this
    times what the correspondence itself costs before any second light is added.
    """
    search = srde._erode(mask)  # the search region estimate() hands that path
    return timed(lambda: estimate_with_lights(srde, views, mask, search), repeat)[1]


def run_scene(rig, seed: int, k: int, physics: Physics, repeat: int = 1) -> dict:
    scene = random_scene(seed, rig, config=RandomSceneConfig(n_lights=k))
    rendering = render(scene, rig, physics=physics, supersample=2)
    mask = rendering.object_masks[0]
    lights = rig_lights(scene)
    lit = rig.with_lights(lights)
    first = rig.with_lights([lights[0]])
    record = {"seed": seed, "k": k,
              "on_object": rendering.highlight_on_object[:, 0, :].sum(axis=1).tolist(),
              "path_first_time_s": correspondence_time(SRDE(first, refine=False),
                                                       rendering.views, mask, repeat)}
    if k == 1:
        result, t_default = timed(lambda: SRDE(lit).estimate(rendering.views, mask), repeat)
        _, t_geo = timed(lambda: SRDE(lit, refine=False).estimate(rendering.views, mask), repeat)
        epe = masked_epe(result, lit, rendering, mask)
        record.update(status=result.status, epe=epe, wrong=0, first_status=result.status,
                      first_epe=epe, best_single=epe, time_s=t_geo, single_time_s=t_geo,
                      default_time_s=t_default, single_default_time_s=t_default, merged=0,
                      **fused_record(result, lit, rendering, mask))
        return record
    result, t_default = timed(lambda: SRDE(lit).estimate(rendering.views, mask), repeat)
    _, t_multi = timed(lambda: SRDE(lit, refine=False).estimate(rendering.views, mask),
                       repeat)
    singles = []
    for light in lights:
        one = rig.with_lights([light])
        singles.append(masked_epe(SRDE(one).estimate(rendering.views, mask), one, rendering,
                                  mask))
    first_result, t_single_default = timed(lambda: SRDE(first).estimate(rendering.views, mask),
                                           repeat)
    _, t_single = timed(lambda: SRDE(first, refine=False).estimate(rendering.views, mask),
                        repeat)
    finite = [e for e in singles if np.isfinite(e)]
    record.update(
        status=result.status, reason=result.reason, epe=masked_epe(result, lit, rendering, mask),
        wrong=wrong_assignments(result, rendering) if result.ok else 0,
        observations=0 if result.lights is None else result.lights.n_observations,
        first_status=first_result.status,
        first_epe=masked_epe(first_result, first, rendering, mask),
        best_single=min(finite) if finite else float("nan"), singles=singles,
        time_s=t_multi, single_time_s=t_single, default_time_s=t_default,
        single_default_time_s=t_single_default,
        merged=0 if result.lights is None else len(result.lights.merged_blobs),
        **fused_record(result, lit, rendering, mask))
    return record


def fused_rows(records: list[dict]) -> tuple[list[str], dict]:
    """Fusion of the all-lights estimates, per number of lights."""
    lines = ["| lights | SRDE ok | kept by fusion | sent back | with trimmed px | SRDE EPE "
             f"(px) | fused EPE (px) | fused worse than SRDE by > {FUSED_WORSE_PX:g} px |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for k in LIGHT_COUNTS:
        ok = [r for r in records if r["k"] == k and "fused_status" in r]
        if not ok:
            continue
        kept = [r for r in ok if r["fused_status"] == "srde"]
        row = {"srde_ok": len(ok), "kept": len(kept), "sent_back": len(ok) - len(kept),
               "trimmed": int(sum(r["trimmed_px"] > 0 for r in ok)),
               "srde_epe": float(np.mean([r["srde_map_epe"] for r in ok])),
               "fused_epe": float(np.mean([r["fused_epe"] for r in ok])),
               "fused_worse": int(sum(r["fused_epe"] > r["srde_map_epe"] + FUSED_WORSE_PX
                                      for r in ok))}
        numbers[str(k)] = row
        lines.append(f"| {k} | {row['srde_ok']} | {row['kept']} | {row['sent_back']} | "
                     f"{row['trimmed']} | {row['srde_epe']:.4f} | {row['fused_epe']:.4f} | "
                     f"{row['fused_worse']} |")
    return lines, numbers


def summary_rows(records: list[dict]) -> tuple[list[str], dict]:
    lines = ["| lights | scenes | solved (all lights) | wrong assignments | wrong planes (ok, "
             "EPE > 1 px) | ambiguous | "
             "inconsistent | EPE all lights | EPE best single light | EPE first light only | "
             "worse than best single light (scenes; by > 0.001 px) | "
             "first light only: solved / wrong plane | time all lights (ms) | time one light "
             "(ms) | all / one light, same scene | time with refinement (ms) | with "
             "refinement, all / one light, same scene |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for k in LIGHT_COUNTS:
        rs = [r for r in records if r["k"] == k]
        if not rs:
            continue
        ok = [r for r in rs if r["status"] == "ok"]
        both = [r for r in ok if np.isfinite(r["best_single"])]
        first_ok = [r for r in rs if r["first_status"] == "ok"]
        first_wrong = [r for r in first_ok if r["first_epe"] > WRONG_PLANE_PX]
        row = {
            "scenes": len(rs), "solved": len(ok) / len(rs),
            "wrong_assignments": int(sum(r["wrong"] for r in rs)),
            "scenes_with_wrong": int(sum(r["wrong"] > 0 for r in rs)),
            "wrong_planes": int(sum(r["epe"] > WRONG_PLANE_PX for r in ok)),
            "ambiguous": int(sum(r["status"] == "ambiguous" for r in rs)),
            "inconsistent": int(sum(r["status"] == "inconsistent" for r in rs)),
            "epe": float(np.mean([r["epe"] for r in ok])) if ok else float("nan"),
            "epe_best_single_same": float(np.mean([r["best_single"] for r in both]))
            if both else float("nan"),
            "epe_all_same": float(np.mean([r["epe"] for r in both])) if both else float("nan"),
            "epe_first": float(np.mean([r["first_epe"] for r in first_ok]))
            if first_ok else float("nan"),
            "first_solved": len(first_ok) / len(rs), "first_wrong_plane": len(first_wrong),
            "worse_than_best_single": int(sum(r["epe"] > r["best_single"] for r in both)),
            "worse_beyond_margin": int(sum(r["epe"] > r["best_single"] + WORSE_MARGIN_PX
                                           for r in both)),
            "worst_excess_px": max((r["epe"] - r["best_single"] for r in both), default=0.0),
            "solved_with_merged_blobs": int(sum(r.get("merged", 0) > 0 for r in ok)),
            "default_time_ms": 1000 * float(np.median([r["default_time_s"] for r in rs])),
            "time_ms": 1000 * float(np.median([r["time_s"] for r in rs])),
            "single_time_ms": 1000 * float(np.median([r["single_time_s"] for r in rs])),
            # Each scene's two geometric calls run one after the other: their ratio is
            # spared the machine's drift between scenes and runs.
            "time_ratio": float(np.median([r["time_s"] / r["single_time_s"] for r in rs])),
            "default_time_ratio": float(np.median(
                [r["default_time_s"] / r["single_default_time_s"] for r in rs
                 if "single_default_time_s" in r])) if any(
                "single_default_time_s" in r for r in rs) else float("nan"),
        }
        numbers[str(k)] = row
        lines.append(
            f"| {k} | {row['scenes']} | {row['solved']:.0%} | {row['wrong_assignments']} "
            f"({row['scenes_with_wrong']} scenes) | {row['wrong_planes']} | {row['ambiguous']} | "
            f"{row['inconsistent']} | "
            f"{row['epe_all_same']:.4f} | {row['epe_best_single_same']:.4f} | "
            f"{row['epe_first']:.4f} | {row['worse_than_best_single']} of {len(both)}; "
            f"{row['worse_beyond_margin']} | "
            f"{row['first_solved']:.0%} / {row['first_wrong_plane']} | "
            f"{row['time_ms']:.0f} | {row['single_time_ms']:.0f} | {row['time_ratio']:.2f}x | "
            f"{row['default_time_ms']:.0f} | {row['default_time_ratio']:.2f}x |")
    return lines, numbers


def time_rows(records: list[dict]) -> tuple[list[str], dict]:
    """Geometric time against k: the correspondence path's own cost and each light's."""
    lines = ["| lights | all lights (ms) | correspondence path told of the first light only "
             "(ms) | all lights / that, same scene | single-light path, first light only "
             "(ms) | correspondence path, first light / single-light path, same scene |",
             "|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for k in LIGHT_COUNTS:
        rs = [r for r in records if r["k"] == k and "path_first_time_s" in r]
        if not rs:
            continue
        row = {"time_ms": 1000 * float(np.median([r["time_s"] for r in rs])),
               "path_first_ms": 1000 * float(np.median([r["path_first_time_s"] for r in rs])),
               "single_ms": 1000 * float(np.median([r["single_time_s"] for r in rs])),
               "path_first_over_single": float(np.median(
                   [r["path_first_time_s"] / r["single_time_s"] for r in rs]))}
        # With one light ``estimate`` takes the single-light path: no ratio to the path.
        row["all_over_path_first"] = float(np.median(
            [r["time_s"] / r["path_first_time_s"] for r in rs])) if k > 1 else float("nan")
        numbers[str(k)] = row
        ratio = "-" if k == 1 else f"{row['all_over_path_first']:.2f}x"
        lines.append(f"| {k} | {row['time_ms']:.1f} | {row['path_first_ms']:.1f} | {ratio} | "
                     f"{row['single_ms']:.1f} | {row['path_first_over_single']:.2f}x |")
    return lines, numbers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40, help="scenes per number of lights")
    parser.add_argument("--repeat", type=int, default=3,
                        help="each time is the shortest of this many calls (default 3)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument("--tables-only", action="store_true",
                        help="rewrite the tables from the results folder's JSON records")
    parser.add_argument("--lights", type=int, nargs="+", default=list(LIGHT_COUNTS),
                        choices=LIGHT_COUNTS, help="numbers of lights (default all)")
    parser.add_argument("--light-samples", type=int, default=None,
                        help="samples per sphere light (default: the faithful physics' 64)")
    parser.add_argument("--seed0", type=int, default=SEED0,
                        help=f"first seed (default {SEED0}; scene i with k lights: "
                        "seed0 + 100 k + i)")
    parser.add_argument("--name", default=NAME, help=f"results file name (default {NAME})")
    args = parser.parse_args(argv)
    physics = Physics.faithful()
    name, seed0 = args.name, args.seed0
    if args.light_samples is not None:
        physics = replace(physics, light_samples=args.light_samples)
        name = f"{name}_samples_{args.light_samples}"
    rig = default_rig()
    records = []
    repeat = args.repeat
    if args.tables_only:
        stored = json.loads((args.out / f"{name}.json").read_text())
        records, repeat = stored["records"], stored.get("repeat", 1)
        seed0 = stored.get("seed0", SEED0)
        args.scenes = max(sum(r["k"] == k for r in records) for k in LIGHT_COUNTS)
    for k in args.lights if not args.tables_only else ():
        for i in range(args.scenes):
            record = run_scene(rig, seed0 + 100 * k + i, k, physics, args.repeat)
            records.append(record)
            print(f"k={k} seed {record['seed']}: {record['status']} epe {record['epe']:.4f} "
                  f"wrong {record['wrong']} best single {record['best_single']:.4f} "
                  f"first {record['first_status']} {record['first_epe']:.4f}", flush=True)
    table, numbers = summary_rows(records)
    fused_table, fused_numbers = fused_rows(records)
    time_table, time_numbers = time_rows(records)
    md = ["# SRDE with several known lights", "",
          __doc__.split("\n\n", 1)[1].split("\n\nRun:")[0].replace("\n", " "), "",
          f"{args.scenes} scenes per number of lights (seeds {seed0} + 100 k + i), sphere "
          f"lights sampled at {physics.light_samples} points. Machine: "
          f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}. "
          f"Each time is the shortest of {repeat} call(s) on the same images (a new frame's "
          "first call finds colder caches).",
          "", "EPE columns: mean masked EPE (px) over the scenes where both the all-lights "
          "estimate and some single light succeeded; first light only: over its own "
          "successes.", "", *table, "",
          "Solved objects with blobs of merged highlights (no centre measures a light there; "
          "the lobes of all lights fitted together): " + ", ".join(
              f"{row['solved_with_merged_blobs']} with {k} lights" for k, row in numbers.items()
              if k != "1") + ".", "",
          "Fusion of the all-lights estimates (SGBM backbone, default border check; EPE over "
          "the objects SRDE solved, fused map and SRDE's own map on the mask):", "",
          *fused_table, ""]
    if time_table[2:]:
        md += ["Geometric time against k, medians over scenes (the refinement off). With two "
               "or more lights `estimate` matches highlights to lights: it scans every view's "
               "band for candidates and searches the assignments. Told of the first light "
               "only, that path shows what the correspondence itself costs; what is added to "
               "it with every light, the assignment's growth with k:", "", *time_table, ""]
    write_results(args.out, name, md, {"numbers": numbers, "fused": fused_numbers,
                                       "time": time_numbers,
                                       "records": records, "repeat": repeat,
                                       "seed0": seed0}, default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
