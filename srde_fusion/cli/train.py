"""``train-standin``: train the stand-in stereo network and export it to ONNX."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..adapters.standin.training import TrainingConfig, train_standin

__all__ = ["register"]


def _run_cli(args: argparse.Namespace) -> int:
    config = TrainingConfig(size=args.size, steps=args.steps, seed=args.seed,
                            batch_size=args.batch_size, threads=args.threads,
                            crop_hw=tuple(args.crop), learning_rate=args.learning_rate,
                            init_onnx=args.init)
    command = (f"srde-fusion train-standin --out {Path(args.out).name} --size {args.size} "
               f"--steps {args.steps} --seed {args.seed} --batch-size {args.batch_size} "
               f"--crop {args.crop[0]} {args.crop[1]} --learning-rate {args.learning_rate:g}"
               + (f" --init {Path(args.init).name}" if args.init else ""))
    report = train_standin(args.out, config, progress=not args.quiet, command=command)
    print(f"wrote {report.onnx_path} and {report.info_path.name}: held-out EPE "
          f"{report.initial_epe_px:.2f} -> {report.final_epe_px:.2f} px, bad-2 "
          f"{report.final_bad2:.1%}, ONNX parity {report.parity_max_abs_px:.1e} px, "
          f"{report.seconds / 60:.1f} min")
    return 0


def register(subparsers: Any) -> None:
    """Add the ``train-standin`` subcommand."""
    parser = subparsers.add_parser(
        "train-standin",
        help="train the tiny stand-in stereo network and export it to ONNX",
        description="Train the stand-in stereo network on procedural textured stereo pairs "
        "(CPU), export it to ONNX with dynamic height and width, and write a JSON record "
        "(config, command, held-out metrics) next to it.",
    )
    defaults = TrainingConfig()
    parser.add_argument("--out", required=True, help="output .onnx path")
    parser.add_argument("--steps", type=int, default=defaults.steps,
                        help=f"optimiser steps (default {defaults.steps})")
    parser.add_argument("--size", choices=("tiny", "default"), default=defaults.size,
                        help="architecture size (default: default)")
    parser.add_argument("--seed", type=int, default=defaults.seed, help="random seed")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size,
                        help=f"pairs per step (default {defaults.batch_size})")
    parser.add_argument("--crop", type=int, nargs=2, metavar=("H", "W"),
                        default=list(defaults.crop_hw),
                        help="training crop height and width, multiples of 32 (default "
                        f"{defaults.crop_hw[0]} {defaults.crop_hw[1]})")
    parser.add_argument("--learning-rate", type=float, default=defaults.learning_rate,
                        help=f"peak learning rate (default {defaults.learning_rate:g})")
    parser.add_argument("--init", default=None, metavar="ONNX",
                        help="start from the weights of this stand-in export (same size): "
                        "a fine-tuning stage")
    parser.add_argument("--threads", type=int, default=defaults.threads,
                        help=f"torch CPU threads (default {defaults.threads})")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=_run_cli)
