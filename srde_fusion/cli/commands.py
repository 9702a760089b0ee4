"""The product's workflows, and the ``demo``, ``fuse``, ``srde`` and ``eval`` commands.

Each workflow is a library function (:func:`run_demo`, :func:`fuse_scene`,
:func:`srde_scene`, :func:`~srde_fusion.evaluation.evaluate.evaluate_dataset`) that returns a
result and writes its files; the command-line handlers only map flags to keyword
arguments and print a summary.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._json import json_safe
from ..errors import FileFormatError, SRDEError
from ..fusion import FusionResult, HybridStereo, fuse
from ..geometry import CameraRig
from ..io import read_scene, write_disparity, write_mask, write_scene
from ..masks import HighlightSegmenter, resolve_masker

__all__ = [
    "DemoResult",
    "SceneRun",
    "write_fusion_outputs",
    "run_demo",
    "fuse_scene",
    "srde_scene",
    "register",
    "DEMO_SEED",
]

#: Seed of the demo scene: a textured room with two glossy objects.
DEMO_SEED = 7
#: Objects in the demo scene.
DEMO_OBJECTS = 2
#: File names written by :func:`write_fusion_outputs`.
FUSED_PFM = "fused_disparity.pfm"
FUSED_PNG = "fused_disparity.png"
BACKBONE_PFM = "backbone_disparity.pfm"
SRDE_PFM = "srde_disparity.pfm"
SOURCE_PNG = "source.png"
REPORT_JSON = "report.json"
FIGURE_PNG = "figure.png"


@dataclass(frozen=True)
class SceneRun:
    """What a workflow produced for one scene.

    Attributes
    ----------
    fusion : FusionResult
        The fused map, source map and per-object reports.
    scores : dict or None
        ``scores[method][region]`` against ground truth (see
        :func:`~srde_fusion.evaluation.evaluate.score_fusion`), None without ground truth.
    files : dict of str -> pathlib.Path
        Every file written, by role.
    notes : tuple of str
        Anything the caller should know (e.g. a file that could not be written).
    """

    fusion: FusionResult
    scores: dict | None
    files: dict
    notes: tuple[str, ...] = ()

    def table(self) -> str:
        """Return markdown tables of the scores (backbone, SRDE, fused; full and objects)."""
        return _scores_table(self.scores) if self.scores is not None else ""


@dataclass(frozen=True)
class DemoResult(SceneRun):
    """A :class:`SceneRun` of the demo, with the folder of the rendered scene."""

    scene_dir: Path | None = None


def _scores_table(scores: dict) -> str:
    from ..evaluation import METHODS, TABLE_KEYS, format_markdown_table

    parts = []
    for region, title in (("full", "Full scene"), ("masked", "Objects (masked)")):
        rows = {("fused" if m == "hybrid" else m): scores[m][region] for m in METHODS}
        parts.append(f"### {title}\n\n" + format_markdown_table(rows, TABLE_KEYS))
    return "\n".join(parts)



def write_fusion_outputs(out_dir: str | os.PathLike, result: FusionResult,
                         image: np.ndarray, *, gt_disparity: np.ndarray | None = None,
                         region: np.ndarray | None = None, extra: dict | None = None,
                         title: str | None = None, srde_only: bool = False) -> SceneRun:
    """Write a fusion result: disparity maps, source map, JSON report and figure.

    Files: ``fused_disparity.pfm`` (invalid = inf) and ``fused_disparity.png`` (KITTI
    16-bit, value / 256, 0 = invalid), ``backbone_disparity.pfm``, ``srde_disparity.pfm``,
    ``source.png`` (8-bit: 0 = backbone, k = object k's SRDE plane), ``report.json``
    (per-object decisions and, with ground truth, the scores) and ``figure.png``. With
    ``srde_only`` (SRDE run without a backbone) the disparity files are
    ``srde_disparity.pfm`` and ``srde_disparity.png`` only.

    Parameters
    ----------
    out_dir : path
        Created if needed.
    result : FusionResult
    image : numpy.ndarray, (H, W, 3) uint8
        The reference view (for the figure).
    gt_disparity : numpy.ndarray, (H, W), float, optional
        Ground truth; adds scores to the report and error maps to the figure.
    region : numpy.ndarray, (H, W), bool, optional
        The objects for the masked scores (the ground-truth masks where known).
    extra : dict, optional
        More JSON-serialisable entries for the report.
    title : str, optional
        Figure title.
    srde_only : bool
        Write and draw SRDE's map only.

    Returns
    -------
    SceneRun
    """
    from ..evaluation import comparison_figure, save_figure, score_fusion

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"{out}: could not create the output folder: {exc}") from None
    files: dict[str, Path] = {}
    notes: list[str] = []
    main, main_pfm = ("srde", SRDE_PFM) if srde_only else ("fused", FUSED_PFM)
    main_png = main_pfm.replace(".pfm", ".png")
    files[f"{main}_pfm"] = write_disparity(out / main_pfm, result.disparity)
    try:
        files[f"{main}_png"] = write_disparity(out / main_png, result.disparity)
    except FileFormatError as exc:  # beyond the 16-bit format's range
        notes.append(f"{main_png} not written: {exc}")
    if not srde_only:
        files["backbone_pfm"] = write_disparity(out / BACKBONE_PFM, result.backbone_disparity)
        files["srde_pfm"] = write_disparity(out / SRDE_PFM, result.srde_disparity)
    files["source_png"] = write_mask(out / SOURCE_PNG, result.source)

    scores = None
    if gt_disparity is not None:
        if region is None and result.objects:
            region = result.source > 0
        scores = score_fusion(result, gt_disparity, region)
    maps = ({"SRDE": result.disparity} if srde_only else
            {"backbone": result.backbone_disparity, "SRDE": result.srde_disparity,
             "fused": result.disparity})
    fig = comparison_figure(image, maps, gt_disparity=gt_disparity, source=result.source,
                            region=region, title=title)
    files["figure_png"] = save_figure(fig, out / FIGURE_PNG)

    report = {"fusion": result.report(), "scores": scores, "notes": notes,
              "files": {k: p.name for k, p in files.items()} | {"report_json": REPORT_JSON}}
    if extra:
        report.update(extra)
    files["report_json"] = out / REPORT_JSON
    files["report_json"].write_text(json.dumps(json_safe(report), indent=2, allow_nan=False) + "\n")
    return SceneRun(result, scores, files, tuple(notes))


def run_demo(out_dir: str | os.PathLike = "demo_out", *, seed: int = DEMO_SEED,
             n_objects: int = DEMO_OBJECTS, scale: float = 1.0, backbone: Any = "default",
             rig: CameraRig | None = None) -> DemoResult:
    """Run the embedded default: render a scene, run the stand-in backbone, fuse, write.

    Renders a textured room with glossy flat objects for the paper's 3x3 array
    (640x480, ``scale`` resizes it), saves it as a scene folder (``out_dir/scene``),
    runs the bundled stand-in stereo network on the stereo pair, finds the objects with
    the built-in :class:`~srde_fusion.masks.stages.HighlightSegmenter`, fuses, and writes the
    outputs of :func:`write_fusion_outputs` with the ground truth.

    Parameters
    ----------
    out_dir : path
    seed : int
        Scene seed.
    n_objects : int
        Glossy objects in the scene.
    scale : float
        Image scale relative to 640x480 (e.g. 0.5 for a quick run).
    backbone : str, path, torch module or callable
        ``"default"`` (the bundled stand-in), an ``.onnx`` file, a torch module, or a
        ready ``backbone(left, right)`` callable.
    rig : CameraRig, optional
        The camera array; the paper's by default.

    Returns
    -------
    DemoResult
    """
    from ..synthetic import default_rig, random_scene, render, scene_to_dict

    if not (isinstance(scale, (int, float)) and 0.1 <= scale <= 4.0):
        raise SRDEError(f"scale: expected a factor in [0.1, 4], got {scale!r}")
    rig = (rig or default_rig())
    if scale != 1.0:
        rig = rig.scaled(scale)
    scene = random_scene(seed, rig, n_objects=n_objects, background="textured")
    rig = rig.with_light(scene.light.position_m)
    rendering = render(scene, rig, noise_seed=seed)
    out = Path(out_dir)
    scene_dir = write_scene(out / "scene", rendering.views, rig, mask=rendering.instance_mask,
                            gt_disparity=rendering.disparity_px,
                            metadata={"seed": seed, "scene": scene_to_dict(scene)})

    model = HybridStereo(_load_backbone(backbone), rig, masker=HighlightSegmenter())
    result = model(rendering.views)
    diagnostics = model.masker.last_diagnostics
    run = write_fusion_outputs(
        out, result, rendering.views[rig.reference], gt_disparity=rendering.disparity_px,
        region=rendering.instance_mask > 0, title=f"demo scene (seed {seed})",
        extra={"scene_dir": scene_dir.name,
               "segmenter": None if diagnostics is None else list(diagnostics.reasons)})
    return DemoResult(run.fusion, run.scores, run.files, run.notes, scene_dir)


def _load_backbone(source: Any, preset: str | None = None) -> Any:
    """Return a backbone callable: model files and torch modules go through the adapters."""
    torch = sys.modules.get("torch")  # a torch module can only exist if torch is imported
    is_module = torch is not None and isinstance(source, torch.nn.Module)
    if callable(source) and not is_module:
        return source
    # The CLI workflows are the one place the core reaches into the adapters (DESIGN §6).
    from ..adapters import load_backbone

    return load_backbone(source, preset)


def _worker_backbone(source: str, preset: str | None, threads: int) -> Any:
    """Load a backbone in an evaluation worker, its ONNX session on ``threads`` threads."""
    import onnxruntime as ort

    from ..adapters import load_backbone

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return load_backbone(source, preset, session_options=options)



def fuse_scene(scene_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
               backbone: Any = "default", preset: str | None = None, mask: Any = None,
               auto_mask: bool = False, light: Any = None) -> SceneRun:
    """Fuse a backbone's disparity with SRDE for one scene folder and write the outputs.

    Parameters
    ----------
    scene_dir : path
        A scene folder (``rig.json`` with the light, one image per camera, optional
        ``mask.png`` and ground truth).
    out_dir : path
    backbone : str, path, torch module or callable
        ``"default"``, an ``.onnx`` file, a torch module or a callable.
    preset : str, optional
        Conventions of an ONNX model (``"igev"``, ``"raft-stereo"``, ...).
    mask : path or array, optional
        Object masks; the scene's ``mask.png`` if present, else the built-in segmenter.
    auto_mask : bool
        Use the built-in segmenter even if the scene has a mask.
    light : array_like (3,), optional
        Light position in metres, overriding the rig's.

    Returns
    -------
    SceneRun
    """
    scene = read_scene(scene_dir)
    choice = resolve_masker("auto" if auto_mask and mask is None else mask,
                            scene_labels=scene.mask_labels, where=str(scene.path))
    masker, source = choice.masker, choice.description
    model = HybridStereo(_load_backbone(backbone, preset), scene.rig, light, masker)
    result = model(scene.views)
    region = None
    if scene.mask_labels is not None:
        region = scene.mask_labels > 0
    return write_fusion_outputs(out_dir, result, scene.views[scene.rig.reference],
                                gt_disparity=scene.gt_disparity, region=region,
                                title=scene.name, extra={"scene": str(scene.path),
                                                         "masks": source})


def srde_scene(scene_dir: str | os.PathLike, out_dir: str | os.PathLike | None = None, *,
               mask: Any = None, auto_mask: bool = False, light: Any = None,
               method: str = "default") -> SceneRun:
    """Run SRDE alone on one scene folder (no backbone); write its disparity and report.

    Outside the objects there is no disparity (NaN, ``inf`` in the PFM). Parameters as
    :func:`fuse_scene`; ``method`` selects the SRDE variant. Without ``out_dir`` nothing
    is written.

    Returns
    -------
    SceneRun
        Its ``fusion`` has an all-invalid backbone, so ``fusion.disparity`` is SRDE's
        map where SRDE succeeded and NaN elsewhere.
    """
    from ..srde import SRDE

    scene = read_scene(scene_dir)
    rig = scene.rig if light is None else scene.rig.with_light(light)
    choice = resolve_masker("auto" if auto_mask and mask is None else mask,
                            scene_labels=scene.mask_labels, where=str(scene.path))
    masker, source = choice.masker, choice.description
    masks = masker(list(scene.views), rig)
    nothing = np.full((rig.height, rig.width), np.nan, np.float32)
    result = fuse(nothing, scene.views, rig, masks, SRDE(rig, method=method) if masks else None,
                  border_check=None)
    if out_dir is None:
        return SceneRun(result, None, {})
    region = scene.mask_labels > 0 if scene.mask_labels is not None else None
    return write_fusion_outputs(out_dir, result, scene.views[rig.reference],
                                gt_disparity=scene.gt_disparity, region=region,
                                title=f"{scene.name}: SRDE alone", srde_only=True,
                                extra={"scene": str(scene.path), "masks": source})


# --------------------------------------------------------------------------- CLI
def _print_objects(result: FusionResult) -> None:
    if not result.objects:
        print("no glossy object found: the backbone's disparity is kept everywhere")
    for obj in result.objects:
        print(f"object {obj.index}: {obj.status} ({obj.pixel_count} px) - {obj.reason}")


def _print_files(run: SceneRun) -> None:
    for note in run.notes:
        print(f"note: {note}")
    folder = run.files["report_json"].parent
    names = ", ".join(p.name for p in run.files.values())
    print(f"wrote {folder}/: {names}")


def _cli_demo(args: argparse.Namespace) -> int:
    run = run_demo(args.out, seed=args.seed, n_objects=args.objects, scale=args.scale,
                   backbone=args.backbone)
    _print_objects(run.fusion)
    print()
    print(run.table())
    _print_files(run)
    return 0


def _cli_fuse(args: argparse.Namespace) -> int:
    run = fuse_scene(args.scene_dir, args.out, backbone=args.backbone, preset=args.preset,
                     mask=args.mask, auto_mask=args.auto_mask, light=args.light)
    _print_objects(run.fusion)
    if run.scores is not None:
        print()
        print(run.table())
    _print_files(run)
    return 0


def _cli_srde(args: argparse.Namespace) -> int:
    run = srde_scene(args.scene_dir, args.out, mask=args.mask, auto_mask=args.auto_mask,
                     light=args.light, method=args.method)
    for obj in run.fusion.objects:
        srde = obj.srde
        plane = getattr(srde, "plane", None)
        detail = srde.reason or (f"plane n = {np.round(plane.n, 4).tolist()}, "
                                 f"c = {plane.offset_m:.4f} m, residual "
                                 f"{srde.residual_px:.3f} px" if plane is not None else "")
        print(f"object {obj.index}: {srde.status} ({obj.pixel_count} px) - {detail}")
    if not run.fusion.objects:
        print("no glossy object found")
    if run.scores is not None:
        from ..evaluation import format_markdown_table

        print()
        print(format_markdown_table({"srde": run.scores["srde"]["masked"]},
                                    ["epe", "rmse", "bmp0.1", "bad1", "coverage"]), end="")
    if run.files:
        _print_files(run)
    return 0


def _cli_eval(args: argparse.Namespace) -> int:
    from ..evaluation import BackboneLoader, evaluate_dataset
    from ..io import list_scenes

    jobs = (os.cpu_count() or 1) if args.jobs is None else args.jobs
    if jobs < 1:
        raise SRDEError(f"--jobs: expected a positive number of worker processes, got {jobs}")
    jobs = min(jobs, len(list_scenes(args.dataset_dir)))  # a missing dataset is reported first
    if jobs > 1:
        threads = max(1, (os.cpu_count() or 1) // jobs)
        backbone = BackboneLoader(functools.partial(_worker_backbone, args.backbone, args.preset,
                                                    threads))
    else:
        backbone = _load_backbone(args.backbone, args.preset)
    evaluation = evaluate_dataset(args.dataset_dir, backbone, masks=args.masks,
                                  progress=not args.quiet, jobs=jobs, srde_method=args.method)
    text = evaluation.to_markdown()
    print(text, end="")
    print(f"\n{len(evaluation.scenes)} scene(s) in {evaluation.wall_s:.1f} s: "
          f"{evaluation.scenes_per_second:.2f} scenes/s with {evaluation.jobs} process(es)")
    if args.out is not None:
        out = Path(args.out)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileFormatError(f"{out}: could not create the output folder: {exc}") from None
        (out / "eval.md").write_text(f"## {Path(args.dataset_dir).name}: backbone "
                                     f"{args.backbone}, masks {args.masks}\n\n{text}")
        (out / "eval.json").write_text(json.dumps(evaluation.to_dict(), indent=2,
                                                  allow_nan=False) + "\n")
        print(f"wrote {out}/: eval.md, eval.json")
    return 0



def _light(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in metres, got {text!r}")
    return values  # type: ignore[return-value]


def _add_mask_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mask", default=None, metavar="FILE",
                   help="object mask of the reference view (PNG labels: 0 = background, "
                   "1..K or 255 = object; or .npy); default: the scene's mask.png, else the "
                   "built-in highlight segmenter")
    p.add_argument("--auto-mask", action="store_true",
                   help="use the built-in highlight segmenter even if the scene has a mask")
    p.add_argument("--light", type=_light, default=None, metavar="X,Y,Z",
                   help="light position in metres (array frame), overriding rig.json")


def register(subparsers: Any) -> None:
    """Add the ``demo``, ``fuse``, ``srde`` and ``eval`` subcommands."""
    p = subparsers.add_parser(
        "demo", help="render a scene, run the stand-in backbone, fuse with SRDE, write results",
        description="The end-to-end default: render a textured room with glossy flat objects "
        "for a 3x3 camera array, run the bundled stand-in stereo network, find the objects "
        "with the built-in highlight segmenter, fuse with SRDE, and write the fused "
        "disparity (PFM, KITTI PNG), the source map, a JSON report and a figure; print "
        "the metrics of backbone, SRDE and fused map against ground truth.")
    p.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--seed", type=int, default=DEMO_SEED,
                   help=f"scene seed (default {DEMO_SEED})")
    p.add_argument("--objects", type=int, default=DEMO_OBJECTS,
                   help=f"glossy objects in the scene (default {DEMO_OBJECTS})")
    p.add_argument("--scale", type=float, default=1.0,
                   help="image scale relative to 640x480 (default 1; 0.5 is quicker)")
    p.add_argument("--backbone", default="default",
                   help="'default' (bundled stand-in network) or a stereo model .onnx")
    p.set_defaults(func=_cli_demo)

    p = subparsers.add_parser(
        "fuse", help="fuse a stereo model's disparity with SRDE for one scene folder",
        description="Run a stereo model on the scene's stereo pair, find the glossy objects "
        "(mask file, the scene's mask.png, or the built-in segmenter), replace their "
        "disparity by SRDE's where SRDE succeeds and agrees with the model, and write the "
        "fused disparity, source map, report and figure.")
    p.add_argument("scene_dir", help="scene folder: rig.json (with the light), cam*.png, "
                   "optional mask.png and gt_disparity.pfm")
    p.add_argument("--backbone", required=True,
                   help="'default' (bundled stand-in network) or a stereo model .onnx")
    p.add_argument("--preset", default=None,
                   help="conventions of the .onnx model: igev, igev++, raft-stereo, crestereo, "
                   "nmrf, foundationstereo or generic")
    _add_mask_options(p)
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=_cli_fuse)

    p = subparsers.add_parser(
        "srde", help="SRDE alone: disparity of the glossy objects of one scene folder",
        description="Estimate each glossy object's plane from its specular highlight and "
        "the known light, and its disparity; no stereo model is run.")
    p.add_argument("scene_dir", help="scene folder: rig.json (with the light), cam*.png")
    _add_mask_options(p)
    p.add_argument("--method", choices=("default", "paper"), default="default",
                   help="SRDE variant (default: joint triangulation with outlier rejection)")
    p.add_argument("--out", default=None, help="output folder (default: print only)")
    p.set_defaults(func=_cli_srde)

    p = subparsers.add_parser(
        "eval", help="evaluate backbone, SRDE and fused maps on a dataset with ground truth",
        description="For every scene folder of a dataset: run the stereo model, the mask "
        "stage, SRDE and the fusion; score backbone, SRDE and fused maps against ground "
        "truth over the full scene and over the objects; print mean ± std tables.")
    p.add_argument("dataset_dir", help="folder of scene folders (as written by "
                   "`srde-fusion render`)")
    p.add_argument("--backbone", required=True,
                   help="'default' (bundled stand-in network) or a stereo model .onnx")
    p.add_argument("--preset", default=None, help="conventions of the .onnx model")
    p.add_argument("--masks", choices=("user", "auto"), default="user",
                   help="'user': each scene's mask.png; 'auto': the built-in segmenter")
    p.add_argument("--method", choices=("default", "paper"), default="default",
                   help="SRDE variant")
    p.add_argument("--out", default=None, help="folder for eval.md and eval.json")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="worker processes, each loading the model once (default: one per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cli_eval)
