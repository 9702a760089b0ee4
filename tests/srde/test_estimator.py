"""SRDE end to end: synthetic highlights with exact geometry, rendered scenes, every
failure status and every input error."""

from __future__ import annotations

import numpy as np
import pytest

from srde_fusion.errors import ImageError, LightError, MaskError, RigError, SRDEError
from srde_fusion.evaluation import evaluate
from srde_fusion.geometry import CameraRig, Plane, plane_disparity
from srde_fusion.imaging import linear_to_srgb
from srde_fusion.srde import SRDE, SRDE_STATUSES, SRDEResult

W, H = 320, 240


@pytest.fixture(scope="module")
def rig():
    """A small 3x3 array (fx 300 px, 85 mm baselines) for fast synthetic scenes."""
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(W, H))


PLANE = Plane.from_point_normal([0.02, 0.01, 0.8], [0.15, -0.1, -1.0])
LIGHT = np.array([0.2, -0.3, 0.05])


def box_mask(u0=70, v0=60, u1=260, v1=200):
    mask = np.zeros((H, W), dtype=bool)
    mask[v0:v1, u0:u1] = True
    return mask


def centers_of(rig, point):
    return np.stack([rig.project(point, j) for j in range(rig.n_cameras)])


def render_highlights(centers, *, sigma=3.0, peak=2.0, background=0.06, gain=None):
    """8-bit sRGB views with a Gaussian highlight (clipped core) at each centre; NaN: none."""
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    views = []
    for j, c in enumerate(centers):
        linear = np.full((H, W), background)
        if np.all(np.isfinite(c)):
            r2 = (uu - c[0]) ** 2 + (vv - c[1]) ** 2
            linear = linear + peak * np.exp(-r2 / (2 * sigma ** 2))
        if gain is not None:
            linear = linear * gain[j]
        views.append(np.round(linear_to_srgb(np.clip(linear, 0, 1)) * 255).astype(np.uint8))
    return views


def masked_epe(result, plane, rig, mask):
    return float(np.mean(np.abs(result.disparity[mask] - plane_disparity(plane, rig)[mask])))


# ---------------------------------------------------------------------------- synthetic scenes
def test_default_mode_recovers_the_plane(rig):
    virtual = PLANE.mirror(LIGHT)
    mask = box_mask()
    result = SRDE(rig, LIGHT).estimate(render_highlights(centers_of(rig, virtual)), mask)
    assert result.ok and result and result.status == "ok" and result.reason == ""
    assert result.method == "default" and result.notes == ()
    assert result.used_views.all() and result.used_views.dtype == bool
    assert result.residual_px < 0.05
    np.testing.assert_allclose(result.highlight_centers, centers_of(rig, virtual), atol=0.05)
    assert np.linalg.norm(result.virtual_light_m - virtual) < 2e-3
    assert result.plane.angle_to(PLANE) < 0.05
    assert result.disparity.dtype == np.float32 and result.disparity.shape == (H, W)
    assert np.isnan(result.disparity[~mask]).all() and np.isfinite(result.disparity[mask]).all()
    assert masked_epe(result, PLANE, rig, mask) < 0.02
    assert len(result.detections) == 9 and all(result.detections)


def test_paper_and_default_agree_on_an_easy_scene(rig):
    # Sigma 4 px gives a gradient ring wide enough for the paper's 10 x 10 px rule.
    views = render_highlights(centers_of(rig, PLANE.mirror(LIGHT)), sigma=4.0)
    mask = box_mask()
    # These Gaussian blobs sit exactly on the projected virtual light, with no irradiance
    # falloff: there is no centroid bias to remove, and a physical lobe fit would chase
    # one. Compare the two geometric pipelines.
    default = SRDE(rig, LIGHT, refine=False).estimate(views, mask)
    paper = SRDE(rig, LIGHT, method="paper").estimate(views, mask)
    assert default.ok and paper.ok and paper.method == "paper"
    assert masked_epe(default, PLANE, rig, mask) < 0.01
    assert masked_epe(paper, PLANE, rig, mask) < 0.3
    assert np.nanmax(np.abs(paper.disparity - default.disparity)) < 0.5
    # The joint solve is the more accurate one.
    assert masked_epe(default, PLANE, rig, mask) < masked_epe(paper, PLANE, rig, mask)


