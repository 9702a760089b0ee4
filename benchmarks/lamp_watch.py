"""A lamp the rig lists but that is off, across the frames of a line: when it is named.

Lines: for k = 2-4 lamps, the lamps and camera exposure of the several-light benchmark's
first k-lamp scene (``multi_light.py``: seed 12000 + 100 k, the paper's 3 x 3 array,
640 x 480 px), fixed, and one flat glossy object per frame, each a new random scene's
object relit by those lamps (``synthetic.relit``), its exposure metered as a camera's
automatic exposure would (the object's median linear luminance in the reference view at
0.08, the middle of the random scenes' diffuse levels: with the line's exposure, objects
of other albedos under four lamps came out white), rendered with ``Physics.faithful()``
(2 x 2 samples per pixel). A frame is kept when some lamp other than the last puts its
highlight on the object in at least 2 views (otherwise no estimate can see the object,
with any rig). Every frame is rendered twice, each a stream of its own:

* ``all lit``: every lamp lit, the rig listing them all (a lamp named is a false alarm);
* ``last lamp off``: the last lamp switched off, the rig still listing it (a burnt-out
  lamp left in ``rig.json``).

Each frame's SRDE result (the rig listing every lamp) goes into ``fusion.LampTally``, as
``HybridStereo.stream`` does (``stream.lamps``): per lamp, the solved objects that see
it and those whose plane puts its highlights on the object in 2 or more views where the
images are dark. It names a lamp no solved object sees and at least 2 need dark. The
table gives the frame after which the dark lamp is named, the lamps named in either
stream that are lit (false alarms), and what the streams solved: objects, objects whose
plane is wrong (masked EPE above 1 px), and refusals because a reading needs a lamp
dark (``ambiguous``).

Run: ``python benchmarks/lamp_watch.py [--frames 40]``; writes
``benchmarks/results/lamp_watch.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import os
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np
from multi_light import SEED0, WRONG_PLANE_PX, masked_epe  # run from this folder
from results_files import write_results

from srde_fusion.fusion import LampTally
from srde_fusion.imaging import luminance
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import (
    RandomSceneConfig,
    default_rig,
    highlights_on_objects,
    random_scene,
    relit,
    render,
)
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "lamp_watch"
LIGHT_COUNTS = (2, 3, 4)
#: Seeds of the objects that pass along the lines (the same objects for every line).
OBJECT_SEED0 = 20000
MIN_VIEWS = 2
#: The object's median linear luminance in the reference view that the exposure meters.
METERED_LEVEL = 0.08


def metered(scene, rig):
    """Return ``scene`` with the exposure that puts its object at METERED_LEVEL.

    Metered on a plain render (the faithful one's exposure scales the same way); clipped
    pixels hold the median down, so it is metered again until it lands within 5 %.
    """
    for _ in range(4):
        rendering = render(scene, rig)
        level = float(np.median(luminance(rendering.views[rig.reference])[
            rendering.object_masks[0]]))
        if abs(level / METERED_LEVEL - 1.0) < 0.05:
            break
        scene = replace(scene, exposure=scene.exposure * METERED_LEVEL / max(level, 1e-3))
    return scene


def frames_of_line(rig, line, n_frames: int):
    """Yield ``(seed, scene, on_object)``: objects relit by ``line`` that a lamp lit reaches.

    ``on_object`` ``(k, views)`` bool: where each lamp puts its highlight on the object
    (the exposure the meter sets does not move it).
    """
    seed = OBJECT_SEED0
    found = 0
    while found < n_frames:
        scene = relit(random_scene(seed, rig), line)
        on_object = highlights_on_objects(scene, rig)[:, 0]  # (k, views)
        if on_object[:-1].sum(axis=1).max() >= MIN_VIEWS:
            found += 1
            yield seed, metered(scene, rig), on_object
        seed += 1


def run_line(rig, k: int, n_frames: int, physics: Physics) -> tuple[list[dict], dict]:
    line = random_scene(SEED0 + 100 * k, rig, config=RandomSceneConfig(n_lights=k))
    listed = rig.with_lights(rig_lights(line))
    srde = SRDE(listed)
    tallies = {"all_lit": LampTally.for_rig(listed), "last_off": LampTally.for_rig(listed)}
    records = []
    for seed, scene, on_object in frames_of_line(rig, line, n_frames):
        record = {"k": k, "seed": seed, "dark_on_object_views": int(on_object[-1].sum())}
        for stream, lamps in (("all_lit", scene.lights), ("last_off", scene.lights[:-1])):
            rendering = render(replace(scene, light=None, lights=lamps), rig, physics=physics,
                               supersample=2)
            mask = rendering.object_masks[0]
            result = srde.estimate(rendering.views, mask)
            tallies[stream] = tallies[stream].added([result])
            record[stream] = {"status": result.status, "reason": result.reason[:300],
                              "epe": masked_epe(result, listed, rendering, mask),
                              "named": list(tallies[stream].unseen)}
        records.append(record)
        print(f"k={k} object {seed}: " + "; ".join(
            f"{s} {record[s]['status']} {record[s]['epe']:.4f} named {record[s]['named']}"
            for s in tallies), flush=True)
    return records, {stream: {"solved": t.solved, "seen": list(t.seen), "dark": list(t.dark),
                              "refused_dark": t.refused_dark, "warning": t.warning()}
                     for stream, t in tallies.items()}


def summary_rows(records: list[dict], tallies: dict) -> tuple[list[str], dict]:
    lines = ["| lamps | frames | dark lamp named after (frames) | lit lamps named, last lamp "
             "off | lamps named, all lit | solved, last lamp off / all lit | wrong planes, "
             "last lamp off / all lit | refused for a lamp that may be dark, last lamp off / "
             "all lit | warned at the end, last lamp off / all lit |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for k in sorted({r["k"] for r in records}):
        rs = [r for r in records if r["k"] == k]
        named = [i + 1 for i, r in enumerate(rs) if k - 1 in r["last_off"]["named"]]
        row = {
            "frames": len(rs),
            "dark_named_after": named[0] if named else None,
            "lit_named_last_off": sorted({j for r in rs for j in r["last_off"]["named"]
                                          if j != k - 1}),
            "named_all_lit": sorted({j for r in rs for j in r["all_lit"]["named"]}),
            **{f"{key}_{s}": value for s in ("last_off", "all_lit") for key, value in (
                ("solved", sum(r[s]["status"] == "ok" for r in rs)),
                ("wrong", sum(r[s]["status"] == "ok" and r[s]["epe"] > WRONG_PLANE_PX
                              for r in rs)),
                ("refused_dark", tallies[str(k)][s]["refused_dark"]))},
            "tallies": tallies[str(k)],
        }
        numbers[str(k)] = row
        lines.append(
            f"| {k} | {row['frames']} | {named[0] if named else 'never'} | "
            f"{row['lit_named_last_off'] or 'none'} | {row['named_all_lit'] or 'none'} | "
            f"{row['solved_last_off']} / {row['solved_all_lit']} | "
            f"{row['wrong_last_off']} / {row['wrong_all_lit']} | "
            f"{row['refused_dark_last_off']} / {row['refused_dark_all_lit']} | "
            + " / ".join("yes" if row["tallies"][s]["warning"] else "no"
                         for s in ("last_off", "all_lit")) + " |")
    return lines, numbers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames per line")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument("--name", default=NAME, help=f"results file name (default {NAME})")
    args = parser.parse_args(argv)
    rig, physics = default_rig(), Physics.faithful()
    records, tallies = [], {}
    for k in LIGHT_COUNTS:
        line_records, tallies[str(k)] = run_line(rig, k, args.frames, physics)
        records += line_records
    table, numbers = summary_rows(records, tallies)
    warnings = [f"- {k} lamps, {stream.replace('_', ' ')}: "
                + tallies[str(k)][stream]["warning"].replace("\n", " / ")
                for stream in ("last_off", "all_lit") for k in LIGHT_COUNTS
                if tallies[str(k)][stream]["warning"]]
    md = ["# A lamp the rig lists but that is off, across the frames of a line", "",
          __doc__.split("\n\n", 1)[1].split("\n\nRun:")[0].replace("\n", " "), "",
          f"{args.frames} frames per line (objects of seeds {OBJECT_SEED0} on, those a lit "
          f"lamp reaches). Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
          f"{platform.python_version()}.", "", *table, "",
          "What the tally says at the end of each line (``LampTally.warning()``; nothing "
          "where not listed):", "", *warnings, ""]
    write_results(args.out, args.name, md, {"numbers": numbers, "records": records},
                  default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
