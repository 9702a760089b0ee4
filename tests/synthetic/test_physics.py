"""The renderer's switchable physics: each effect does what its physics says, and the
default stays the refinement's own model."""

import json

import numpy as np
import pytest

from srde_fusion.cli.main import main
from srde_fusion.errors import SceneError
from srde_fusion.geometry import CameraRig
from srde_fusion.synthetic import (
    Light,
    Material,
    Physics,
    PlanarObject,
    Scene,
    disc_samples,
    fresnel_exact,
    ior_from_f0,
    render,
    schlick_fresnel,
    smith_g1_ggx,
    smith_g2_height_correlated,
)


def test_exact_fresnel_matches_the_dielectric_closed_form():
    cos = np.linspace(0.0, 1.0, 101)
    n = 1.49
    g = np.sqrt(n * n - 1 + cos * cos)
    expected = 0.5 * (g - cos) ** 2 / (g + cos) ** 2 * (
        1 + ((cos * (g + cos) - 1) / (cos * (g - cos) + 1)) ** 2)
    np.testing.assert_allclose(fresnel_exact(cos, n), expected, atol=1e-12)


def test_exact_fresnel_of_a_conductor_at_normal_incidence_and_grazing():
    n, k = 0.18, 3.4  # gold-like at 600 nm
    normal = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
    assert float(fresnel_exact(np.array(1.0), n, k)) == pytest.approx(normal, rel=1e-12)
    assert float(fresnel_exact(np.array(0.0), n, k)) == pytest.approx(1.0, abs=1e-12)


def test_brewster_angle_halves_the_reflectance():
    # At Brewster's angle the p-polarised reflectance vanishes: F = R_s / 2.
    n = 1.5
    theta = np.arctan(n)
    c = np.cos(theta)
    cos_t = np.sqrt(1 - np.sin(theta) ** 2 / n**2)
    r_s = ((c - n * cos_t) / (c + n * cos_t)) ** 2
    assert float(fresnel_exact(np.array(c), n)) == pytest.approx(r_s / 2, rel=1e-9)


def test_schlick_departs_from_exact_fresnel_at_grazing_angles():
    # Why the mismatched benchmark switches it: close at normal incidence, not beyond 70 deg.
    f0 = 0.04
    n = ior_from_f0(f0)
    assert n == pytest.approx(1.5)
    assert float(schlick_fresnel(np.array(1.0), f0)) == pytest.approx(float(fresnel_exact(1.0, n)))
    c = np.cos(np.radians(80.0))
    gap = float(schlick_fresnel(np.array(c), f0)) - float(fresnel_exact(np.array(c), n))
    assert abs(gap) > 0.01


def test_height_correlated_masking_is_at_least_the_separable_product():
    cos = np.linspace(0.05, 1.0, 40)
    cl, cv = np.meshgrid(cos, cos)
    for alpha in (0.01, 0.1, 0.5):
        g2 = smith_g2_height_correlated(cl, cv, alpha)
        product = smith_g1_ggx(cl, alpha) * smith_g1_ggx(cv, alpha)
        assert np.all(g2 >= product - 1e-12) and np.all(g2 <= 1.0)
        # Equal when one direction is unmasked (normal incidence: Lambda = 0).
        np.testing.assert_allclose(smith_g2_height_correlated(1.0, cos, alpha),
                                   smith_g1_ggx(cos, alpha), rtol=1e-9)


def test_disc_samples_cover_the_unit_disc_evenly():
    pts = disc_samples(256).astype(np.float64)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert r.max() < 1.0
    # Equal area per point: a quarter of them inside radius 1/2.
    assert np.mean(r < 0.5) == pytest.approx(0.25, abs=0.01)


@pytest.mark.parametrize("n", [4, 16, 64, 256, 1024])
def test_disc_samples_have_the_discs_centre_and_spread_at_every_count(n):
    # A lamp whose samples' mean sits off its centre renders as a lamp moved there.
    pts = disc_samples(n).astype(np.float64)
    assert pts.shape == (n, 2)
    np.testing.assert_allclose(pts.mean(axis=0), 0.0, atol=1e-7)
    np.testing.assert_allclose(pts.T @ pts / n, np.eye(2) / 4, atol=1e-6)
    assert len(np.unique(pts.round(6), axis=0)) == n  # no point used twice


@pytest.mark.parametrize("n", [0, 2, 6, 63])
def test_disc_samples_reject_counts_that_are_not_multiples_of_4(n):
    with pytest.raises(ValueError, match="multiple of 4"):
        disc_samples(n)


@pytest.mark.parametrize("bad", [{"fresnel": "cook"}, {"light": "area"}, {"masking": "v"},
                                 {"light_samples": 0}, {"light_samples": 2.5},
                                 {"light_samples": 6},
                                 {"diffuse_transmittance": 1}, {"full_well_e": -1.0},
                                 {"read_noise_e": 3.0}, {"read_noise_e": -1, "full_well_e": 1e4}])
def test_physics_rejects_bad_settings_naming_them(bad):
    with pytest.raises(SceneError, match="physics\\." + next(iter(bad))):
        Physics(**bad)


def _scene(radius_m=0.0, roughness=0.05, **material):
    plate = PlanarObject("rectangle", (0.0, 0.0, 0.8), (0.15, 0.0, -1.0), (0.4, 0.3),
                         material=Material(roughness=roughness, **material))
    return Scene((plate,), Light((-0.25, 0.0, 0.0), radius_m=radius_m, intensity=0.2),
                 ambient=0.05)