def test_default_mode_drops_and_names_an_outlier_view(rig):
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    centers[2, 1] += 3.0
    result = SRDE(rig, LIGHT).estimate(render_highlights(centers), box_mask())
    assert result.ok
    assert result.used_views.tolist() == [True, True, False] + [True] * 6
    assert len(result.notes) == 1
    assert result.notes[0].startswith("view 2 (cam2): dropped as an outlier, 3.0")
    assert masked_epe(result, PLANE, rig, box_mask()) < 0.02


def test_views_without_a_highlight_are_left_out_and_noted(rig):
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    centers[[0, 8]] = np.nan
    result = SRDE(rig, LIGHT).estimate(render_highlights(centers), box_mask())
    assert result.ok
    assert not result.used_views[[0, 8]].any() and result.used_views.sum() == 7
    assert np.isnan(result.highlight_centers[[0, 8]]).all()
    assert [n.split(":")[0] for n in result.notes] == ["view 0 (cam0)", "view 8 (cam8)"]
    assert masked_epe(result, PLANE, rig, box_mask()) < 0.02


def test_a_stereo_pair_is_enough():
    stereo = CameraRig.stereo(0.12, fx=300.0, image_size=(W, H))
    views = render_highlights(centers_of(stereo, PLANE.mirror(LIGHT)))
    result = SRDE(stereo, LIGHT).estimate(views, box_mask())
    assert result.ok and result.used_views.tolist() == [True, True]
    assert masked_epe(result, PLANE, stereo, box_mask()) < 0.05
    paper = SRDE(stereo, LIGHT, method="paper", detector="blob").estimate(views, box_mask())
    assert paper.ok and masked_epe(paper, PLANE, stereo, box_mask()) < 0.05


def test_white_references_undo_per_camera_gain(rig):
    gain = np.linspace(0.5, 1.0, 9)
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    # No clipping: each camera's gain scales its whole highlight.
    views = render_highlights(centers, peak=0.8, gain=gain)
    whites = [np.full((H, W), round(255 * float(linear_to_srgb(0.9 * g))), np.uint8)
              for g in gain]
    result = SRDE(rig, LIGHT, white_references=whites).estimate(views, box_mask())
    assert result.ok and result.used_views.all()
    assert masked_epe(result, PLANE, rig, box_mask()) < 0.02


def test_region_replaces_the_eroded_mask(rig):
    views = render_highlights(centers_of(rig, PLANE.mirror(LIGHT)))
    region = np.zeros((H, W), dtype=bool)
    region[:, :100] = True  # the highlight is at u ~ 153: not in this region
    result = SRDE(rig, LIGHT).estimate(views, box_mask(), region=region)
    assert result.status == "no_highlight"


# ---------------------------------------------------------------------------- failure statuses
def status_of(rig, light, centers, mask=None, **options):
    result = SRDE(rig, light, **options).estimate(render_highlights(centers),
                                                  box_mask() if mask is None else mask)
    assert isinstance(result, SRDEResult) and not result and not result.ok
    assert result.status in SRDE_STATUSES
    assert np.isnan(result.disparity).all() and result.disparity.shape == (H, W)
    return result


def test_no_highlight_in_the_reference_view(rig):
    result = status_of(rig, LIGHT, np.full((9, 2), np.nan))
    assert result.status == "no_highlight"
    assert result.reason.startswith("view 4 (cam4, reference): no bright blob")
    assert result.plane is None and result.virtual_light_m is None


def test_no_highlight_in_too_many_views(rig):
    centers = np.full((9, 2), np.nan)
    centers[4] = centers_of(rig, PLANE.mirror(LIGHT))[4]
    result = status_of(rig, LIGHT, centers)
    assert result.status == "no_highlight"
    assert result.reason.startswith("only 1 of 9 views show a highlight (min_views 2); "
                                    "view 0 (cam0): no bright blob")


