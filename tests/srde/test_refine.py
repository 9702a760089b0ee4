"""Tests for the photometric plane refinement (srde_fusion.srde.refine.plane).

Scenes come from the renderer, which draws GGX or Blinn-Phong lobes (with the lobe
conventions of :mod:`srde_fusion.synthetic.shading`); the refinement fits its own lobe family, so
every scene is rendered with a model other than the fitted one. Images are 320x240 with
the paper's field of view to keep the suite fast.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from srde_fusion.errors import ImageError, LightError, MaskError, SRDEError
from srde_fusion.geometry import CameraRig, Plane, plane_disparity, plane_from_lights
from srde_fusion.srde import SRDE
from srde_fusion.srde.refine import LOBES, PlaneRefinement, refine_plane
from srde_fusion.srde.refine import joint as joint_module
from srde_fusion.srde.refine.diffuse import DiffuseLights
from srde_fusion.srde.refine.joint import JointLobeModel
from srde_fusion.srde.refine.layout import I_FORE, I_SPEC, I_TAIL, N_PLANE
from srde_fusion.srde.refine.model import DEFAULT_F0, LobeModel
from srde_fusion.srde.refine.plane import compare_planes
from srde_fusion.srde.refine.samples import sample_windows
from srde_fusion.synthetic import random_scene, render

# Tolerances, in one place. Disparity errors are masked mean absolute errors (EPE), px.
ROUGH_REFINED_EPE_PX = 0.02  # brief target 0.01 px at 640x480; 320x240 has 4x fewer pixels
ROUGH_GAIN = 5.0  # refinement must cut a rough scene's error at least this much
SHARP_SLACK_PX = 0.002  # "not worse" on sharp lobes, up to noise
TAIL_TOL = 0.03
FORESHORTENING_TOL = 0.06
WIDTH_RTOL = 0.04
# Analytic model slopes against central differences with steps of 1e-6 rad (tilts),
# 1e-7 m (offset) and 1e-5 (shape): these agree to ~2e-5 of the largest slope.
SLOPE_RTOL = 1e-4
SLOPE_STEPS = (1e-6, 1e-6, 1e-7, 1e-5, 1e-5, 1e-5)


@pytest.fixture(scope="module")
def rig() -> CameraRig:
    """The paper's 3x3 array at half resolution (same field of view)."""
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(320, 240))


def _case(rig: CameraRig, seed: int, lobe: str, roughness: float):
    """Render a point-lit scene, run SRDE for the initial plane; return what a test needs."""
    scene = random_scene(seed, rig, lobe=lobe, roughness=roughness, light_radius_m=0.0)
    out = render(scene, rig)
    mask = out.instance_mask == 1
    lit_rig = rig.with_light(scene.light.position_m)
    est = SRDE(lit_rig, refine=False).estimate(out.views, mask)
    assert est.ok, est.reason
    centers = np.where(est.used_views[:, None], est.highlight_centers, np.nan)
    return dict(views=out.views, rig=lit_rig, light=np.array(scene.light.position_m), mask=mask,
                plane=est.plane, centers=centers, truth=out.planes[0],
                gt=out.disparity_px.astype(np.float64))


def _epe(case, plane: Plane) -> float:
    pred = plane_disparity(plane, case["rig"])
    return float(np.mean(np.abs(pred - case["gt"])[case["mask"]]))


def _refine(case, **kwargs) -> PlaneRefinement:
    return refine_plane(case["views"], case["rig"], case["light"], case["mask"], case["plane"],
                        centers_uv=case["centers"], **kwargs)


@pytest.fixture(scope="module")
def rough_blinn_phong(rig):
    return _case(rig, 1, "blinn_phong", 0.065)


@pytest.fixture(scope="module")
def rough_ggx(rig):
    return _case(rig, 2, "ggx", 0.065)


# ------------------------------------------------------------------ accuracy
@pytest.mark.parametrize("name", ["rough_blinn_phong", "rough_ggx"])
def test_refinement_removes_the_rough_lobe_bias(name, request):
    case = request.getfixturevalue(name)
    before = _epe(case, case["plane"])
    result = _refine(case)
    after = _epe(case, result.plane)
    assert result.ok and result.status == "refined" and result.reason == ""
    assert before > 0.1  # the centroid bias this module exists for
    assert after < ROUGH_REFINED_EPE_PX
    assert after * ROUGH_GAIN < before
    assert result.cost_final < result.cost_initial
    assert result.converged
    assert result.initial_plane == case["plane"]


