"""Tests for the closed-form intensities of the lobe model (refine.intensities)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from srde_fusion.srde.refine.intensities import IntensitySolver
from srde_fusion.srde.refine.samples import HighlightSamples

TRUE_INTENSITIES = np.array([0.7, 0.2, 0.1])  # specular, diffuse, level


def _scene(clip: float | None):
    """A lobe and a diffuse term over 200 samples, observed with ``clip`` as the top."""
    x = np.linspace(-3.0, 3.0, 200)
    lobe, diffuse = np.exp(-x * x), 0.3 * np.cos(x)
    y = TRUE_INTENSITIES @ np.stack([lobe, diffuse, np.ones_like(x)])
    saturated = np.zeros(len(x), bool) if clip is None else y >= clip
    if clip is not None:
        y = np.minimum(y, clip)
    order = np.argsort(saturated, kind="stable")  # unsaturated first, as sampled
    samples = HighlightSamples(np.zeros((len(x), 3)), np.ones((len(x), 3)), y[order],
                               saturated[order], (0,), 8, 1, 2)
    return samples, lobe[order], SimpleNamespace(diffuse=diffuse[order])


@pytest.mark.parametrize("clip", [None, 0.6])
def test_intensities_are_recovered_exactly(clip):
    samples, lobe, g = _scene(clip)
    assert clip is None or samples.saturated.sum() > 10
    solver = IntensitySolver(samples)
    coef, model = solver.solve(g, lobe)
    np.testing.assert_allclose(coef, TRUE_INTENSITIES, rtol=1e-9)
    assert np.max(np.abs(solver.residual(model))) < 1e-12


def test_a_saturated_sample_only_counts_below_its_bound():
    samples, _, _ = _scene(0.6)
    solver = IntensitySolver(samples)
    model = samples.luminance.copy()
    model[samples.saturated] += 0.5  # brighter than the clipped observation: no error
    model[~samples.saturated] += 0.5
    residual = solver.residual(model)
    assert np.all(residual[samples.saturated] == 0.0)
    np.testing.assert_allclose(residual[~samples.saturated], 0.5)
    model[samples.saturated] -= 0.7  # darker than a lower bound: an error
    np.testing.assert_allclose(solver.residual(model)[samples.saturated], -0.2)


def test_projection_removes_the_span_of_the_intensity_basis():
    samples, lobe, g = _scene(None)
    solver = IntensitySolver(samples)
    basis = np.stack([lobe, g.diffuse, np.ones_like(lobe)])
    rng = np.random.default_rng(0)
    slopes = rng.normal(size=(2, len(lobe))) + np.outer([1.0, 2.0], lobe)  # (2, P)
    projected = solver.project_out(slopes.copy(), g, lobe, TRUE_INTENSITIES)
    np.testing.assert_allclose(projected @ basis.T, 0.0, atol=1e-9)
