"""Evaluation: metrics, scene and dataset scoring, figures.

Imports ``fusion``, ``masks``, ``srde``, ``io`` and ``geometry``.
"""

from __future__ import annotations

from .evaluate import (
    METHODS,
    REGIONS,
    TABLE_KEYS,
    BackboneLoader,
    DatasetEvaluation,
    SceneEvaluation,
    evaluate_dataset,
    evaluate_scene,
    mask_iou,
    score_fusion,
)
from .figures import (
    DISPARITY_CMAP,
    ERROR_CMAP,
    colorize_disparity,
    colorize_source,
    comparison_figure,
    save_figure,
)
from .metrics import (
    BAD_THRESHOLDS_PX,
    BMP_THRESHOLDS_PX,
    D1_ABS_THRESHOLD_PX,
    D1_REL_THRESHOLD,
    METRIC_KEYS,
    PAPER_KEYS,
    THRESHOLD_KEYS,
    evaluate,
    fill_holes_background,
    format_markdown_table,
    summarize,
)

__all__ = [
    "METHODS",
    "REGIONS",
    "TABLE_KEYS",
    "score_fusion",
    "mask_iou",
    "SceneEvaluation",
    "DatasetEvaluation",
    "BackboneLoader",
    "evaluate_scene",
    "evaluate_dataset",
    "colorize_disparity",
    "colorize_source",
    "comparison_figure",
    "save_figure",
    "DISPARITY_CMAP",
    "ERROR_CMAP",
    "BMP_THRESHOLDS_PX",
    "BAD_THRESHOLDS_PX",
    "THRESHOLD_KEYS",
    "D1_ABS_THRESHOLD_PX",
    "D1_REL_THRESHOLD",
    "METRIC_KEYS",
    "PAPER_KEYS",
    "evaluate",
    "fill_holes_background",
    "summarize",
    "format_markdown_table",
]