def test_fitted_lobe_matches_the_rendered_ggx(rough_ggx):
    fit = _refine(rough_ggx).params
    # GGX is the fitted family's tail 1/2, its width the roughness, a microfacet BRDF (k=0)
    assert fit.tail == pytest.approx(0.5, abs=TAIL_TOL)
    assert fit.width == pytest.approx(0.065, rel=WIDTH_RTOL)
    assert fit.foreshortening == pytest.approx(0.0, abs=FORESHORTENING_TOL)
    assert fit.specular > 0


def test_fitted_lobe_matches_the_rendered_blinn_phong(rough_blinn_phong):
    # The renderer's own physics uses Schlick's Fresnel: the model matched to it.
    fit = _refine(rough_blinn_phong, fresnel="schlick").params
    # cos^e ~ exp(-sin^2 / alpha^2): tail 0 and width sqrt(2) alpha; the renderer's
    # Blinn-Phong BRDF has no 1 / (4 cos cos), hence k = 1
    assert fit.tail == pytest.approx(0.0, abs=TAIL_TOL)
    assert fit.width == pytest.approx(math.sqrt(2.0) * 0.065, rel=WIDTH_RTOL)
    assert fit.foreshortening == pytest.approx(1.0, abs=FORESHORTENING_TOL)


def test_a_fixed_lobe_fits_its_own_rendering(rough_blinn_phong):
    result = _refine(rough_blinn_phong, lobe="blinn_phong", foreshortening=1.0)
    assert result.ok
    assert _epe(rough_blinn_phong, result.plane) < ROUGH_REFINED_EPE_PX
    assert result.params.foreshortening == 1.0
    assert result.params.width == pytest.approx(0.065, rel=WIDTH_RTOL)


@pytest.mark.parametrize(("seed", "lobe"), [(3, "ggx"), (4, "blinn_phong")])
def test_sharp_lobes_do_not_get_worse(rig, seed, lobe):
    case = _case(rig, seed, lobe, 0.01)
    before = _epe(case, case["plane"])
    result = _refine(case)
    assert _epe(case, result.plane) <= before + SHARP_SLACK_PX


@pytest.mark.parametrize("shift_px", [-6.0, 10.0])
def test_recovers_from_a_virtual_light_at_the_wrong_depth(rough_ggx, shift_px):
    # Slide the true virtual light along the reference ray so that its image in the
    # farthest camera moves by shift_px: a plane off by 9-16 px of disparity.
    rig, light = rough_ggx["rig"], rough_ggx["light"]
    virtual = rough_ggx["truth"].mirror(light)
    ref = rig.reference_center_m
    span_px = rig.intrinsics.fx * np.max(np.linalg.norm(rig.centers_m - ref, axis=1))
    w0 = 1.0 / (virtual[2] - ref[2])
    wrong = plane_from_lights(light, ref + (virtual - ref) * w0 / (w0 + shift_px / span_px), ref)
    assert _epe(rough_ggx, wrong) > 5.0
    result = refine_plane(rough_ggx["views"], rig, light, rough_ggx["mask"], wrong,
                          centers_uv=rough_ggx["centers"])
    assert result.ok
    assert _epe(rough_ggx, result.plane) < ROUGH_REFINED_EPE_PX


def test_a_stereo_pair_is_enough():
    rig = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240))
    case = _case(rig, 2, "blinn_phong", 0.05)
    before = _epe(case, case["plane"])
    result = _refine(case)
    assert result.ok
    assert _epe(case, result.plane) < min(before / 2.0, 3 * ROUGH_REFINED_EPE_PX)


def test_float_views_give_the_same_plane(rough_ggx):
    floats = dict(rough_ggx, views=[v.astype(np.float32) / 255.0 for v in rough_ggx["views"]])
    a, b = _refine(rough_ggx), _refine(floats)
    assert b.ok
    assert b.plane.angle_to(a.plane) < 1e-3
    assert b.plane.offset_m == pytest.approx(a.plane.offset_m, abs=1e-6)


