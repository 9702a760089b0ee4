"""Peak memory of fusion on a large image with many objects, without the backbone.

A procedural 4000x3000 scene for a 3x3 array: a textured background plane, 64 flat
grey objects on an 8x8 grid, each with the highlight of one light at the exact images of
its virtual light in every view; the backbone's disparity is given (the planes' exact
disparity), so no network runs. Each case runs in a fresh subprocess, which reports:

* ``peak RSS``: the process's peak resident memory (``ru_maxrss``), inputs included
  (9 views are 324 MB as uint8 RGB);
* ``inputs``: the bytes of the views, the disparity and the masks handed over;
* ``traced peak``: the peak of memory allocated *during* the call (``tracemalloc``,
  which sees numpy's and OpenCV-through-numpy allocations), inputs excluded;
* ``result``: what the returned ``FusionResult`` keeps beyond the fused maps.

Cases: ``postprocess`` with a label image (what ``fuse --mask`` does) and ``fuse`` with a
list of 64 full-image masks (the caller's own list, counted in the inputs).

Run: ``python benchmarks/fuse_memory.py [--size 4000 3000] [--objects 64]``. Writes
``benchmarks/results/fuse_memory.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np

from srde_fusion.fusion import fuse, postprocess
from srde_fusion.geometry import CameraRig, Plane, plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import highlight_normal

RESULTS = Path(__file__).resolve().parent / "results"
TARGET_BYTES = 2 * 1024**3
LIGHT_M = np.array([0.3, -0.4, 0.0])
BACKGROUND_DEPTH_M = 5.0
OBJECT_DEPTH_M = (1.6, 2.4)
HIGHLIGHT_SIGMA_PX = 4.0
HIGHLIGHT_PEAK = 600.0   # grey levels before clipping: a clipped core, as on a camera
CASES = ("postprocess, label image", "fuse, list of full masks")


def make_scene(size: tuple[int, int], n_objects: int, seed: int = 0):
    """Views (9 x (H, W, 3) uint8), disparity (H, W) float32, labels (H, W) uint8, rig."""
    w, h = size
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=0.9 * w, image_size=(w, h),
                         light_position_m=LIGHT_M)
    rng = np.random.default_rng(seed)
    fx, base = rig.intrinsics.fx, rig.baseline_m
    bg_shift = fx * base / BACKGROUND_DEPTH_M
    pad = int(np.ceil(bg_shift)) + 2
    texture = cv2.GaussianBlur(rng.integers(0, 256, (h + 2 * pad, w + 2 * pad), np.uint8),
                               (0, 0), 1.5)
    offsets = (rig.centers_m - rig.reference_center_m)[:, :2] / base
    views = []
    for du, dv in offsets:
        # The background plane moves by its disparity along each camera's baseline.
        u0, v0 = pad + int(round(du * bg_shift)), pad + int(round(dv * bg_shift))
        grey = texture[v0:v0 + h, u0:u0 + w]
        views.append(np.repeat(grey[:, :, None], 3, axis=2))
    disparity = np.full((h, w), bg_shift, np.float32)
    labels = np.zeros((h, w), np.uint8)
    side = int(np.ceil(np.sqrt(n_objects)))
    cell_w, cell_h = w // side, h // side
    for k in range(n_objects):
        r, c = divmod(k, side)
        bw, bh = int(cell_w * 0.6), int(cell_h * 0.6)
        u0 = c * cell_w + (cell_w - bw) // 2
        v0 = r * cell_h + (cell_h - bh) // 2
        centre_uv = np.array([u0 + bw / 2, v0 + bh / 2])
        depth = rng.uniform(*OBJECT_DEPTH_M)
        point = rig.backproject(centre_uv, depth)
        normal = highlight_normal(point, LIGHT_M, rig.reference_center_m)
        plane = Plane.from_point_normal(point, normal, rig.reference_center_m)
        box = (u0, v0, u0 + bw, v0 + bh)
        disparity[v0:v0 + bh, u0:u0 + bw] = plane_disparity(plane, rig, window=box)
        labels[v0:v0 + bh, u0:u0 + bw] = k + 1
        virtual = plane.mirror(LIGHT_M)
        d_centre = fx * base / depth
        level = int(rng.integers(40, 90))
        for j, view in enumerate(views):
            # The object moves by its own disparity; its highlight is the virtual light's image.
            su = u0 - int(round(offsets[j, 0] * d_centre))
            sv = v0 - int(round(offsets[j, 1] * d_centre))
            view[max(sv, 0):sv + bh, max(su, 0):su + bw] = level
            hu, hv = rig.project(virtual, j)
            r_px = int(4 * HIGHLIGHT_SIGMA_PX)
            a0, b0 = max(int(hu) - r_px, 0), max(int(hv) - r_px, 0)
            a1, b1 = min(int(hu) + r_px + 1, w), min(int(hv) + r_px + 1, h)
            vv, uu = np.mgrid[b0:b1, a0:a1]
            blob = HIGHLIGHT_PEAK * np.exp(-((uu - hu) ** 2 + (vv - hv) ** 2)
                                           / (2 * HIGHLIGHT_SIGMA_PX ** 2))
            patch = view[b0:b1, a0:a1].astype(np.float64) + blob[:, :, None]
            view[b0:b1, a0:a1] = np.clip(patch, 0, 255).astype(np.uint8)
    return views, disparity, labels, rig


def _kept_bytes(result) -> int:
    """Bytes of the arrays the result keeps per object (disparity boxes)."""
    total = 0
    for obj in result.objects:
        for holder in (obj.estimate, obj.srde):
            array = getattr(holder, "disparity_box", None)
            total += 0 if array is None else array.nbytes
    return total


def child(case: str, size: tuple[int, int], n_objects: int) -> dict:
    """Run one case in this process and measure it."""
    views, disparity, labels, rig = make_scene(size, n_objects)
    masks = labels
    if case == CASES[1]:
        masks = [labels == k for k in range(1, n_objects + 1)]
    inputs = (sum(v.nbytes for v in views) + disparity.nbytes
              + (labels.nbytes if case == CASES[0] else sum(m.nbytes for m in masks)))
    del labels
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    tracemalloc.start()
    start = time.perf_counter()
    if case == CASES[0]:
        result = postprocess(disparity, views, rig, masks)
    else:
        result = fuse(disparity, views, rig, masks, SRDE(rig))
    seconds = time.perf_counter() - start
    traced_now, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    statuses = [o.status for o in result.objects]
    return dict(case=case, width=size[0], height=size[1], views=rig.n_cameras,
                objects=len(result.objects), srde=statuses.count("srde"),
                fallback=statuses.count("fallback"), seconds=seconds, inputs_bytes=inputs,
                rss_before_bytes=rss_before, peak_rss_bytes=peak_rss,
                traced_peak_bytes=traced_peak, traced_after_bytes=traced_now,
                per_object_result_bytes=_kept_bytes(result))


def _gb(n: float) -> str:
    return f"{n / 1024**3:.2f} GB"


def _mb(n: float) -> str:
    return f"{n / 1024**2:.1f} MB"


def to_markdown(rows: list[dict]) -> str:
    w, h = rows[0]["width"], rows[0]["height"]
    lines = ["# Fusion peak memory", "",
             f"{w}x{h}, {rows[0]['views']} views, {rows[0]['objects']} objects, the backbone's "
             "disparity given (no network). Each case in a fresh process; target: peak "
             f"RSS <= {_gb(TARGET_BYTES)}.", "",
             "| case | peak RSS | inputs | traced peak during the call | kept per object "
             "(all objects) | SRDE / fallback | time |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['case']} | {_gb(r['peak_rss_bytes'])} | {_mb(r['inputs_bytes'])} | "
                     f"{_mb(r['traced_peak_bytes'])} | {_mb(r['per_object_result_bytes'])} | "
                     f"{r['srde']} / {r['fallback']} | {r['seconds']:.1f} s |")
    ok = all(r["peak_rss_bytes"] <= TARGET_BYTES for r in rows)
    lines += ["", f"Target met: {'yes' if ok else 'NO'}. Peak RSS includes the inputs and the "
              "interpreter with numpy, OpenCV and scipy loaded; the traced peak is what the call "
              "itself allocated at most at one time."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, nargs=2, default=(4000, 3000), metavar=("W", "H"))
    parser.add_argument("--objects", type=int, default=64)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--child", choices=CASES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    size = (args.size[0], args.size[1])
    if args.child:
        print(json.dumps(child(args.child, size, args.objects)))
        return
    rows = []
    for case in CASES:
        done = subprocess.run(
            [sys.executable, __file__, "--child", case, "--size", *map(str, size),
             "--objects", str(args.objects)], capture_output=True, text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{case}: peak RSS {_gb(r['peak_rss_bytes'])}, traced peak "
              f"{_mb(r['traced_peak_bytes'])}, {r['srde']} srde / {r['fallback']} fallback, "
              f"{r['seconds']:.1f} s", flush=True)
    text = to_markdown(rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fuse_memory.md").write_text(text)
    (args.out / "fuse_memory.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
