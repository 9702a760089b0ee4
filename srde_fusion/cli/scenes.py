"""``demo``, ``fuse`` and ``srde``: the scene-folder workflows from the command line.

Each handler maps flags to a :mod:`srde_fusion.workflows` function and prints its result.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SRDEError
from ..evaluation import format_markdown_table
from ..fusion import FusionResult
from ..io import is_kitti_folder
from ..masks import UserMasks
from ..workflows import (
    DEMO_OBJECTS,
    DEMO_SEED,
    SceneRun,
    fuse_dataset,
    fuse_scene,
    run_demo,
    srde_scene,
)
from .backbones import add_spec_options, backbone_from, spec_from_args

__all__ = ["register"]


def _print_objects(result: FusionResult) -> None:
    if not result.objects:
        print("no glossy object found: the backbone's disparity is kept everywhere")
    for obj in result.objects:
        print(f"object {obj.index}: {obj.status} ({obj.pixel_count} px) - {obj.reason}")


def _print_masks(run: SceneRun) -> None:
    if run.masks:
        print(f"masks: {run.masks}")


def _print_files(run: SceneRun) -> None:
    for note in run.notes:
        print(f"note: {note}")
    folder = run.files["report_json"].parent
    names = ", ".join(p.name for p in run.files.values())
    print(f"wrote {folder}/: {names}")


def _cli_demo(args: argparse.Namespace) -> int:
    run = run_demo(args.out, seed=args.seed, n_objects=args.objects, scale=args.scale,
                   backbone=backbone_from(args.backbone, spec_from_args(args),
                                          device=args.device))
    _print_objects(run.fusion)
    _print_masks(run)
    print()
    print(run.table())
    _print_files(run)
    return 0


def _is_dataset(folder: str) -> bool:
    """Say whether the folder holds scenes (or KITTI frames) rather than being one scene."""
    path = Path(folder)
    if is_kitti_folder(path):
        return True
    return (path.is_dir() and not (path / "rig.json").is_file()
            and not (path / "calib.txt").is_file()
            and any((p / "rig.json").is_file() or (p / "calib.txt").is_file()
                    for p in path.iterdir() if p.is_dir()))


def _mask_source(args: argparse.Namespace) -> Any:
    """Return the --mask file, or a reader that keeps its binary mask as one object."""
    if not args.mask_as_one:
        return args.mask
    if args.mask is None:
        raise SRDEError("--mask-as-one: expected --mask FILE (the mask to keep whole), got none")
    return UserMasks(args.mask, split_components=False)


def _cli_fuse(args: argparse.Namespace) -> int:
    if args.backbone is None and (args.preset or args.spec) is not None:
        raise SRDEError("--preset/--spec: expected with --backbone (the conventions of a model "
                        "to run), got --disparity")
    backbone = (None if args.backbone is None
                else backbone_from(args.backbone, spec_from_args(args), device=args.device))
    if _is_dataset(args.scene_dir):
        if backbone is None:
            raise SRDEError(f"{args.scene_dir}: expected --backbone for a folder of scenes or "
                            f"frames (one --disparity map cannot serve several), got --disparity")
        dataset = fuse_dataset(args.scene_dir, args.out, backbone=backbone, mask=_mask_source(args),
                               auto_mask=args.auto_mask, light=args.light,
                               progress=not args.quiet, max_faces=args.max_faces)
        for name, reason in dataset.failures.items():
            print(f"{name}: failed - {reason}")
        print(f"{dataset.summary()}; results in {Path(args.out)}/<scene>/")
        return 1 if dataset.failures else 0
    run = fuse_scene(args.scene_dir, args.out, backbone=backbone, disparity=args.disparity,
                     disparity_scale=args.disparity_scale, mask=_mask_source(args),
                     auto_mask=args.auto_mask, light=args.light, max_faces=args.max_faces)
    _print_objects(run.fusion)
    _print_masks(run)
    if run.scores is not None:
        print()
        print(run.table())
    _print_files(run)
    return 0


def _cli_srde(args: argparse.Namespace) -> int:
    run = srde_scene(args.scene_dir, args.out, mask=_mask_source(args), auto_mask=args.auto_mask,
                     light=args.light, method=args.method, max_faces=args.max_faces)
    for obj in run.fusion.objects:
        srde = obj.srde
        plane = getattr(srde, "plane", None)
        detail = srde.reason
        if not detail and plane is not None:
            detail = (f"plane n = {np.round(plane.n, 4).tolist()}, c = {plane.offset_m:.4f} m, "
                      f"residual {srde.residual_px:.3f} px")
            sigma = getattr(srde, "disparity_sigma_px", float("nan"))
            if np.isfinite(sigma):  # a refined plane's standard error
                detail += f", disparity +- {sigma:.4f} px"
        print(f"object {obj.index}: {srde.status} ({obj.pixel_count} px) - {detail}")
    if not run.fusion.objects:
        print("no glossy object found")
    _print_masks(run)
    if run.scores is not None:
        print()
        print(format_markdown_table({"srde": run.scores["srde"]["masked"]},
                                    ["epe", "rmse", "bmp0.1", "bad1", "coverage"]), end="")
    if run.files:
        _print_files(run)
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
    p.add_argument("--mask-as-one", action="store_true",
                   help="with --mask: a binary (0/255) mask is one object, not split into its "
                   "connected components")
    p.add_argument("--light", type=_light, default=None, metavar="X,Y,Z",
                   help="light position in metres (array frame), overriding rig.json")
    p.add_argument("--max-faces", type=int, choices=(1, 2, 3), default=1, metavar="N",
                   help="most flat faces an object may have, 1-3 (default 1): with 2 or 3, an "
                   "object whose highlights show several planes (a box seen on an edge) gets "
                   "one plane per face; needs rig.json to list every light")


def _add_device_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="cpu", metavar="cpu|cuda[:N]",
                   help="where the model runs (torch device; CUDA execution provider for "
                   "ONNX); default cpu")


def register(subparsers: Any) -> None:
    """Add the ``demo``, ``fuse`` and ``srde`` subcommands."""
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
                   help="'default' (bundled stand-in network), 'sgbm' (OpenCV "
                   "semi-global matching) or a stereo model .onnx")
    add_spec_options(p)
    _add_device_option(p)
    p.set_defaults(func=_cli_demo)

    p = subparsers.add_parser(
        "fuse", help="fuse a stereo model's disparity with SRDE for one scene folder",
        description="Run a stereo model on the scene's stereo pair (or take the disparity "
        "map your pipeline already made, --disparity), find the glossy objects "
        "(mask file, the scene's mask.png, or the built-in segmenter), replace their "
        "disparity by SRDE's where SRDE succeeds and agrees with the model, and write the "
        "fused disparity, source map, report and figure.")
    p.add_argument("scene_dir", help="scene folder: rig.json (with the light), cam*.png, "
                   "optional mask.png and gt_disparity.pfm; or a Middlebury folder; or a folder "
                   "of scene folders, each fused into OUT/<scene>; or a KITTI folder "
                   "(image_2/, image_3/), each frame fused into OUT/<frame> (one frame: "
                   "KITTI_DIR/<frame>)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--backbone",
                        help="'default' (bundled stand-in network), 'sgbm' (OpenCV "
                        "semi-global matching) or a stereo model .onnx")
    source.add_argument("--disparity", metavar="FILE",
                        help="a disparity map your pipeline already made for the reference "
                        "view (.pfm, KITTI 16-bit .png or .npy), instead of running a model")
    p.add_argument("--disparity-scale", type=float, default=1.0, metavar="S",
                   help="multiply --disparity's values by S to get pixels (default 1)")
    add_spec_options(p)
    _add_mask_options(p)
    p.add_argument("--out", required=True, help="output folder")
    _add_device_option(p)
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
