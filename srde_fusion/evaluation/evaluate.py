"""Evaluation against ground truth: backbone alone vs SRDE alone vs the fused (hybrid) map.

Each method is scored twice: over the full scene (every pixel with finite ground truth)
and over the objects (the union of the ground-truth object masks, or of the masks used
when the scene has none). SRDE alone only covers the objects it was run on; outside
them it has no prediction, which the metrics count as invalid pixels (see
:mod:`srde_fusion.evaluation.metrics`) and the ``coverage`` column shows.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import pickle
import socket
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from .._atomic import write_atomic
from .._json import json_safe
from ..errors import DisparityError, FileFormatError, LightError, SRDEError
from ..fusion import DEFAULT_BORDER_CHECK, BorderCheck, FusionResult, fuse
from ..io import SceneData, list_scenes, read_scene
from ..masks import resolve_masker
from ..srde import SRDE
from .metrics import PAPER_KEYS, evaluate, format_markdown_table, summarize

__all__ = [
    "METHODS",
    "REGIONS",
    "TABLE_KEYS",
    "score_fusion",
    "mask_iou",
    "SceneEvaluation",
    "DatasetEvaluation",
    "SceneFailure",
    "BackboneLoader",
    "evaluate_scene",
    "evaluate_dataset",
]

#: Methods compared, in table order.
METHODS = ("backbone", "srde", "fused")
#: Regions scored: every pixel with ground truth, and the objects only.
REGIONS = ("full", "masked")
#: Columns of the markdown tables: the paper's metrics, then KITTI-style ones.
TABLE_KEYS = (*PAPER_KEYS, "bad0.5", "bad1", "bad2", "bad3", "bad4", "d1", "coverage")
#: Mask sources :func:`evaluate_scene` understands by name.


def _with_coverage(metrics: dict[str, Any]) -> dict[str, Any]:
    valid = metrics["valid_px"]
    metrics["coverage"] = (1.0 - metrics["invalid_pred_px"] / valid) if valid else math.nan
    return metrics


def score_fusion(result: FusionResult, gt_disparity: np.ndarray, region: np.ndarray | None
                 ) -> dict[str, dict[str, dict[str, Any]]]:
    """Score the backbone, SRDE alone and the fused map against ground truth.

    Parameters
    ----------
    result : FusionResult
    gt_disparity : numpy.ndarray, (H, W), float, pixels
        Ground truth; non-finite pixels are not scored.
    region : numpy.ndarray, (H, W), bool, or None
        The objects; None leaves the masked scores empty (NaN).

    Returns
    -------
    dict
        ``scores[method][region]`` -> :func:`~srde_fusion.evaluation.metrics.evaluate` result plus
        ``coverage`` (fraction of scored pixels with a prediction), for ``method`` in
        :data:`METHODS` and ``region`` in :data:`REGIONS`.
    """
    gt = np.asarray(gt_disparity, dtype=np.float32)
    maps = {"backbone": result.backbone_disparity, "srde": result.srde_disparity,
            "fused": result.disparity}
    empty = np.zeros(gt.shape, dtype=bool)
    return {
        method: {
            "full": _with_coverage(evaluate(pred, gt)),
            "masked": _with_coverage(evaluate(pred, gt, empty if region is None else region)),
        }
        for method, pred in maps.items()
    }


def mask_iou(predicted: Sequence[np.ndarray], truth: Sequence[np.ndarray]) -> np.ndarray:
    """Best intersection-over-union of each true object with any predicted mask.

    Parameters
    ----------
    predicted, truth : sequences of numpy.ndarray, (H, W), bool

    Returns
    -------
    numpy.ndarray, (len(truth),), float64
        0 for an object no predicted mask touches.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.zeros((4, 4), bool); a[:2] = True
    >>> b = np.zeros((4, 4), bool); b[:1] = True
    >>> mask_iou([b], [a]).tolist()
    [0.5]
    """
    out = np.zeros(len(truth))
    for i, t in enumerate(truth):
        for p in predicted:
            union = np.count_nonzero(t | p)
            if union:
                out[i] = max(out[i], np.count_nonzero(t & p) / union)
    return out


@dataclass(frozen=True)
class SceneEvaluation:
    """Scores of one scene.

    Attributes
    ----------
    name : str
    scores : dict
        ``scores[method][region]`` -> metrics, see :func:`score_fusion`.
    report : dict
        The fusion report (:meth:`~srde_fusion.fusion.fuse.FusionResult.report`).
    mask_source : str
        ``"user"``, ``"auto"`` or the masker's name.
    mask_iou : tuple of float
        Best IoU of each ground-truth object with the masks used (empty without
        ground-truth masks).
    seconds : dict of str -> float
        Wall-clock time of the backbone, the mask stage and SRDE plus fusion.
    """

    name: str
    scores: Mapping[str, Mapping[str, Mapping[str, Any]]]
    report: Mapping[str, Any]
    mask_source: str
    mask_iou: tuple[float, ...] = ()
    seconds: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable view (NaN becomes None)."""
        return json_safe({
            "name": self.name, "mask_source": self.mask_source, "scores": self.scores,
            "mask_iou": list(self.mask_iou), "seconds": self.seconds, "fusion": self.report,
        })



