from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from srde_fusion.errors import DisparityError, MaskError, SRDEError
from srde_fusion.evaluation import (
    METRIC_KEYS,
    PAPER_KEYS,
    THRESHOLD_KEYS,
    evaluate,
    fill_holes_background,
    format_markdown_table,
    summarize,
)


def test_keys_and_threshold_names():
    assert [k for k, _ in THRESHOLD_KEYS] == [
        "bmp0.1",
        "bmp0.01",
        "bmp0.001",
        "bad0.5",
        "bad1",
        "bad2",
        "bad3",
        "bad4",
    ]
    assert METRIC_KEYS == (
        "epe",
        "rmse",
        "bmp0.1",
        "bmp0.01",
        "bmp0.001",
        "bad0.5",
        "bad1",
        "bad2",
        "bad3",
        "bad4",
        "d1",
        "valid_px",
        "invalid_pred_px",
    )
    assert set(PAPER_KEYS) <= set(METRIC_KEYS)


def test_hand_computed_values():
    # Errors (exact in binary): 0, 0.0625, 0.75, 1.5, 5.0; gt 8 everywhere.
    gt = np.full((1, 5), 8.0)
    pred = gt + np.array([[0.0, 0.0625, -0.75, 1.5, -5.0]])
    m = evaluate(pred, gt)
    assert set(m) == set(METRIC_KEYS)
    assert m["epe"] == pytest.approx((0.0625 + 0.75 + 1.5 + 5.0) / 5)
    assert m["rmse"] == pytest.approx(math.sqrt((0.0625**2 + 0.75**2 + 1.5**2 + 25.0) / 5))
    assert m["bmp0.1"] == pytest.approx(3 / 5)
    assert m["bmp0.01"] == pytest.approx(4 / 5)
    assert m["bmp0.001"] == pytest.approx(4 / 5)
    assert m["bad0.5"] == pytest.approx(3 / 5)
    assert m["bad1"] == pytest.approx(2 / 5)
    assert m["bad2"] == pytest.approx(1 / 5)
    assert m["bad3"] == pytest.approx(1 / 5)
    assert m["bad4"] == pytest.approx(1 / 5)
    # 5 px > 3 px and > 5 % of 8 px.
    assert m["d1"] == pytest.approx(1 / 5)
    assert (m["valid_px"], m["invalid_pred_px"]) == (5, 0)
    assert isinstance(m["valid_px"], int) and isinstance(m["epe"], float)


def test_threshold_is_strict():
    gt = np.zeros((1, 2))
    m = evaluate(np.array([[1.0, 2.0]]), gt)
    # |error| = 1 is not above 1; |error| = 2 is above 1 but not above 2.
    assert m["bad1"] == 0.5 and m["bad2"] == 0.0


@pytest.mark.parametrize(("gt_px", "is_d1"), [(100.0, False), (50.0, True)])
def test_d1_needs_both_absolute_and_relative_error(gt_px, is_d1):
    # 4 px is above 3 px; it is 4 % of 100 px (not an outlier) but 8 % of 50 px (outlier).
    gt = np.full((2, 2), gt_px)
    pred = gt.copy()
    pred[0, 0] += 4.0
    m = evaluate(pred, gt)
    assert m["d1"] == (0.25 if is_d1 else 0.0)
    assert m["bad3"] == 0.25


def test_d1_uses_absolute_gt():
    m = evaluate(np.array([[0.0]]), np.array([[-70.0]]))
    # 70 px error on |gt| = 70: outlier (negative gt is finite, so it is evaluated).
    assert m["d1"] == 1.0 and m["valid_px"] == 1


def test_invalid_gt_and_invalid_prediction():
    gt = np.array([[1.0, np.nan, 3.0, np.inf], [5.0, 6.0, 7.0, 8.0]])
    pred = np.array([[1.0, 2.0, np.nan, 4.0], [5.25, np.inf, 7.0, -np.inf]])
    m = evaluate(pred, gt)
    # Evaluated: 6 pixels (gt finite); 3 predictions are not finite.
    assert m["valid_px"] == 6
    assert m["invalid_pred_px"] == 3
    # EPE/RMSE over the 3 finite predictions: errors 0, 0.25, 0.
    assert m["epe"] == pytest.approx(0.25 / 3)
    assert m["rmse"] == pytest.approx(math.sqrt(0.0625 / 3))
    # Threshold metrics count the invalid predictions as wrong, over all 6 pixels.
    assert m["bad4"] == pytest.approx(3 / 6)
    assert m["bmp0.1"] == pytest.approx(4 / 6)
    assert m["d1"] == pytest.approx(3 / 6)


def test_all_predictions_invalid():
    m = evaluate(np.full((2, 2), np.nan), np.ones((2, 2)))
    assert math.isnan(m["epe"]) and math.isnan(m["rmse"])
    assert m["bad0.5"] == 1.0 and m["d1"] == 1.0
    assert (m["valid_px"], m["invalid_pred_px"]) == (4, 4)