def test_other_views_are_searched_only_over_the_object_depth_range(rig):
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    u, v = np.rint(centers[4]).astype(int)
    mask = box_mask(u - 20, v - 20, u + 21, v + 21)
    # An object this near would move ~100 px between views: off this small mask.
    result = status_of(rig, LIGHT, centers, mask=mask, object_depth_m=(0.2, 0.25))
    assert result.status == "no_highlight"
    assert ("view 0 (cam0): no position along the baseline (object depth 0.2-0.25 m) lies on "
            "the object") in result.reason
    assert SRDE(rig, LIGHT).estimate(render_highlights(centers), mask).ok


def test_inconsistent_centres():
    stereo = CameraRig.stereo(0.1, fx=300.0, image_size=(W, H))
    centers = centers_of(stereo, PLANE.mirror(LIGHT))
    centers[1, 1] += 4.0  # rectified views must agree in v
    result = status_of(stereo, LIGHT, centers)
    assert result.status == "inconsistent"
    assert result.reason == ("triangulation: no two views agree on one virtual light within 1 px; "
                             "residuals of a joint fit per view (px) {0: 2.00, 1: 2.00}")


def test_too_few_agreeing_views(rig):
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    centers[2, 1] += 3.0
    result = status_of(rig, LIGHT, centers, min_views=9)
    assert result.status == "too_few_views"
    assert result.reason.startswith("triangulation: only 8 views agree (min_views 9); view 2")


def test_paper_mode_needs_a_pair_of_neighbours():
    row = CameraRig.grid(1, 4, baseline_m=0.085, fx=300.0, image_size=(W, H))
    centers = centers_of(row, PLANE.mirror(LIGHT))
    centers[[0, 2]] = np.nan  # views 1 and 3 remain: not neighbours
    result = status_of(row, LIGHT, centers, method="paper", detector="blob")
    assert result.status == "too_few_views"
    assert result.reason.startswith("pairs: no pair of neighbouring cameras has a highlight")
    # The joint solve is happy with any two views.
    default = SRDE(row, LIGHT).estimate(render_highlights(centers), box_mask())
    assert default.ok and default.used_views.tolist() == [False, True, False, True]


def test_virtual_light_at_infinity(rig):
    centers = np.tile(centers_of(rig, PLANE.mirror(LIGHT))[4], (9, 1))
    result = status_of(rig, LIGHT, centers)
    assert result.status == "at_infinity"
    assert result.reason.startswith("virtual light: its image moves only 0.0")


def test_virtual_light_behind_the_cameras(rig):
    centers = centers_of(rig, PLANE.mirror(LIGHT))
    centers = centers[4] + 0.3 * (centers[4] - centers)  # shifts the wrong way
    result = status_of(rig, LIGHT, centers)
    assert result.status == "behind_cameras"
    assert "behind the cameras" in result.reason and "z = -" in result.reason


def test_light_on_the_plane(rig):
    light = np.array([0.0, 0.0, 0.8])
    light = light - PLANE.signed_distance(light) * PLANE.n
    result = status_of(rig, light, centers_of(rig, light))
    assert result.status == "light_on_plane"
    assert "the light lies (nearly) on the plane" in result.reason


def test_light_behind_the_plane(rig):
    light = np.array([0.05, -0.05, 1.0])
    assert PLANE.signed_distance(light) < 0
    result = status_of(rig, light, centers_of(rig, PLANE.mirror(light)))
    assert result.status == "light_behind_plane"
    assert result.reason.startswith("plane: the light is 0.17")


def test_cameras_behind_the_plane(rig):
    # A steep plane through the array: the right column of cameras is behind it.
    plane = Plane.from_point_normal([0.06, 0.0, 0.0], [-1.0, 0.0, -0.15], (0, 0, 0))
    light = np.array([-0.1, 0.0, 0.3])
    result = status_of(rig, light, centers_of(rig, plane.mirror(light)),
                       mask=np.ones((H, W), bool), object_depth_m=(0.01, 10.0))
    assert result.status == "inconsistent"
    assert "view 5 (cam5) on its far side" in result.reason


