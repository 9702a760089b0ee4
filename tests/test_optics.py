"""The refinement's dielectric Fresnel form against the general one."""

from __future__ import annotations

import numpy as np
import pytest

from srde_fusion.optics import fresnel_dielectric, fresnel_exact


@pytest.mark.parametrize("ior", [1.0001, 1.2, 1.49, 2.4])
def test_dielectric_form_equals_the_general_fresnel_equations(ior):
    cos = np.linspace(0.0, 1.0, 2001)
    np.testing.assert_allclose(fresnel_dielectric(cos, ior), fresnel_exact(cos, ior),
                               atol=1e-13)


@pytest.mark.parametrize("ior", [1.2, 1.49, 2.4])
def test_dielectric_slope_matches_a_fine_difference_of_the_general_form(ior):
    cos = np.linspace(0.01, 0.99, 99)
    step = 1e-6
    expected = (fresnel_exact(cos + step, ior) - fresnel_exact(cos - step, ior)) / (2 * step)
    _, slope = fresnel_dielectric(cos, ior, slope=True)
    np.testing.assert_allclose(slope, expected, rtol=1e-6, atol=1e-9)
    # Reflectance falls towards normal incidence: the slope is negative throughout.
    assert np.all(slope < 0.0)


def _dielectric_written_out(c: np.ndarray, ior: float):
    """The dielectric form and its slope as the formulas read, one expression each."""
    g = np.sqrt(c * c + (ior * ior - 1.0))
    a = (g - c) / (g + c)
    b_num, b_den = c * (g + c) - 1.0, c * (g - c) + 1.0
    b = b_num / b_den
    dg = c / g
    da = 2.0 * (c * dg - g) / ((g + c) * (g + c))
    db = ((g + c * dg + 2.0 * c) * b_den - b_num * (g + c * dg - 2.0 * c)) / (b_den * b_den)
    return 0.5 * (a * a) * (1.0 + b * b), a * da * (1.0 + b * b) + (a * a) * b * db


@pytest.mark.parametrize("ior", [1.0001, 1.49, 2.4])
def test_in_place_dielectric_form_gives_the_written_out_values_to_the_bit(ior):
    # The refinement's results must not depend on how the arithmetic is arranged.
    cos = np.random.default_rng(3).uniform(0.0, 1.0, 5000)
    reflectance, slope = fresnel_dielectric(cos, ior, slope=True)
    expected_reflectance, expected_slope = _dielectric_written_out(cos, ior)
    np.testing.assert_array_equal(reflectance, expected_reflectance)
    np.testing.assert_array_equal(slope, expected_slope)
    np.testing.assert_array_equal(fresnel_dielectric(cos, ior), expected_reflectance)
