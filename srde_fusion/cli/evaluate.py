"""``eval``: backbone, SRDE and fused maps scored on a dataset with ground truth."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import os
import sys
from pathlib import Path
from typing import Any

from .._atomic import folder_lock
from ..errors import SRDEError
from ..evaluation import BackboneLoader, evaluate_dataset
from ..io import list_scenes
from .backbones import add_spec_options, backbone_from, spec_from_args

__all__ = ["register"]

# How long eval waits for a Dask scheduler to answer, seconds.
_CONNECT_TIMEOUT_S = 10


def _spec_record(spec: Any) -> Any:
    """Return the spec as ``eval.json`` records it: every field of a --spec file, else None."""
    return None if spec is None or isinstance(spec, str) else dataclasses.asdict(spec)


def _dask_executor(address: str, stack: contextlib.ExitStack) -> Any:
    """Connect to a Dask scheduler (closed with ``stack``); return its client's executor."""
    try:  # an optional dependency: the [cluster] extra
        from distributed import Client
    except ImportError:
        raise SRDEError("--scheduler: expected Dask's distributed package (pip install "
                        "'srde-fusion[cluster]'), got none installed") from None
    try:
        client = stack.enter_context(Client(address, timeout=_CONNECT_TIMEOUT_S))
    except (OSError, TimeoutError, ValueError) as exc:
        raise SRDEError(f"--scheduler: expected a Dask scheduler at {address!r}, got "
                        f"{type(exc).__name__}: {exc}") from None
    return client.get_executor()


def _cli_eval(args: argparse.Namespace) -> int:
    if args.scheduler is not None and args.jobs is not None:
        raise SRDEError("--jobs, --scheduler: expected one of them (processes here, or a Dask "
                        "cluster's workers), got both")
    jobs = 1 if args.scheduler is not None else (os.cpu_count() or 1) if args.jobs is None \
        else args.jobs
    if jobs < 1:
        raise SRDEError(f"--jobs: expected a positive number of worker processes, got {jobs}")
    jobs = min(jobs, len(list_scenes(args.dataset_dir)))  # a missing dataset is reported first
    spec = spec_from_args(args)
    if jobs > 1 or args.scheduler is not None:
        threads = max(1, (os.cpu_count() or 1) // jobs) if args.scheduler is None else None
        backbone = BackboneLoader(functools.partial(backbone_from, args.backbone, spec,
                                                    threads=threads, device=args.device))
        backbone_from(args.backbone, spec, device=args.device)  # fail here, not in workers
    else:
        backbone = backbone_from(args.backbone, spec, device=args.device)
    with contextlib.ExitStack() as stack:
        if args.out is not None:  # checked and held before any scene is computed
            stack.enter_context(folder_lock(args.out))
        executor = (None if args.scheduler is None
                    else _dask_executor(args.scheduler, stack))
        evaluation = evaluate_dataset(args.dataset_dir, backbone, masks=args.masks,
                                      progress=not args.quiet, jobs=jobs, executor=executor,
                                      srde_method=args.method, strict=args.strict)
        text = evaluation.to_markdown()
        print(text, end="")
        print(f"\n{len(evaluation.scenes)} scene(s) in {evaluation.wall_s:.1f} s: "
              f"{evaluation.scenes_per_second:.2f} scenes/s with {evaluation.jobs} process(es)"
              + ("" if executor is None else f" of the Dask cluster at {args.scheduler}"))
        if args.out is not None:
            files = evaluation.write(
                args.out, f"{Path(args.dataset_dir).name}: backbone {args.backbone}, masks "
                f"{args.masks}", settings={
                    "dataset": str(args.dataset_dir), "backbone": args.backbone,
                    "preset": args.preset, "spec": _spec_record(spec),
                    "masks": args.masks, "srde_method": args.method,
                    "device": args.device, "jobs": evaluation.jobs,
                    **({} if args.scheduler is None else {"scheduler": args.scheduler})})
            print(f"wrote {Path(args.out)}/: {', '.join(f.name for f in files)}")
    if evaluation.failures:
        print(f"{len(evaluation.failures)} scene(s) could not be evaluated (see the table "
              f"above); --strict stops at the first", file=sys.stderr)
        return 1
    return 0


def register(subparsers: Any) -> None:
    """Add the ``eval`` subcommand."""
    p = subparsers.add_parser(
        "eval", help="evaluate backbone, SRDE and fused maps on a dataset with ground truth",
        description="For every scene folder of a dataset: run the stereo model, the mask "
        "stage, SRDE and the fusion; score backbone, SRDE and fused maps against ground "
        "truth over the full scene and over the objects; print mean ± std tables.")
    p.add_argument("dataset_dir", help="folder of scene folders (as written by "
                   "`srde-fusion render`)")
    p.add_argument("--backbone", required=True,
                   help="'default' (bundled stand-in network), 'sgbm' (OpenCV "
                   "semi-global matching) or a stereo model .onnx")
    add_spec_options(p)
    p.add_argument("--masks", choices=("user", "auto"), default="user",
                   help="'user': each scene's mask.png; 'auto': the built-in segmenter")
    p.add_argument("--method", choices=("default", "paper"), default="default",
                   help="SRDE variant")
    p.add_argument("--out", default=None, help="folder for eval.md and eval.json (checked, "
                   "and locked against a second run, before any scene is evaluated)")
    p.add_argument("--strict", action="store_true",
                   help="stop at the first scene that cannot be evaluated (default: evaluate "
                   "the others, list the failed ones, exit status 1)")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="worker processes, each loading the model once (default: one per core)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="evaluate the scenes on a Dask cluster (e.g. tcp://host:8786; needs "
                   "the [cluster] extra); its workers must see DATASET_DIR at the same path "
                   "and load the model themselves")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--device", default="cpu", metavar="cpu|cuda[:N]",
                   help="where the model runs (torch device; CUDA execution provider for "
                   "ONNX); default cpu")
    p.set_defaults(func=_cli_eval)
