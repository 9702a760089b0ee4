"""Plane geometry and virtual-light triangulation, against exact projections.

Highlight centres here are the exact projections of the mirrored light, so the
triangulated virtual light, the plane and the disparity must come back to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from srde_fusion.geometry import (
    CameraRig,
    Plane,
    adjacent_pairs,
    incidence_angle_deg,
    max_shift_px,
    mirror_point,
    pairwise_virtual_lights,
    plane_depth,
    plane_disparity,
    plane_from_lights,
    robust_triangulate,
    triangulate_rectified,
)

# Exact centres in, float64 arithmetic throughout: only rounding separates the answers.
REL_TOL = 1e-6


@st.composite
def rigs(draw):
    """Random rectified rigs: grids of 1-4 rows and 2-4 columns, and stereo pairs."""
    fx = draw(st.floats(300.0, 1500.0))
    fy = fx * draw(st.floats(0.9, 1.1))
    w, h = 640, 480
    cx = draw(st.floats(280.0, 360.0))
    cy = draw(st.floats(200.0, 280.0))
    baseline = draw(st.floats(0.02, 0.3))
    if draw(st.booleans()):
        return CameraRig.stereo(baseline, fx, fy, cx, cy, image_size=(w, h))
    rows = draw(st.integers(1, 4))
    cols = draw(st.integers(2, 4))
    return CameraRig.grid(rows, cols, baseline, fx, fy, cx, cy, image_size=(w, h))


@st.composite
def planes_and_lights(draw, rig):
    """A plane in front of the rig and a light on the cameras' side of it."""
    z = draw(st.floats(0.3, 3.0))
    point = np.array([draw(st.floats(-0.3, 0.3)) * z, draw(st.floats(-0.3, 0.3)) * z, z])
    tilt = np.radians(draw(st.floats(0.0, 60.0)))
    azimuth = np.radians(draw(st.floats(0.0, 360.0)))
    normal = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                       -np.cos(tilt)])
    plane = Plane.from_point_normal(point, normal, rig.reference_center_m)
    light = np.array([draw(st.floats(-1.0, 1.0)), draw(st.floats(-1.0, 1.0)),
                      draw(st.floats(-0.5, 0.5))])
    assume(plane.signed_distance(light) > 0.05)
    assume(np.all(plane.signed_distance(rig.centers_m) > 0.05))
    virtual = plane.mirror(light)
    # Every camera must see the virtual light in front of it, not nearly edge-on.
    assume(np.all(virtual[2] - rig.centers_m[:, 2] > 0.1))
    return plane, light, virtual


def exact_centers(rig, point):
    return np.stack([rig.project(point, j) for j in range(rig.n_cameras)])


@given(data=st.data())
def test_triangulation_recovers_virtual_light_plane_and_disparity(data):
    rig = data.draw(rigs())
    plane, light, virtual = data.draw(planes_and_lights(rig))
    centers = exact_centers(rig, virtual)
    tri = triangulate_rectified(rig, centers)
    scale = np.linalg.norm(virtual)
    np.testing.assert_allclose(tri.point_m, virtual, rtol=0, atol=REL_TOL * scale)
    assert tri.rms_px < 1e-6
    assert tri.used.all()
    np.testing.assert_allclose(tri.reference_uv, rig.project(virtual), atol=1e-6)
    np.testing.assert_allclose(1.0 / tri.inverse_depth_per_m, virtual[2], rtol=REL_TOL)

    estimated = plane_from_lights(light, tri.point_m, rig.reference_center_m)
    assert estimated.angle_to(plane) < np.degrees(REL_TOL)
    assert estimated.offset_m == pytest.approx(plane.offset_m, rel=REL_TOL, abs=1e-9)
    assert np.dot(estimated.n, plane.n) > 0  # same orientation, towards the cameras

    uv = np.array([[rig.intrinsics.cx, rig.intrinsics.cy], [10.0, 20.0], [600.0, 450.0]])
    truth = plane_disparity(plane, rig, uv)
    got = plane_disparity(estimated, rig, uv)
    valid = np.isfinite(truth)
    np.testing.assert_array_equal(np.isfinite(got), valid)
    np.testing.assert_allclose(got[valid], truth[valid], rtol=1e-5)


@given(data=st.data())
def test_pairwise_triangulation_is_exact_for_every_adjacent_pair(data):
    rig = data.draw(rigs())
    _, _, virtual = data.draw(planes_and_lights(rig))
    pairs = adjacent_pairs(rig)
    points = pairwise_virtual_lights(rig, exact_centers(rig, virtual), pairs)
    assert points.shape == (len(pairs), 3)
    np.testing.assert_allclose(points, np.broadcast_to(virtual, points.shape), rtol=0,
                               atol=REL_TOL * np.linalg.norm(virtual))


@given(data=st.data())
def test_robust_triangulation_drops_a_displaced_view(data):
    rig = data.draw(rigs())
    assume(rig.n_cameras >= 4)
    _, _, virtual = data.draw(planes_and_lights(rig))
    centers = exact_centers(rig, virtual)
    bad = data.draw(st.integers(0, rig.n_cameras - 1))
    angle = data.draw(st.floats(0.0, 2 * np.pi))
    centers[bad] += 5.0 * np.array([np.cos(angle), np.sin(angle)])
    tri = robust_triangulate(rig, centers, max_residual_px=1.0, min_residual_px=0.1)
    expected = np.ones(rig.n_cameras, dtype=bool)
    expected[bad] = False
    np.testing.assert_array_equal(tri.used, expected)
    np.testing.assert_allclose(tri.point_m, virtual, atol=REL_TOL * np.linalg.norm(virtual))
    assert tri.residuals_px[bad] > 1.0


