"""Tests for the light's extent in the photometric refinement (srde_fusion.srde.refine.disc).

A spherical light of known radius turns the refinement's lobe into the lobe averaged over
the light's disc. These tests check the quadrature against a fine numerical average, the
point-light limit, the public option's checks, that a radius of 0 or None is exactly the
point model, that on a faithful render with a light wider than the lobe the radius
brings the plane closer than the point model does, and that a disc well inside the lobe
is read through fewer points to the same plane.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from srde_fusion.errors import LightError
from srde_fusion.geometry import CameraRig, RigLight, plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.srde.refine import LOBES, refine_plane
from srde_fusion.srde.refine.disc import (
    DISC_RINGS,
    PIXEL_DISC_RINGS,
    RINGS_REACH_UNITS,
    disc_geometry,
    disc_points,
    disc_rings,
    lobe_unit,
    max_disc_rings,
)
from srde_fusion.srde.refine.lobes import lobe_shape
from srde_fusion.synthetic import Physics, RandomSceneConfig, random_scene, render

# A light 1 m away whose half-vector disc has radius b = R / (2 r) (R = 2 mm: b = 1e-3).
DISTANCE_M = 1.0
# The quadrature's largest error against a fine average, relative to the lobe's peak,
# while the disc's radius is at most one lobe unit (module notes of refine.disc).
QUADRATURE_TOL = 0.01
# Fine reference average: points of a polar grid over the disc.
FINE_RINGS, FINE_ANGLES = 200, 256


def _fine_disc_mean(lobe: str, s: np.ndarray, b: float, log_width: float, tail: float):
    """Lobe averaged over the half-vector disc of radius ``b`` around offset ``s``."""
    # midpoint rule in r^2 (equal areas) and in angle
    radii = b * np.sqrt((np.arange(FINE_RINGS) + 0.5) / FINE_RINGS)
    angles = 2.0 * np.pi * (np.arange(FINE_ANGLES) + 0.5) / FINE_ANGLES
    x = (radii[:, None] * np.cos(angles)[None, :]).ravel()
    y = (radii[:, None] * np.sin(angles)[None, :]).ravel()
    sin2 = (s[:, None] - x[None, :]) ** 2 + y[None, :] ** 2
    g = SimpleNamespace(sin2_h=sin2, cos_h=np.sqrt(1.0 - sin2))
    return lobe_shape(lobe, g, log_width, tail).mean(axis=1)


def _disc(s: np.ndarray, radius_m: float):
    sin2 = s * s
    cos = np.sqrt(1.0 - sin2)
    geometry = SimpleNamespace(sin2_h=sin2, cos_h=cos)
    geometry.disc = disc_geometry(cos, sin2, np.full_like(s, DISTANCE_M), radius_m)
    return geometry


def test_the_points_cover_the_disc_with_its_moments():
    points, weights = disc_points()
    assert len(points) == 19 and np.all(weights == weights[0])
    assert weights.sum() == pytest.approx(1.0, abs=1e-15)
    assert np.all(np.hypot(points[:, 0], points[:, 1]) < 1.0)
    # centred, with the disc's mean |xi|^2, and symmetric about both axes
    np.testing.assert_allclose(weights @ points, 0.0, atol=1e-15)
    assert weights @ np.sum(points**2, axis=1) == pytest.approx(0.5, abs=1e-15)
    for mirror in ([1.0, -1.0], [-1.0, 1.0]):
        image = points * np.array(mirror)
        assert np.min(np.hypot(*(image[:, None, :] - points[None, :, :]).transpose(2, 0, 1)),
                      axis=1).max() < 1e-12


@pytest.mark.parametrize(("lobe", "tail"), [("gtr", 0.5), ("gtr", 0.0), ("gtr", -0.2),
                                            ("ggx", 0.5), ("blinn_phong", 0.0)])
@pytest.mark.parametrize("disc_in_lobe_units", [0.3, 1.0])
def test_the_quadrature_matches_a_fine_average_over_the_disc(lobe, tail, disc_in_lobe_units):
    width = 0.02
    # one lobe unit: z = 2 (1 - w^2) sin^2 / w^2 = 1 (blinn_phong: half of that)
    unit = width / math.sqrt((2.0 if lobe != "blinn_phong" else 1.0) * (1.0 - width**2))
    b = disc_in_lobe_units * unit
    radius_m = math.sin(2.0 * b) * DISTANCE_M
    s = np.linspace(0.0, b + 4.0 * unit, 41)
    quadrature = lobe_shape(lobe, _disc(s, radius_m), math.log(width), tail)
    fine = _fine_disc_mean(lobe, s, b, math.log(width), tail)
    assert np.max(np.abs(quadrature - fine)) < QUADRATURE_TOL * fine.max()
    # and the point lobe is far off: the disc is no detail
    point = lobe_shape(lobe, SimpleNamespace(sin2_h=s * s, cos_h=np.sqrt(1 - s * s)),
                       math.log(width), tail)
    assert np.max(np.abs(point - fine)) > 3 * QUADRATURE_TOL * fine.max()


def test_pixel_samples_read_a_wide_disc_through_the_finer_pattern():
    # A disc 1.5 lobe units in radius is past the 19 points' reach (2.2 % of the peak off
    # the fine average): the ripple a block mean smooths and a pixel shows. The pixel
    # pattern's 61 points stay within 1 % (0.9 %).
    lobe, tail, width = "gtr", 0.5, 0.01
    unit = width / math.sqrt(2.0 * (1.0 - width**2))
    b = 1.5 * unit
    radius_m = math.sin(2.0 * b) * DISTANCE_M
    s = np.linspace(0.0, b + 4.0 * unit, 81)
    fine = _fine_disc_mean(lobe, s, b, math.log(width), tail)

    def error(rings):
        sin2 = s * s
        geometry = SimpleNamespace(sin2_h=sin2, cos_h=np.sqrt(1.0 - sin2))
        geometry.disc = disc_geometry(geometry.cos_h, sin2, np.full_like(s, DISTANCE_M),
                                      radius_m, rings=rings)
        return np.max(np.abs(lobe_shape(lobe, geometry, math.log(width), tail) - fine))

    assert len(disc_points(PIXEL_DISC_RINGS)[0]) == 61
    assert error(PIXEL_DISC_RINGS) < QUADRATURE_TOL * fine.max() < error(DISC_RINGS)


@pytest.mark.parametrize(("lobe", "tail", "tol"), [("gtr", 0.5, QUADRATURE_TOL),
                                                   ("gtr", -0.2, 1.5 * QUADRATURE_TOL),
                                                   ("blinn_phong", 0.0, 1.5 * QUADRATURE_TOL)])
def test_fewer_rings_read_a_disc_well_inside_the_lobe(lobe, tail, tol):
    # Each ring count's reach (RINGS_REACH_UNITS) is where its pattern still follows the
    # fine average; a larger disc takes the next count, up to the samples' most.
    width = 0.01
    unit = lobe_unit(lobe, width)
    for rings, units in enumerate(RINGS_REACH_UNITS, start=1):
        b = units * unit
        s = np.linspace(0.0, b + 4.0 * unit, 81)
        fine = _fine_disc_mean(lobe, s, b, math.log(width), tail)
        sin2 = s * s
        g = SimpleNamespace(sin2_h=sin2, cos_h=np.sqrt(1.0 - sin2))
        g.disc = disc_geometry(g.cos_h, sin2, np.full_like(s, DISTANCE_M),
                               math.sin(2.0 * b) * DISTANCE_M, rings=rings)
        assert g.disc.reach == pytest.approx(b, rel=1e-9)
        assert np.max(np.abs(lobe_shape(lobe, g, math.log(width), tail) - fine)) \
            < tol * fine.max()
        assert disc_rings(0.999 * b, lobe, width, block_px=1) == rings
        assert disc_rings(1.01 * b, lobe, width, block_px=1) == rings + 1
        assert disc_rings(0.999 * b, lobe, width, block_px=7) == min(rings, DISC_RINGS)
    assert disc_rings(10.0 * unit, lobe, width, block_px=1) == max_disc_rings(1) \
        == PIXEL_DISC_RINGS
    assert disc_rings(10.0 * unit, lobe, width, block_px=5) == max_disc_rings(5) == DISC_RINGS
    # a lobe at the width's bound (1) is flat: any disc is small against it
    assert disc_rings(0.5, lobe, 1.0, block_px=1) == 1


@pytest.mark.parametrize("lobe", LOBES)
def test_a_tiny_disc_is_the_point_lobe(lobe):
    s = np.linspace(0.0, 0.2, 50)
    point = lobe_shape(lobe, SimpleNamespace(sin2_h=s * s, cos_h=np.sqrt(1 - s * s)),
                       math.log(0.05), 0.3)
    disc = lobe_shape(lobe, _disc(s, 1e-7), math.log(0.05), 0.3)
    np.testing.assert_allclose(disc, point, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("disc_in_lobe_units", "peak_rtol"), [(0.5, QUADRATURE_TOL), (2.0, 0.05)])
def test_the_disc_lowers_the_peak_and_keeps_the_energy(disc_in_lobe_units, peak_rtol):
    # In the tangent plane every point's lobe has the point lobe's integral, so the
    # average has it too; the light's extent spreads it (a lower, wider highlight).
    width = 0.01
    unit = width / math.sqrt(2.0 * (1.0 - width**2))
    b = disc_in_lobe_units * unit
    s = np.linspace(0.0, b + 60.0 * unit, 20001)  # GGX's tail holds ~1e-3 beyond 30 units
    disc = lobe_shape("ggx", _disc(s, math.sin(2.0 * b) * DISTANCE_M), math.log(width), 0.5)
    point = lobe_shape("ggx", SimpleNamespace(sin2_h=s * s, cos_h=np.sqrt(1 - s * s)),
                       math.log(width), 0.5)
    energy = [float(np.trapezoid(v * s, s)) for v in (disc, point)]
    assert energy[0] == pytest.approx(energy[1], rel=2e-3)
    # the exact average's peak: (1 - (1 + beta^2 / 2)^-1) / (beta^2 / 2) for GGX
    half_beta2 = disc_in_lobe_units**2 / 2.0
    assert disc[0] == pytest.approx((1.0 - 1.0 / (1.0 + half_beta2)) / half_beta2,
                                    rel=peak_rtol)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _oblique_case(theta_d_deg: float, tilt_across: float, offset: float):
    """Normal, light and eye directions: light and eye 2 theta_d apart, the normal offset
    from their half vector by ``offset`` (sin), turned ``tilt_across`` (rad) out of the
    plane of incidence."""
    half = math.radians(theta_d_deg)
    light = np.array([math.sin(half), 0.0, math.cos(half)])
    eye = np.array([-math.sin(half), 0.0, math.cos(half)])
    h = _unit(light + eye)
    # tangent directions at h: in the plane of incidence (x) and across it (y)
    tx, ty = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    t = math.cos(tilt_across) * tx + math.sin(tilt_across) * ty
    normal = _unit(math.sqrt(1.0 - offset**2) * h + offset * t)
    return normal, light, eye


def _fine_sphere_mean(lobe, normal, light, eye, b, log_width, tail):
    """Lobe averaged over the light directions of a disc of angular radius 2 b around
    ``light``, each direction's own half vector with the eye."""
    radii = 2.0 * b * np.sqrt((np.arange(FINE_RINGS) + 0.5) / FINE_RINGS)
    angles = 2.0 * np.pi * (np.arange(FINE_ANGLES) + 0.5) / FINE_ANGLES
    a1 = _unit(np.cross(light, [0.0, 1.0, 0.0]))
    a2 = np.cross(light, a1)
    r, a = np.meshgrid(radii, angles, indexing="ij")
    dirs = (np.cos(r.ravel())[:, None] * light + np.sin(r.ravel())[:, None]
            * (np.cos(a.ravel())[:, None] * a1 + np.sin(a.ravel())[:, None] * a2))
    h = _unit(dirs + eye)
    cos = np.clip(h @ normal, -1.0, 1.0)
    g = SimpleNamespace(sin2_h=1.0 - cos**2, cos_h=cos)
    return float(lobe_shape(lobe, g, log_width, tail).mean())


