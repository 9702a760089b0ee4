"""Calibrating several lights at once: accuracy per light, honesty of its uncertainty.

Rendered captures of an A3 ArUco plate (``srde_fusion.synthetic.plate_scene`` with several
lights), 3x3 array (85 mm, 640x480, fx 600), three plate poses per calibration, tilted at
random, the plates 0.9-1.1 m away. Per trial the lights are drawn at random: the first
about 0.5 m beside and above the array, the others 12-20 cm from it and from each other,
mostly side by side (so that their highlights share the plate's free centre). Each
calibration runs the full pipeline (``estimate_lights``: markers, every highlight,
sorting by geometry, one solve per light), once told the number of lights and once
counting them; lamps 4-8 cm apart ('close', whose highlights merge on the plate) also
each from the same plate poses lit by it alone, the others switched off
(``estimate_light``, as ``calibrate_light_files(light=K)`` runs it); all with the
renderer's own model and with ``Physics.faithful()`` (exact
Fresnel, the light integrated over its 3 mm radius, height-correlated masking, diffuse
transmittance, photon and read noise).

Reported per number of lights and physics: calibrations that ran, that were refused (a
reasoned error: ambiguity, too few views), and that went wrong (an estimate more than
10 mm from every true light, or two estimates on one light: a wrong assignment); each
light's error in mm; how often the true light lies within the reported 1/2/3-sigma
ellipsoids (the regions a 3D Gaussian falls in with probability 68.3 / 95.4 / 99.7 %);
and the single-light calibration (``estimate_light``) on the same kind of captures.

Downstream: what the calibrated lights cost SRDE. For the several-light benchmark's
object scenes (``random_scene`` with k lights, seeds 12000 + 100 k + i, faithful physics),
the same lamps are calibrated from three plate captures, from the rays alone
(``photometric=False``) and read from the highlights' images (the default for up to
``MAX_IMAGE_READ_LIGHTS`` lamps; the limit is lifted here for three, to show why it is
there), and SRDE, told of each calibration's lights, is scored on the object (masked EPE)
beside SRDE told of the true lights.

Run: ``python benchmarks/light_calibration_multi.py [--trials 8] [--downstream 40] [--quick]``.
Writes ``benchmarks/results/light_calibration_multi.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from multi_light import masked_epe  # (run from this folder)
from scipy.stats import chi2

from srde_fusion.calibration import Board, estimate_light, estimate_lights
from srde_fusion.calibration import captures as calibration_captures
from srde_fusion.errors import SRDEError
from srde_fusion.geometry import CameraRig
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import (
    Physics,
    RandomSceneConfig,
    default_rig,
    highlight_normal,
    plate_scene,
    random_scene,
    render,
)

RESULTS = Path(__file__).resolve().parent / "results"
SUPERSAMPLE = 2
PLATE_SIZE_M = (0.42, 0.297)
CAPTURES = 3
LIGHT_RADIUS_M = 0.003
#: An estimate farther than this from every true light is a wrong calibration.
WRONG_M = 0.01
SIGMA_RADII = tuple(float(np.sqrt(chi2.ppf(p, 3))) for p in (0.6827, 0.9545, 0.9973))


#: Lamp layouts: the range of distances between neighbouring lamps, metres.
LAYOUTS = {"spread": (0.12, 0.2), "close": (0.04, 0.08)}


def draw_lights(rng: np.random.Generator, k: int, spacing_m=LAYOUTS["spread"]) -> np.ndarray:
    first = np.array([rng.uniform(0.05, 0.25), rng.uniform(-0.42, -0.3), rng.uniform(0.0, 0.1)])
    lights = [first]
    while len(lights) < k:
        side = rng.choice([-1.0, 1.0])
        step = np.array([side * rng.uniform(*spacing_m), rng.uniform(-0.04, 0.04),
                         rng.uniform(-0.04, 0.04)])
        cand = lights[rng.integers(len(lights))] + step
        if min(np.linalg.norm(cand - p) for p in lights) >= spacing_m[0]:
            lights.append(cand)
    return np.array(lights)


def captures(rng, rig, board, lights_m, physics, alone: bool = False):
    """Render ``CAPTURES`` random plate poses lit by every lamp.

    ``alone``: also render each pose lit by each lamp alone (the others switched off),
    and return ``(views, alone_views)`` with ``alone_views[k]`` lamp k's captures.
    """
    views = []
    alone_views: list[list] = [[] for _ in lights_m]
    for _ in range(CAPTURES):
        center = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.06, 0.06),
                           rng.uniform(0.9, 1.1)])
        aim = center + [rng.uniform(-0.03, 0.03), rng.uniform(-0.015, 0.015), 0.0]
        pose = dict(center_m=center, normal=highlight_normal(aim, lights_m.mean(axis=0),
                                                             rig.reference_center_m),
                    rotation_rad=rng.uniform(-0.15, 0.15), light_radius_m=LIGHT_RADIUS_M)
        noise_seed = int(rng.integers(1 << 30))
        views.append(render(plate_scene(board, rig, lights_m, **pose), rig,
                            supersample=SUPERSAMPLE, physics=physics,
                            noise_seed=noise_seed).views)
        for k in range(len(lights_m) if alone else 0):
            alone_views[k].append(render(plate_scene(board, rig, lights_m[k], **pose), rig,
                                         supersample=SUPERSAMPLE, physics=physics,
                                         noise_seed=noise_seed + 1 + k).views)
    return (views, alone_views) if alone else views


def score(estimates, truth) -> dict:
    """Per-estimate error and Mahalanobis distance to its nearest true light."""
    rows, taken = [], []
    for est in estimates:
        d = np.linalg.norm(truth - est.position_m, axis=1)
        k = int(np.argmin(d))
        taken.append(k)
        rows.append(dict(light=k, error_m=float(d[k]),
                         sigma_m=float(np.sqrt(np.trace(est.position_cov_m2))),
                         mahalanobis=est.sigma_distance(truth[k]), n_rays=est.n_rays))
    wrong = len(set(taken)) != len(taken) or any(r["error_m"] > WRONG_M for r in rows)
    return dict(lights=rows, wrong=bool(wrong))


def run(trials: int, plan) -> list[dict]:
    """``plan``: (physics, layout, number of lights) triples to run ``trials`` times each."""
    rig = default_rig()
    board = Board.corner_layout(plate_size_m=PLATE_SIZE_M)
    out = []
    for physics_name, layout, k in plan:
        physics = Physics.faithful() if physics_name == "faithful" else None
        for trial in range(trials):
            seed = [k, trial, 17] if layout == "spread" else [k, trial, 17, 1]
            rng = np.random.default_rng(seed)
            truth = draw_lights(rng, k, LAYOUTS[layout])
            modes = ("given", "counted") if k > 1 else ("single",)
            if layout == "close":
                modes += ("each alone",)
                views, alone_views = captures(rng, rig, board, truth, physics, alone=True)
            else:
                views = captures(rng, rig, board, truth, physics)
            for mode in modes:
                t0 = time.perf_counter()
                rec = dict(physics=physics_name, layout=layout, n_lights=k, trial=trial,
                           mode=mode, truth_m=truth.tolist())
                try:
                    if mode == "single":
                        estimates = (estimate_light(views, rig, board),)
                    elif mode == "each alone":
                        # Each lamp from the captures it lights alone, the others off
                        # (calibrate_light_files(light=K) / calibrate-light --light K).
                        estimates = tuple(estimate_light(alone_views[j], rig, board)
                                          for j in range(k))
                    else:
                        found = estimate_lights(views, rig, board,
                                                n_lights=k if mode == "given" else None)
                        estimates = found.lights
                    rec.update(status="ok", **score(estimates, truth))
                    if len(estimates) != k:
                        # Counting returned lights that are not the lamps: as wrong as a
                        # wrong assignment (merged highlights read as one lamp between).
                        rec.update(status="miscounted", wrong=True,
                                   reason=f"counted {len(estimates)} lights, not {k}")
                except SRDEError as exc:
                    rec.update(status="refused", reason=str(exc)[:300], wrong=False,
                               lights=[])
                rec["seconds"] = time.perf_counter() - t0
                out.append(rec)
                errs = ", ".join(f"{r['error_m'] * 1e3:.2f} mm ({r['mahalanobis']:.1f} s)"
                                 for r in rec["lights"])
                print(f"{physics_name:8s} {layout:6s} {k} lights {mode:7s} trial {trial}: "
                      f"{rec['status']}{' WRONG' if rec['wrong'] else ''} {errs}"
                      f"{' ' + rec.get('reason', '') if rec['status'] != 'ok' else ''}",
                      flush=True)
    return out


def downstream(k: int, n_scenes: int) -> list[dict]:
    """SRDE's masked EPE on k-light object scenes with true, rays' and images' lights."""
    rig = default_rig()
    board = Board.corner_layout(plate_size_m=PLATE_SIZE_M)
    physics = Physics.faithful()
    out = []
    for i in range(n_scenes):
        seed = 12000 + 100 * k + i
        scene = random_scene(seed, rig, config=RandomSceneConfig(n_lights=k))
        truth = np.array([light.position_m for light in scene.lights])
        rendering = render(scene, rig, physics=physics, supersample=SUPERSAMPLE)
        views = captures(np.random.default_rng([seed, 5]), rig, board, truth, physics)
        rec = dict(n_lights=k, seed=seed)
        try:
            lights = {"true": truth,
                      "rays": estimate_lights(views, rig, board, n_lights=k,
                                              photometric=False).positions_m,
                      "images": images_read(views, rig, board, k)}
        except SRDEError as exc:
            rec.update(status="refused", reason=str(exc)[:200])
            out.append(rec)
            print(f"downstream {k} lights seed {seed}: refused {rec['reason']}", flush=True)
            continue
        mask = rendering.object_masks[0]
        for name, positions in lights.items():
            # Worst light's error: each true light to its nearest estimate.
            gaps = np.linalg.norm(truth[:, None] - positions[None], axis=2).min(axis=1)
            result = SRDE(rig.with_lights(positions)).estimate(rendering.views, mask)
            rec[name] = dict(worst_light_mm=float(gaps.max() * 1e3),
                             epe_px=masked_epe(result, rig, rendering, mask))
        rec["status"] = ("wrong" if max(rec[n]["worst_light_mm"] for n in ("rays", "images"))
                         > WRONG_M * 1e3 else "ok")
        out.append(rec)
        print(f"downstream {k} lights seed {seed}: " + ", ".join(
            f"{n} {rec[n]['worst_light_mm']:.2f} mm {rec[n]['epe_px']:.4f} px"
            for n in lights), flush=True)
    return out