def test_region_restricts_pixels():
    gt = np.zeros((2, 2))
    pred = np.array([[0.0, 10.0], [0.0, 0.0]])
    region = np.array([[True, False], [True, True]])
    m = evaluate(pred, gt, region)
    assert m["valid_px"] == 3 and m["epe"] == 0.0 and m["bad0.5"] == 0.0
    # Integer masks (non-zero = inside) are accepted too.
    assert evaluate(pred, gt, region.astype(np.uint8)) == m


@pytest.mark.parametrize(
    ("gt", "region"),
    [
        (np.zeros((2, 2)), np.zeros((2, 2), bool)),
        (np.full((2, 2), np.nan), None),
        (np.array([[np.nan, 1.0], [1.0, 1.0]]), np.array([[True, False], [False, False]])),
    ],
    ids=["empty-region", "no-valid-gt", "region-on-invalid-gt"],
)
def test_nothing_to_evaluate_gives_nan_and_zero_counts(gt, region):
    m = evaluate(np.zeros((2, 2)), gt, region)
    assert set(m) == set(METRIC_KEYS)
    for key in METRIC_KEYS:
        if key in ("valid_px", "invalid_pred_px"):
            assert m[key] == 0
        else:
            assert math.isnan(m[key]), key


def test_integer_and_float32_inputs():
    m = evaluate(np.array([[3, 4]], np.int32), np.array([[3.0, 3.5]], np.float32))
    assert m["epe"] == pytest.approx(0.25)


@pytest.mark.parametrize(
    ("pred", "gt", "region", "error", "match"),
    [
        (
            np.zeros((2, 3)),
            np.zeros((2, 2)),
            None,
            DisparityError,
            r"pred: expected the shape of gt \(2, 2\), got \(2, 3\)",
        ),
        (
            np.zeros((2, 2, 1)),
            np.zeros((2, 2)),
            None,
            DisparityError,
            r"pred: expected shape \(H, W\), got \(2, 2, 1\)",
        ),
        ([[0.0]], np.zeros((1, 1)), None, DisparityError, "pred: expected a numpy array"),
        (
            np.zeros((2, 2)),
            np.zeros((2, 2), complex),
            None,
            DisparityError,
            "gt: expected a float disparity map, got dtype complex128",
        ),
        (
            np.zeros((2, 2)),
            np.zeros((2, 2)),
            np.ones((3, 2), bool),
            MaskError,
            r"region: expected shape \(2, 2\), got \(3, 2\)",
        ),
    ],
    ids=["shape-mismatch", "ndim", "not-array", "dtype", "region-shape"],
)
def test_evaluate_errors(pred, gt, region, error, match):
    with pytest.raises(error, match=match):
        evaluate(pred, gt, region)


# ---------------------------------------------------------------------- properties
_SHAPE = (4, 5)
_disparities = arrays(np.float64, _SHAPE, elements=st.floats(0.0, 300.0))
_noise = arrays(np.float64, _SHAPE, elements=st.floats(-20.0, 20.0))


@given(_disparities)
def test_perfect_prediction_scores_zero(gt):
    m = evaluate(gt.copy(), gt)
    for key in METRIC_KEYS:
        if key == "valid_px":
            assert m[key] == gt.size
        else:
            assert m[key] == 0, key


@given(_disparities, _noise)
def test_bad_fraction_is_monotone_in_threshold(gt, noise):
    m = evaluate(gt + noise, gt)
    thresholds = sorted(THRESHOLD_KEYS, key=lambda kv: kv[1])
    fractions = [m[k] for k, _ in thresholds]
    assert all(0.0 <= f <= 1.0 for f in fractions)
    assert all(a >= b for a, b in zip(fractions, fractions[1:], strict=False))
    # D1 requires more than bad3, so it never exceeds it.
    assert m["d1"] <= m["bad3"]
    assert m["rmse"] >= m["epe"] - 1e-12


@given(_disparities, _noise, arrays(bool, _SHAPE))
def test_region_agrees_with_nan_gt(gt, noise, region):
    # Leaving a pixel out by region or by invalid gt is the same thing.
    masked_gt = np.where(region, gt, np.nan)
    a, b = evaluate(gt + noise, gt, region), evaluate(gt + noise, masked_gt)
    assert a.keys() == b.keys()
    for key in a:
        assert a[key] == b[key] or (math.isnan(a[key]) and math.isnan(b[key])), key


# ---------------------------------------------------------------------- summaries and tables
def test_summarize_mean_std_and_nan():
    rows = [
        {"epe": 1.0, "valid_px": 10},
        {"epe": 3.0, "valid_px": 20},
        {"epe": float("nan"), "valid_px": 0},
    ]
    summary = summarize(rows)
    assert list(summary) == ["epe", "valid_px"]
    assert summary["epe"] == (2.0, 1.0)
    assert summary["valid_px"][0] == pytest.approx(10.0)
    assert summary["valid_px"][1] == pytest.approx(np.std([10, 20, 0]))
    all_nan = summarize([{"epe": float("nan")}])
    assert all(math.isnan(v) for v in all_nan["epe"])