@pytest.mark.parametrize("theta_d_deg", [5.0, 30.0, 45.0])
@pytest.mark.parametrize("tilt_across", [0.0, 0.7, math.pi / 2])
def test_the_light_seen_from_aside_is_an_ellipse_of_half_vectors(theta_d_deg, tilt_across):
    # The light's disc moves the half vector by half as much in the plane of incidence
    # as across it times cos(theta_d): the model's ellipse matches a fine average over
    # the light's own directions, where the round disc falls short from the side.
    lobe, width, tail = "gtr", 0.03, 0.5
    unit = width / math.sqrt(2.0 * (1.0 - width**2))
    b = 1.0 * unit
    radius_m = math.sin(2.0 * b) * DISTANCE_M
    errors = {"ellipse": [], "round": []}
    fine_values = []
    for offset in np.linspace(0.0, b + 3.0 * unit, 15):
        normal, light, eye = _oblique_case(theta_d_deg, tilt_across, offset)
        fine = _fine_sphere_mean(lobe, normal, light, eye, b, math.log(width), tail)
        fine_values.append(fine)
        h = _unit(light + eye)
        cos_h = np.array([float(h @ normal)])
        cosines = dict(cos_i=np.array([float(normal @ light)]),
                       cos_o=np.array([float(normal @ eye)]),
                       cos_io=np.array([float(light @ eye)]))
        r = np.array([DISTANCE_M])
        for name, extra in (("ellipse", cosines), ("round", {})):
            g = SimpleNamespace(sin2_h=1.0 - cos_h**2, cos_h=cos_h)
            g.disc = disc_geometry(cos_h, 1.0 - cos_h**2, r, radius_m, **extra)
            errors[name].append(abs(float(lobe_shape(lobe, g, math.log(width), tail)[0]) - fine))
    peak = max(fine_values)
    assert max(errors["ellipse"]) < 1.5 * QUADRATURE_TOL * peak
    if theta_d_deg >= 30.0:  # the round disc misses the elongation
        assert max(errors["round"]) > 2.0 * max(errors["ellipse"])


