"""Tests for the plane-induced maps that place the refinement's samples (refine.samples)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.errors import SRDEError
from srde_fusion.geometry import CameraRig, Plane
from srde_fusion.srde import SRDE
from srde_fusion.srde.refine.model import DEFAULT_F0, SUPPORT_POINTS, LobeModel
from srde_fusion.srde.refine.samples import (
    MASK_MARGIN_PX,
    mask_bbox,
    references_from_views,
    sample_windows,
    warp_change_px,
)
from srde_fusion.synthetic import random_scene, render


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


def test_a_pair_is_read_pixel_by_pixel_as_far_from_the_outline_as_blocks():
    # Two views: every pixel is a sample (block means would turn the pixels beside the
    # clipped core into lower bounds), over the same eroded outline the blocks keep.
    pair = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240))
    scene = random_scene(2, pair, roughness=0.05, light_radius_m=0.0)
    out = render(scene, pair)
    lit = pair.with_light(scene.light.position_m)
    mask = out.instance_mask == 1
    est = SRDE(lit, refine=False).estimate(out.views, mask)
    assert est.ok, est.reason
    centers = est.highlight_centers

    def cut(**options):
        return sample_windows(out.views, lit, mask, est.plane, centers, **options)

    pixels, settled, blocks = cut(), cut(settled=True), cut(pixel_samples=False)
    assert pixels.block_px == 1 < blocks.block_px
    assert pixels.half_window_px == blocks.half_window_px
    assert pixels.view_indices == blocks.view_indices == (0, 1)
    assert pixels.n_samples > 3 * blocks.n_samples
    # the reference view's pixel samples lie where a block centred on them would fit
    k = lit.intrinsics
    reference = np.all(pixels.camera_m == lit.centers_m[lit.reference], axis=1)
    u = np.rint(pixels.ray[reference, 0] * k.fx + k.cx).astype(int)
    v = np.rint(pixels.ray[reference, 1] * k.fy + k.cy).astype(int)
    side = 2 * (MASK_MARGIN_PX + blocks.block_px // 2) + 1
    kept = cv2.erode(mask.astype(np.uint8), np.ones((side, side), np.uint8)) > 0
    assert reference.any() and kept[v, u].all()
    # placed for a fitted plane, they come as near the outline as a block's pixels do
    assert pixels.may_come_nearer and not settled.may_come_nearer
    assert settled.outline_px == MASK_MARGIN_PX < pixels.outline_px
    assert settled.n_samples > pixels.n_samples
    # the model meets a block's mean averaged over the block, a pixel at its centre
    light = np.asarray(lit.light)

    def support(samples):
        return LobeModel(samples, lit, mask_bbox(mask), light, est.plane, "gtr", DEFAULT_F0,
                         None).n_support

    assert support(pixels) == 1 < support(blocks) == SUPPORT_POINTS ** 2
    # Block means one pixel wide (a small window on a larger array) are block means: the
    # model is averaged over the pixel as over any block.
    assert pixels.every_pixel and not blocks.every_pixel
    assert support(replace(pixels, every_pixel=False)) == SUPPORT_POINTS ** 2


@pytest.mark.parametrize("value", [1, "yes", 0.0])
def test_the_pixel_option_takes_a_bool_or_none(value):
    pair = CameraRig.stereo(0.085, fx=300.0, image_size=(320, 240),
                            light_position_m=(0.1, -0.3, 0.0))
    with pytest.raises(SRDEError, match="refine_pixels: expected True, False or None"):
        SRDE(pair, refine_pixels=value)
