"""Tests for the lobe families of the refinement (refine.lobes)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from srde_fusion.srde.refine import LOBES
from srde_fusion.srde.refine.lobes import lobe_shape, lobe_shape_slopes

# Half-vector angles from the mirror direction to grazing, radians.
ANGLES = np.linspace(0.0, 1.5, 31)
LOG_WIDTH = math.log(0.2)


def _geometry(angles: np.ndarray):
    """The two fields a lobe reads: sin^2 and cos of the half-vector angle."""
    return SimpleNamespace(sin2_h=np.sin(angles) ** 2, cos_h=np.cos(angles))


@pytest.mark.parametrize(("lobe", "tail"), [("gtr", 0.5), ("gtr", 0.0), ("gtr", -0.2),
                                            ("ggx", 0.5), ("blinn_phong", 0.0)])
def test_every_lobe_peaks_at_one_and_falls_off(lobe, tail):
    shape = lobe_shape(lobe, _geometry(ANGLES), LOG_WIDTH, tail)
    assert shape[0] == pytest.approx(1.0, abs=1e-15)
    # (GGX's heavy tail still holds ~2e-3 of the peak at 86 degrees for w = 0.2)
    assert np.all(np.diff(shape) <= 0.0) and shape[-1] < 1e-2


def test_gtr_with_tail_one_half_is_ggx():
    g = _geometry(ANGLES)
    np.testing.assert_allclose(lobe_shape("gtr", g, LOG_WIDTH, 0.5),
                               lobe_shape("ggx", g, LOG_WIDTH, 0.5), rtol=1e-12, atol=1e-300)


def test_gtr_is_continuous_at_the_gaussian_limit():
    # |tail| < 1e-9 takes exp(-z); a small tail goes through (1 + t z)^(-1/t)
    g = _geometry(ANGLES)
    np.testing.assert_allclose(lobe_shape("gtr", g, LOG_WIDTH, 0.0),
                               lobe_shape("gtr", g, LOG_WIDTH, 1e-7), rtol=1e-5, atol=1e-12)


def test_a_light_tail_ends_at_zero_with_zero_slopes():
    g = _geometry(ANGLES)
    shape = lobe_shape("gtr", g, LOG_WIDTH, -0.2)
    ended = shape == 0.0
    assert ended.any() and not ended[0]
    slopes = lobe_shape_slopes("gtr", g, LOG_WIDTH, -0.2, shape)
    assert np.all(slopes.by[ended] == 0.0) and np.all(slopes.by_tail[ended] == 0.0)
    assert np.all(slopes.by_log_width[ended] == 0.0)


@pytest.mark.parametrize("lobe", LOBES)
def test_slope_along_the_geometry_agrees_with_finite_differences(lobe):
    angles = np.linspace(0.05, 0.6, 12)
    g = _geometry(angles)
    shape = lobe_shape(lobe, g, LOG_WIDTH, 0.3)
    slopes = lobe_shape_slopes(lobe, g, LOG_WIDTH, 0.3, shape)
    step = 1e-7
    field = "sin2_h" if slopes.along is g.sin2_h else "cos_h"
    up, down = _geometry(angles), _geometry(angles)
    setattr(up, field, getattr(g, field) + step)
    setattr(down, field, getattr(g, field) - step)
    expected = (lobe_shape(lobe, up, LOG_WIDTH, 0.3) - lobe_shape(lobe, down, LOG_WIDTH, 0.3)) / (
        2 * step)
    np.testing.assert_allclose(slopes.by, expected, rtol=1e-5, atol=1e-9)