def test_robust_triangulation_ignores_missing_views(rig3x3):
    virtual = np.array([0.05, -0.02, 1.8])
    centers = exact_centers(rig3x3, virtual)
    centers[[0, 7]] = np.nan
    tri = robust_triangulate(rig3x3, centers, max_residual_px=1.0)
    assert tri.used.tolist() == [False, True, True, True, True, True, True, False, True]
    assert np.isnan(tri.residuals_px[[0, 7]]).all()
    np.testing.assert_allclose(tri.point_m, virtual, atol=1e-9)


def test_robust_triangulation_reports_no_agreement(small_stereo_rig):
    rig = small_stereo_rig
    centers = np.array([[10.0, 5.0], [4.0, 15.0]])  # 10 px apart vertically
    tri = robust_triangulate(rig, centers, max_residual_px=1.0)
    assert not tri.used.any()
    assert np.isnan(tri.point_m).all() and np.isnan(tri.rms_px)


def test_triangulation_needs_two_distinct_centres(rig3x3):
    centers = np.full((9, 2), np.nan)
    centers[4] = (300.0, 200.0)
    tri = triangulate_rectified(rig3x3, centers)
    assert np.isnan(tri.point_m).all()


def test_triangulation_at_infinity_gives_nan_point(rig3x3):
    centers = np.tile([300.0, 200.0], (9, 1))
    tri = triangulate_rectified(rig3x3, centers)
    assert tri.inverse_depth_per_m == pytest.approx(0.0, abs=1e-15)
    assert max_shift_px(rig3x3, tri.inverse_depth_per_m, tri.used) < 1e-9


def test_max_shift_px_of_a_grid(rig3x3):
    # Two baselines across the grid in x and in y: the diagonal of 2 x 2 baselines.
    w = 0.5
    expected = np.hypot(2 * 0.085 * 600.0, 2 * 0.085 * 600.0) * w
    assert max_shift_px(rig3x3, w, np.ones(9, bool)) == pytest.approx(expected)


@pytest.mark.parametrize(("rows", "cols", "expected"), [
    (3, 3, 20),   # 6 horizontal + 6 vertical + 8 diagonal
    (2, 2, 6),    # 4 sides + 2 diagonals
    (1, 3, 2),
    (1, 2, 1),
])
def test_adjacent_pairs_of_grids(rows, cols, expected):
    rig = CameraRig.grid(rows, cols, baseline_m=0.1, fx=500.0, image_size=(64, 48))
    pairs = adjacent_pairs(rig)
    assert len(pairs) == expected
    centers = rig.centers_m
    for i, j in pairs:
        assert i < j
        assert np.linalg.norm(centers[i] - centers[j]) <= 0.1 * np.sqrt(2) + 1e-12


def test_adjacent_pairs_of_the_paper_array(rig3x3):
    pairs = set(adjacent_pairs(rig3x3))
    assert {(0, 1), (0, 3), (0, 4), (1, 3), (4, 8), (2, 4)} <= pairs
    assert (0, 2) not in pairs and (0, 8) not in pairs and (0, 5) not in pairs


def test_pairwise_marks_missing_and_zero_displacement_as_nan(rig3x3):
    centers = exact_centers(rig3x3, [0.0, 0.0, 2.0])
    centers[1] = np.nan
    centers[3] = centers[4]  # no displacement along the (3, 4) baseline
    points = pairwise_virtual_lights(rig3x3, centers, [(0, 1), (3, 4), (4, 5)])
    assert np.isnan(points[0]).all() and np.isnan(points[1]).all()
    np.testing.assert_allclose(points[2], [0.0, 0.0, 2.0], atol=1e-12)


def test_incidence_angle_matches_the_ray_normal_angle(rig3x3):
    plane = Plane.from_point_normal([0, 0, 1.5], [0.3, -0.2, -1.0], rig3x3.reference_center_m)
    uv = np.array([[100.0, 50.0], [319.5, 239.5], [630.0, 470.0]])
    rays = rig3x3.rays(uv)
    expected = np.degrees(np.arccos(-(rays @ plane.n) / np.linalg.norm(rays, axis=1)))
    np.testing.assert_allclose(incidence_angle_deg(plane, rig3x3, uv), expected, atol=1e-12)
    full = incidence_angle_deg(plane, rig3x3)
    assert full.shape == (480, 640)
    assert full[50, 100] == pytest.approx(expected[0])


def test_incidence_angle_above_90_when_the_plane_is_behind_the_ray(small_stereo_rig):
    # A plane tilted so steeply that rays at one image edge meet it behind the camera.
    plane = Plane.from_point_normal([0, 0, 1.0], [0.99, 0.0, -0.1], (0, 0, 0))
    angles = incidence_angle_deg(plane, small_stereo_rig)
    depth = plane_depth(plane, small_stereo_rig)
    np.testing.assert_array_equal(angles > 90.0, np.isnan(depth))
    assert (angles > 90.0).any() and (angles < 90.0).any()


def test_mirror_is_an_involution_and_lights_give_the_plane():
    plane = Plane.from_point_normal([0.1, 0.2, 1.3], [0.2, 0.1, -1.0])
    light = np.array([0.3, -0.4, 0.1])
    virtual = mirror_point(light, plane)
    np.testing.assert_allclose(plane.mirror(virtual), light, atol=1e-12)
    back = plane_from_lights(light, virtual)
    assert back.angle_to(plane) < 1e-9
    assert back.offset_m == pytest.approx(plane.offset_m)