def test_grazing_plane(rig):
    result = status_of(rig, LIGHT, centers_of(rig, PLANE.mirror(LIGHT)), max_incidence_deg=5.0)
    assert result.status == "grazing"
    assert "mask pixels see it at more than 5 deg incidence" in result.reason
    assert result.plane is not None and result.plane.angle_to(PLANE) < 0.1


def test_mask_too_small_to_erode(rig):
    mask = np.zeros((H, W), dtype=bool)
    mask[100:104, 100:104] = True
    result = status_of(rig, LIGHT, centers_of(rig, PLANE.mirror(LIGHT)), mask=mask)
    assert result.status == "mask_too_small"
    assert result.reason == "mask: nothing left to search after eroding the 16-px mask by 3 px"


# ---------------------------------------------------------------------------- input errors
@pytest.mark.parametrize(("make", "error", "match"), [
    (lambda v, m: (v[:8], m), ImageError, "expected 9 images"),
    (lambda v, m: ([x[:-1] for x in v], m), ImageError,
     "views: expected images of the rig's size 320x240, got 320x239"),
    (lambda v, m: ([v[0][:, :-2]] + v[1:], m), ImageError, r"views\[1\]: expected the same size"),
    (lambda v, m: ([x.astype(np.int32) for x in v], m), ImageError, "dtype uint8 or float"),
    (lambda v, m: (v, np.zeros_like(m)), MaskError, "empty mask"),
    (lambda v, m: (v, m[:-1]), MaskError, r"mask: expected shape \(240, 320\)"),
    (lambda v, m: (v, m.tolist()), MaskError, "mask: expected a numpy array"),
])
def test_estimate_input_errors(rig, make, error, match):
    views = render_highlights(np.full((9, 2), np.nan))
    views, mask = make(views, box_mask())
    with pytest.raises(error, match=match):
        SRDE(rig, LIGHT).estimate(views, mask)


def test_empty_region_is_an_error(rig):
    views = render_highlights(np.full((9, 2), np.nan))
    with pytest.raises(MaskError, match="region: expected at least one pixel"):
        SRDE(rig, LIGHT).estimate(views, box_mask(), region=np.zeros((H, W), bool))


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"light": None}, LightError, "expected a light position .* got neither"),
    ({"light": [0.1, 0.2]}, LightError, "light: expected 3 finite numbers"),
    ({"light": "up"}, LightError, "light: expected 3"),
    ({"method": "fast"}, SRDEError, r"method: expected one of \['default', 'paper'\]"),
    ({"detector": "ring"}, SRDEError, "method: expected one of"),
    ({"window": 4}, SRDEError, "window: expected an odd integer"),
    ({"mask_erosion_px": -1}, SRDEError, "mask_erosion_px: expected an integer >= 0"),
    ({"max_residual_px": 0.0}, SRDEError, r"max_residual_px: expected a number in \(0"),
    ({"min_residual_px": 2.0}, SRDEError, r"min_residual_px: expected a number in \(0, 1\]"),
    ({"min_views": 1}, SRDEError, r"min_views: expected an integer in \[2, 9\]"),
    ({"min_views": 10}, SRDEError, r"min_views: expected an integer in \[2, 9\]"),
    ({"object_depth_m": (1.0, 0.5)}, SRDEError, "object_depth_m: expected 0 < near < far"),
    ({"object_depth_m": 3.0}, SRDEError, r"object_depth_m: expected \(near, far\)"),
    ({"max_incidence_deg": 95.0}, SRDEError, r"max_incidence_deg: expected a number in \(0, 90\]"),
    ({"white_references": [np.ones((H, W), np.uint8)] * 8}, ImageError, "expected 9 images"),
])
def test_constructor_input_errors(rig, kwargs, error, match):
    args = {"light": LIGHT}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        SRDE(rig, **args)


def test_rig_must_be_a_camera_rig():
    with pytest.raises(RigError, match="rig: expected a CameraRig, got dict"):
        SRDE({"fx": 300.0}, LIGHT)


def test_light_comes_from_the_rig(rig):
    srde = SRDE(rig.with_light(LIGHT))
    np.testing.assert_array_equal(srde.light_m, LIGHT)


