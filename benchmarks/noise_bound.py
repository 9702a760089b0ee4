"""How close SRDE's refined planes come to what the sensor's noise allows (Cramer-Rao bound).

On the stereo pair, the refinement misses its accuracy target on noisy renders of
``mismatched_physics.py`` while meeting it without the noise. This benchmark asks whether
any fit of those data could do better. For every scene of that benchmark (its seeds and
its ``faithful`` physics: photon noise of a 10,000 e- well, 5 e- read noise, 8-bit sRGB),
the Fisher information of the plane is computed from the refinement's own lobe model at
the true plane, its photometric parameters (lobe shape, intensities) fitted there and
estimated along with the plane, and each sample's noise variance from the sensor:
``(sum w_c^2) (y / well + (read / well)^2 + q(y)^2 / 12) / pixels``, with Rec. 709 weights
``w_c``, ``q(y)`` the linear step of one 8-bit sRGB code at ``y`` and ``pixels`` the
sample's block area. Its inverse bounds the variance of the plane's mean disparity over
the mask for any unbiased estimator; the table gives ``sqrt(2 / pi) sigma``, the mean
absolute error a Gaussian error of that spread has, beside the masked EPE SRDE reaches.

Two bounds: on the samples the refinement fits (on the 3x3 array block means of 2-7 px,
on the pair every pixel), and on every
pixel of the same windows (blocks of 1 px). A block with a clipped pixel is only a lower
bound, and neither bound counts what such samples say (their information is left out,
which makes both bounds a little loose).

Whether the fit reaches the bound is measured directly on the scenes with the largest
bounds: each is rendered again with other noise draws, and the spread of SRDE's mean
disparity error over the draws is set beside the bound's sigma. The same draws check
SRDE's own standard error of its disparity (``PlaneRefinement.disparity_sigma_px``, from
the fit's residuals), and every scene compares its errors at the object box's corners
with it.

A cell of the accuracy benchmark is one noise draw per scene. ``--cell`` renders every
scene of the cells named (``RIG:LO-HI:MM``, e.g. ``stereo:0.04-0.08:15``) again with
``--draws`` draws in all (the benchmark's own first) and gives the cell's mean masked EPE
per draw, with the light's radius unknown and given: how far one draw's cell mean
stands from what the cell gives on average.

Run: ``python benchmarks/noise_bound.py [--per-cell 3] [--draws 8] [--scenes 4]``; writes
``benchmarks/results/noise_bound.md`` and ``.json``. ``python benchmarks/noise_bound.py
--per-cell 10 --cell stereo:0.04-0.08:15 --cell stereo:0.04-0.08:10 --draws 6`` writes
``noise_bound_cells.md`` and ``.json`` instead.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import platform
import time
from pathlib import Path

import numpy as np
from mismatched_physics import (
    LIGHT_RADII_M,
    PHYSICS,
    ROUGHNESS_BINS,
    cell_scenes,
    refinement_setup,
    rigs,
    scene_for,
)
from results_files import write_results

from srde_fusion.geometry import RigLight, plane_disparity
from srde_fusion.imaging import REC709_LUMA, SRGB_TO_LINEAR_U8, linear_to_srgb
from srde_fusion.srde import SRDE
from srde_fusion.srde.refine import plane as refine_internals
from srde_fusion.srde.refine import samples as sample_internals
from srde_fusion.srde.refine.layout import N_PLANE
from srde_fusion.synthetic import render

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "noise_bound"
CELLS_NAME = "noise_bound_cells"
PHYSICS_NAME = "faithful"
EVERY_PIXEL = 100_000  # samples per window side: blocks of one pixel
#: A zero-mean Gaussian error of sigma has a mean absolute value of this times sigma.
TO_MEAN_ABS = math.sqrt(2.0 / math.pi)


def sample_variance(luminance: np.ndarray, block_px: int, well_e: float, read_e: float
                    ) -> np.ndarray:
    """Noise variance of block-mean linear luminance samples ``(P,)`` under the sensor."""
    y = np.clip(luminance, 0.0, 1.0)
    code = np.clip(np.rint(linear_to_srgb(y) * 255.0).astype(int), 0, 254)
    step = SRGB_TO_LINEAR_U8[code + 1] - SRGB_TO_LINEAR_U8[code]
    weights2 = float(np.sum(np.asarray(REC709_LUMA, dtype=np.float64) ** 2))
    per_pixel = weights2 * (y / well_e + (read_e / well_e) ** 2 + step.astype(np.float64) ** 2 / 12)
    return per_pixel / block_px ** 2


@contextlib.contextmanager
def block_samples(samples_per_side: int | None):
    """The refinement reads this many block samples per window side on every rig while
    inside (None: its own rule, which reads every pixel on a rig of few cameras)."""
    saved = sample_internals.SAMPLES_PER_SIDE, sample_internals.PIXEL_SAMPLES_MAX_CAMERAS
    if samples_per_side is not None:
        sample_internals.SAMPLES_PER_SIDE = samples_per_side
        sample_internals.PIXEL_SAMPLES_MAX_CAMERAS = 0
    try:
        yield
    finally:
        sample_internals.SAMPLES_PER_SIDE, sample_internals.PIXEL_SAMPLES_MAX_CAMERAS = saved


def bound_sigma_px(views, rig, mask, truth, samples_per_side: int | None, well_e: float,
                   read_e: float) -> tuple[float, int, int] | None:
    """The bound's sigma of the mean disparity over the mask, the samples and block size.

    ``samples_per_side``: as :func:`block_samples`.
    """
    setup = refinement_setup(views, rig, mask, truth)
    # Placed as the refinement's last fit places them, for a plane already found (the
    # pair's pixel samples then come nearest the outline).
    with block_samples(samples_per_side):
        samples = refine_internals.sample_windows(setup.views, rig, mask, truth, setup.centers,
                                                  box=setup.box, settled=True)
    if isinstance(samples, str):
        return None
    model = setup.model(samples, truth)
    start = model.initial_guess()
    if start is None:
        return None
    theta, _ = refine_internals._profile_at_start(model, start, 40)
    _, _, _, shading, lobe = model.lobe_at(theta)
    # Every parameter the fit estimates: plane, lobe shape, and the three intensities.
    jac = np.vstack([model.reduce(model.model_slopes(theta, model.free_all)),
                     lobe, shading.diffuse, np.ones_like(lobe)])
    keep = ~samples.saturated
    variance = sample_variance(samples.luminance[keep], samples.block_px, well_e, read_e)
    fisher = (jac[:, keep] / variance) @ jac[:, keep].T
    covariance = np.linalg.pinv(fisher)

    def mean_disparity(t):
        return float(np.mean(plane_disparity(model.plane(t), rig)[mask]))

    gradient = np.zeros(len(jac))
    for row, index in enumerate(model.free_all[:N_PLANE]):
        step = 1e-6
        up, down = theta.copy(), theta.copy()
        up[index] += step
        down[index] -= step
        gradient[row] = (mean_disparity(up) - mean_disparity(down)) / (2 * step)
    return math.sqrt(float(gradient @ covariance @ gradient)), samples.n_samples, samples.block_px


def bounds_on(views, rig, mask, truth, physics) -> dict:
    """The bound on the samples SRDE fits and on every pixel, for one render.

    ``{"sigma_blocks", "n_blocks", "block_blocks", "sigma_pixels", ...}``: sigma (px), the
    number of samples and their block size; a label is absent where no samples were cut.
    """
    found = {}
    for label, side in (("blocks", None), ("pixels", EVERY_PIXEL)):
        bound = bound_sigma_px(views, rig, mask, truth, side, physics.full_well_e,
                               physics.read_noise_e)
        if bound is not None:
            found[f"sigma_{label}"], found[f"n_{label}"], found[f"block_{label}"] = bound
    return found


def corner_disparity_px(plane, rig, mask) -> np.ndarray:
    """A plane's stereo disparity at the four corners of the mask's box, ``(4,)`` px."""
    x, y, w, h = refine_internals.mask_bbox(mask)
    corners = np.array([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]],
                       dtype=np.float64)
    return np.asarray(plane_disparity(plane, rig, corners), dtype=np.float64)


def srde_errors(views, rig, mask, truth_disparity, truth) -> dict | None:
    """SRDE's masked EPE, signed mean error, errors at the box corners and its own
    standard error there (px); None if it fails."""
    result = SRDE(rig).estimate(views, mask)
    if not result.ok:
        return None
    error = plane_disparity(result.plane, rig)[mask] - truth_disparity[mask]
    return {"epe": float(np.mean(np.abs(error))), "signed": float(np.mean(error)),
            "corner_errors": (corner_disparity_px(result.plane, rig, mask)
                              - corner_disparity_px(truth, rig, mask)).tolist(),
            "sigma_reported": result.disparity_sigma_px}


def run(args) -> dict:
    physics, supersample = PHYSICS[PHYSICS_NAME]
    report: dict = {"rigs": {}}
    for rig_name, rig in rigs().items():
        records = []
        for _, seed, config in cell_scenes(args.per_cell):
            scene = scene_for(seed, rig, config)
            lit = rig.with_light(scene.light.position_m)
            out = render(scene, rig, physics=physics, supersample=supersample)
            mask, truth = out.object_masks[0], scene.objects[0].plane
            record = {"seed": seed, "roughness": scene.objects[0].material.roughness,
                      "light_radius_m": scene.light.radius_m}
            record.update(bounds_on(out.views, lit, mask, truth, physics))
            found = srde_errors(out.views, lit, mask, out.disparity_px, truth)
            if found is not None:
                record.update(found)
            records.append(record)
            print(f"{rig_name} {seed}: " + ", ".join(
                f"{k} {v:.4f}" for k, v in record.items() if k.startswith(("sigma", "epe"))),
                flush=True)
        # Efficiency: repeat the noise on the scenes whose bound is largest.
        ranked = sorted((r for r in records if "sigma_blocks" in r and "epe" in r),
                        key=lambda r: -r["sigma_blocks"])[:args.scenes]
        draws = []
        configs = {seed: config for _, seed, config in cell_scenes(args.per_cell)}
        for record in ranked:
            scene = scene_for(record["seed"], rig, configs[record["seed"]])
            lit = rig.with_light(scene.light.position_m)
            signed, corners, reported = [], [], []
            for draw in range(args.draws):
                out = render(scene, rig, physics=physics, supersample=supersample,
                             noise_seed=1000 + draw)
                found = srde_errors(out.views, lit, out.object_masks[0], out.disparity_px,
                                    scene.objects[0].plane)
                if found is not None:
                    signed.append(found["signed"])
                    corners.append(found["corner_errors"])
                    reported.append(found["sigma_reported"])
            many = len(signed) > 1
            draws.append({"seed": record["seed"], "sigma_blocks": record["sigma_blocks"],
                          "sigma_pixels": record.get("sigma_pixels", float("nan")),
                          "signed": signed,
                          "spread": float(np.std(signed, ddof=1)) if many else float("nan"),
                          # the largest corner's spread, against SRDE's own standard error
                          "corner_spread": float(np.max(np.std(corners, axis=0, ddof=1)))
                          if many else float("nan"),
                          "sigma_reported": float(np.median(reported)) if reported
                          else float("nan")})
            print(f"{rig_name} {record['seed']}: spread over {len(signed)} draws "
                  f"{draws[-1]['spread']:.4f} px, bound sigma {record['sigma_blocks']:.4f}",
                  flush=True)
        report["rigs"][rig_name] = {"records": records, "draws": draws}
    return report


def tables(report: dict) -> list[str]:
    md = []
    for rig_name, part in report["rigs"].items():
        records = part["records"]
        md += [f"## {rig_name}", "",
               "Per light radius and roughness bin, mean over scenes: SRDE's masked EPE / the "
               "bound on its samples / the bound on every pixel (px; bounds as "
               "sqrt(2/pi) sigma):", "",
               "| light radius | " + " | ".join(f"{lo}-{hi}" for lo, hi in ROUGHNESS_BINS)
               + " |", "|---:|" + "---|" * len(ROUGHNESS_BINS)]
        for radius in LIGHT_RADII_M:
            cells = []
            for lo, hi in ROUGHNESS_BINS:
                chosen = [r for r in records if r["light_radius_m"] == radius
                          and lo <= r["roughness"] < hi and "epe" in r and "sigma_blocks" in r]
                if not chosen:
                    cells.append("-")
                    continue
                epe = np.mean([r["epe"] for r in chosen])
                blocks = TO_MEAN_ABS * np.mean([r["sigma_blocks"] for r in chosen])
                pixels = TO_MEAN_ABS * np.mean([r.get("sigma_pixels", np.nan) for r in chosen])
                cells.append(f"{epe:.4f} / {blocks:.4f} / {pixels:.4f}")
            md.append(f"| {radius * 1000:g} mm | " + " | ".join(cells) + " |")
        scored = [r for r in records if "epe" in r and "sigma_blocks" in r]
        with_pixels = [r for r in scored if "sigma_pixels" in r]
        ratio = [r["sigma_pixels"] / r["sigma_blocks"] for r in with_pixels]
        epe = np.mean([r["epe"] for r in scored])
        blocks = TO_MEAN_ABS * np.mean([r["sigma_blocks"] for r in scored])
        pixels = TO_MEAN_ABS * np.mean([r["sigma_pixels"] for r in with_pixels])
        md += ["", f"- {len(scored)} scenes scored; mean EPE {epe:.4f} px, mean bound "
               f"{blocks:.4f} px (samples), {pixels:.4f} px (pixels); every pixel instead of "
               f"block means: sigma x {np.median(ratio):.2f} (median; "
               f"{min(ratio):.2f}-{max(ratio):.2f})", ""]
        reported = [r for r in scored if np.isfinite(r.get("sigma_reported", np.nan))]
        if reported:
            ratios = np.concatenate([np.abs(r["corner_errors"]) / r["sigma_reported"]
                                     for r in reported])
            md += [f"- SRDE's own standard error (`refinement.disparity_sigma_px`, the largest "
                   f"of the box corners'): {len(reported)} scenes, median "
                   f"{np.median([r['sigma_reported'] for r in reported]):.4f} px; of their "
                   f"{len(ratios)} corner errors {np.mean(ratios <= 1):.0%} within 1 sigma, "
                   f"{np.mean(ratios <= 2):.0%} within 2, {np.mean(ratios <= 3):.0%} within 3",
                   ""]
        if part["draws"]:
            md += ["Repeated noise draws on the scenes with the largest bounds (the same "
                   "render, other sensor noise); SRDE's own standard error (median over the "
                   "draws) against the spread of its error at the box corner that spreads "
                   "most:", "",
                   "| seed | draws | spread of SRDE's mean error (px) | bound sigma, samples | "
                   "spread / bound | bound sigma, pixels | corner spread | SRDE's sigma |",
                   "|---:|---:|---:|---:|---:|---:|---:|---:|"]
            for d in part["draws"]:
                md.append(f"| {d['seed']} | {len(d['signed'])} | {d['spread']:.4f} | "
                          f"{d['sigma_blocks']:.4f} | {d['spread'] / d['sigma_blocks']:.2f} | "
                          f"{d['sigma_pixels']:.4f} | {d['corner_spread']:.4f} | "
                          f"{d['sigma_reported']:.4f} |")
            md.append("")
    return md


def parse_cell(text: str) -> tuple[str, tuple[float, float], float]:
    """``RIG:LO-HI:MM`` -> (rig name, roughness bin, light radius in metres)."""
    try:
        rig_name, bin_text, radius_mm = text.split(":")
        lo, hi = (float(v) for v in bin_text.split("-"))
        radius_m = float(radius_mm) / 1000.0
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected RIG:LO-HI:MM (e.g. stereo:0.04-0.08:15), got {text!r}") from None
    if rig_name not in rigs() or (lo, hi) not in ROUGHNESS_BINS \
            or not any(math.isclose(radius_m, r) for r in LIGHT_RADII_M):
        raise argparse.ArgumentTypeError(
            f"expected a rig of {list(rigs())}, a bin of {list(ROUGHNESS_BINS)} and a radius "
            f"of {[r * 1000 for r in LIGHT_RADII_M]} mm, got {text!r}")
    return rig_name, (lo, hi), radius_m


def cell_draws(cells, per_cell: int, draws: int) -> list[dict]:
    """SRDE's masked EPE on every scene of ``cells`` over ``draws`` noise draws.

    Draw 0 is the accuracy benchmark's own render; draw d > 0 is the same scene with
    sensor noise seed ``1000 + d``. Each draw is read with the light's radius unknown
    (a point light, the default) and given.
    """
    physics, supersample = PHYSICS[PHYSICS_NAME]
    records = []
    for rig_name, roughness, radius_m in cells:
        rig = rigs()[rig_name]
        for _, seed, config in cell_scenes(per_cell):
            if tuple(config.roughness) != roughness \
                    or not math.isclose(max(config.light_radius_m), radius_m):
                continue
            scene = scene_for(seed, rig, config)
            told = {"unknown": rig.with_light(scene.light.position_m),
                    "given": rig.with_lights([RigLight(scene.light.position_m,
                                                       radius_m=scene.light.radius_m)])}
            epe: dict[str, list[float]] = {name: [] for name in told}
            signed: dict[str, list[float]] = {name: [] for name in told}
            for draw in range(draws):
                out = render(scene, rig, physics=physics, supersample=supersample,
                             noise_seed=None if draw == 0 else 1000 + draw)
                if draw == 0:  # the bounds on the benchmark's own render, as in run()
                    found = bounds_on(out.views, told["unknown"], out.object_masks[0],
                                      scene.objects[0].plane, physics)
                    bounds = {f"sigma_{label}": found.get(f"sigma_{label}", math.nan)
                              for label in ("blocks", "pixels")}
                for name, lit in told.items():
                    found = srde_errors(out.views, lit, out.object_masks[0], out.disparity_px,
                                        scene.objects[0].plane)
                    epe[name].append(math.nan if found is None else found["epe"])
                    signed[name].append(math.nan if found is None else found["signed"])
            records.append({"rig": rig_name, "roughness_bin": list(roughness),
                            "light_radius_m": radius_m, "seed": seed, "epe": epe,
                            "signed": signed, **bounds})
            print(f"{rig_name} {seed}: " + "; ".join(
                f"{name} " + " ".join(f"{e:.4f}" for e in values)
                for name, values in epe.items()), flush=True)
    return records


def cell_tables(records: list[dict], draws: int) -> list[str]:
    """Per cell and radius knowledge: the cell's mean EPE per draw, over scenes solved in all."""
    md = ["| rig | roughness | light radius | radius | scenes | cell mean EPE per draw (px) "
          "| mean over draws | largest | draws above 0.02 px | mean without the scene of "
          "largest error | bound, samples / every pixel | too near: draw 0 / all draws / "
          "scenes on average |",
          "|---|---|---:|---|---:|---|---:|---:|---:|---:|---|---|"]
    keys = sorted({(r["rig"], tuple(r["roughness_bin"]), r["light_radius_m"]) for r in records})
    for rig_name, roughness, radius_m in keys:
        rows = [r for r in records if (r["rig"], tuple(r["roughness_bin"]), r["light_radius_m"])
                == (rig_name, roughness, radius_m)]
        for name in ("unknown", "given"):
            errors = np.array([r["epe"][name] for r in rows], dtype=np.float64)
            every = np.all(np.isfinite(errors), axis=1)
            solved = errors[every]
            # A positive disparity error puts the plane too near.
            if not len(solved):
                continue
            signs = np.array([r["signed"][name] for r in rows], dtype=np.float64)[every]
            bound = [TO_MEAN_ABS * np.mean([r[f"sigma_{label}"]
                                            for r, ok in zip(rows, every, strict=True) if ok])
                     for label in ("blocks", "pixels")]
            per_draw = solved.mean(axis=0)
            worst = int(np.argmax(solved.mean(axis=1)))
            rest = np.delete(solved, worst, axis=0).mean() if len(solved) > 1 else math.nan
            md.append(f"| {rig_name} | {roughness[0]}-{roughness[1]} | {radius_m * 1000:g} mm | "
                      f"{name} | {len(solved)} | "
                      + " / ".join(f"{v:.4f}" for v in per_draw)
                      + f" | {per_draw.mean():.4f} | {per_draw.max():.4f} | "
                      f"{int(np.sum(per_draw > 0.02))} of {draws} | {rest:.4f} | "
                      f"{bound[0]:.4f} / {bound[1]:.4f} | {np.mean(signs[:, 0] > 0):.0%} / "
                      f"{np.mean(signs > 0):.0%} / {np.mean(signs.mean(axis=1) > 0):.0%} |")
    return md


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-cell", type=int, default=3,
                        help="scenes per roughness bin and light radius (as mismatched_physics)")
    parser.add_argument("--scenes", type=int, default=4,
                        help="scenes per rig whose noise is drawn again")
    parser.add_argument("--draws", type=int, default=8, help="noise draws per such scene")
    parser.add_argument("--cell", type=parse_cell, action="append", default=[],
                        help="RIG:LO-HI:MM: render this cell's scenes with --draws noise draws "
                        "instead (repeatable)")
    parser.add_argument("--samples-per-side", type=int, default=None,
                        help="--cell only: SRDE's refinement reads this many block samples "
                        f"per window side on every rig (by default "
                        f"{sample_internals.SAMPLES_PER_SIDE}, and every pixel with "
                        f"{sample_internals.PIXEL_SAMPLES_MAX_CAMERAS} cameras or fewer; a large "
                        "number: every pixel)")
    parser.add_argument("--name", default=CELLS_NAME,
                        help="--cell only: results file name (default %(default)s)")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    if args.cell:
        side = sample_internals.SAMPLES_PER_SIDE
        with block_samples(args.samples_per_side):
            records = cell_draws(args.cell, args.per_cell, args.draws)
        md = ["# One noise draw per scene: how far a cell's mean stands from its average", "",
              f"Every scene of the cells named (``mismatched_physics.py``'s, {args.per_cell} "
              f"per cell, physics `{PHYSICS_NAME}`) rendered with {args.draws} sensor noise "
              "draws (the first is the benchmark's own), each read by SRDE with the light's "
              "radius unknown (a point light) and given; the cell's mean masked EPE per draw, "
              "over the scenes solved in every draw; the bound (as above, sqrt(2/pi) sigma, "
              "on the benchmark's own render) over the same scenes; and the share of planes "
              "too near (a positive mean disparity error) in the benchmark's own draw, over "
              "all draws, and of the scenes whose error averaged over the draws is positive "
              "(a lean that the noise draws do not average out). "
              + (f"The refinement read {args.samples_per_side} block samples per window "
                 f"side (default {side}), and the bound on samples is on those. "
                 if args.samples_per_side is not None else "")
              + "Machine: "
              f"{platform.machine()}, {os.cpu_count()} cores, Python "
              f"{platform.python_version()}; {time.perf_counter() - start:.0f} s.", "",
              *cell_tables(records, args.draws), ""]
        write_results(args.out, args.name, md, {"records": records})
        return 0
    report = run(args)
    md = ["# How close SRDE comes to the sensor's noise bound", "",
          __doc__.split("\n\n", 2)[1].replace("\n", " "), "",
          f"Scenes: those of `mismatched_physics.py` ({args.per_cell} per rig, roughness bin "
          f"and light radius), physics `{PHYSICS_NAME}`. Machine: {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}; "
          f"{time.perf_counter() - start:.0f} s.", "", *tables(report)]
    write_results(args.out, NAME, md, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
