"""Evaluation against ground truth: backbone alone vs SRDE alone vs the fused (hybrid) map.

Each method is scored twice: over the full scene (every pixel with finite ground truth)
and over the objects (the union of the ground-truth object masks, or of the masks used
when the scene has none). SRDE alone only covers the objects it was run on; outside
them it has no prediction, which the metrics count as invalid pixels (see
:mod:`srde_fusion.metrics`) and the ``coverage`` column shows.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import MaskError, SRDEError
from .fusion import DEFAULT_BORDER_CHECK, BorderCheck, FusionResult, fuse
from .io import SceneData, list_scenes, read_scene
from .masks import HighlightSegmenter, UserMasks
from .metrics import PAPER_KEYS, evaluate, format_markdown_table, summarize

__all__ = [
    "METHODS",
    "REGIONS",
    "TABLE_KEYS",
    "score_fusion",
    "mask_iou",
    "SceneEvaluation",
    "DatasetEvaluation",
    "evaluate_scene",
    "evaluate_dataset",
]

#: Methods compared, in table order.
METHODS = ("backbone", "srde", "hybrid")
#: Regions scored: every pixel with ground truth, and the objects only.
REGIONS = ("full", "masked")
#: Columns of the markdown tables: the paper's metrics, then KITTI-style ones.
TABLE_KEYS = (*PAPER_KEYS, "bad1", "d1", "coverage")
#: Mask sources :func:`evaluate_scene` understands by name.
MASK_SOURCES = ("user", "auto")


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
        ``scores[method][region]`` -> :func:`~srde_fusion.metrics.evaluate` result plus
        ``coverage`` (fraction of scored pixels with a prediction), for ``method`` in
        :data:`METHODS` and ``region`` in :data:`REGIONS`.
    """
    gt = np.asarray(gt_disparity, dtype=np.float32)
    maps = {"backbone": result.backbone_disparity, "srde": result.srde_disparity,
            "hybrid": result.disparity}
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
        The fusion report (:meth:`~srde_fusion.fusion.FusionResult.report`).
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
        return _json_safe({
            "name": self.name, "mask_source": self.mask_source, "scores": self.scores,
            "mask_iou": list(self.mask_iou), "seconds": self.seconds, "fusion": self.report,
        })


def _json_safe(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


@dataclass(frozen=True)
class DatasetEvaluation:
    """Scores of every scene of a dataset, and their summary.

    Attributes
    ----------
    scenes : tuple of SceneEvaluation
    """

    scenes: tuple[SceneEvaluation, ...]

    def summary(self) -> dict[str, dict[str, dict[str, tuple[float, float]]]]:
        """Mean and standard deviation over scenes, ``summary[method][region][key]``."""
        return {method: {region: summarize([s.scores[method][region] for s in self.scenes])
                         for region in REGIONS} for method in METHODS}

    def counts(self) -> dict[str, int]:
        """Objects, objects fused with SRDE, and fallbacks, over all scenes."""
        return {
            "scenes": len(self.scenes),
            "objects": sum(s.report["n_objects"] for s in self.scenes),
            "srde": sum(s.report["n_srde"] for s in self.scenes),
            "fallback": sum(s.report["n_fallback"] for s in self.scenes),
        }

    def mean_mask_iou(self) -> float:
        """Mean best IoU of the ground-truth objects with the masks used (NaN if none)."""
        ious = [v for s in self.scenes for v in s.mask_iou]
        return float(np.mean(ious)) if ious else math.nan

    def to_markdown(self, keys: Sequence[str] = TABLE_KEYS) -> str:
        """Two tables (full scene, objects only), mean ± std over scenes."""
        summary = self.summary()
        counts = self.counts()
        lines = [
            f"{counts['scenes']} scene(s), {counts['objects']} object(s): SRDE used on "
            f"{counts['srde']}, backbone kept on {counts['fallback']} (fallback).",
        ]
        iou = self.mean_mask_iou()
        if not math.isnan(iou):
            lines.append(f"Mask IoU with the ground-truth objects: {iou:.3f} (mean over objects).")
        for region, title in (("full", "Full scene"), ("masked", "Objects (masked)")):
            rows = {method: summary[method][region] for method in METHODS}
            lines += ["", f"### {title}", "", format_markdown_table(rows, keys).rstrip("\n")]
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable view: summary, counts and every scene."""
        summary = {m: {r: {k: {"mean": v[0], "std": v[1]} for k, v in keys.items()}
                       for r, keys in regions.items()} for m, regions in self.summary().items()}
        return _json_safe({"counts": self.counts(), "mask_iou_mean": self.mean_mask_iou(),
                           "summary": summary, "scenes": [s.to_dict() for s in self.scenes]})


Backbone = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _masker_for(masks: Any, scene: SceneData) -> tuple[Any, str]:
    if isinstance(masks, str):
        if masks == "user":
            if scene.mask_labels is None:
                raise MaskError(f"{scene.path}: expected a mask.png for --masks user, got none")
            return UserMasks(scene.mask_labels), "user"
        if masks == "auto":
            return HighlightSegmenter(), "auto"
        raise SRDEError(f"masks: expected one of {list(MASK_SOURCES)} or a masker, got {masks!r}")
    if callable(masks):
        return masks, type(masks).__name__
    raise SRDEError(f"masks: expected one of {list(MASK_SOURCES)} or a masker, got "
                    f"{type(masks).__name__}")


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
        :class:`~srde_fusion.masks.HighlightSegmenter`; or any
        ``masker(views, rig) -> list of masks``.
    srde_method : str
        See :class:`~srde_fusion.srde.SRDE`.
    border_check : BorderCheck or None
        See :func:`~srde_fusion.fusion.fuse`.

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
    from .errors import DisparityError, LightError
    from .srde import SRDE

    if not isinstance(scene, SceneData):
        scene = read_scene(scene)
    if scene.gt_disparity is None:
        raise DisparityError(f"{scene.path}: expected a ground-truth disparity "
                             f"(gt_disparity.pfm or .npy) to evaluate against, got none")
    rig = scene.rig
    if rig.light_position_m is None:
        raise LightError(f"{scene.path}: expected a light position in rig.json, got none")
    masker, source = _masker_for(masks, scene)
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


def evaluate_dataset(dataset_dir: str | os.PathLike, backbone: Backbone, *,
                     masks: Any = "user", progress: bool = True, **options: Any
                     ) -> DatasetEvaluation:
    """Evaluate every scene folder of a dataset.

    Parameters
    ----------
    dataset_dir : path
        A folder of scene folders (see :func:`~srde_fusion.io.list_scenes`).
    backbone : callable
        ``backbone(left, right) -> (H, W)`` disparity in pixels.
    masks : {"user", "auto"} or masker
        See :func:`evaluate_scene`.
    progress : bool
        Show a progress bar on stderr.
    **options
        Passed to :func:`evaluate_scene` (``srde_method``, ``border_check``).

    Returns
    -------
    DatasetEvaluation
    """
    folders = list_scenes(dataset_dir)
    if progress:
        from tqdm import tqdm

        folders = tqdm(folders, desc="evaluating", unit="scene")
    return DatasetEvaluation(tuple(evaluate_scene(Path(f), backbone, masks=masks, **options)
                                   for f in folders))
