"""Disparity error metrics: the paper's EPE, RMSE and bmp, and the stereo benchmarks' bad-t and D1.

All metrics compare a predicted disparity map with ground truth over the pixels where the
ground truth is finite (and inside an optional region). A prediction that is NaN or inf on
such a pixel has no error to average, so it is left out of ``epe``/``rmse`` and counted in
``invalid_pred_px``; for every threshold metric it counts as wrong (its error is taken as
``+inf``), so a method cannot improve its bad-pixel rates by leaving pixels empty.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._checks import check_mask
from ..errors import DisparityError, SRDEError

__all__ = [
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

#: Bad-matched-pixel thresholds of the paper (pixels): keys ``bmp0.1``, ``bmp0.01``, ``bmp0.001``.
BMP_THRESHOLDS_PX = (0.1, 0.01, 0.001)
#: Stereo-benchmark bad-pixel thresholds (pixels): keys ``bad0.5`` ... ``bad4``.
BAD_THRESHOLDS_PX = (0.5, 1.0, 2.0, 3.0, 4.0)
#: ``(key, threshold_px)`` for every "fraction of pixels with |error| > threshold" metric.
THRESHOLD_KEYS: tuple[tuple[str, float], ...] = tuple(
    [(f"bmp{t:g}", t) for t in BMP_THRESHOLDS_PX] + [(f"bad{t:g}", t) for t in BAD_THRESHOLDS_PX]
)
#: KITTI D1: a pixel is an outlier if its error exceeds 3 px *and* 5 % of the true disparity.
D1_ABS_THRESHOLD_PX = 3.0
D1_REL_THRESHOLD = 0.05
#: Keys of :func:`evaluate`'s result, in table order.
METRIC_KEYS = ("epe", "rmse", *(k for k, _ in THRESHOLD_KEYS), "d1", "valid_px", "invalid_pred_px")
#: The columns the paper reports (Table of the evaluation), in its order.
PAPER_KEYS = ("epe", "bmp0.1", "bmp0.01", "bmp0.001", "rmse")

_COUNT_KEYS = ("valid_px", "invalid_pred_px")


def _check_map(array: Any, name: str) -> np.ndarray:
    if not isinstance(array, np.ndarray):
        raise DisparityError(f"{name}: expected a numpy array (H, W), got {type(array).__name__}")
    if array.ndim != 2:
        raise DisparityError(f"{name}: expected shape (H, W), got {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise DisparityError(f"{name}: expected a float disparity map, got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)


def evaluate(pred: np.ndarray, gt: np.ndarray, region: np.ndarray | None = None) -> dict[str, Any]:
    """Compare a disparity map with ground truth.

    Parameters
    ----------
    pred : numpy.ndarray, (H, W), float, pixels
        Predicted disparity; NaN or inf = no prediction.
    gt : numpy.ndarray, (H, W), float, pixels
        Ground truth; pixels where it is not finite are not evaluated.
    region : numpy.ndarray, (H, W), bool, optional
        Evaluate only inside this region (e.g. one object's mask).

    Returns
    -------
    dict
        ``epe`` (mean absolute error, px) and ``rmse`` (px) over pixels with a finite
        prediction; ``bmp0.1``, ``bmp0.01``, ``bmp0.001``, ``bad0.5``, ``bad1``, ``bad2``,
        ``bad3``, ``bad4`` (fraction of evaluated pixels with ``|error| > t`` px) and
        ``d1`` (fraction with error > 3 px and > 5 % of ``|gt|``), all floats in [0, 1];
        ``valid_px`` (int, evaluated pixels) and ``invalid_pred_px`` (int, evaluated
        pixels without a finite prediction, counted wrong by every fraction). With no
        evaluated pixel every metric is NaN and both counts are 0. ``epe`` and ``rmse``
        are NaN when no evaluated pixel has a finite prediction.

    Raises
    ------
    DisparityError
        ``pred`` or ``gt`` is not an ``(H, W)`` real array, or their shapes differ.
    MaskError
        ``region`` does not have the shape of ``gt``.

    Examples
    --------
    >>> import numpy as np
    >>> m = evaluate(np.array([[1.0, 2.5], [3.0, np.nan]]), np.full((2, 2), 2.0))
    >>> m["epe"], m["bad0.5"], m["invalid_pred_px"]
    (0.8333333333333334, 0.75, 1)
    """
    pred64 = _check_map(pred, "pred")
    gt64 = _check_map(gt, "gt")
    if pred64.shape != gt64.shape:
        raise DisparityError(f"pred: expected the shape of gt {gt64.shape}, got {pred64.shape}")
    selected = np.isfinite(gt64)
    if region is not None:
        selected &= check_mask(region, gt64.shape, "region", allow_empty=True)
    valid_px = int(selected.sum())
    if valid_px == 0:
        out: dict[str, Any] = {key: math.nan for key in METRIC_KEYS}
        out.update({key: 0 for key in _COUNT_KEYS})
        return out

    gt_sel = gt64[selected]
    pred_sel = pred64[selected]
    has_pred = np.isfinite(pred_sel)
    # A missing prediction is wrong for every threshold: its error is +inf. So is one
    # whose difference from the truth lies beyond float64 (values near 1e308).
    error = np.full(valid_px, np.inf)
    with np.errstate(over="ignore"):
        error[has_pred] = np.abs(pred_sel[has_pred] - gt_sel[has_pred])
    finite_error = error[has_pred]  # (the predictions are finite; an error may not be)

    out = {}
    if finite_error.size:
        with np.errstate(over="ignore"):
            out["epe"] = float(finite_error.mean())
            mean_square = float(np.mean(finite_error**2))
        out["rmse"] = (math.sqrt(mean_square) if math.isfinite(mean_square)
                       else _scaled_rms(finite_error))
    else:
        out["epe"] = out["rmse"] = math.nan
    for key, threshold_px in THRESHOLD_KEYS:
        out[key] = float(np.count_nonzero(error > threshold_px)) / valid_px
    d1_outlier = (error > D1_ABS_THRESHOLD_PX) & (error > D1_REL_THRESHOLD * np.abs(gt_sel))
    out["d1"] = float(np.count_nonzero(d1_outlier)) / valid_px
    out["valid_px"] = valid_px
    out["invalid_pred_px"] = int(np.count_nonzero(~has_pred))
    return out


def _scaled_rms(values: np.ndarray) -> float:
    """Root mean square of non-negative values whose squares overflow float64.

    Divided by the largest first (inf if that is inf), as a norm is computed.
    """
    largest = float(values.max())
    if not math.isfinite(largest):
        return largest
    return largest * math.sqrt(float(np.mean((values / largest) ** 2)))


def fill_holes_background(disparity_px: np.ndarray) -> np.ndarray:
    """Fill a disparity map's holes the way the KITTI devkit does before scoring.

    Along each row, a run of missing (NaN or inf) pixels between two valid ones takes the
    smaller of the two disparities -- the background, which is what an occlusion next to
    a foreground edge shows; a run at a row's end takes its one valid neighbour. Rows with
    no valid pixel then take the nearest filled row above or below. This lets a method
    that leaves holes be scored over every pixel, like one that fills them.

    Parameters
    ----------
    disparity_px : numpy.ndarray, (H, W), float, pixels
        NaN or inf where the method gave no value.

    Returns
    -------
    numpy.ndarray, (H, W), float32, pixels
        The map with every hole filled; all NaN if the input has no valid pixel.

    Raises
    ------
    DisparityError
        Not a 2-D numeric array.

    Examples
    --------
    >>> d = np.array([[np.nan, 5.0, np.nan, np.nan, 2.0, np.nan]])
    >>> fill_holes_background(d).tolist()
    [[5.0, 5.0, 2.0, 2.0, 2.0, 2.0]]
    """
    disp = _check_map(disparity_px, "disparity_px").astype(np.float32)
    height, width = disp.shape
    valid = np.isfinite(disp)
    if not valid.any():
        return np.full_like(disp, np.nan)
    cols = np.arange(width)
    # index of the last valid pixel at or left of x, and of the first at or right of x
    left_idx = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right_idx = np.minimum.accumulate(np.where(valid, cols, width)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(height)[:, None]
    left_val = np.where(left_idx >= 0, disp[rows, left_idx.clip(0, width - 1)], np.inf)
    right_val = np.where(right_idx < width, disp[rows, right_idx.clip(0, width - 1)], np.inf)
    filled = np.where(valid, disp, np.minimum(left_val, right_val))
    empty_rows = ~valid.any(axis=1)
    if empty_rows.any():
        full = np.flatnonzero(~empty_rows)
        nearest = full[np.abs(full[None, :] - np.arange(height)[:, None]).argmin(axis=1)]
        filled = filled[nearest]
    return filled.astype(np.float32)


def summarize(results: Sequence[Mapping[str, Any]]) -> dict[str, tuple[float, float]]:
    """Mean and standard deviation of each metric over several evaluations.

    Parameters
    ----------
    results : sequence of dict
        Results of :func:`evaluate` (or any dicts of numbers with the same keys), e.g. one
        per scene.

    Returns
    -------
    dict of str -> (float, float)
        ``(mean, std)`` per key, in the order of ``results[0]``. NaN entries (an empty
        region, no finite prediction) are left out of that key's statistics; a key that is
        NaN everywhere gives ``(nan, nan)``. The standard deviation is the population one
        (``ddof=0``), describing the spread of the given samples.

    Raises
    ------
    SRDEError
        No results, or results with different keys or non-numeric values.

    Examples
    --------
    >>> summarize([{"epe": 1.0}, {"epe": 3.0}, {"epe": float("nan")}])
    {'epe': (2.0, 1.0)}
    """
    if isinstance(results, Mapping) or not isinstance(results, Sequence) or not results:
        raise SRDEError(f"results: expected a non-empty list of metric dicts, got {results!r:.80}")
    keys = list(results[0])
    for i, res in enumerate(results):
        if not isinstance(res, Mapping) or set(res) != set(keys):
            got = sorted(res) if isinstance(res, Mapping) else type(res).__name__
            raise SRDEError(f"results[{i}]: expected the keys of results[0] {keys}, got {got}")
    summary: dict[str, tuple[float, float]] = {}
    for key in keys:
        try:
            values = np.array([float(res[key]) for res in results], dtype=np.float64)
        except (TypeError, ValueError):
            raise SRDEError(
                f"results: expected numbers under {key!r}, got a non-numeric value"
            ) from None
        values = values[~np.isnan(values)]
        if values.size == 0:
            summary[key] = (math.nan, math.nan)
        else:
            summary[key] = (float(values.mean()), float(values.std()))
    return summary


def _format_value(value: Any, digits: int) -> str:
    if isinstance(value, tuple):
        if len(value) != 2:
            raise SRDEError(f"table cell: expected a number or (mean, std), got {value!r}")
        mean, std = value
        if math.isnan(float(mean)):
            return "n/a"
        return f"{_format_value(mean, digits)} ± {float(std):.{digits}f}"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    value = float(value)
    return "n/a" if math.isnan(value) else f"{value:.{digits}f}"


def format_markdown_table(rows: Mapping[str, Mapping[str, Any]], keys: Sequence[str] = PAPER_KEYS,
                          *, digits: int = 4, name_header: str = "method") -> str:
    """Format metrics as a markdown table, one row per method and one column per metric.

    Parameters
    ----------
    rows : dict of str -> dict
        Row name -> result of :func:`evaluate` (numbers) or :func:`summarize`
        (``(mean, std)`` pairs, shown as ``mean ± std``).
    keys : sequence of str
        The metric columns, in order; :data:`PAPER_KEYS` by default.
    digits : int
        Digits after the decimal point. Integer counts are shown as integers, NaN as ``n/a``.
    name_header : str
        Header of the first column.

    Returns
    -------
    str
        The table, ending with a newline.

    Raises
    ------
    SRDEError
        No rows, or a requested key missing from a row.

    Examples
    --------
    >>> print(format_markdown_table({"srde": {"epe": 0.029, "rmse": 0.0954}}, ["epe", "rmse"]),
    ...       end="")
    | method | epe | rmse |
    |---|---|---|
    | srde | 0.0290 | 0.0954 |
    """
    if not isinstance(rows, Mapping) or not rows:
        raise SRDEError(f"rows: expected a non-empty dict of name -> metrics, got {rows!r:.80}")
    keys = list(keys)
    lines = [
        "| " + " | ".join([name_header, *keys]) + " |",
        "|" + "---|" * (len(keys) + 1),
    ]
    for name, metrics in rows.items():
        missing = [k for k in keys if k not in metrics]
        if missing:
            raise SRDEError(f"rows[{name!r}]: expected metrics {keys}, missing {missing}")
        cells = [_format_value(metrics[k], digits) for k in keys]
        lines.append("| " + " | ".join([str(name), *cells]) + " |")
    return "\n".join(lines) + "\n"
