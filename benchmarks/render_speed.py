"""Render speed of the synthetic renderer on the paper's 3 x 3 array (640 x 480).

Times ``render`` (all nine views plus ground truth) and ``random_scene`` for a few
scene kinds, best-of and mean ± std over repeats, and writes the table to
benchmarks/results/render_speed.md and .json.

    python benchmarks/render_speed.py [--repeats 5] [--scenes 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS = Path(__file__).resolve().parent / "results"

CASES = [
    ("1 object, background at infinity", dict(n_objects=1, background="none"), 1),
    ("3 objects, background at infinity", dict(n_objects=3, size_m=(0.12, 0.25)), 1),
    ("1 object, textured background", dict(n_objects=1, background="textured"), 1),
    ("1 object, textured, supersample 2", dict(n_objects=1, background="textured"), 2),
]


def _time(fn, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenes", type=int, default=3, help="random scenes per case")
    args = parser.parse_args()
    rig = default_rig()
    load_before = os.getloadavg()[0]
    rows = []
    for name, options, supersample in CASES:
        render_s, sample_s = [], []
        for seed in range(args.scenes):
            sample_s += _time(lambda: random_scene(seed, rig, **options), 1)  # noqa: B023
            scene = random_scene(seed, rig, **options)
            render(scene, rig, supersample=supersample)  # warm-up: textures, tables
            render_s += _time(lambda: render(scene, rig, supersample=supersample), args.repeats)  # noqa: B023
        rows.append({
            "case": name,
            "views": rig.n_cameras,
            "render_best_s": float(np.min(render_s)),
            "render_mean_s": float(np.mean(render_s)),
            "render_std_s": float(np.std(render_s)),
            "per_view_ms": float(np.mean(render_s) / rig.n_cameras * 1000),
            "random_scene_mean_s": float(np.mean(sample_s)),
        })
    lines = [
        f"# Render speed: {rig.n_cameras} views at {rig.width}x{rig.height}",
        "",
        f"{os.cpu_count()} CPU(s), {platform.processor() or platform.machine()}, "
        f"numpy {np.__version__}; {args.scenes} scenes x {args.repeats} repeats per case; "
        f"1-min load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after "
        "(other work on the machine slows every number).",
        "",
        "| case | render best (s) | render mean ± std (s) | per view (ms) | random_scene (s) |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['render_best_s']:.3f} | {r['render_mean_s']:.3f} ± "
            f"{r['render_std_s']:.3f} | {r['per_view_ms']:.0f} | {r['random_scene_mean_s']:.3f} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "render_speed.md").write_text(text)
    (RESULTS / "render_speed.json").write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