# ---------------------------------------------------------------------------- rendered scenes
scenes = pytest.importorskip("srde_fusion.synthetic")

#: Masked EPE bounds on rendered sharp-lobe scenes (the paper reports 0.029 px mean).
SHARP_EPE_MEAN_PX = 0.015
SHARP_EPE_MAX_PX = 0.03


@pytest.fixture(scope="module")
def paper_rig():
    return scenes.default_rig()


def rendered(rig, seed, **options):
    scene = scenes.random_scene(seed, rig, **options)
    return scene, scenes.render(scene, rig)


def test_rendered_sharp_lobes_default_mode(paper_rig):
    epes = []
    for seed in range(4):
        scene, out = rendered(paper_rig, seed, roughness=(0.003, 0.008),
                              light_radius_m=(0.002, 0.005))
        mask = out.object_masks[0]
        result = SRDE(paper_rig.with_light(scene.light.position_m)).estimate(out.views, mask)
        assert result.ok, result.reason
        metrics = evaluate(result.disparity, out.disparity_px, mask)
        assert metrics["bmp0.1"] <= 0.02
        epes.append(metrics["epe"])
        virtual = out.virtual_lights_m[0]
        assert np.linalg.norm(result.virtual_light_m - virtual) < 1e-3 * np.linalg.norm(virtual)
        np.testing.assert_allclose(result.highlight_centers, out.highlight_uv[0], atol=0.1)
    assert max(epes) < SHARP_EPE_MAX_PX
    assert np.mean(epes) < SHARP_EPE_MEAN_PX


def test_rendered_paper_and_default_agree(paper_rig):
    # Moderate lobes: wide enough for the paper's ring detector, sharp enough for centroids.
    for seed in (2, 4):
        scene, out = rendered(paper_rig, seed, roughness=(0.01, 0.015),
                              light_radius_m=(0.005, 0.01))
        mask = out.object_masks[0]
        rig = paper_rig.with_light(scene.light.position_m)
        default = SRDE(rig).estimate(out.views, mask)
        paper = SRDE(rig, method="paper").estimate(out.views, mask)
        assert default.ok and paper.ok, (default.reason, paper.reason)
        assert np.nanmax(np.abs(paper.disparity - default.disparity)) < 0.5
        assert (evaluate(default.disparity, out.disparity_px, mask)["epe"]
                < evaluate(paper.disparity, out.disparity_px, mask)["epe"])


def test_rendered_stereo_pair(paper_rig):
    stereo = CameraRig.stereo(0.12, fx=600.0, image_size=(640, 480))
    scene, out = rendered(stereo, 0, roughness=(0.003, 0.008), light_radius_m=(0.002, 0.005))
    mask = out.object_masks[0]
    result = SRDE(stereo.with_light(scene.light.position_m)).estimate(out.views, mask)
    assert result.ok
    assert evaluate(result.disparity, out.disparity_px, mask)["epe"] < 0.1


@pytest.mark.parametrize(("lobe", "seed"), [("ggx", 2), ("blinn_phong", 1)])
def test_rendered_rough_lobe_is_refined(paper_rig, lobe, seed):
    # Rough lobes bias the blob centroid in depth; the default method's photometric
    # refinement removes it, whichever lobe the scene was rendered with.
    scene, out = rendered(paper_rig, seed, roughness=0.065, lobe=lobe)
    mask = out.object_masks[0]
    rig = paper_rig.with_light(scene.light.position_m)
    refined = SRDE(rig).estimate(out.views, mask)
    geometric = SRDE(rig, refine=False).estimate(out.views, mask)
    assert refined.ok and geometric.ok, (refined.reason, geometric.reason)
    assert geometric.refinement is None and refined.refinement is not None
    assert refined.refinement.ok, refined.refinement.reason
    epe_refined = evaluate(refined.disparity, out.disparity_px, mask)["epe"]
    epe_geometric = evaluate(geometric.disparity, out.disparity_px, mask)["epe"]
    assert epe_refined < 0.01
    assert epe_refined < epe_geometric / 3