# ------------------------------------------------------------------ through refine_plane
@pytest.fixture(scope="module")
def wide_light():
    """A sharp lobe close to a 15 mm light (disc radius ~3 lobe widths), faithful render.

    The renderer integrates the light over 256 points of its disc (its default 64 alias
    on a lobe this sharp); no sensor noise, 8-bit sRGB.
    """
    rig = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240))
    config = RandomSceneConfig(roughness=0.006, light_radius_m=0.015, clip_ratio=(2.0, 6.0),
                               distance_m=(0.3, 0.45), light_offset_m=(0.05, 0.2))
    scene = random_scene(103, rig, config=config)
    physics = replace(Physics.faithful(), full_well_e=None, read_noise_e=0.0,
                      light_samples=256)
    out = render(scene, rig, physics=physics, supersample=2)
    light = np.array(scene.light.position_m)
    lit = rig.with_light(light)
    mask = out.object_masks[0]
    geometric = SRDE(lit, refine=False).estimate(out.views, mask)
    assert geometric.ok, geometric.reason
    return SimpleNamespace(
        views=out.views, rig=lit, light=light, mask=mask, plane=geometric.plane,
        radius_m=scene.light.radius_m, truth=out.disparity_px,
        centers=np.where(geometric.used_views[:, None], geometric.highlight_centers, np.nan))


