"""``render``: a synthetic dataset of glossy flat objects with exact ground truth."""

from __future__ import annotations

import argparse
from typing import Any

from ..geometry import CameraRig
from ..synthetic import BACKGROUNDS, LOBES, Physics, render_dataset

__all__ = ["register"]


def _cli_render(args: argparse.Namespace) -> int:
    rig = None
    if args.rig is not None:
        rig = CameraRig.from_json(args.rig)
    folders = render_dataset(
        args.out_dir,
        n_scenes=args.scenes,
        seed=args.seed,
        rig=rig,
        background=args.background,
        n_objects=args.objects,
        supersample=args.supersample,
        physics=Physics.faithful() if args.physics == "faithful" else None,
        lobe=args.lobe,
        n_lights=args.lights[0] if len(args.lights) == 1 else tuple(args.lights),
        all_highlights_on_objects=args.all_highlights,
        progress=not args.quiet,
        overwrite=args.force,
    )
    print(f"wrote {len(folders)} scene(s) to {args.out_dir}")
    return 0


def register(subparsers: Any) -> None:
    """Add the ``render`` subcommand (a synthetic dataset with ground truth)."""
    p = subparsers.add_parser(
        "render",
        help="render a synthetic dataset of glossy flat objects with ground truth",
        description="Render random scenes (flat textureless glossy objects, one light never "
        "seen directly, highlight inside every object in every view) into scene folders "
        "with views, rig.json (with the light), mask.png, gt_disparity.pfm and scene.json.",
    )
    p.add_argument("out_dir", help="dataset folder to create (one scene_NNNN folder per scene)")
    p.add_argument("--scenes", type=int, default=10, help="number of scenes (default 10)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    p.add_argument(
        "--background",
        choices=BACKGROUNDS,
        default="none",
        help="'none': background at infinity (the paper's setting); 'textured': "
        "textured walls and panels at finite depth",
    )
    p.add_argument(
        "--rig",
        default=None,
        help="rig.json of the camera array (default: 3x3, 85 mm, 640x480, fx 600)",
    )
    p.add_argument("--objects", type=int, default=1, help="objects per scene (default 1)")
    p.add_argument(
        "--lights", type=int, nargs="+", default=[1], metavar="N",
        help="lights per scene: N, or MIN MAX drawn per scene (default 1); rig.json lists "
        "them all, scene.json holds each light's virtual lights and highlight centres")
    p.add_argument(
        "--all-highlights", action="store_true",
        help="with several lights, put every light's highlight inside every object in every "
        "view (by default only the first light's is guaranteed)")
    p.add_argument("--lobe", choices=LOBES, default="ggx", help="specular lobe (default ggx)")
    p.add_argument(
        "--supersample", type=int, default=1, help="k: average k x k samples per pixel (default 1)"
    )
    p.add_argument(
        "--physics", choices=("model", "faithful"), default="model",
        help="'model': the refinement's own shading model (fast, fits are exact by "
        "construction); 'faithful': exact Fresnel, the light integrated over its area, "
        "height-correlated masking, diffuse transmittance, photon and read noise")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true",
                   help="replace the scene folders already in OUT_DIR (refused without it)")
    p.set_defaults(func=_cli_render)
