"""A lamp the rig knows is switched off: objects solved, wrong planes, against the rig without it.

Scenes: the several-light benchmark's (``multi_light.py``: one flat glossy object before
the paper's 3 x 3 array, k = 2-4 lights, ``Physics.faithful()``), rendered with the last
of the k lamps switched off, while the rig still knows all k (a burnt-out or unplugged
lamp left in ``rig.json``). Every scene is estimated twice:

* ``rig with the dark lamp``: ``SRDE`` told of all k lamps;
* ``rig without it``: ``SRDE`` told of the k - 1 lamps that are lit, the rig as it
  should be (the bar for "costs nothing").

Each ``ok`` result of the first then goes through ``fuse`` (the several-light benchmark's
SGBM backbone, default border check): does fusion send a wrong plane back, and is the
fused map ever worse than the backbone's own?

A plane is wrong when an ``ok`` result's masked EPE exceeds 1 px; an assignment is wrong
when an ``ok`` result gives the dark lamp a highlight, or a lit lamp a candidate that is
not the blob nearest to its true highlight (``multi_light.wrong_assignments``). The dark
lamp's highlight is "predicted on the object" in a scene when the lamp, lit, would put
it there in some view (``synthetic.highlights_on_objects``). SRDE takes the rig as the
truth: a lamp it knows whose highlight the plane puts on the object is expected there,
and one that is not there counts against the plane. With two lamps known and one dark,
the one lit lamp's blobs are one virtual light, the image of either lamp on its own
plane, each reading putting the other lamp's highlights on the object where the view is
dark: nothing in the images tells the two apart, so these are the scenes where a stale
rig costs most (SRDE refuses such an object as ``ambiguous`` when both readings explain
as much, rule 10 in ``docs/DESIGN.md``). The notes of an ``ok`` result name a lamp none
of whose highlights is seen where the plane puts them on the object (``noted as switched
off``).

Run: ``python benchmarks/dark_lamp.py [--scenes 40]``; writes
``benchmarks/results/dark_lamp.md`` and ``.json`` (``--tables-only`` rewrites them from
the stored records).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np
from multi_light import (  # run from this folder
    SEED0,
    WRONG_PLANE_PX,
    fused_record,
    masked_epe,
    wrong_assignments,
)
from results_files import write_results

from srde_fusion.srde import SRDE
from srde_fusion.synthetic import (
    RandomSceneConfig,
    default_rig,
    highlights_on_objects,
    random_scene,
    render,
)
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "dark_lamp"
LIGHT_COUNTS = (2, 3, 4)


def run_scene(rig, seed: int, k: int, physics: Physics) -> dict:
    scene = random_scene(seed, rig, config=RandomSceneConfig(n_lights=k))
    lights = rig_lights(scene)
    lit_scene = replace(scene, lights=scene.lights[:-1])  # the last lamp switched off
    rendering = render(lit_scene, rig, physics=physics, supersample=2)
    mask = rendering.object_masks[0]
    # Where the dark lamp would put its highlight, lit (geometry only).
    predicted = highlights_on_objects(scene, rig)[-1, 0]
    known = rig.with_lights(lights)
    without = rig.with_lights(lights[:-1])
    result = SRDE(known).estimate(rendering.views, mask)
    bar = SRDE(without).estimate(rendering.views, mask)
    return {"seed": seed, "k": k, "dark_on_object_views": int(predicted.sum()),
            "status": result.status, "reason": result.reason,
            "epe": masked_epe(result, known, rendering, mask),
            "wrong": wrong_assignments(result, rendering, dark=k - 1) if result.ok else 0,
            "notes": list(result.notes),
            "without_status": bar.status, "without_epe": masked_epe(bar, without, rendering,
                                                                   mask),
            # what fusion does with the plane (SGBM backbone, default border check)
            **fused_record(result, known, rendering, mask, backbone_epe=True)}


def summary_rows(records: list[dict]) -> tuple[list[str], dict]:
    lines = ["| lights known (one dark) | scenes | dark lamp predicted on the object (scenes) | "
             "solved, rig with the dark lamp | solved, rig without it | wrong planes | wrong "
             "assignments | EPE with / without (px, both solved) | noted as switched off | "
             "wrong planes fusion sends back | fused EPE above the backbone's |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for k in sorted({r["k"] for r in records}):
        rs = [r for r in records if r["k"] == k]
        ok = [r for r in rs if r["status"] == "ok"]
        both = [r for r in ok if r["without_status"] == "ok"]
        row = {
            "scenes": len(rs),
            "dark_predicted": sum(r["dark_on_object_views"] > 0 for r in rs),
            "solved": len(ok),
            "solved_without": sum(r["without_status"] == "ok" for r in rs),
            "wrong_planes": sum(r["epe"] > WRONG_PLANE_PX for r in ok),
            "wrong_assignments": sum(r["wrong"] for r in ok),
            "epe": float(np.mean([r["epe"] for r in both])) if both else float("nan"),
            "epe_without": float(np.mean([r["without_epe"] for r in both])) if both
            else float("nan"),
            "noted": sum(any("switched off" in n for n in r["notes"]) for r in ok),
            "wrong_sent_back": sum(r["epe"] > WRONG_PLANE_PX and r["fused_status"] != "srde"
                                   for r in ok),
            "fused_above_backbone": sum(r["fused_epe"] > r["backbone_epe"] for r in ok),
            "statuses": {s: sum(r["status"] == s for r in rs) for s in
                         sorted({r["status"] for r in rs})},
        }
        numbers[str(k)] = row
        lines.append(f"| {k} | {row['scenes']} | {row['dark_predicted']} | {row['solved']} | "
                     f"{row['solved_without']} | {row['wrong_planes']} | "
                     f"{row['wrong_assignments']} | {row['epe']:.4f} / {row['epe_without']:.4f} | "
                     f"{row['noted']} | {row['wrong_sent_back']} of {row['wrong_planes']} | "
                     f"{row['fused_above_backbone']} |")
    return lines, numbers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40, help="scenes per number of lights")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument("--name", default=NAME, help=f"results file name (default {NAME})")
    parser.add_argument("--tables-only", action="store_true",
                        help="rewrite the tables from the results folder's JSON records")
    args = parser.parse_args(argv)
    rig, physics = default_rig(), Physics.faithful()
    records = []
    if args.tables_only:
        records = json.loads((args.out / f"{args.name}.json").read_text())["records"]
        args.scenes = max(sum(r["k"] == k for r in records) for k in LIGHT_COUNTS)
    for k in LIGHT_COUNTS if not args.tables_only else ():
        for i in range(args.scenes):
            record = run_scene(rig, SEED0 + 100 * k + i, k, physics)
            records.append(record)
            print(f"k={k} seed {record['seed']}: {record['status']} epe {record['epe']:.4f} "
                  f"without {record['without_status']} {record['without_epe']:.4f} "
                  f"wrong {record['wrong']}", flush=True)
    table, numbers = summary_rows(records)
    refused = sorted({r["reason"].split(";")[0] for r in records if r["status"] != "ok"})
    md = ["# A lamp the rig knows is switched off", "",
          __doc__.split("\n\n", 1)[1].split("\n\nRun:")[0].replace("\n", " "), "",
          f"{args.scenes} scenes per number of lights (seeds {SEED0} + 100 k + i, the "
          f"several-light benchmark's). Machine: {platform.machine()}, {os.cpu_count()} "
          f"cores, Python {platform.python_version()}.", "", *table, "",
          "Why the others were refused (first clause of each reason):", "",
          *[f"- {reason}" for reason in refused], ""]
    write_results(args.out, args.name, md, {"numbers": numbers, "records": records},
                  default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
