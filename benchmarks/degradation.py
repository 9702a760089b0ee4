"""Degradation curves: where SRDE stops being worth it, and whether fusion falls back in time.

Rendered hybrid scenes (textured room, one or two flat glossy objects, one light, the
paper's 3x3 array) are degraded along one axis at a time, and SRDE alone, the backbone
alone (the bundled stand-in network) and the fused map are scored against ground truth
on the objects:

* ``centre_noise_px`` -- Gaussian noise (std per coordinate, px) added to every detected
  highlight centre before the virtual light is triangulated (SRDE's default method, whose
  photometric refinement starts from those centres, and the geometric solve alone);
* ``image_noise_dn`` -- Gaussian noise (std, 8-bit grey levels) added to every view;
  the backbone sees the noisy views too;
* ``blur_sigma_px`` -- Gaussian blur of every view (sigma, px); the backbone sees it too;
* ``light_error_mm`` -- the light position SRDE is given is off by this distance, in a
  fixed random direction per scene (two directions);
* ``mask_offset_px`` -- the true object masks eroded (negative) or dilated (positive) by
  this radius before SRDE and fusion use them.

For every object: SRDE's status and its EPE over the true object mask, the backbone's EPE
there, the fused EPE there and whether fusion used SRDE. A *harmful* decision is fusion
using SRDE on an object where the fused map is worse than the backbone; a *missed* one is
fusion falling back although SRDE alone was better. Full-scene EPE is reported too,
since a dilated mask moves SRDE's plane onto the background.

Fusion's fallbacks were built against these curves. Before the photometric outline check,
the stricter ratios on weak SRDE evidence and the mask trim (outline ratios alone), on the
same 6 scenes: light error 800 mm 5/18 object-runs harmful (fused/backbone 0.948), 1600 mm
8/18 harmful (2.280); centre noise 8 px 2/18 harmful, 16 px 3/18; mask dilation 32/64 px
full-scene fused/backbone 1.020/1.204. Tried on the way: a photometric ring over every
inner-ring pixel (light 1600 mm 1 harmful, but eroded masks fell back: inside a glossy
object the shading follows the reflection, not the surface), over textured pixels only
(too few pixels: light 1600 mm 2 harmful, 1.12), and the stricter ratios alone. The trim
costs about 1 px of object EPE at 5-20 grey levels of image noise (noise makes the
object's interior look textured, and inside an unclipped highlight the backbone matches
the reflection better than SRDE's plane matches the surface); judging texture after a
sigma-1 blur fixed that but trimmed clean highlights' rims (0.5 px at no noise).

Run: ``python benchmarks/degradation.py [--scenes 6] [--seed 3000] [--scale 1.0]``;
writes ``benchmarks/results/degradation.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from srde_fusion.errors import SRDEError
from srde_fusion.evaluation import evaluate
from srde_fusion.fusion import DEFAULT_BORDER_CHECK, BorderCheck, fuse
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import default_rig, random_scene, render

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "degradation"

#: Levels of each degradation axis (the first is the undegraded case).
AXES = {
    "centre_noise_px": (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0),
    "image_noise_dn": (0.0, 5.0, 10.0, 20.0, 40.0),
    "blur_sigma_px": (0.0, 2.0, 4.0, 8.0, 16.0),
    "light_error_mm": (0.0, 10.0, 25.0, 50.0, 100.0, 200.0, 400.0, 800.0, 1600.0),
    "mask_offset_px": (-16, -8, -4, -2, 0, 2, 4, 8, 16, 32, 64),
}
#: What each axis means, for the tables.
AXIS_TITLES = {
    "centre_noise_px": "Highlight-centre noise (std per coordinate, px)",
    "image_noise_dn": "Image noise (std, 8-bit grey levels)",
    "blur_sigma_px": "Image blur (Gaussian sigma, px)",
    "light_error_mm": "Light-position error (mm)",
    "mask_offset_px": "Mask erosion (< 0) / dilation (> 0) (px)",
}
#: Repeats of the random perturbations (centre noise draws, light-error directions).
CENTRE_NOISE_REPEATS = 2
LIGHT_DIRECTIONS = 2
#: An SRDE EPE above this is called "no longer sub-pixel" in the summary, px.
SUBPIXEL_PX = 1.0
#: A stricter outline check, tried on the centre-noise and light axes: SRDE may put the
#: object at most 2x nearer than the top of what the backbone sees along its outline
#: (default 4x, 2x only when SRDE's own evidence is weak).
STRICT_CHECK = BorderCheck(min_front_ratio=0.5)
#: SRDE variants of the centre-noise axis: (name, SRDE refine option, outline check).
CENTRE_NOISE_VARIANTS = (
    ("default", None, DEFAULT_BORDER_CHECK),
    ("default, strict outline check", None, STRICT_CHECK),
    ("geometric", False, DEFAULT_BORDER_CHECK),
)
_MM = 1e-3
VARIANT_TITLES = {
    "default": "SRDE default, default outline check",
    "default, strict outline check": "SRDE default, stricter outline check "
                                     "(min_front_ratio 0.5 instead of 0.25)",
    "geometric": "SRDE geometric solve only (refine=False), default outline check",
}
#: Columns of the summary: threshold key -> header.
SUMMARY_COLUMNS = {
    "srde_not_subpixel": f"SRDE median EPE > {SUBPIXEL_PX:g} px",
    "srde_worse_than_backbone": "SRDE worse than the backbone on some object",
    "first_harmful": "first harmful fusion decision",
    "fused_worse_than_backbone": "fused worse than the backbone (mean over objects)",
    "full_scene_fused_worse": "fused worse than the backbone (full scene)",
}


class CentreNoiseSRDE(SRDE):
    """SRDE whose detected highlight centres get Gaussian noise before the solve."""

    def __init__(self, rig, *, noise_px: float, seed: int, **options) -> None:
        super().__init__(rig, **options)
        self.noise_px = float(noise_px)
        self._rng = np.random.default_rng(seed)

    def _solve_joint(self, views, mask, centers, detections, missing):
        noisy = centers + self._rng.normal(0.0, self.noise_px, centers.shape)  # NaN stays NaN
        return super()._solve_joint(views, mask, noisy, detections, missing)


@dataclass
class Capture:
    """One rendered scene and its clean backbone map."""

    seed: int
    rig: object
    views: list
    gt: np.ndarray
    truth: list
    backbone: np.ndarray


def add_noise(views: list, std_dn: float, seed: int) -> list:
    if std_dn == 0:
        return views
    rng = np.random.default_rng(seed)
    return [np.clip(np.rint(v + rng.normal(0.0, std_dn, v.shape)), 0, 255).astype(np.uint8)
            for v in views]


def blur(views: list, sigma_px: float) -> list:
    if sigma_px == 0:
        return views
    return [cv2.GaussianBlur(v, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT) for v in views]


def offset_mask(mask: np.ndarray, offset_px: int) -> np.ndarray:
    if offset_px == 0:
        return mask
    r = abs(int(offset_px))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    op = cv2.dilate if offset_px > 0 else cv2.erode
    return op(mask.astype(np.uint8), kernel).astype(bool)


def _epe(pred: np.ndarray, gt: np.ndarray, region: np.ndarray) -> float:
    return float(evaluate(pred, gt, region)["epe"])


def score(cap: Capture, views: list, backbone: np.ndarray, masks: list, srde: SRDE, *,
          border_check: BorderCheck = DEFAULT_BORDER_CHECK) -> dict:
    """Fuse and score every object (over its true mask) and the full scene."""
    # Masks eroded away leave their object to the backbone: fuse refuses empty masks.
    kept = [k for k, m in enumerate(masks) if m.any()]
    result = fuse(backbone, views, cap.rig, [masks[k] for k in kept], srde if kept else None,
                  border_check=border_check)
    objects = []
    for k, truth in enumerate(cap.truth):
        report = result.objects[kept.index(k)] if k in kept else None
        srde_result = None if report is None else report.srde
        srde_ok = srde_result is not None and srde_result.ok
        objects.append({
            "srde_status": "mask eroded away" if report is None else srde_result.status,
            "used": bool(report is not None and report.used_srde),
            "epe_backbone": _epe(result.backbone_disparity, cap.gt, truth),
            "epe_srde": _epe(srde_result.disparity, cap.gt, truth) if srde_ok else math.nan,
            "coverage_srde": (float(np.mean(np.isfinite(srde_result.disparity[truth])))
                              if srde_ok else 0.0),
            "epe_fused": _epe(result.disparity, cap.gt, truth),
        })
    everywhere = np.ones(cap.gt.shape, dtype=bool)
    return {"objects": objects,
            "full_backbone": _epe(result.backbone_disparity, cap.gt, everywhere),
            "full_fused": _epe(result.disparity, cap.gt, everywhere)}


def run_axis(axis: str, level: float, caps: list, backbone_fn) -> list:
    out = []
    for cap in caps:
        rig, views, masks, bb = cap.rig, cap.views, cap.truth, cap.backbone
        if axis == "centre_noise_px":
            for rep in range(CENTRE_NOISE_REPEATS):
                for variant, refine, check in CENTRE_NOISE_VARIANTS:
                    # The same seed gives every variant the same noise draws.
                    srde = CentreNoiseSRDE(rig, noise_px=level, seed=cap.seed * 100 + rep,
                                           refine=refine)
                    out.append({"variant": variant,
                                **score(cap, views, bb, masks, srde, border_check=check)})
            continue
        if axis == "light_error_mm":
            rng = np.random.default_rng(cap.seed)
            for _ in range(LIGHT_DIRECTIONS):
                direction = rng.normal(size=3)
                direction /= np.linalg.norm(direction)
                light = rig.light + level * _MM * direction
                srde = SRDE(rig, light=light)
                for variant, check in (("default", DEFAULT_BORDER_CHECK),
                                       ("default, strict outline check", STRICT_CHECK)):
                    out.append({"variant": variant,
                                **score(cap, views, bb, masks, srde, border_check=check)})
            continue
        if axis == "mask_offset_px":
            masks = [offset_mask(m, int(level)) for m in masks]
        elif axis in ("image_noise_dn", "blur_sigma_px") and level != 0:
            views = (add_noise(views, level, cap.seed) if axis == "image_noise_dn"
                     else blur(views, level))
            bb = backbone_fn(*(views[j] for j in rig.stereo_pair))
        out.append(score(cap, views, bb, masks, SRDE(rig)))
    return out


def prepare(n_scenes: int, seed0: int, scale: float, backbone_fn) -> list:
    rig0 = default_rig()
    if scale != 1.0:
        rig0 = rig0.scaled(scale)
    caps = []
    for i in range(n_scenes):
        seed = seed0 + i
        scene = random_scene(seed, rig0, n_objects=1 + i % 2, background="textured")
        rig = rig0.with_light(scene.light.position_m)
        capture = render(scene, rig, noise_seed=seed)
        views = list(capture.views)
        bb = backbone_fn(*(views[j] for j in rig.stereo_pair))
        caps.append(Capture(seed, rig, views, capture.disparity_px, capture.object_masks, bb))
    return caps


# ----------------------------------------------------------------- summaries
def _mean_std(values) -> tuple[float, float]:
    v = np.array([x for x in values if np.isfinite(x)], dtype=np.float64)
    return (float(v.mean()), float(v.std())) if v.size else (math.nan, math.nan)


def _fmt(pair: tuple[float, float], digits: int = 3) -> str:
    mean, std = pair
    return "n/a" if not np.isfinite(mean) else f"{mean:.{digits}f} ± {std:.{digits}f}"


def summarize_level(runs: list) -> dict:
    objects = [o for r in runs for o in r["objects"]]
    n = len(objects)
    ok = [o for o in objects if np.isfinite(o["epe_srde"])]
    harmful = [o for o in objects if o["used"] and o["epe_fused"] > o["epe_backbone"]]
    missed = [o for o in objects if not o["used"] and np.isfinite(o["epe_srde"])
              and o["epe_srde"] < o["epe_backbone"]]
    srde_worse = [o for o in ok if o["epe_srde"] > o["epe_backbone"]]
    statuses: dict[str, int] = {}
    for o in objects:
        statuses[o["srde_status"]] = statuses.get(o["srde_status"], 0) + 1
    bb = _mean_std(o["epe_backbone"] for o in objects)
    fused = _mean_std(o["epe_fused"] for o in objects)
    return {
        "objects": n,
        "srde_ok": len(ok) / n,
        "srde_epe": _mean_std(o["epe_srde"] for o in ok),
        "srde_epe_median": float(np.median([o["epe_srde"] for o in ok])) if ok else math.nan,
        "srde_coverage": float(np.mean([o["coverage_srde"] for o in objects])),
        "backbone_epe": bb,
        "fused_epe": fused,
        "fused_over_backbone": fused[0] / bb[0],
        "used": float(np.mean([o["used"] for o in objects])),
        "harmful": len(harmful),
        "missed": len(missed),
        "srde_worse_than_backbone": len(srde_worse),
        "full_fused_over_backbone": float(np.mean([r["full_fused"] for r in runs])
                                          / np.mean([r["full_backbone"] for r in runs])),
        "statuses": statuses,
    }


def axis_table(axis: str, rows: dict) -> str:
    lines = [f"| {axis} | SRDE ok | SRDE EPE | SRDE median | backbone EPE | fused EPE | "
             "fused / backbone | SRDE used | harmful | missed | full scene fused / backbone |",
             "|" + "---|" * 11]
    for level, s in rows.items():
        lines.append(
            f"| {level:g} | {s['srde_ok']:.0%} | {_fmt(s['srde_epe'])} | "
            f"{s['srde_epe_median']:.3f} | {_fmt(s['backbone_epe'], 2)} | "
            f"{_fmt(s['fused_epe'])} | {s['fused_over_backbone']:.3f} | {s['used']:.0%} | "
            f"{s['harmful']} | {s['missed']} | {s['full_fused_over_backbone']:.3f} |")
    return "\n".join(lines) + "\n"


def statuses_line(rows: dict) -> str:
    parts = []
    for level, s in rows.items():
        failed = {k: v for k, v in s["statuses"].items() if k != "ok"}
        if failed:
            parts.append(f"{level:g}: " + ", ".join(f"{k} {v}" for k, v in sorted(failed.items())))
    return "SRDE failures by level: " + ("; ".join(parts) if parts else "none") + "."


def worth_it(axis: str, rows: dict) -> dict:
    """Where SRDE stops being sub-pixel, stops beating the backbone, and where fusion harms."""
    levels = list(rows)

    def first(pred):
        return next((lv for lv in levels if pred(rows[lv])), None)

    return {
        "srde_not_subpixel": first(lambda s: not (s["srde_epe_median"] <= SUBPIXEL_PX)),
        "srde_worse_than_backbone": first(lambda s: s["srde_worse_than_backbone"] > 0),
        "fused_worse_than_backbone": first(lambda s: s["fused_over_backbone"] > 1.0),
        "first_harmful": first(lambda s: s["harmful"] > 0),
        "first_fallback": first(lambda s: s["used"] < 1.0),
        "full_scene_fused_worse": first(lambda s: s["full_fused_over_backbone"] > 1.0),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--seed", type=int, default=3000)
    parser.add_argument("--scale", type=float, default=1.0,
                        help="image scale relative to 640x480")
    parser.add_argument("--axes", default=",".join(AXES))
    args = parser.parse_args()
    from srde_fusion.adapters import load_backbone

    started = time.time()
    backbone_fn = load_backbone("default")
    caps = prepare(args.scenes, args.seed, args.scale, backbone_fn)
    n_objects = sum(len(c.truth) for c in caps)
    print(f"prepared {len(caps)} scenes, {n_objects} objects in {time.time() - started:.0f} s",
          flush=True)
    w, h = caps[0].rig.image_size
    lines = ["# Degradation: where SRDE stops being worth it", "",
             f"{args.scenes} rendered hybrid scenes (seeds {args.seed}.."
             f"{args.seed + args.scenes - 1}), {n_objects} flat glossy objects, 3x3 array, "
             f"85 mm, {w}x{h}, textured room; "
             "backbone: the bundled stand-in network. EPE in px over each object's true mask, "
             "mean ± std over objects (SRDE EPE over the objects where SRDE succeeded; SRDE "
             "ok = that fraction). `fused / backbone` is the ratio of mean object EPEs; "
             "`SRDE used` = objects where fusion took SRDE's disparity; `harmful` = objects "
             "where fusion took SRDE and the fused EPE is above the backbone's; `missed` = "
             "objects where fusion fell back although SRDE alone was better; `full scene` = "
             "ratio of full-image EPEs.", ""]
    out: dict = {"scenes": args.scenes, "seed": args.seed, "image_size": [w, h],
                 "objects": n_objects, "axes": {}}
    summary = ["## Summary: first level at which ...", "",
               "| axis | SRDE variant | " + " | ".join(SUMMARY_COLUMNS.values()) + " |",
               "|" + "---|" * (len(SUMMARY_COLUMNS) + 2)]
    body: list[str] = []
    for axis in args.axes.split(","):
        if axis not in AXES:
            raise SRDEError(f"--axes: expected names from {list(AXES)}, got {axis!r}")
        t0 = time.time()
        variants: dict = {}
        for level in AXES[axis]:
            runs = run_axis(axis, level, caps, backbone_fn)
            for run in runs:
                variants.setdefault(run.pop("variant", "default"), {}).setdefault(
                    level, []).append(run)
        out["axes"][axis] = {}
        body += [f"## {AXIS_TITLES[axis]}", ""]
        for variant, per_level in variants.items():
            rows = {level: summarize_level(runs) for level, runs in per_level.items()}
            if len(variants) > 1:
                body += [f"### {VARIANT_TITLES[variant]}", ""]
            body += [axis_table(axis, rows), statuses_line(rows), ""]
            marks = worth_it(axis, rows)
            summary.append(f"| {axis} | {variant} | " + " | ".join(
                "not reached" if marks[key] is None else f"{marks[key]:g}"
                for key in SUMMARY_COLUMNS) + " |")
            out["axes"][axis][variant] = {"levels": {str(k): v for k, v in rows.items()},
                                          "thresholds": marks}
            print(f"{axis} [{variant}]: {marks}", flush=True)
        body += [f"({time.time() - t0:.0f} s)", ""]
    lines += [*summary, "", *body]
    lines += [f"Machine: {platform.processor() or platform.machine()}, "
              f"{platform.python_version()}; total {time.time() - started:.0f} s.", ""]
    out["seconds"] = time.time() - started
    text = "\n".join(lines)
    print(text)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    (RESULTS_DIR / f"{NAME}.md").write_text(text)
    (RESULTS_DIR / f"{NAME}.json").write_text(
        json.dumps(out, indent=1, default=float, allow_nan=True) + "\n")


if __name__ == "__main__":
    main()