def test_default_window_centres_come_from_the_initial_plane(rough_ggx):
    result = refine_plane(rough_ggx["views"], rough_ggx["rig"], rough_ggx["light"],
                          rough_ggx["mask"], rough_ggx["plane"])
    assert result.ok
    assert _epe(rough_ggx, result.plane) < ROUGH_REFINED_EPE_PX


def test_the_reported_standard_error_matches_the_spread_over_noise_draws(rig):
    # The same scene under 8 draws of its sensor noise, at two noise levels: the spread
    # of the refined plane's disparity at the object box's corners against the standard
    # error each fit reports from its own residuals.
    base = random_scene(2, rig, lobe="ggx", roughness=0.065, light_radius_m=0.0)
    lit = rig.with_light(base.light.position_m)
    spreads, reported = [], []
    for noise in (0.002, 0.01):
        scene = dataclasses.replace(base, noise_std=noise)
        errors, sigmas = [], []
        for draw in range(8):
            out = render(scene, rig, noise_seed=draw)
            mask = out.instance_mask == 1
            result = SRDE(lit).estimate(out.views, mask)
            assert result.refinement.ok
            rows, cols = np.nonzero(mask)
            v = np.array([rows.min(), rows.min(), rows.max(), rows.max()])
            u = np.array([cols.min(), cols.max(), cols.min(), cols.max()])
            errors.append(plane_disparity(result.plane, lit)[v, u]
                          - plane_disparity(out.planes[0], lit)[v, u])
            assert result.disparity_sigma_px == result.refinement.disparity_sigma_px
            sigmas.append(result.disparity_sigma_px)
        spreads.append(float(np.max(np.std(errors, axis=0, ddof=1))))
        reported.append(float(np.median(sigmas)))
    for spread, sigma in zip(spreads, reported, strict=True):
        assert 0.5 < sigma / spread < 2.0, (sigma, spread)
    assert reported[1] > 2.0 * reported[0]  # five times the noise: several times the error


def test_result_is_frozen_and_reports_itself(rough_ggx):
    result = _refine(rough_ggx)
    assert result.n_samples > 100 and result.iterations >= 1 and result.time_s > 0
    assert result.residual == pytest.approx(math.sqrt(result.cost_final))
    assert result.lobe == "gtr"
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.status = "kept_initial"


# ------------------------------------------------------------------ the model's derivatives
@pytest.mark.parametrize(("lobe", "tail"), [
    ("gtr", 0.3), ("gtr", 0.0), ("gtr", 2e-4), ("gtr", -0.2), ("ggx", 0.5),
    ("blinn_phong", 0.0),
])
@pytest.mark.parametrize(("fresnel", "light_radius_m"), [
    ("exact", None), ("schlick", None), ("exact", 0.01), ("exact", 0.05)])
def test_model_slopes_agree_with_finite_differences(rough_ggx, lobe, tail, fresnel,
                                                    light_radius_m):
    case = rough_ggx
    samples = sample_windows(case["views"], case["rig"], case["mask"], case["plane"],
                              case["centers"])
    model = LobeModel(samples, case["rig"], (0, 0, 320, 240), case["light"], case["plane"],
                       lobe, DEFAULT_F0, None, fresnel=fresnel, light_radius_m=light_radius_m)
    theta = model.start_theta()
    # off the initial plane, a tail where both of the "gtr" derivative's branches apply
    theta[:N_PLANE] = [0.01, -0.02, 0.003]
    theta[I_TAIL], theta[I_FORE], theta[I_SPEC:] = tail, 0.7, [0.5, 0.1, 0.2]
    slopes = model.reduce(model.model_slopes(theta, model.free_all))
    for row, index in enumerate(model.free_all):
        up, down = theta.copy(), theta.copy()
        up[index] += SLOPE_STEPS[index]
        down[index] -= SLOPE_STEPS[index]
        expected = (model.luminance(model.reflection.geometry(up[:N_PLANE]), up)
                    - model.luminance(model.reflection.geometry(down[:N_PLANE]), down)) / (
                        2 * SLOPE_STEPS[index])
        scale = np.max(np.abs(expected))
        assert scale > 0
        assert np.max(np.abs(slopes[row] - expected)) < SLOPE_RTOL * scale, index


