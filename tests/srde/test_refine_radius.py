"""A lamp's radius fitted with the plane (refine.radius), on a face seen in few views."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from srde_fusion.errors import SRDEError
from srde_fusion.geometry import Plane, plane_disparity
from srde_fusion.srde.refine import radius as radius_module
from srde_fusion.srde.refine import refine_plane, refine_plane_and_radius
from srde_fusion.srde.refine.radius import RADIUS_ANGLES_RAD, _parabola_vertex
from srde_fusion.synthetic import default_rig, render
from srde_fusion.synthetic.faceted import faceted_scene
from srde_fusion.synthetic.physics import Physics

#: benchmarks/faceted.py's 3-face ridge whose end face (face 0) shows its light's
#: highlight in four views; the lamp's radius is 6.9 mm.
SEED = 73013


@pytest.fixture(scope="module")
def end_face():
    """The end face alone: its true mask, plane and highlights, a faithful render."""
    rig = default_rig()
    faceted = faceted_scene(SEED, rig, n_faces=3, convex=True)
    rendering = render(faceted.scene, rig, physics=Physics.faithful(), supersample=2)
    on = rendering.highlight_on_object[0, 0]
    return SimpleNamespace(
        views=rendering.views, rig=rig, mask=rendering.instance_mask == 1,
        plane=faceted.scene.objects[0].plane, light=np.array(faceted.scene.lights[0].position_m),
        radius_m=faceted.scene.lights[0].radius_m, truth=rendering.disparity_px,
        centers=np.where(on[:, None], rendering.highlight_uv_by_light[0, 0], np.nan), on=on)


def _epe(case, plane) -> float:
    return float(np.mean(np.abs(plane_disparity(plane, case.rig) - case.truth)[case.mask]))


def test_the_parabola_vertex():
    x = (0.1, 0.25, 0.5)
    y = tuple(2.0 * (v - 0.3) ** 2 + 1.0 for v in x)
    assert _parabola_vertex(x, y) == pytest.approx(0.3)
    assert _parabola_vertex(x, tuple(-v for v in y)) is None  # a maximum
    assert _parabola_vertex(x, tuple(2.0 * (v - 0.7) ** 2 for v in x)) is None  # beyond


def test_the_radius_the_fit_prefers_is_the_lamp_s(end_face):
    case = end_face
    assert np.count_nonzero(case.on) == 4
    point = refine_plane(case.views, case.rig, case.light, case.mask, case.plane,
                         centers_uv=case.centers)
    search = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                     centers_uv=case.centers)
    assert search.refinement.ok, search.refinement.reason
    # From the true plane, as a point light the face tilts (measured 0.23 px); with the
    # radius fitted it stays (0.03 px), and the radius is the lamp's.
    assert _epe(case, point.plane) > 0.15
    assert _epe(case, search.refinement.plane) < 0.05
    assert search.light_radius_m == pytest.approx(case.radius_m, rel=0.15)
    # The grid starts at a point light, whose fit is the one refine_plane makes, and goes
    # up until the cost rises; then the parabolas' vertices. The answer is the cheapest.
    height_m = float(case.plane.signed_distance(case.light))
    grid = [r for r in search.radii_m if any(
        abs(r - height_m * a) < 1e-12 for a in RADIUS_ANGLES_RAD)]
    assert grid == pytest.approx([height_m * a for a in RADIUS_ANGLES_RAD[:len(grid)]])
    assert len(grid) == 3  # 0, 5.2 and 10.3 mm: the third costs more than the second
    costs = dict(zip(search.radii_m, search.costs, strict=True))
    assert costs[grid[-1]] > min(costs[r] for r in grid[:-1])
    assert search.point_cost == point.cost_final
    assert search.refinement.cost_final == min(search.costs)
    assert search.refinement.cost_final < 0.6 * search.point_cost


def test_a_start_with_the_light_behind_it_is_one_refused_fit(end_face):
    case = end_face
    n = np.asarray(case.plane.n)
    behind = Plane(tuple(-n), -case.plane.offset_m)  # the same plane, seen from its back
    search = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, behind,
                                     centers_uv=case.centers)
    assert not search.refinement.ok
    assert search.radii_m == (0.0,) and search.light_radius_m == 0.0
    assert math.isinf(search.point_cost)


def test_a_radius_that_hardly_lowers_the_cost_is_not_taken(end_face):
    case = end_face
    # Here the lamp's radius saves 58 % of the point light's cost: asked for more, the
    # search keeps the point fit and still says which radius was cheapest.
    search = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                     centers_uv=case.centers, min_gain=0.9)
    assert search.light_radius_m == 0.0
    assert search.refinement.cost_final == search.point_cost
    assert search.cheapest_radius_m == pytest.approx(case.radius_m, rel=0.15)
    assert min(search.costs) < 0.6 * search.point_cost


def test_a_radius_can_be_held_to_a_point_fit_that_was_refined(end_face, monkeypatch):
    case = end_face
    refine = radius_module.refine_plane

    def point_refused(*args, light_radius_m=None, **kwargs):
        fit = refine(*args, light_radius_m=light_radius_m, **kwargs)
        return fit if light_radius_m else dataclasses.replace(fit, status="kept_initial",
                                                              reason="refused here")

    monkeypatch.setattr(radius_module, "refine_plane", point_refused)
    # By default a radius that refines where the point light's fit was refused saves all
    # of its cost; held to a refined point fit, the search keeps the refused point fit.
    search = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                     centers_uv=case.centers, min_gain=0.9)
    assert search.refinement.ok and search.light_radius_m > 0.0
    assert math.isinf(search.point_cost) and search.saving == 1.0
    held = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                   centers_uv=case.centers, min_gain=0.9, point_fit_needed=True)
    # Nothing could be taken after a refused point fit: the search ends there.
    assert not held.refinement.ok and held.light_radius_m == 0.0
    assert held.radii_m == (0.0,) and len(search.radii_m) > 1


def test_a_search_whose_first_fits_are_all_refused_ends(end_face, monkeypatch):
    case = end_face
    refine = radius_module.refine_plane
    tried = []

    def refused(*args, light_radius_m=None, **kwargs):
        tried.append(light_radius_m or 0.0)
        fit = refine(*args, light_radius_m=light_radius_m, **kwargs)
        return dataclasses.replace(fit, status="kept_initial", reason="refused here")

    monkeypatch.setattr(radius_module, "refine_plane", refused)
    search = refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                     centers_uv=case.centers)
    # The point light and the grid's first radii, then no larger disc (the slow ones).
    height_m = float(case.plane.signed_distance(case.light))
    expected = [height_m * a for a in RADIUS_ANGLES_RAD[:radius_module.MAX_REFUSED_FITS]]
    assert list(search.radii_m) == pytest.approx(expected)
    assert tried == pytest.approx(expected)
    assert not search.refinement.ok and search.light_radius_m == 0.0
    assert all(math.isinf(c) for c in search.costs)


def test_a_point_fit_demand_that_is_not_a_bool_is_refused(end_face):
    case = end_face
    with pytest.raises(SRDEError, match=r"point_fit_needed: expected True or False, got 1"):
        refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                point_fit_needed=1)


@pytest.mark.parametrize("min_gain", [-0.1, 1.0, float("nan"), "0.1", True])
def test_a_minimum_gain_that_is_not_a_fraction_is_refused(end_face, min_gain):
    case = end_face
    with pytest.raises(SRDEError, match=r"min_gain: expected a fraction in \[0, 1\), got"):
        refine_plane_and_radius(case.views, case.rig, case.light, case.mask, case.plane,
                                min_gain=min_gain)
