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