def test_summarize_real_evaluations():
    gt = np.full((2, 2), 10.0)
    results = [evaluate(gt + 0.5, gt), evaluate(gt + 1.5, gt)]
    summary = summarize(results)
    assert summary["epe"] == (1.0, 0.5)
    assert summary["bad1"] == (0.5, 0.5)


@pytest.mark.parametrize(
    ("results", "match"),
    [
        ([], "non-empty list"),
        ({"epe": 1.0}, "non-empty list"),
        ([{"epe": 1.0}, {"rmse": 1.0}], r"results\[1\]: expected the keys of results\[0\]"),
        ([{"epe": "bad"}], "expected numbers under 'epe'"),
    ],
    ids=["empty", "dict", "keys", "non-numeric"],
)
def test_summarize_errors(results, match):
    with pytest.raises(SRDEError, match=match):
        summarize(results)


def test_markdown_table():
    rows = {
        "backbone": {"epe": 0.0628, "rmse": 0.1682, "valid_px": 100},
        "srde": {"epe": (0.029, 0.02), "rmse": (float("nan"), float("nan")), "valid_px": 7},
    }
    table = format_markdown_table(rows, ["epe", "rmse", "valid_px"], digits=3)
    assert table == (
        "| method | epe | rmse | valid_px |\n"
        "|---|---|---|---|\n"
        "| backbone | 0.063 | 0.168 | 100 |\n"
        "| srde | 0.029 ± 0.020 | n/a | 7 |\n"
    )


def test_markdown_table_defaults_to_paper_columns():
    gt = np.full((2, 2), 10.0)
    table = format_markdown_table({"m": summarize([evaluate(gt, gt)])}, name_header="model")
    header = table.splitlines()[0]
    assert header == "| model | epe | bmp0.1 | bmp0.01 | bmp0.001 | rmse |"
    assert "0.0000 ± 0.0000" in table


def test_markdown_table_errors():
    with pytest.raises(SRDEError, match=r"rows\['x'\]: expected metrics .* missing \['bad1'\]"):
        format_markdown_table({"x": {"epe": 1.0}}, ["epe", "bad1"])
    with pytest.raises(SRDEError, match="non-empty dict"):
        format_markdown_table({})


def test_fill_holes_background_takes_the_smaller_row_neighbour():
    nan, inf = np.nan, np.inf
    disp = np.array([[nan, 5.0, nan, nan, 2.0, nan],
                     [nan, nan, nan, nan, nan, nan],
                     [1.0, inf, 3.0, 4.0, 9.0, 6.0]])
    filled = fill_holes_background(disp)
    assert filled.dtype == np.float32
    # interior runs take min(left, right); row ends the one neighbour they have
    assert filled[0].tolist() == [5.0, 5.0, 2.0, 2.0, 2.0, 2.0]
    assert filled[2].tolist() == [1.0, 1.0, 3.0, 4.0, 9.0, 6.0]
    # a row with no valid pixel copies the nearest filled row
    assert filled[1].tolist() == filled[0].tolist()
    assert np.isnan(fill_holes_background(np.full((2, 3), np.nan))).all()


@given(arrays(np.float64, (5, 7), elements=st.one_of(
    st.floats(0, 100, allow_nan=False), st.just(math.nan))))
def test_fill_holes_background_keeps_valid_pixels_and_stays_in_range(disp):
    filled = fill_holes_background(disp)
    valid = np.isfinite(disp)
    kept = disp[valid].astype(np.float32)  # the result is float32
    assert np.array_equal(filled[valid], kept)
    if valid.any():
        assert np.isfinite(filled).all()
        assert kept.min() <= filled.min() and filled.max() <= kept.max()


def test_fill_holes_background_rejects_bad_input():
    with pytest.raises(DisparityError, match="expected shape"):
        fill_holes_background(np.zeros(4))


def test_errors_beyond_float_range_are_scored_not_warned():
    # Squares of 1e154 px overflow float64 and a difference of 2e308 px does not exist:
    # the metrics stay exact where they can and infinite where they cannot, with no
    # floating-point warning (the suite turns warnings into errors).
    gt = np.array([[1.34e154, 0.0]])
    pred = np.array([[0.0, 0.0]])
    metrics = evaluate(pred, gt)
    assert metrics["rmse"] == pytest.approx(1.34e154 / np.sqrt(2.0))
    assert metrics["epe"] == pytest.approx(0.67e154)
    assert metrics["bad1"] == 0.5
    far = evaluate(np.array([[1.7e308]]), np.array([[-1.7e308]]))
    assert far["epe"] == far["rmse"] == np.inf and far["bad4"] == 1.0