def images_read(views, rig: CameraRig, board: Board, k: int) -> np.ndarray:
    """The lights read from the highlights' images, past the default limit if need be."""
    limit = calibration_captures.MAX_IMAGE_READ_LIGHTS
    calibration_captures.MAX_IMAGE_READ_LIGHTS = max(limit, k)
    try:
        return estimate_lights(views, rig, board, n_lights=k).positions_m
    finally:
        calibration_captures.MAX_IMAGE_READ_LIGHTS = limit


def downstream_rows(records: list[dict]) -> list[str]:
    lines = ["| lights | scenes | calibrated | wrong calibrations | solved with all three | "
             "EPE true lights (mean / median px) | EPE rays' lights | EPE images' lights | "
             "images better than rays | worst light off, rays / images (mean mm) | default |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for k in sorted({r["n_lights"] for r in records}):
        recs = [r for r in records if r["n_lights"] == k]
        ok = [r for r in recs if r["status"] == "ok"]
        both = [r for r in ok if all(np.isfinite(r[n]["epe_px"])
                                     for n in ("true", "rays", "images"))]

        def stat(name, rows=both):
            e = np.array([r[name]["epe_px"] for r in rows])
            return f"{e.mean():.4f} / {np.median(e):.4f}" if len(e) else "-"
        better = sum(r["images"]["epe_px"] < r["rays"]["epe_px"] for r in both)
        off = (f"{np.mean([r['rays']['worst_light_mm'] for r in ok]):.2f} / "
               f"{np.mean([r['images']['worst_light_mm'] for r in ok]):.2f}" if ok else "-")
        default = "images" if k <= calibration_captures.MAX_IMAGE_READ_LIGHTS else "rays"
        lines.append(f"| {k} | {len(recs)} | {sum(r['status'] != 'refused' for r in recs)} | "
                     f"{sum(r['status'] == 'wrong' for r in recs)} | {len(both)} | "
                     f"{stat('true')} | {stat('rays')} | {stat('images')} | "
                     f"{better} of {len(both)} | {off} | {default} |")
    return lines


def summarise(records: list[dict]) -> list[dict]:
    rows = []
    keys = sorted({(r["physics"], r["layout"], r["n_lights"], r["mode"]) for r in records},
                  key=lambda t: (t[0], -len(t[1]), t[2], t[3]))
    for physics, layout, k, mode in keys:
        recs = [r for r in records if (r["physics"], r["layout"], r["n_lights"], r["mode"]) ==
                (physics, layout, k, mode)]
        lights = [light for r in recs if r["status"] == "ok" and not r["wrong"]
                  for light in r["lights"]]
        err = np.array([light["error_m"] for light in lights]) * 1e3
        maha = np.array([light["mahalanobis"] for light in lights])
        ratio = np.array([light["error_m"] / light["sigma_m"] for light in lights])
        row = dict(physics=physics, layout=layout, n_lights=k, mode=mode,
                   calibrations=len(recs),
                   ok=sum(r["status"] == "ok" and not r["wrong"] for r in recs),
                   refused=sum(r["status"] == "refused" for r in recs),
                   wrong=sum(bool(r["wrong"]) for r in recs), lights=len(lights),
                   seconds=float(np.mean([r["seconds"] for r in recs])))
        if lights:
            row.update(mean_mm=float(err.mean()), median_mm=float(np.median(err)),
                       max_mm=float(err.max()), median_ratio=float(np.median(ratio)),
                       **{f"within_{s}sigma": float(np.mean(maha <= rad))
                          for s, rad in zip((1, 2, 3), SIGMA_RADII, strict=True)})
        rows.append(row)
    return rows


def write(rows: list[dict], records: list[dict], args, far: list[dict]) -> None:
    RESULTS.mkdir(exist_ok=True)
    lines = [
        "# Light calibration with several lights",
        "",
        f"3x3 array, A3 plate, {CAPTURES} random plate poses per calibration at 0.9-1.1 m, "
        f"{SUPERSAMPLE}x{SUPERSAMPLE} supersampling, lights of {LIGHT_RADIUS_M * 1e3:g} mm "
        "radius, 12-20 cm apart ('spread') or 4-8 cm apart ('close'); "
        f"`python benchmarks/light_calibration_multi.py --trials {args.trials}`. 'given': "
        "told the number of lights; 'counted': it counts them; 'single': `estimate_light` "
        "with one light; 'each alone': every lamp calibrated from the same plate poses lit "
        "by it alone, the others switched off (`estimate_light`, as "
        "`calibrate_light_files(light=K)` / `calibrate-light --light K` run it). Errors per "
        "light; sigma = "
        "sqrt(trace C) of the reported covariance; 'within k sigma': the true light inside "
        "the reported k-sigma ellipsoid (68.3 / 95.4 / 99.7 % for an honest Gaussian). "
        "'wrong': an estimate > 10 mm from every true light, two on one light, or a count "
        "that is not the number of lamps; errors and sigmas are over the calibrations that "
        "were neither refused nor wrong.",
        "",
        "| physics | layout | lights | mode | calibrations | ok | refused | wrong | mean mm | "
        "median mm | max mm | median err/sigma | within 1 sigma | within 2 sigma | "
        "within 3 sigma | s per calibration |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "mean_mm" in r:
            stats = (f"{r['mean_mm']:.2f} | {r['median_mm']:.2f} | {r['max_mm']:.2f} | "
                     f"{r['median_ratio']:.2f} | {r['within_1sigma']:.0%} | "
                     f"{r['within_2sigma']:.0%} | {r['within_3sigma']:.0%}")
        else:
            stats = " | ".join(["-"] * 7)
        lines.append(f"| {r['physics']} | {r['layout']} | {r['n_lights']} | {r['mode']} | "
                     f"{r['calibrations']} "
                     f"| {r['ok']} | {r['refused']} | {r['wrong']} | {stats} | "
                     f"{r['seconds']:.1f} |")
    refused = [r for r in records if r["status"] != "ok"]
    if refused:
        lines += ["", "Refused and miscounted calibrations (the reason each gave):", ""]
        lines += [f"- {r['physics']}, {r['layout']}, {r['n_lights']} lights, {r['mode']}, "
                  f"trial {r['trial']}: "
                  f"{r['reason']}" for r in refused]
    if far:
        lines += ["", "## What the calibrated lights cost SRDE", "",
                  f"{args.downstream} object scenes per number of lights from the several-light "
                  "benchmark (`random_scene`, faithful physics, seeds 12000 + 100 k + i); their "
                  f"lamps calibrated from {CAPTURES} plate captures, from the rays alone and "
                  "read from the highlights' images (the default up to "
                  "`MAX_IMAGE_READ_LIGHTS` lamps, the limit lifted here for three; 'default' "
                  "says which the calibration returns); SRDE told of each set of lights "
                  f"(`--downstream {args.downstream}`). 'wrong': a true "
                  "light more than 10 mm from every calibrated one (the plate captures of a "
                  "layout not made for them). EPE over the scenes every set of lights solved.",
                  ""]
        lines += downstream_rows(far)
        wrong = [r for r in far if r["status"] != "ok"]
        if wrong:
            lines += ["", "Refused or wrong calibrations:", ""]
            lines += [f"- {r['n_lights']} lights, seed {r['seed']}: " + (
                r.get("reason") or f"a true light {r['rays']['worst_light_mm']:.0f} mm from "
                                   f"every calibrated one") for r in wrong]
    (RESULTS / "light_calibration_multi.md").write_text("\n".join(lines) + "\n")
    (RESULTS / "light_calibration_multi.json").write_text(
        json.dumps(dict(summary=rows, records=records, downstream=far), indent=1))
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--downstream", type=int, default=40,
                        help="object scenes per number of lights for the downstream part")
    parser.add_argument("--quick", action="store_true", help="2 trials, model physics only")
    args = parser.parse_args()
    if args.quick:
        args.trials, args.downstream = 2, 2
    physics = ("model",) if args.quick else ("model", "faithful")
    plan = [(p, "spread", k) for p in physics for k in (1, 2, 3)]
    plan += [(p, "close", k) for p in physics for k in (2, 3)]
    records = run(args.trials, plan)
    far = [r for k in (2, 3) for r in downstream(k, args.downstream)]
    write(summarise(records), records, args, far)


if __name__ == "__main__":
    main()