@dataclass(frozen=True)
class SceneFailure:
    """A scene that could not be evaluated, and why.

    Attributes
    ----------
    name : str
        The scene folder's name.
    error : str
        The error's type (``"FileFormatError"``, ``"MaskError"``, ...).
    reason : str
        The error's message.
    """

    name: str
    error: str
    reason: str

    def to_dict(self) -> dict[str, str]:
        """Return a JSON-serialisable view."""
        return {"name": self.name, "error": self.error, "reason": self.reason}


@dataclass(frozen=True)
class DatasetEvaluation:
    """Scores of every scene of a dataset, and their summary.

    Attributes
    ----------
    scenes : tuple of SceneEvaluation
        The scenes evaluated, in dataset order.
    jobs : int
        Processes that evaluated the scenes: 1 in the calling process, the pool's size
        with ``jobs > 1``, and with an executor the distinct worker processes (host and
        process id) that returned scenes.
    wall_s : float
        Wall-clock time of the whole evaluation, seconds (NaN if not measured).
    failures : tuple of SceneFailure
        Scenes that could not be evaluated (bad files, no mask, no light, ...).
    runner : str
        Where the scenes ran: ``"this process"``, ``"N processes"`` or the executor's
        type (``"ThreadPoolExecutor"``, ``"ClientExecutor"`` for Dask, ...).
    """

    scenes: tuple[SceneEvaluation, ...]
    jobs: int = 1
    wall_s: float = math.nan
    failures: tuple[SceneFailure, ...] = ()
    runner: str = "this process"

    @property
    def scenes_per_second(self) -> float:
        """Scenes evaluated per second of wall-clock time (NaN if not measured)."""
        return len(self.scenes) / self.wall_s if self.wall_s > 0 else math.nan

    def summary(self) -> dict[str, dict[str, dict[str, tuple[float, float]]]]:
        """Mean and standard deviation over scenes, ``summary[method][region][key]``."""
        return {method: {region: summarize([s.scores[method][region] for s in self.scenes])
                         for region in REGIONS} for method in METHODS}

    def counts(self) -> dict[str, int]:
        """Objects, objects fused with SRDE, and fallbacks, over all scenes."""
        return {
            "scenes": len(self.scenes),
            "failed": len(self.failures),
            "objects": sum(s.report["n_objects"] for s in self.scenes),
            "srde": sum(s.report["n_srde"] for s in self.scenes),
            "fallback": sum(s.report["n_fallback"] for s in self.scenes),
        }

    def mean_mask_iou(self) -> float:
        """Mean best IoU of the ground-truth objects with the masks used (NaN if none)."""
        ious = [v for s in self.scenes for v in s.mask_iou]
        return float(np.mean(ious)) if ious else math.nan

    def to_markdown(self, keys: Sequence[str] = TABLE_KEYS) -> str:
        """Two tables (full scene, objects only), mean ± std over scenes; failed scenes."""
        counts = self.counts()
        lines = [
            f"{counts['scenes']} scene(s), {counts['objects']} object(s): SRDE used on "
            f"{counts['srde']}, backbone kept on {counts['fallback']} (fallback)."
            + (f" {counts['failed']} scene(s) failed (listed below)." if self.failures else ""),
        ]
        iou = self.mean_mask_iou()
        if not math.isnan(iou):
            lines.append(f"Mask IoU with the ground-truth objects: {iou:.3f} (mean over objects).")
        if self.scenes:
            summary = self.summary()
            for region, title in (("full", "Full scene"), ("masked", "Objects (masked)")):
                rows = {method: summary[method][region] for method in METHODS}
                lines += ["", f"### {title}", "", format_markdown_table(rows, keys).rstrip("\n")]
        if self.failures:
            lines += ["", "### Scenes that failed", "", "| scene | error | reason |",
                      "|---|---|---|"]
            lines += [f"| {f.name} | {f.error} | {f.reason.replace('|', '/')} |"
                      for f in self.failures]
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable view: summary, counts and every scene."""
        summary = {m: {r: {k: {"mean": v[0], "std": v[1]} for k, v in keys.items()}
                       for r, keys in regions.items()}
                   for m, regions in self.summary().items()} if self.scenes else {}
        run = {"jobs": self.jobs, "runner": self.runner, "wall_s": self.wall_s,
               "scenes_per_second": self.scenes_per_second}
        return json_safe({"counts": self.counts(), "mask_iou_mean": self.mean_mask_iou(),
                           "summary": summary, "run": run,
                           "scenes": [s.to_dict() for s in self.scenes],
                           "failures": [f.to_dict() for f in self.failures]})

    def write(self, out_dir: str | os.PathLike, title: str,
              settings: Mapping[str, Any] | None = None) -> list[Path]:
        """Write ``eval.md`` (the tables under ``title``) and ``eval.json`` into ``out_dir``.

        ``settings`` (the backbone, mask source, SRDE method, ...) are recorded in both,
        so a results folder says how it was made.

        Returns
        -------
        list of pathlib.Path
            The files written.

        Raises
        ------
        FileFormatError
            The folder cannot be created.
        """
        out = Path(out_dir)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileFormatError(f"{out}: could not create the output folder: {exc}") from None
        md, js = out / "eval.md", out / "eval.json"
        settings = dict(settings or {})
        listed = "".join(f"- {k}: {v}\n" for k, v in settings.items())
        write_atomic(md, f"## {title}\n\n{listed}{chr(10) if listed else ''}{self.to_markdown()}")
        data = {"settings": json_safe(settings), **self.to_dict()}
        write_atomic(js, json.dumps(data, indent=2, allow_nan=False) + "\n")
        return [md, js]


Backbone = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class BackboneLoader:
    """A backbone that each worker process of :func:`evaluate_dataset` loads for itself.

    Model sessions usually cannot be pickled, so parallel evaluation sends this recipe
    to the workers instead; ``load()`` runs once in each worker process (the first time
    one of its scenes needs it) and the backbone is kept there for its next scenes.

    Attributes
    ----------
    load : callable
        ``load() -> backbone``. It is pickled, so a module-level function or a
        ``functools.partial`` of one.
    """

    load: Callable[[], Backbone]


# Backbones loaded in this process, by their loader's pickle (a worker process of a pool
# or a cluster loads each model once and keeps it for its next scenes), with the loader.
_LOADED: dict[Any, tuple[BackboneLoader, Backbone]] = {}
_LOADING = threading.Lock()


def _limit_threads(threads: int) -> None:
    # Each worker gets its share of the cores; OpenCV (and torch, if loaded) would
    # otherwise start a thread per core in every process.
    cv2.setNumThreads(threads)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)


def _worker_backbone(backbone: Backbone | BackboneLoader) -> Backbone:
    """Return the backbone itself, or the one its loader made in this process (loaded once)."""
    if not isinstance(backbone, BackboneLoader):
        return backbone
    try:
        key: Any = pickle.dumps(backbone)
    except Exception:  # pickling raises several types; only threads here can share it
        key = id(backbone)
    with _LOADING:  # threads of one process share the model, loaded by the first
        entry = _LOADED.get(key)
        if entry is None or (isinstance(key, int) and entry[0] is not backbone):
            entry = _LOADED[key] = (backbone, backbone.load())
        return entry[1]


def _evaluate_task(folder: str, backbone: Backbone | BackboneLoader, masks: Any, strict: bool,
                   options: dict[str, Any]) -> tuple[SceneEvaluation | SceneFailure, str]:
    """Evaluate one scene wherever an executor runs it; also say which process did."""
    # A backbone that cannot be loaded is raised, not recorded as a failure of the scene.
    model = _worker_backbone(backbone)
    result = _evaluate_or_fail(Path(folder), model, masks, strict, options)
    return result, f"{socket.gethostname()}:{os.getpid()}"


def _evaluate_or_fail(folder: Path, backbone: Backbone, masks: Any, strict: bool,
                      options: dict[str, Any]) -> SceneEvaluation | SceneFailure:
    """Evaluate one scene; a bad scene is a failure record unless ``strict``."""
    try:
        return evaluate_scene(folder, backbone, masks=masks, **options)
    except SRDEError as exc:
        if strict:
            raise
        return SceneFailure(folder.name, type(exc).__name__, str(exc))



def evaluate_scene(scene: SceneData | str | os.PathLike, backbone: Backbone, *,
                   masks: Any = "user", srde_method: str = "default",
                   border_check: BorderCheck | None = DEFAULT_BORDER_CHECK) -> SceneEvaluation:
    """Run backbone, mask stage, SRDE and fusion on one scene and score them.

    Parameters
    ----------
    scene : SceneData or path
        A scene folder (or one loaded with :func:`~srde_fusion.io.read_scene`) with a
        light in its ``rig.json`` and a ground-truth disparity.
    backbone : callable
        ``backbone(left, right) -> (H, W)`` disparity in pixels.
    masks : {"user", "auto"} or masker
        ``"user"``: the scene's ``mask.png``; ``"auto"``: the built-in
        :class:`~srde_fusion.masks.stages.HighlightSegmenter`; or any
        ``masker(views, rig) -> list of masks``.
    srde_method : str
        See :class:`~srde_fusion.srde.estimator.SRDE`.
    border_check : BorderCheck or None
        See :func:`~srde_fusion.fusion.fuse.fuse`.

    Returns
    -------
    SceneEvaluation

    Raises
    ------
    FileFormatError
        The scene folder cannot be read.
    DisparityError
        The scene has no ground-truth disparity.
    MaskError
        ``masks="user"`` and the scene has no mask.
    LightError
        The scene's rig has no light.
    """
    if not isinstance(scene, SceneData):
        scene = read_scene(scene)
    if scene.gt_disparity is None:
        raise DisparityError(f"{scene.path}: expected a ground-truth disparity "
                             f"(gt_disparity.pfm or .npy) to evaluate against, got none")
    rig = scene.rig
    if rig.light_position_m is None:
        raise LightError(f"{scene.path}: expected a light position in rig.json, got none")
    choice = resolve_masker(masks, scene_labels=scene.mask_labels, where=str(scene.path))
    masker, source = choice.masker, choice.description
    views = list(scene.views)

    t0 = time.perf_counter()
    left, right = (views[i] for i in rig.stereo_pair)
    backbone_disparity = backbone(left, right)
    t1 = time.perf_counter()
    used_masks = masker(views, rig)
    t2 = time.perf_counter()
    srde = SRDE(rig, method=srde_method) if len(used_masks) else None
    result = fuse(backbone_disparity, views, rig, used_masks, srde, border_check=border_check)
    t3 = time.perf_counter()

    truth = scene.masks
    region = (np.logical_or.reduce(truth) if truth
              else np.logical_or.reduce(used_masks) if len(used_masks) else None)
    ious = tuple(float(v) for v in mask_iou(used_masks, truth)) if truth else ()
    return SceneEvaluation(
        name=scene.name, scores=score_fusion(result, scene.gt_disparity, region),
        report=result.report(), mask_source=source, mask_iou=ious,
        seconds={"backbone": t1 - t0, "masks": t2 - t1, "srde_and_fusion": t3 - t2})


def evaluate_dataset(dataset_dir: str | os.PathLike, backbone: Backbone | BackboneLoader, *,
                     masks: Any = "user", progress: bool = True, jobs: int = 1,
                     executor: Executor | None = None, strict: bool = False,
                     **options: Any) -> DatasetEvaluation:
    """Evaluate every scene folder of a dataset: in this process, in several, or on a cluster.

    Scenes are independent, so they can be evaluated side by side: ``jobs > 1`` starts a
    pool of worker processes on this machine, and ``executor`` hands the scenes to any
    :class:`concurrent.futures.Executor` -- a thread pool, a process pool, or a Dask
    ``distributed`` client's ``client.get_executor()`` that spreads them over a cluster.
    Each worker process loads a :class:`BackboneLoader`'s model once; the scores are the
    same as in one process, and scenes stay in dataset order.

    Parameters
    ----------
    dataset_dir : path
        A folder of scene folders (see :func:`~srde_fusion.io.files.list_scenes`). With
        an executor whose workers run on other machines, the path must name the same
        folder there (a shared file system).
    backbone : callable or BackboneLoader
        ``backbone(left, right) -> (H, W)`` disparity in pixels, or a loader that makes
        one. Where scenes run in other processes (``jobs > 1``, a process pool, Dask) it
        is pickled to them; one that holds a model session cannot be, so pass a
        :class:`BackboneLoader` instead. A thread pool shares the callable itself.
    masks : {"user", "auto"} or masker
        See :func:`evaluate_scene`.
    progress : bool
        Show a progress bar on stderr.
    jobs : int
        Worker processes on this machine (at most one per scene); 1 evaluates in this
        process. ``os.cpu_count()`` uses every core. Only 1 with an ``executor``.
    executor : concurrent.futures.Executor, optional
        Where to run the scenes, one task per scene; it is used, not shut down.
    strict : bool
        Stop at the first scene that cannot be evaluated (raise its error). By default
        such a scene is recorded in ``failures`` and the others are still evaluated.
    **options
        Passed to :func:`evaluate_scene` (``srde_method``, ``border_check``).

    Returns
    -------
    DatasetEvaluation
        With ``jobs`` (the processes used), ``runner`` and ``wall_s``, hence
        ``scenes_per_second``.

    Raises
    ------
    SRDEError
        ``jobs`` is not a positive integer, ``executor`` is not an Executor or comes with
        ``jobs > 1``, or a backbone that cannot be pickled is given with ``jobs > 1``;
        with ``strict``, whatever :func:`evaluate_scene` raises.
    """
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise SRDEError(f"jobs: expected a positive integer (worker processes), got {jobs!r}")
    if executor is not None and not isinstance(executor, Executor):
        raise SRDEError(f"executor: expected a concurrent.futures.Executor, got "
                        f"{type(executor).__name__}")
    if executor is not None and jobs != 1:
        raise SRDEError(f"jobs, executor: expected one way to run the scenes in parallel, got "
                        f"jobs={jobs} and an executor")
    start = time.perf_counter()
    folders = list_scenes(dataset_dir)
    if executor is not None:
        results, workers = _run_on(executor, folders, backbone, masks, strict, options,
                                   progress, f"evaluating ({type(executor).__name__})")
        return _collect(results, len(workers), time.perf_counter() - start,
                        type(executor).__name__)
    jobs = min(jobs, len(folders))
    if jobs <= 1:
        if isinstance(backbone, BackboneLoader):
            backbone = backbone.load()
        if progress:
            folders = tqdm(folders, desc="evaluating", unit="scene")
        try:
            results = [_evaluate_or_fail(Path(f), backbone, masks, strict, options)
                       for f in folders]
        finally:
            if progress:  # end the bar's line, so an error message starts on its own
                folders.close()
        return _collect(results, 1, time.perf_counter() - start)
    try:
        pickle.dumps(backbone)
    except Exception as exc:  # pickling raises several exception types
        raise SRDEError(
            f"backbone: expected a picklable backbone or a BackboneLoader for jobs > 1 (every "
            f"worker process needs its own), got {type(backbone).__name__} ({exc})") from None
    threads = max(1, (os.cpu_count() or 1) // jobs)
    # Fresh interpreters: forking a process that runs model sessions or OpenMP pools
    # can deadlock the child.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(jobs, mp_context=context, initializer=_limit_threads,
                             initargs=(threads,)) as pool:
        results, _ = _run_on(pool, folders, backbone, masks, strict, options, progress,
                             f"evaluating ({jobs} processes)")
    return _collect(results, jobs, time.perf_counter() - start, f"{jobs} processes")


def _run_on(executor: Executor, folders: Sequence[Path], backbone: Any, masks: Any,
            strict: bool, options: dict[str, Any], progress: bool, label: str
            ) -> tuple[list[SceneEvaluation | SceneFailure], set[str]]:
    """Submit one task per scene; collect the results in dataset order, and the workers."""
    futures: list[Future] = [executor.submit(_evaluate_task, str(f), backbone, masks, strict,
                                             options) for f in folders]
    results, workers = [], set()
    bar = tqdm(total=len(futures), desc=label, unit="scene", disable=not progress)
    try:
        for future in futures:
            result, worker = future.result()
            results.append(result)
            workers.add(worker)
            bar.update()
    except BaseException:
        for future in futures:  # stop what has not started (strict, an interrupt)
            future.cancel()
        raise
    finally:
        bar.close()
    return results, workers


def _collect(results: list[SceneEvaluation | SceneFailure], jobs: int, wall_s: float,
             runner: str = "this process") -> DatasetEvaluation:
    return DatasetEvaluation(tuple(r for r in results if isinstance(r, SceneEvaluation)), jobs,
                             wall_s, tuple(r for r in results if isinstance(r, SceneFailure)),
                             runner)
