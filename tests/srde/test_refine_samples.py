"""Tests for the plane-induced maps that place the refinement's samples (refine.samples)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.geometry import CameraRig, Plane
from srde_fusion.srde.refine.samples import references_from_views, warp_change_px


@pytest.fixture(scope="module")
def rig() -> CameraRig:
    """The paper's 3x3 array at half resolution (same field of view)."""
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(320, 240))


@given(tilt_x=st.floats(-0.5, 0.5), tilt_y=st.floats(-0.5, 0.5), depth=st.floats(0.4, 3.0),
       camera=st.integers(0, 8), u=st.floats(0, 319), v=st.floats(0, 239))
def test_plane_induced_map_agrees_with_ray_casting(rig, tilt_x, tilt_y, depth, camera, u, v):
    plane = Plane.from_point_normal([0.0, 0.0, depth], [tilt_x, tilt_y, -1.0])
    ray = rig.rays(np.array([u, v]))
    center = rig.centers_m[camera]
    point = center + ray * (plane.offset_m - plane.n @ center) / (plane.n @ ray)
    expected = rig.project(point)
    to_ref = references_from_views(rig, plane)[camera]
    assert to_ref @ [u, v, 1.0] == pytest.approx(expected, abs=1e-6)


def test_warp_change_is_the_largest_corner_move_by_ray_casting(rig):
    before = Plane.from_point_normal([0.0, 0.0, 1.0], [0.1, -0.2, -1.0])
    after = Plane.from_point_normal([0.0, 0.0, 1.1], [0.15, -0.2, -1.0])
    box = (40, 30, 100, 80)  # x, y, width, height
    corners = np.array([[40.0, 30.0], [139.0, 30.0], [40.0, 109.0], [139.0, 109.0]])
    rays = rig.rays(corners)
    ref = rig.reference_center_m

    def seen(plane, camera):
        points = ref + rays * ((plane.offset_m - plane.n @ ref) / (rays @ plane.n))[:, None]
        return rig.project(points, camera)

    expected = max(np.max(np.abs(seen(after, j) - seen(before, j))) for j in range(9))
    assert expected > 1.0
    assert warp_change_px(rig, before, after, box) == pytest.approx(expected, rel=1e-9)
