"""Faceted objects: faces found, per-face EPE, wrong splits and time, against one plane.

Scenes: one faceted object (``synthetic.faceted_scene``: two faces sharing an edge, as a
ridge or a valley, or three faces in a row as a ridge; dihedral angle 15-60 deg between
neighbouring normals) before the paper's 3 x 3 array (640 x 480 px, fx 600 px), each face
with a light of its own whose highlight lies on it in the reference view and in at least
3 views, rendered with ``Physics.faithful()`` (2 x 2 samples per pixel). The mask is the
union of the faces. Every scene is estimated two ways on the same images and mask:

* ``faces``: ``SRDE(max_faces=3)`` with a rig that knows every light;
* ``one plane``: ``SRDE`` with the same rig (today's several-light path: one plane).

Each lit face is also estimated alone, its true pixels as the mask, with the same rig
(one plane): a flat object that turns its back on some of the known lights, whose
highlights are one light's while the others' lie elsewhere. It must come out within
0.5 px or as a reasoned failure.

Fusion: the ``faces`` estimate goes through ``fuse`` with the default border check,
the backbone being OpenCV SGBM on the rig's stereo pair (the background is black, so
the textured band is the object's silhouette edge). An object is *kept* when fusion uses
SRDE's disparity and *sent back* when it falls back to the backbone although SRDE
succeeded. Fused per-face EPE: the fused map on each face's true pixels, over the kept
objects; backbone per-face EPE over the same faces and SGBM's valid pixels.

Per face: masked EPE (px) of the estimate on the face's true pixels. A face counts as
*lit* when the renderer puts its own light's highlight on it in at least 2 views
(``Rendering.highlight_on_object``); *found* when the estimate is ``ok`` with faces and
one of its faces' planes is within 0.5 px of the face's true plane over the face (the
faces are matched by their pixels). Wrong split: mask pixels whose estimated face is not
their true face (the faces matched by the most shared pixels), % of the mask. *Wrong
objects*: ``ok`` results (with faces, or one plane from the faces estimator) with a face
not found or more than 5 % of the mask on the wrong face. Times:
median of the whole ``estimate`` call (two processes may share the two cores).

Run: ``python benchmarks/faceted.py [--scenes 20]``; writes
``benchmarks/results/faceted.md`` and ``.json``. Scenes the method was not tuned on:
``--scenes 20 --seed0 51000 --name faceted_heldout``; seeds first run after the rules
were drawn from those two sets: ``--scenes 20 --seed0 61000 --name faceted_new``; further
sets, each first run with the code of its time: ``--seed0 71000 --name faceted_71000``,
``--seed0 81000 --name faceted_81000``, ``--seed0 91000 --name faceted_91000`` (each then
shaped a rule), ``--seed0 101000 --name faceted_101000`` (run only after them) and
``--seed0 111000 --name faceted_111000`` (first run when fusion learnt the highlights);
``--seed0 141000 --name faceted_141000`` first ran with the faces' last try (cut blobs
recentred and matched near the outline).
``--lamp-radii`` gives the rig every lamp's radius, as a ``rig.json`` with the lamps
measured would (by default the rig knows positions only, and each face's second reading
fits the radius). ``--refused-only`` runs again only the scenes whose stored record is a
failure and keeps the others' records: for a change that only runs where every try of the
faces has failed (the md says how many were run again).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
from fusion_eval import sgbm_backbone  # the fusion benchmark's SGBM (run from this folder)
from results_files import write_results

from srde_fusion.fusion import fuse
from srde_fusion.geometry import plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import default_rig, render
from srde_fusion.synthetic.faceted import faceted_scene
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

RESULTS_DIR = Path(__file__).resolve().parent / "results"
NAME = "faceted"
KINDS = (("2 faces, ridge", 2, True), ("2 faces, valley", 2, False), ("3 faces, ridge", 3, True))
FOUND_PX = 0.5
TARGET_PX = 0.05
WRONG_SPLIT_PCT = 5.0
SEED0 = 31000
#: The backbone of the fused maps: the fusion benchmark's SGBM.
SGBM = sgbm_backbone()


class Estimated:
    """An estimator that returns a result already computed (fusion without re-running)."""

    def __init__(self, result) -> None:
        self.result = result

    def estimate(self, views, mask):
        return self.result


def face_epe(disparity: np.ndarray, truth: np.ndarray, part: np.ndarray,
             valid_only: bool = False) -> float:
    values = disparity[part]
    finite = np.isfinite(values)
    if valid_only and finite.any():
        return float(np.mean(np.abs(values[finite] - truth[part][finite])))
    if not np.all(finite):
        return float("nan")
    return float(np.mean(np.abs(values - truth[part])))


def timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def run_scene(rig, seed: int, n_faces: int, convex: bool, lamp_radii: bool = False) -> dict:
    faceted = faceted_scene(seed, rig, n_faces=n_faces, convex=convex)
    rendering = render(faceted.scene, rig, physics=Physics.faithful(), supersample=2)
    lit_rig = rig.with_lights(rig_lights(faceted.scene, radii=lamp_radii))
    mask = rendering.instance_mask > 0
    truth = rendering.disparity_px
    parts = [rendering.instance_mask == k + 1 for k in range(n_faces)]
    seen = rendering.highlight_on_object
    lit = [int(seen[k, k].sum()) >= 2 for k in range(n_faces)]
    result, t_faces = timed(lambda: SRDE(lit_rig, max_faces=3).estimate(rendering.views, mask))
    single, t_single = timed(lambda: SRDE(lit_rig).estimate(rendering.views, mask))
    record = {"seed": seed, "faces": n_faces, "convex": convex,
              "dihedral_deg": list(faceted.dihedral_deg), "lit": lit,
              "status": result.status, "reason": result.reason,
              "n_found_faces": 0 if result.faces is None else len(result.faces.faces),
              "time_s": t_faces, "single_status": single.status, "single_time_s": t_single}
    d_faces = result.disparity
    record["epe"] = [face_epe(d_faces, truth, p) if result.ok else float("nan") for p in parts]
    record["single_epe"] = [face_epe(single.disparity, truth, p) if single.ok else float("nan")
                            for p in parts]
    found = [False] * n_faces
    views = [0] * n_faces
    radius_notes = [""] * n_faces
    wrong_split = float("nan")
    if result.ok and result.faces is not None:
        labels = np.zeros(mask.shape, np.uint8)
        u0, v0, u1, v1 = result.box
        labels[v0:v1, u0:u1] = result.faces.labels_box
        # Each true face takes the estimated face it shares the most pixels with.
        match = [int(np.argmax(np.bincount(labels[p], minlength=len(result.faces.faces) + 1)[1:]))
                 + 1 for p in parts]
        wrong = sum(int(np.count_nonzero(labels[p] != match[k])) for k, p in enumerate(parts))
        wrong_split = 100.0 * wrong / int(mask.sum())
        for k, p in enumerate(parts):
            face = result.faces.faces[match[k] - 1]
            gap = np.abs(plane_disparity(face.plane, rig)[p] - truth[p])
            found[k] = bool(np.max(gap) <= FOUND_PX)
            views[k] = int(np.count_nonzero(face.used_views))
            radius_notes[k] = next((n for n in face.notes if "radius is not known" in n), "")
    # Per true face: the views that measured its light, and what the refinement said
    # about the light's radius (fitted, kept a point light, or nothing: not searched).
    record.update(found=found, wrong_split_pct=wrong_split, face_views=views,
                  radius_notes=radius_notes)
    # Each lit face alone, as a mask of one flat object would hold it (every light known):
    # the one-plane path must give the face's plane or a reasoned failure.
    face_masks = []
    for k, p in enumerate(parts):
        if lit[k]:
            alone = SRDE(lit_rig).estimate(rendering.views, p)
            gap = (float(np.max(np.abs(plane_disparity(alone.plane, rig)[p] - truth[p])))
                   if alone.ok else float("nan"))
            face_masks.append({"face": k, "status": alone.status, "gap_px": gap})
    record["face_masks"] = face_masks
    backbone = SGBM(*(rendering.views[j] for j in rig.stereo_pair))
    fused = fuse(backbone, rendering.views, lit_rig, [mask], Estimated(result))
    report = fused.objects[0]
    record.update(fused_status=report.status, fused_reason=report.reason,
                  fused_epe=[face_epe(fused.disparity, truth, p) for p in parts],
                  backbone_epe=[face_epe(backbone, truth, p, valid_only=True) for p in parts],
                  backbone_coverage=[float(np.mean(np.isfinite(backbone[p]))) for p in parts])
    return record


def summary_rows(records: list[dict]) -> tuple[list[str], dict]:
    lines = ["| object | scenes | faces lit (>= 2 views) | faces found | objects ok | "
             "wrong objects | per-face EPE mean / max (px) | faces <= 0.05 px | wrong split (% "
             "of mask, mean / max) | one plane: per-face EPE mean / max (px) | time faces / one "
             "plane (ms) |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    fused_lines = ["| object | SRDE ok with faces | kept by fusion | sent back | fused per-face "
                   "EPE mean / max (px) | fused faces <= 0.05 px | SGBM per-face EPE mean "
                   "(valid px) | SGBM coverage |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    numbers = {}
    for label, n_faces, convex in KINDS:
        rs = [r for r in records if r["faces"] == n_faces and r["convex"] == convex]
        if not rs:
            continue
        lit = sum(sum(r["lit"]) for r in rs)
        found = sum(sum(f and li for f, li in zip(r["found"], r["lit"], strict=True)) for r in rs)
        ok = [r for r in rs if r["status"] == "ok" and r["n_found_faces"] >= 2]
        # Wrong: an ok result (with faces or one plane) with a face off by more than
        # FOUND_PX, or more than WRONG_SPLIT_PCT of the mask on the wrong face.
        wrong = [r for r in rs if r["status"] == "ok" and (
            not all(r["found"]) or not r["wrong_split_pct"] <= WRONG_SPLIT_PCT)]
        epes = [e for r in ok for e in r["epe"]]
        single = [e for r in rs if r["single_status"] == "ok" for e in r["single_epe"]]
        splits = [r["wrong_split_pct"] for r in ok]
        row = {
            "scenes": len(rs), "faces_lit": lit, "faces_found": found,
            "objects_ok": len(ok), "objects_wrong": len(wrong),
            "statuses": {s: sum(r["status"] == s for r in rs)
                         for s in sorted({r["status"] for r in rs})},
            "epe_mean": float(np.nanmean(epes)) if epes else float("nan"),
            "epe_max": float(np.nanmax(epes)) if epes else float("nan"),
            "faces_within_target": int(sum(e <= TARGET_PX for e in epes)), "faces_ok": len(epes),
            "wrong_split_mean_pct": float(np.mean(splits)) if splits else float("nan"),
            "wrong_split_max_pct": float(np.max(splits)) if splits else float("nan"),
            "single_epe_mean": float(np.nanmean(single)) if single else float("nan"),
            "single_epe_max": float(np.nanmax(single)) if single else float("nan"),
            "single_ok": sum(r["single_status"] == "ok" for r in rs),
            "time_ms": 1000 * float(np.median([r["time_s"] for r in rs])),
            "single_time_ms": 1000 * float(np.median([r["single_time_s"] for r in rs])),
        }
        kept = [r for r in ok if r.get("fused_status") == "srde"]
        fused_epes = [e for r in kept for e in r["fused_epe"]]
        backbone_epes = [e for r in ok for e in r.get("backbone_epe", [])]
        coverage = [c for r in rs for c in r.get("backbone_coverage", [])]
        row.update({
            "fused_kept": len(kept), "fused_sent_back": len(ok) - len(kept),
            "fused_epe_mean": float(np.nanmean(fused_epes)) if fused_epes else float("nan"),
            "fused_epe_max": float(np.nanmax(fused_epes)) if fused_epes else float("nan"),
            "fused_faces_within_target": int(sum(e <= TARGET_PX for e in fused_epes)),
            "fused_faces": len(fused_epes),
            "backbone_epe_mean": (float(np.nanmean(backbone_epes)) if backbone_epes
                                  else float("nan")),
            "backbone_coverage": float(np.mean(coverage)) if coverage else float("nan"),
        })
        numbers[label] = row
        fused_lines.append(
            f"| {label} | {len(ok)} | {row['fused_kept']} | {row['fused_sent_back']} | "
            f"{row['fused_epe_mean']:.4f} / {row['fused_epe_max']:.4f} | "
            f"{row['fused_faces_within_target']} of {row['fused_faces']} | "
            f"{row['backbone_epe_mean']:.2f} | {100 * row['backbone_coverage']:.0f} % |")
        lines.append(
            f"| {label} | {row['scenes']} | {lit} | {found} | {len(ok)} | {len(wrong)} | "
            f"{row['epe_mean']:.4f} / {row['epe_max']:.4f} | {row['faces_within_target']} of "
            f"{row['faces_ok']} | {row['wrong_split_mean_pct']:.2f} / "
            f"{row['wrong_split_max_pct']:.2f} | {row['single_epe_mean']:.3f} / "
            f"{row['single_epe_max']:.3f} ({row['single_ok']} ok) | {row['time_ms']:.0f} / "
            f"{row['single_time_ms']:.0f} |")
    alone = [f for r in records for f in r.get("face_masks", [])]
    right = sum(f["status"] == "ok" and f["gap_px"] <= FOUND_PX for f in alone)
    wrong = [f for f in alone if f["status"] == "ok" and not f["gap_px"] <= FOUND_PX]
    failed = {s: sum(f["status"] == s for f in alone)
              for s in sorted({f["status"] for f in alone} - {"ok"})}
    numbers["face_masks"] = {"faces": len(alone), "right": right, "wrong": len(wrong),
                             "wrong_gaps_px": [f["gap_px"] for f in wrong], "failed": failed}
    gaps = ", ".join(f"{f['gap_px']:.2f}" for f in wrong) or "none"
    face_lines = [
        "Each lit face as its own mask (`SRDE` with every light, one plane; a flat object "
        "turned from some of the lights): "
        f"{len(alone)} faces, {right} within {FOUND_PX} px, {len(wrong)} wrong (ok but "
        f"off by more: {gaps} px), failed: "
        + (", ".join(f"{s} {n}" for s, n in failed.items()) or "none") + "."]
    return lines + ["", "Fused (SGBM backbone, default border check), over the objects SRDE "
                    "solved with faces:", "", *fused_lines, "", *face_lines], numbers


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20, help="scenes per kind of object")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR, help="results folder")
    parser.add_argument("--seed0", type=int, default=SEED0,
                        help=f"first seed (default {SEED0}; scene i of kind k: seed0 + 1000 k + i)")
    parser.add_argument("--name", default=NAME, help=f"results file name (default {NAME})")
    parser.add_argument("--lamp-radii", action="store_true",
                        help="the rig knows every lamp's radius (rig.json's radius_m)")
    parser.add_argument("--tables-only", action="store_true",
                        help="rewrite the tables from the results folder's JSON records")
    parser.add_argument("--refused-only", action="store_true",
                        help="run again only the scenes whose stored record is not ok, "
                             "keeping the others' (for a change that solved objects cannot "
                             "reach)")
    args = parser.parse_args(argv)
    rig = default_rig()
    records = []
    stored = {}
    if args.tables_only or args.refused_only:
        path = args.out / f"{args.name}.json"
        if not path.is_file():
            raise SystemExit(f"expected stored records at {path}, got no such file")
        records = json.loads(path.read_text())["records"]
        stored = {record["seed"]: record for record in records}
    for kind, (_, n_faces, convex) in enumerate(KINDS if not args.tables_only else ()):
        for i in range(args.scenes):
            seed = args.seed0 + 1000 * kind + i
            if args.refused_only:
                if seed not in stored:
                    raise SystemExit(f"--refused-only: expected a stored record of seed {seed} "
                                     f"in {args.name}.json, got none (run the set in full)")
                if stored[seed]["status"] == "ok":
                    continue
                records.remove(stored[seed])
            record = run_scene(rig, seed, n_faces, convex, args.lamp_radii)
            if args.refused_only:
                record["run_again"] = "refused only"
            records.append(record)
            print(f"{n_faces} faces {'ridge' if convex else 'valley'} seed {record['seed']}: "
                  f"{record['status']} epe {np.round(record['epe'], 4).tolist()} found "
                  f"{record['found']} split {record['wrong_split_pct']:.2f} % one plane "
                  f"{np.round(record['single_epe'], 3).tolist()}", flush=True)
    records.sort(key=lambda record: record["seed"])
    table, numbers = summary_rows(records)
    statuses = "; ".join(f"{k}: " + ", ".join(f"{s} {n}" for s, n in row["statuses"].items())
                         for k, row in numbers.items() if "statuses" in row)
    md = ["# Faceted objects", "",
          __doc__.split("\n\n", 1)[1].split("\n\nRun:")[0].replace("\n", " "), "",
          f"{len(records)} scenes (seeds {args.seed0} + 1000 kind + i). Machine: "
          f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}."
          + (" The rig knows every lamp's radius (`--lamp-radii`)." if args.lamp_radii else "")
          + (f" Run again: the {again} scenes stored as refused (`--refused-only`); the "
             f"others' records are an earlier run's." if (again := sum(
                 "run_again" in record for record in records)) else ""),
          "", "Per-face EPE and wrong split over the objects solved with faces; the target is "
          f"per-face EPE <= {TARGET_PX} px.", "", *table, "", f"Statuses: {statuses}.", ""]
    write_results(args.out, args.name, md, {"numbers": numbers, "records": records},
                  default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