# ------------------------------------------------------------------ one lobe per light
def test_a_joint_model_of_one_light_is_the_single_light_model(rough_ggx):
    case = rough_ggx
    samples = sample_windows(case["views"], case["rig"], case["mask"], case["plane"],
                              case["centers"])
    single = LobeModel(samples, case["rig"], (0, 0, 320, 240), case["light"], case["plane"],
                        "gtr", DEFAULT_F0, None)
    joint = JointLobeModel([LobeModel(samples, case["rig"], (0, 0, 320, 240), case["light"],
                                      case["plane"], "gtr", DEFAULT_F0, None)])
    theta = single.initial_guess()
    theta[:N_PLANE] = [0.004, -0.003, 0.001]
    r_single, t_single = single.evaluate(theta)
    r_joint, t_joint = joint.evaluate(theta)
    np.testing.assert_allclose(r_joint, r_single, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(t_joint, t_single, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(joint.jacobian(t_joint, single.free_all),
                               single.jacobian(t_single, single.free_all), rtol=1e-6,
                               atol=1e-9 * np.abs(single.jacobian(t_single, single.free_all)).max())


def test_a_far_light_gets_no_intensity_and_changes_nothing(rough_ggx):
    # A further light whose highlight is nowhere near the windows: its lobe is 0 there.
    case = rough_ggx
    samples = sample_windows(case["views"], case["rig"], case["mask"], case["plane"],
                              case["centers"])
    far = np.asarray(case["light"]) + [5.0, 0.0, 0.0]
    parts = [LobeModel(samples, case["rig"], (0, 0, 320, 240), light, case["plane"], "ggx",
                       DEFAULT_F0, None) for light in (case["light"], far)]
    joint = JointLobeModel(parts)
    theta = joint.initial_guess()
    assert theta[-1] == 0.0 and theta[I_SPEC] > 0.0
    alone = LobeModel(samples, case["rig"], (0, 0, 320, 240), case["light"], case["plane"],
                      "ggx", DEFAULT_F0, None)
    np.testing.assert_allclose(joint.evaluate(theta)[0], alone.evaluate(theta[:-1])[0],
                               atol=1e-12)


def _case_model(case) -> LobeModel:
    """One light's lobe model on the case's windows around its initial plane."""
    samples = sample_windows(case["views"], case["rig"], case["mask"], case["plane"],
                              case["centers"])
    return LobeModel(samples, case["rig"], (0, 0, 320, 240), case["light"], case["plane"],
                     "gtr", DEFAULT_F0, None)


def test_further_lights_diffuse_slopes_agree_with_finite_differences(rough_ggx):
    case = rough_ggx
    model = _case_model(case)
    light = np.asarray(case["light"])
    further = np.stack([light + [-0.3, 0.1, 0.05], light + [0.2, 0.25, -0.1]])
    diffuse = DiffuseLights(model.reflection, further)
    params = np.array([0.01, -0.02, 0.003])
    weights = np.array([0.4, 1.3])
    free = np.arange(N_PLANE)
    slopes = diffuse.slopes(params, weights, free, np.zeros((N_PLANE, model.reflection.q.size)))
    for index in free:
        up, down = params.copy(), params.copy()
        up[index] += SLOPE_STEPS[index]
        down[index] -= SLOPE_STEPS[index]
        expected = weights @ (diffuse.at(up) - diffuse.at(down)) / (2 * SLOPE_STEPS[index])
        scale = np.max(np.abs(expected))
        assert scale > 0
        assert np.max(np.abs(slopes[index] - expected)) < SLOPE_RTOL * scale, index
    # normalised to a median of 1 at the initial plane
    np.testing.assert_allclose(np.median(diffuse.at(np.zeros(N_PLANE)), axis=1), 1.0)


def test_a_light_behind_the_plane_sheds_no_diffuse_light(rough_ggx):
    case = rough_ggx
    model = _case_model(case)
    plane = case["plane"]
    behind = np.asarray(plane.normal) * (plane.offset_m - 0.5)  # 0.5 m beyond the plane
    diffuse = DiffuseLights(model.reflection, behind[None])
    assert not np.any(diffuse.at(np.zeros(N_PLANE)))


def test_a_basis_vector_that_underflows_gets_no_coefficient():
    # A lobe that underflows on the samples (1e-160 there): its Jacobi scale of 1e160 made
    # the intensities' solution overflow. It gets 0; the others are solved as without it.
    rng = np.random.default_rng(3)
    basis = np.vstack([rng.uniform(0.1, 1.0, 50), np.full(50, 1e-160), np.ones(50)])
    y = 0.7 * basis[0] + 0.2
    normal, rhs = basis @ basis.T, basis @ y
    with np.errstate(all="raise"):
        coef = joint_module._solve_scaled(normal, rhs)
    np.testing.assert_allclose(coef, [0.7, 0.0, 0.2], atol=1e-9)
    kept = [0, 2]
    np.testing.assert_allclose(coef[kept], np.linalg.solve(normal[np.ix_(kept, kept)],
                                                           rhs[kept]), rtol=1e-9)


def test_compare_planes_ranks_the_true_plane_first(rough_ggx):
    case = rough_ggx
    truth = case["truth"]
    off = Plane(truth.normal, truth.offset_m - 0.004)  # 4 mm nearer
    costs = compare_planes(case["views"], case["rig"], case["light"], case["mask"],
                           [truth, off, case["plane"]], case["centers"])
    assert np.all(np.isfinite(costs))
    # The rough lobe's centroid bias leaves the geometric plane off the truth too.
    assert costs[1] > 2.0 * costs[0] and costs[2] > costs[0]


# ------------------------------------------------------------------ keeping the initial plane
def test_keeps_the_plane_when_everything_is_saturated(rough_ggx):
    white = [np.full_like(v, 255) for v in rough_ggx["views"]]
    result = refine_plane(white, rough_ggx["rig"], rough_ggx["light"], rough_ggx["mask"],
                          rough_ggx["plane"])
    assert not result and result.status == "kept_initial"
    assert result.plane == rough_ggx["plane"]
    assert result.reason.startswith("samples: no view shows a highlight")
    assert result.params is None and math.isnan(result.cost_final)
    assert math.isnan(result.disparity_sigma_px)


def test_keeps_the_plane_without_unsaturated_flanks(rough_ggx):
    # A clipped disc with a hard edge: a highlight, but no lobe flank to fit.
    views = []
    for v in rough_ggx["views"]:
        flat = np.full_like(v, 40)
        flat[v.max(axis=2) >= 200] = 255
        views.append(flat)
    result = refine_plane(views, rough_ggx["rig"], rough_ggx["light"], rough_ggx["mask"],
                          rough_ggx["plane"])
    assert result.status == "kept_initial"
    assert "unsaturated samples on the highlight's flanks" in result.reason


def test_keeps_the_plane_when_the_image_is_not_a_lobe(rough_ggx, rig):
    # Texture-like noise around a highlight-sized bright patch: nothing a lobe explains.
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 256, v.shape, dtype=np.uint8) for v in rough_ggx["views"]]
    result = refine_plane(noise, rough_ggx["rig"], rough_ggx["light"], rough_ggx["mask"],
                          rough_ggx["plane"])
    assert result.status == "kept_initial"
    assert result.reason.startswith(("fit:", "samples:"))
    assert result.plane == rough_ggx["plane"]


