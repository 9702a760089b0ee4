import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from srde_fusion.synthetic import (
    blinn_phong_exponent,
    ggx_ndf,
    schlick_fresnel,
    smith_g1_ggx,
    specular_brdf,
    widened_roughness,
)


def _hemisphere_integral(fn, n_theta=4000):
    """Integral of fn(cos_theta) * cos_theta over the hemisphere (azimuthally symmetric)."""
    theta = np.linspace(0.0, np.pi / 2, n_theta)
    integrand = fn(np.cos(theta)) * np.cos(theta) * np.sin(theta) * 2 * np.pi
    return np.trapezoid(integrand, theta)


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.3, 0.7])
def test_ggx_is_normalised(alpha):
    assert _hemisphere_integral(lambda c: ggx_ndf(c, alpha)) == pytest.approx(1.0, rel=2e-3)


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.3])
def test_blinn_phong_lobe_is_normalised(alpha):
    e = blinn_phong_exponent(alpha)
    # (e + 2) / (2 pi) cos^e is the normalised Blinn-Phong distribution.
    value = _hemisphere_integral(lambda c: (e + 2) / (2 * np.pi) * c**e)
    assert value == pytest.approx(1.0, rel=2e-3)


@given(st.floats(0.001, 1.0), st.floats(0.01, 1.0))
@settings(max_examples=50, deadline=None)
def test_smith_masking_is_a_fraction(alpha, cos_theta):
    g = smith_g1_ggx(np.float64(cos_theta), alpha)
    assert 0.0 < g <= 1.0 + 1e-12


def test_fresnel_limits():
    assert schlick_fresnel(np.float64(1.0), 0.04) == pytest.approx(0.04)
    assert schlick_fresnel(np.float64(0.0), 0.04) == pytest.approx(1.0)


@pytest.mark.parametrize("lobe", ["ggx", "blinn_phong"])
def test_peak_at_normal_incidence_matches_between_lobes(lobe):
    alpha = 0.02
    one = np.float64(1.0)
    peak = specular_brdf(one, one, one, one, alpha, lobe=lobe, f0=1.0)
    # Blinn-Phong's (e + 8) / (8 pi) exceeds 1 / (4 pi alpha^2) by 6 / (8 pi): 0.1 %.
    assert peak == pytest.approx(1.0 / (4 * np.pi * alpha**2), rel=2e-3)


def test_lobes_have_different_tails():
    alpha = 0.05
    cos_h = np.cos(np.radians(10.0))
    one = np.float64(1.0)
    ggx = specular_brdf(one, one, cos_h, one, alpha, lobe="ggx", f0=1.0)
    phong = specular_brdf(one, one, cos_h, one, alpha, lobe="blinn_phong", f0=1.0)
    assert ggx > 10 * phong  # GGX's long tail


def test_widened_roughness():
    assert widened_roughness(0.02, 0.0, np.float64(1.0)) == pytest.approx(0.02)
    wide = widened_roughness(0.02, 0.04, np.array([0.5, 1.0, 2.0]))
    assert np.all(np.diff(wide) < 0)  # a nearer light looks bigger
    assert wide[1] == pytest.approx(np.sqrt(0.02**2 + 0.04**2 / 8))
