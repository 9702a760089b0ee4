"""Speed of SRDE on the paper's 3 x 3 array, against the cost of reading the images.

For 9 views at 640 x 480 and at 1280 x 960 (rendered scenes, textured background, one
glossy object), per frame:

* floor: one streaming pass over the images, every view to linear luminance once
  (``srde_fusion.imaging.luminance``) - what any method that looks at the pixels pays;
* SRDE (numpy/OpenCV): detection in all views, triangulation, the disparity map, with
  the photometric refinement off (``refine=False``);
* SRDE (torch, CPU): the same with ``BatchedSRDE`` (``srde_fusion.srde.batched``);
* the photometric refinement that SRDE's default mode adds (``refine_plane``), alone;
* the stand-in backbone (``load_backbone("default")`` on the stereo pair);
* SRDE + fusion (``fuse`` with the backbone's map), geometric and with the refinement,
  as a fraction of the backbone's time.

Medians over scenes x repeats (each after a warm-up call); ratios are ratios of
medians. Writes ``benchmarks/results/speed.md`` and ``.json``.

    python benchmarks/speed.py [--scenes 5] [--repeats 5] [--backbone-repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from srde_fusion.adapters import load_backbone

from srde_fusion.errors import BackboneError
from srde_fusion.fusion import fuse
from srde_fusion.imaging import luminance
from srde_fusion.srde import SRDE, BatchedSRDE, refine_plane
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS = Path(__file__).resolve().parent / "results"
NAME = "speed"
#: Image sizes measured, as scale factors of the paper's 640 x 480 array.
SCALES = (1.0, 2.0)
#: Targets of the fast path (640 x 480): SRDE within this many floors ...
FLOOR_TARGET = 5.0
#: ... and SRDE + fusion within this fraction of the backbone's time.
BACKBONE_TARGET = 0.05
#: torch intra-op threads for the torch path: on a shared machine, more threads than
#: free cores make torch's CPU kernels wait on each other.
TORCH_THREADS = 1


def _times(fn, repeats: int) -> list[float]:
    fn()  # warm-up: first-call allocations, lazy imports, kernel selection
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def _backbone():
    """The bundled stand-in; if its weights are missing, an untrained one of its size.

    The time of a network does not depend on its weights, only on its architecture.
    """
    try:
        return load_backbone("default"), "bundled stand-in (adapters/standin/weights/standin.onnx)"
    except BackboneError:
        from srde_fusion.adapters import build_standin, export_standin_onnx

        path = Path(tempfile.mkdtemp()) / "standin.onnx"
        export_standin_onnx(build_standin("default"), path)
        return load_backbone(path, "igev"), "stand-in architecture, untrained weights"


def _stats(samples: list[float]) -> dict[str, float]:
    ms = [1000.0 * s for s in samples]
    return {"median_ms": statistics.median(ms), "mean_ms": statistics.fmean(ms),
            "std_ms": statistics.pstdev(ms), "n": len(ms)}


def _measure_scene(samples: dict[str, list[float]], rig, seed: int, backbone, *, repeats: int,
                   backbone_repeats: int) -> bool:
    """Time one rendered scene into ``samples``; whether SRDE succeeded on it."""
    scene = random_scene(seed, rig, background="textured")
    out = render(scene, rig)
    views, masks = list(out.views), out.object_masks
    mask = masks[0]
    light = scene.light.position_m
    lit = rig.with_light(light)
    numpy_srde = SRDE(lit, refine=False)
    torch_srde = BatchedSRDE(lit, refine=False, device="cpu")
    default_srde = SRDE(lit)
    samples["floor"] += _times(lambda: [luminance(v, rig.image_encoding) for v in views],
                               repeats)
    samples["srde_numpy"] += _times(lambda: numpy_srde.estimate(views, mask), repeats)
    samples["srde_torch"] += _times(lambda: torch_srde.estimate(views, mask), repeats)
    result = numpy_srde.estimate(views, mask)
    if result.ok:
        centers = np.where(result.used_views[:, None], result.highlight_centers, np.nan)
        samples["refinement"] += _times(
            lambda: refine_plane(views, lit, light, mask, result.plane, centers_uv=centers),
            repeats)
    left, right = (views[i] for i in rig.stereo_pair)
    if not samples["backbone"]:  # its time hardly depends on the scene
        samples["backbone"] += _times(lambda: backbone(left, right), backbone_repeats)
    backbone_disparity = backbone(left, right)
    samples["fusion"] += _times(lambda: fuse(backbone_disparity, views, lit, masks, numpy_srde),
                                repeats)
    samples["fusion_refined"] += _times(
        lambda: fuse(backbone_disparity, views, lit, masks, default_srde), repeats)
    return result.ok


def measure(scale: float, backbone, *, scenes: int, repeats: int, backbone_repeats: int
            ) -> dict:
    rig = default_rig() if scale == 1.0 else default_rig().scaled(scale)
    samples: dict[str, list[float]] = {k: [] for k in (
        "floor", "srde_numpy", "srde_torch", "refinement", "backbone", "fusion",
        "fusion_refined")}
    ok = sum(_measure_scene(samples, rig, seed, backbone, repeats=repeats,
                            backbone_repeats=backbone_repeats) for seed in range(scenes))
    stats = {k: _stats(v) for k, v in samples.items() if v}
    med = {k: v["median_ms"] for k, v in stats.items()}
    return {
        "size": f"{rig.width}x{rig.height}", "views": rig.n_cameras, "scenes": scenes,
        "srde_ok": ok, "repeats": repeats, "stats": stats,
        "srde_numpy_per_floor": med["srde_numpy"] / med["floor"],
        "srde_torch_per_floor": med["srde_torch"] / med["floor"],
        "fusion_share_of_backbone": med["fusion"] / med["backbone"],
        "fusion_refined_share_of_backbone": med["fusion_refined"] / med["backbone"],
    }


def to_markdown(rows: list[dict], context: dict) -> str:
    lines = [
        "# SRDE speed: 9 views, against the cost of reading them and against the backbone",
        "",
        f"{context['cpus']} CPU(s), {context['processor']}, numpy {context['numpy']}, OpenCV "
        f"{context['opencv']} ({context['cv2_threads']} threads), torch {context['torch']} "
        f"({TORCH_THREADS} thread for the torch path); backbone: {context['backbone']}, "
        f"onnxruntime default threads. 1-min load average {context['load_before']:.1f} "
        f"before, {context['load_after']:.1f} after: the machine is shared, so wall times "
        "include waiting for a core.",
        "",
        "Per frame, medians over scenes x repeats (ms); ratios are ratios of medians. "
        "Floor = every view to linear luminance once. SRDE = highlight detection in all "
        "views, triangulation, disparity map (photometric refinement off).",
        "",
        "| size | floor | SRDE numpy | x floor | SRDE torch (CPU) | x floor | refinement | "
        "backbone | SRDE + fusion | % of backbone | with refinement | % of backbone |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        m = {k: v["median_ms"] for k, v in r["stats"].items()}
        refinement = f"{m['refinement']:.1f}" if "refinement" in m else "n/a"
        lines.append(
            f"| {r['size']} | {m['floor']:.1f} | {m['srde_numpy']:.1f} | "
            f"{r['srde_numpy_per_floor']:.2f} | {m['srde_torch']:.1f} | "
            f"{r['srde_torch_per_floor']:.2f} | {refinement} | {m['backbone']:.0f} | "
            f"{m['fusion']:.1f} | {100 * r['fusion_share_of_backbone']:.2f} % | "
            f"{m['fusion_refined']:.1f} | {100 * r['fusion_refined_share_of_backbone']:.2f} % |")
    lines += ["", "Spread (mean ± std, ms; n samples):", "",
              "| size | quantity | mean ± std | n |", "|---|---|---:|---:|"]
    names = {"floor": "floor (luminance of 9 views)", "srde_numpy": "SRDE numpy",
             "srde_torch": "SRDE torch (CPU)", "refinement": "photometric refinement",
             "backbone": "backbone (stereo pair)", "fusion": "SRDE + fusion",
             "fusion_refined": "SRDE + refinement + fusion"}
    for r in rows:
        for key, label in names.items():
            if key in r["stats"]:
                s = r["stats"][key]
                lines.append(f"| {r['size']} | {label} | {s['mean_ms']:.1f} ± {s['std_ms']:.1f} | "
                             f"{s['n']} |")
    first = rows[0]
    lines += [
        "",
        f"Targets at {first['size']}: SRDE within {FLOOR_TARGET:g}x the floor: "
        f"{first['srde_numpy_per_floor']:.2f}x ("
        f"{'met' if first['srde_numpy_per_floor'] <= FLOOR_TARGET else 'NOT met'}); "
        f"SRDE + fusion within {100 * BACKBONE_TARGET:g} % of the backbone: "
        f"{100 * first['fusion_share_of_backbone']:.2f} % ("
        f"{'met' if first['fusion_share_of_backbone'] <= BACKBONE_TARGET else 'NOT met'}); "
        f"with SRDE's default photometric refinement "
        f"{100 * first['fusion_refined_share_of_backbone']:.2f} %.",
        f"SRDE's default mode calls the photometric refinement: {context['srde_refines']}. "
        f"SRDE succeeded on {', '.join(str(r['srde_ok']) + '/' + str(r['scenes']) for r in rows)} "
        "scenes (the refinement is timed on those).",
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=5, help="rendered scenes per size")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per scene")
    parser.add_argument("--backbone-repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(TORCH_THREADS)
    load_before = os.getloadavg()[0]
    backbone, backbone_name = _backbone()
    rows = [measure(s, backbone, scenes=args.scenes, repeats=args.repeats,
                    backbone_repeats=args.backbone_repeats) for s in SCALES]
    context = {
        "cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
        "numpy": np.__version__, "opencv": cv2.__version__, "cv2_threads": cv2.getNumThreads(),
        "torch": torch.__version__.split("+")[0], "backbone": backbone_name,
        "load_before": load_before, "load_after": os.getloadavg()[0],
        "srde_refines": bool(getattr(SRDE(default_rig(), light=[0.1, -0.4, 0.2]), "refine",
                                     False)),
    }
    text = to_markdown(rows, context)
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{NAME}.md").write_text(text)
    (RESULTS / f"{NAME}.json").write_text(json.dumps({"context": context, "rows": rows},
                                                     indent=2) + "\n")


if __name__ == "__main__":
    main()
