"""``make-board`` and ``calibrate-light``: the light calibration's two commands."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..calibration import (
    DEFAULT_MATCH_TOLERANCE_PX,
    DEFAULT_MAX_INCIDENCE_DEG,
    DEFAULT_MAX_RESIDUAL_M,
    DEFAULT_MIN_VIEWS,
    Board,
    calibrate_light_files,
    write_board,
    write_calibration_figures,
)

__all__ = ["register"]


def register(subparsers) -> None:
    """Add the ``make-board`` and ``calibrate-light`` subcommands."""
    _register_make_board(subparsers)
    _register_calibrate_light(subparsers)


def _make_board_command(args) -> int:
    board = Board.corner_layout(
        dictionary=args.dictionary,
        marker_size_m=args.marker_size_mm / 1000.0,
        plate_size_m=(args.plate_size_mm[0] / 1000.0, args.plate_size_mm[1] / 1000.0),
        margin_m=None if args.margin_mm is None else args.margin_mm / 1000.0,
        first_id=args.first_id,
    )
    png, js = write_board(board, args.out_dir, dpi=args.dpi, overwrite=args.force)
    w, h = board.plate_size_m
    print(f"wrote {png} ({w * 1000:g} x {h * 1000:g} mm at {args.dpi:g} dpi) and {js}")
    print(
        f"{len(board.markers)} markers {board.ids.tolist()} from {board.dictionary}, "
        f"{board.marker_size_m * 1000:g} mm each; print at 100 % scale, then measure a "
        "printed marker and fix marker_size_m and the corners in board.json if it differs"
    )
    return 0


def _register_make_board(subparsers) -> None:
    """Add the ``make-board`` subcommand."""
    p = subparsers.add_parser(
        "make-board",
        help="write a printable ArUco calibration plate (board.png + board.json)",
        description="Write board.png (printable at its true size) and board.json describing an "
        "ArUco plate with one marker in each corner and a free centre for the highlight; "
        "used by calibrate-light.",
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="folder to write board.png and board.json to")
    p.add_argument("--dpi", type=float, default=300.0, help="print resolution (default 300)")
    p.add_argument(
        "--marker-size-mm", type=float, default=50.0, help="side of each marker in mm (default 50)"
    )
    p.add_argument(
        "--plate-size-mm",
        type=float,
        nargs=2,
        default=(297.0, 210.0),
        metavar=("W", "H"),
        help="plate width and height in mm (default 297 210, A4)",
    )
    p.add_argument(
        "--margin-mm",
        type=float,
        default=None,
        help="white border between markers and plate edge in mm (default 0.2 x marker)",
    )
    p.add_argument(
        "--dictionary", default="DICT_4X4_50", help="OpenCV ArUco dictionary (default DICT_4X4_50)"
    )
    p.add_argument("--first-id", type=int, default=0, help="id of the first marker (default 0)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing board.png/board.json (refused without it)")
    p.set_defaults(func=_make_board_command)


def _lights_arg(text: str) -> int | str:
    """``--lights``: a positive number of lights or "auto"."""
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of lights or 'auto', "
                                         f"got {text!r}")
    return value


def _calibrate_light_command(args) -> int:
    options = {} if args.match_tolerance_px is None else {
        "match_tolerance_px": args.match_tolerance_px}
    calibration = calibrate_light_files(
        args.captures,
        args.board,
        args.rig,
        write=not args.dry_run,
        n_lights=args.lights,
        light=args.light,
        method=args.method,
        refine=not args.no_refine,
        photometric=not args.no_photometric,
        min_views=args.min_views,
        max_incidence_deg=args.max_incidence_deg,
        max_residual_m=args.max_residual_mm / 1000.0,
        **options,
    )
    if calibration.lights is None:
        print(calibration.estimate.summary())
    else:
        print(calibration.lights.summary())
        for k, light in enumerate(calibration.rig.lights):
            label = f" ({light.name})" if light.name else ""
            radius = ("radius unknown" if light.radius_m is None
                      else f"radius {light.radius_m * 1000:g} mm, from {args.rig}")
            print(f"rig light {k}{label}: {radius}; the plate cannot measure it")
    index = calibration.light_index
    n = len(calibration.rig.lights)
    if index is not None:
        name = calibration.rig.lights[index].name
        what = f"light {index}" + (f" ({name})" if name else "")
        kept = "" if n == 1 else f"; the other {n - 1} light(s) as rig.json had them"
    else:
        what, kept = ("the light" if n == 1 else f"{n} lights"), ""
    if args.dry_run:
        print(f"{args.rig} left unchanged (--dry-run)")
    else:
        print(f"wrote {what} into {args.rig}{kept} (previous file kept as "
              f"{calibration.backup})")
    if args.figure is not None and calibration.lights is not None:
        board = Board.from_json(args.board)
        for k, estimate in enumerate(calibration.estimates):
            out = Path(args.figure) / f"light{k}"
            files = write_calibration_figures(out, args.captures, estimate, calibration.rig,
                                              board)
            print(f"wrote {out}/: {', '.join(f.name for f in files)}")
    elif args.figure is not None:
        files = write_calibration_figures(args.figure, args.captures, calibration.estimate,
                                          calibration.rig, Board.from_json(args.board))
        print(f"wrote {args.figure}/: {', '.join(f.name for f in files)}")
    return 0


def _register_calibrate_light(subparsers) -> None:
    """Add the ``calibrate-light`` subcommand."""
    p = subparsers.add_parser(
        "calibrate-light",
        help="locate the light from its highlight on an ArUco plate",
        description="Estimate the light position from captures of the ArUco plate (board.json "
        "from make-board): plate pose from the markers of all views, reflected rays of the "
        "highlight centres, least-squares intersection over all captures. Writes the light "
        "into rig.json (keeping the previous file as rig.json.bak, .bak1, ...) and prints "
        "position and residual.",
    )
    p.add_argument(
        "captures",
        nargs="+",
        metavar="CAPTURE_DIR",
        help="folder with one image per camera, named after the camera (one per "
        "plate pose; more poses, tilted differently, give a better light)",
    )
    p.add_argument("--board", required=True, help="the plate's board.json")
    p.add_argument("--rig", required=True, help="rig.json to read, and to write the light into")
    p.add_argument(
        "--lights",
        type=_lights_arg,
        default=None,
        metavar="N|auto",
        help="number of lights the plate shows (one highlight each), or 'auto' to count "
        "them; default: as many as rig.json lists, one if none. Highlights are sorted to "
        "lights by geometry; an ambiguous sorting is an error, never a guess. Lights "
        "already in rig.json keep their names and radius_m (the plate cannot measure a "
        "radius)",
    )
    p.add_argument(
        "--light",
        default=None,
        metavar="K|NAME",
        help="calibrate one of the lights rig.json lists from captures that show it alone "
        "(the other lamps switched off): its name, or its index from 0 (digits that name "
        "no light); the number of lights rig.json lists adds a new one. The other lights "
        "are written back unchanged. Lamps so close that their highlights merge on the "
        "plate are calibrated one at a time this way",
    )
    p.add_argument(
        "--match-tolerance-px",
        type=float,
        default=None,
        help="with several lights: largest distance of a highlight from the image of the "
        f"virtual light it joins (default {DEFAULT_MATCH_TOLERANCE_PX:g})",
    )
    p.add_argument(
        "--method",
        choices=("blob", "paper"),
        default="blob",
        help="highlight detector (default blob)",
    )
    p.add_argument(
        "--min-views",
        type=int,
        default=DEFAULT_MIN_VIEWS,
        help=f"views per capture that must show the highlight (default {DEFAULT_MIN_VIEWS})",
    )
    p.add_argument(
        "--max-incidence-deg",
        type=float,
        default=DEFAULT_MAX_INCIDENCE_DEG,
        help="reject plates tilted further from the line of sight "
        f"(default {DEFAULT_MAX_INCIDENCE_DEG:g})",
    )
    p.add_argument(
        "--max-residual-mm",
        type=float,
        default=DEFAULT_MAX_RESIDUAL_M * 1000.0,
        help="reject rays whose mean distance to the light exceeds this "
        f"(default {DEFAULT_MAX_RESIDUAL_M * 1000:g})",
    )
    p.add_argument(
        "--no-refine",
        action="store_true",
        help="keep the ray intersection (the paper's estimate), skip the joint refinement",
    )
    p.add_argument(
        "--no-photometric",
        action="store_true",
        help="keep the lights of the highlight centres' rays; by default one or two lights "
        "move to where their highlights' images put them (each capture read by SRDE's lobe "
        "fit)",
    )
    p.add_argument("--dry-run", action="store_true", help="print the light, do not write rig.json")
    p.add_argument("--figure", default=None, metavar="DIR",
                   help="write capture_<c>.png per capture (each view: markers found and "
                   "reprojected, highlight centre and its residual) and light_3d.png (plate "
                   "poses, rays, the light) into DIR; with several lights, one DIR/light<k>/ "
                   "per light")
    p.set_defaults(func=_calibrate_light_command)
