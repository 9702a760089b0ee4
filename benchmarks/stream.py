"""Frames per second of ``HybridStereo.stream`` on a fixed rig, and what the stream saves.

A sorting line: the paper's 3 x 3 array (640 x 480 unless ``--scale``), one light, one
glossy object on a textured background, frames differing by sensor noise. Fused three
ways, the same frames each time:

* ``stream``: one ``HybridStereo`` for the rig, ``model.stream(frames)``, with the
  bundled stand-in backbone;
* the stream with a backbone that costs nothing (the ground truth with the object
  blanked), which shows SRDE, masks and fusion alone;
* ``fresh model per frame``: the same free backbone, but a new ``HybridStereo`` (and so
  a new SRDE, search geometry and detector) for every frame, as a script calling it per
  file would: what the stream's reuse saves.

Prints frames per second and the share of each stage; writes
``benchmarks/results/stream.md`` and ``.json``.

    python benchmarks/stream.py [--frames 6] [--scale 1.0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
from srde_fusion.adapters import load_backbone

from srde_fusion.fusion import HybridStereo
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS = Path(__file__).resolve().parent / "results"
NAME = "stream"
SCENE_SEED = 3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--scale", type=float, default=1.0)
    args = parser.parse_args()

    rig = default_rig().scaled(args.scale)
    scene = random_scene(SCENE_SEED, rig, n_objects=1, background="textured")
    rig = rig.with_light(scene.light.position_m)
    renderings = [render(scene, rig, noise_seed=k) for k in range(args.frames)]
    frames = [r.views for r in renderings]
    truth = renderings[0].disparity_px.copy()
    truth[renderings[0].instance_mask > 0] = np.nan

    def free_backbone(left, right):
        return truth

    standin = load_backbone("default")
    left, right = (frames[0][i] for i in rig.stereo_pair)
    standin(left, right)  # warm-up: session start, first-call allocations

    rows = {}
    stream = HybridStereo(standin, rig).stream(frames)
    results = list(stream)
    rows["stream, stand-in backbone"] = _row(stream.stats, results)

    stream = HybridStereo(free_backbone, rig).stream(frames)
    results = list(stream)
    rows["stream, no backbone cost"] = _row(stream.stats, results)

    # The same without the stream: a new model (SRDE, search geometry, detector) per frame.
    start = time.perf_counter()
    fresh = [HybridStereo(free_backbone, rig)(views) for views in frames]
    wall = time.perf_counter() - start
    rows["fresh model per frame, no backbone cost"] = {
        "frames": len(fresh), "fps": len(fresh) / wall, "backbone": None, "masks": None,
        "srde_and_fusion": None, "srde_used": sum(o.used_srde for r in fresh for o in r.objects)}

    w, h = rig.image_size
    lines = [f"# {NAME}", "",
             f"{args.frames} frames, {rig.n_cameras} views of {w}x{h}, one glossy object; "
             f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}.", "",
             "| run | frames/s | backbone | masks | SRDE + fusion | objects on SRDE |",
             "|---|---:|---:|---:|---:|---:|"]
    for name, r in rows.items():
        shares = [f"{r[k]:.0%}" if r[k] is not None else "-"
                  for k in ("backbone", "masks", "srde_and_fusion")]
        lines.append(f"| {name} | {r['fps']:.2f} | {' | '.join(shares)} | "
                     f"{r['srde_used']} / {r['frames']} |")
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{NAME}.md").write_text(text)
    (RESULTS / f"{NAME}.json").write_text(json.dumps(
        {"frames": args.frames, "image_size": [w, h], "rows": rows}, indent=2) + "\n")


def _row(stats, results) -> dict:
    return {"frames": stats.frames, "fps": stats.fps,
            "backbone": stats.backbone_s / stats.busy_s, "masks": stats.masks_s / stats.busy_s,
            "srde_and_fusion": stats.fusion_s / stats.busy_s,
            "srde_used": sum(o.used_srde for r in results for o in r.objects)}


if __name__ == "__main__":
    main()