@pytest.mark.parametrize(("plane", "reason"), [
    (Plane((0.0, 0.0, -1.0), 1.0), "camera(s) [0, 1, 2, 3, 4, 5, 6, 7, 8] lie behind it"),
    (Plane((0.0, 0.0, 1.0), -1.0), "seen edge-on or from behind"),
    (Plane((1.0, 0.0, 0.0), -0.5), "seen edge-on or from behind"),
])
def test_keeps_a_nonsense_initial_plane(rough_ggx, plane, reason):
    result = refine_plane(rough_ggx["views"], rough_ggx["rig"], rough_ggx["light"],
                          rough_ggx["mask"], plane)
    assert result.status == "kept_initial" and result.plane == plane
    assert result.reason.startswith("initial plane:") and reason in result.reason


def test_keeps_a_plane_with_the_light_behind_it(rough_ggx):
    plane = rough_ggx["truth"]
    light = plane.mirror(rough_ggx["light"])  # the virtual light, on the far side
    result = refine_plane(rough_ggx["views"], rough_ggx["rig"], light, rough_ggx["mask"], plane)
    assert result.status == "kept_initial"
    assert "the light is behind it" in result.reason


def test_keeps_the_plane_when_no_window_is_near_the_images(rough_ggx):
    far = np.full((9, 2), 1e5)
    result = refine_plane(rough_ggx["views"], rough_ggx["rig"], rough_ggx["light"],
                          rough_ggx["mask"], rough_ggx["plane"], centers_uv=far)
    assert result.reason == "samples: no view has a highlight centre inside or near the image"