_RIG = CameraRig.stereo(0.1, fx=300.0, image_size=(160, 120))


def test_default_physics_is_the_models():
    scene = _scene(0.01)
    a = render(scene, _RIG)
    b = render(scene, _RIG, physics=Physics())
    for x, y in zip(a.views, b.views, strict=True):
        np.testing.assert_array_equal(x, y)


def test_sampled_point_light_equals_the_point_light():
    scene = _scene(0.0)
    a = render(scene, _RIG)
    b = render(scene, _RIG, physics=Physics(light="sampled"))
    for x, y in zip(a.views, b.views, strict=True):
        np.testing.assert_array_equal(x, y)


def _linear_specular(radius_m, physics):
    """Linear luminance of a dark plate facing the camera, lit from beside it."""
    plate = PlanarObject("rectangle", (0.0, 0.0, 0.8), (0.0, 0.0, -1.0), (0.4, 0.3),
                         material=Material(roughness=0.01, diffuse_rgb=(0.0, 0.0, 0.0)))
    scene = Scene((plate,), Light((-0.1, 0.0, 0.0), radius_m=radius_m, intensity=0.01),
                  ambient=0.0)
    out = render(scene, _RIG, physics=physics)
    lum = (out.views[0].astype(np.float64) / 255.0) ** 2.2
    return lum.mean(axis=-1), out.instance_mask > 0


def test_sampled_light_spreads_the_highlight_with_its_energy():
    # A 3 cm sphere on a smooth coating: integrated over its disc, the highlight is wider
    # and lower than a point light's, and about as bright in total as the widened lobe.
    point, mask = _linear_specular(0.0, Physics())
    widened, _ = _linear_specular(0.03, Physics())
    sampled, _ = _linear_specular(0.03, Physics(light="sampled", light_samples=256))
    assert point.max() < 0.99  # nothing clipped
    assert sampled.max() < 0.7 * point.max()
    assert (sampled > 0.5 * sampled.max()).sum() > (point > 0.5 * point.max()).sum()
    assert sampled[mask].sum() == pytest.approx(widened[mask].sum(), rel=0.15)
    # A disc is not a wider lobe: the two images differ.
    assert np.abs(sampled - widened).max() > 0.01


def test_diffuse_transmittance_darkens_the_diffuse_term():
    scene = _scene(0.0, diffuse_rgb=(0.5, 0.5, 0.5), specular=0.0)
    plain = render(scene, _RIG).views[0].astype(int)
    coated = render(scene, _RIG, physics=Physics(diffuse_transmittance=True)).views[0].astype(int)
    mask = render(scene, _RIG).instance_mask > 0
    assert np.all(coated[mask] <= plain[mask])
    assert (plain[mask] - coated[mask]).mean() > 1.0


def test_photon_noise_grows_with_the_signal():
    rng = np.random.default_rng(0)
    physics = Physics(full_well_e=1000.0)
    for level in (0.04, 0.36):
        linear = np.full(200_000, level, dtype=np.float32)
        noisy = physics.expose(linear, rng)
        assert noisy.mean() == pytest.approx(level, rel=0.01)
        # Poisson: variance = mean electrons, i.e. std = sqrt(level / full_well).
        assert noisy.std() == pytest.approx(np.sqrt(level / 1000.0), rel=0.03)
    with_read = Physics(full_well_e=1000.0, read_noise_e=10.0).expose(
        np.zeros(200_000, np.float32), rng)
    assert with_read.std() == pytest.approx(0.01, rel=0.03)


def test_faithful_render_is_a_pure_function_of_its_arguments():
    scene = _scene(0.01, ior=1.49)
    a = render(scene, _RIG, physics=Physics.faithful(), supersample=2)
    b = render(scene, _RIG, physics=Physics.faithful(), supersample=2)
    for x, y in zip(a.views, b.views, strict=True):
        np.testing.assert_array_equal(x, y)
    c = render(scene, _RIG, physics=Physics.faithful(), supersample=2, noise_seed=5)
    assert any(np.any(x != y) for x, y in zip(a.views, c.views, strict=True))


def test_render_rejects_a_physics_of_the_wrong_type():
    with pytest.raises(SceneError, match="physics: expected a Physics"):
        render(_scene(), _RIG, physics="faithful")


def test_material_checks_its_refractive_index():
    with pytest.raises(SceneError, match="material.ior"):
        Material(ior=-1.0)
    with pytest.raises(SceneError, match="material.extinction"):
        Material(extinction=float("nan"))


def test_render_command_records_the_physics(tmp_path):
    assert main(["render", str(tmp_path / "faithful"), "--scenes", "1", "--physics",
                 "faithful", "--quiet"]) == 0
    assert main(["render", str(tmp_path / "model"), "--scenes", "1", "--quiet"]) == 0
    faithful = json.loads((tmp_path / "faithful/scene_0000/scene.json").read_text())
    model = json.loads((tmp_path / "model/scene_0000/scene.json").read_text())
    assert faithful["physics"] == {**vars(Physics.faithful())}
    assert model["physics"] == {**vars(Physics())}
    assert faithful["scene"] == model["scene"]  # same scene, other physics
    a = (tmp_path / "faithful/scene_0000/cam4.png").read_bytes()
    b = (tmp_path / "model/scene_0000/cam4.png").read_bytes()
    assert a != b