def _epe(case, plane) -> float:
    pred = plane_disparity(plane, case.rig)
    return float(np.mean(np.abs(pred - case.truth)[case.mask]))


def _refine(case, **kwargs):
    return refine_plane(case.views, case.rig, case.light, case.mask, case.plane,
                        centers_uv=case.centers, **kwargs)


def test_the_radius_fixes_a_light_wider_than_the_lobe(wide_light):
    point = _refine(wide_light)
    disc = _refine(wide_light, light_radius_m=wide_light.radius_m)
    assert disc.ok, disc.reason
    assert _epe(wide_light, disc.plane) < 0.5 * _epe(wide_light, point.plane)
    # the pair's target (measured 0.014 px, the point model 0.031)
    assert _epe(wide_light, disc.plane) < 0.02
    # the rendered lobe is GGX of width 0.006: the disc model finds it
    assert disc.params.width == pytest.approx(0.006, rel=0.15)
    assert disc.params.tail == pytest.approx(0.5, abs=0.05)


def test_a_radius_of_zero_is_the_point_model(wide_light):
    point = _refine(wide_light)
    for radius in (0.0, None):
        again = _refine(wide_light, light_radius_m=radius)
        assert again.plane == point.plane and again.params == point.params


def test_srde_hands_the_rig_lights_radius_to_the_refinement(wide_light):
    case = wide_light
    with_radius = case.rig.with_lights([RigLight(tuple(case.light), radius_m=case.radius_m)])
    result = SRDE(with_radius).estimate(case.views, case.mask)
    assert result.ok and result.refinement.ok
    direct = _refine(case, light_radius_m=case.radius_m)
    assert result.plane == direct.plane
    # no radius in the rig, or a light given by position: the point model
    plain = SRDE(case.rig).estimate(case.views, case.mask)
    given = SRDE(with_radius, light=case.light).estimate(case.views, case.mask)
    assert plain.plane == given.plane == _refine(case).plane