# ------------------------------------------------------------------ input errors
def _args(case):
    return [case["views"], case["rig"], case["light"], case["mask"], case["plane"]]


@pytest.mark.parametrize(("index", "value", "error", "match"), [
    (0, [np.zeros((240, 320, 3), np.uint8)] * 8, ImageError, "expected 9 images"),
    (0, [np.zeros((120, 160, 3), np.uint8)] * 9, ImageError, "expected images of the rig's size"),
    (1, "rig.json", SRDEError, "rig: expected a CameraRig, got str"),
    (2, [0.1, 0.2], LightError, "light_m: expected 3 finite numbers"),
    (2, [0.1, np.nan, 0.2], LightError, "light_m: expected 3 finite numbers"),
    (2, "up", LightError, "light_m: expected 3 numbers"),
    (3, np.ones((10, 10), bool), MaskError, r"mask: expected shape \(240, 320\)"),
    (3, np.zeros((240, 320), bool), MaskError, "empty mask"),
    (4, (0.0, 0.0, -1.0), SRDEError, "initial_plane: expected a Plane, got tuple"),
])
def test_positional_input_errors(rough_ggx, index, value, error, match):
    args = _args(rough_ggx)
    args[index] = value
    with pytest.raises(error, match=match):
        refine_plane(*args)


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    (dict(lobe="phong"), SRDEError, r"lobe: expected one of \['gtr', 'ggx', 'blinn_phong'\]"),
    (dict(foreshortening=9.0), SRDEError, "foreshortening: expected None or a number"),
    (dict(foreshortening="auto"), SRDEError, "foreshortening: expected None or a number"),
    (dict(f0=0.0), SRDEError, r"f0: expected a number in \(0, 1\]"),
    (dict(f0=True), SRDEError, r"f0: expected a number in \(0, 1\]"),
    (dict(max_iterations=0), SRDEError, "max_iterations: expected a positive integer"),
    (dict(max_iterations=2.5), SRDEError, "max_iterations: expected a positive integer"),
    (dict(centers_uv=np.zeros((9, 3))), ImageError, r"centers_uv: expected shape \(9, 2\)"),
    (dict(centers_uv=np.full((9, 2), np.inf)), ImageError, "centers_uv: expected finite"),
    (dict(centers_uv="centre"), ImageError, "centers_uv: expected an array"),
    (dict(modelled_lights_m=[[0.1, np.nan, 0.2]]), SRDEError,
     r"modelled_lights_m: expected \(M, 3\) finite metres"),
    (dict(other_lights_m="lamp"), SRDEError, r"other_lights_m: expected \(M, 3\) finite"),
    (dict(modelled_centers_uv=np.zeros((1, 9, 2))), SRDEError,
     "modelled_centers_uv: expected None without modelled_lights_m"),
    (dict(modelled_lights_m=[[0.1, -0.3, 0.2]], modelled_centers_uv=np.zeros((2, 9, 2))),
     ImageError, r"modelled_centers_uv: expected shape \(1, 9, 2\)"),
    (dict(modelled_lights_m=[[0.1, -0.3, 0.2]], modelled_centers_uv=np.full((1, 9, 2), np.inf)),
     ImageError, "modelled_centers_uv: expected finite"),
    (dict(modelled_lights_m=[[0.1, -0.3, 0.2]], modelled_centers_uv="lamp"), ImageError,
     "modelled_centers_uv: expected an array"),
])
def test_keyword_input_errors(rough_ggx, kwargs, error, match):
    with pytest.raises(error, match=match):
        refine_plane(*_args(rough_ggx), **kwargs)


def test_every_lobe_name_is_accepted(rough_ggx):
    for lobe in LOBES:
        assert refine_plane(*_args(rough_ggx), lobe=lobe, max_iterations=1).lobe == lobe