@pytest.mark.parametrize("radius", [-0.001, 1.5, True, "5 mm", float("nan")])
def test_a_bad_radius_is_a_light_error(wide_light, radius):
    with pytest.raises(LightError, match="light_radius_m: expected None or a radius"):
        _refine(wide_light, light_radius_m=radius)


def test_every_rig_light_keeps_its_radius():
    rig = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240)).with_lights(
        [RigLight((0.3, -0.2, 0.0), radius_m=0.01), (-0.3, -0.2, 0.0)])
    assert SRDE(rig).light_radii_m == (0.01, None)
    assert SRDE(rig, light=[0.3, -0.2, 0.0]).light_radii_m == (None,)


@pytest.mark.parametrize(("cos_i", "cos_o", "cos_io"), [
    (0.9, 0.9, 1.0),      # light along the eye: no plane of incidence
    (0.1, 0.1, -0.999),   # light and eye nearly opposite: the stretch is capped
    (0.8, 0.6, 0.5),      # an ordinary case, at s = 0 and beyond
])
def test_the_ellipse_stays_finite_where_its_axes_are_undefined(cos_i, cos_o, cos_io):
    s = np.array([0.0, 1e-12, 1e-4, 0.05])
    cos_h = np.sqrt(1.0 - s * s)
    n = len(s)
    cosines = dict(cos_i=np.full(n, cos_i), cos_o=np.full(n, cos_o), cos_io=np.full(n, cos_io))
    disc = disc_geometry(cos_h, s * s, np.full(n, DISTANCE_M), 0.01, **cosines)
    by_sin2 = np.ones_like(disc.sin2)
    by_cos_h, by_r, by_cosines = disc.slopes(by_sin2)
    for values in (disc.sin2, by_cos_h, by_r, by_cosines):
        assert np.all(np.isfinite(values))
    assert np.all(disc.sin2 >= 0.0)
    if cos_io == 1.0:  # no elongation: the round disc's values
        round_disc = disc_geometry(cos_h, s * s, np.full(n, DISTANCE_M), 0.01)
        np.testing.assert_allclose(np.sort(disc.sin2, axis=0), np.sort(round_disc.sin2, axis=0),
                                   rtol=1e-9, atol=1e-15)


@pytest.fixture(scope="module")
def rough_under_lamp():
    """A rough clipped lobe under a 15 mm light: the disc is well inside the lobe."""
    rig = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240))
    config = RandomSceneConfig(roughness=0.06, light_radius_m=0.015, clip_ratio=(4.0, 8.0))
    scene = random_scene(104, rig, config=config)
    out = render(scene, rig, physics=Physics.faithful(), supersample=2)
    lit = rig.with_lights([RigLight(scene.light.position_m, radius_m=scene.light.radius_m)])
    return SimpleNamespace(views=out.views, rig=lit, mask=out.object_masks[0])


def test_a_disc_inside_the_lobe_is_read_through_fewer_points(rough_under_lamp, monkeypatch):
    # The pair reads every pixel; the pattern's 61 points would multiply the cost of each
    # evaluation, where 7 follow a disc this small as closely (the plane agrees).
    case = rough_under_lamp
    chosen = []

    def recording(*args, **kwargs):
        chosen.append(disc_rings(*args, **kwargs))
        return chosen[-1]

    monkeypatch.setattr("srde_fusion.srde.refine.plane.disc_rings", recording)
    lean = SRDE(case.rig).estimate(case.views, case.mask)
    assert lean.ok and lean.refinement.ok, lean.reason
    assert chosen and set(chosen) == {1}
    monkeypatch.setattr("srde_fusion.srde.refine.plane.disc_rings",
                        lambda reach, lobe, width, block_px: max_disc_rings(block_px))
    full = SRDE(case.rig).estimate(case.views, case.mask)
    assert full.ok and full.refinement.ok
    difference = plane_disparity(lean.plane, case.rig) - plane_disparity(full.plane, case.rig)
    assert np.max(np.abs(difference[case.mask])) < 1e-3
