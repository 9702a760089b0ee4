"""The numpy backend's brightness search: smoothing read at the candidates only."""

import cv2
import numpy as np
import pytest

from srde_fusion.srde import SRDE
from srde_fusion.srde.backends import REDUCED_SMOOTHING_SIGMA_PX, smooth_at
from srde_fusion.synthetic import RandomSceneConfig, default_rig, random_scene, render


def _clipped_blob(size=(240, 300), center=(150.0, 120.0), sigma=40.0, peak=3.0, seed=0):
    yy, xx = np.mgrid[:size[0], :size[1]]
    blob = peak * np.exp(-((xx - center[0]) ** 2 + (yy - center[1]) ** 2) / (2 * sigma**2))
    noise = 0.02 * np.random.default_rng(seed).random(size)
    return (np.minimum(blob, 1.0) + noise).astype(np.float32)


def _diagonal(n=120, start=(10, 50), step=(2, 1)):
    t = np.arange(n)
    return np.stack([start[0] + step[0] * t, start[1] + step[1] * t], axis=1)


def test_below_the_reduced_scale_it_is_opencvs_blur():
    lum = _clipped_blob(sigma=6.0)
    points = _diagonal()
    sigma = REDUCED_SMOOTHING_SIGMA_PX * 0.9
    want = cv2.GaussianBlur(lum, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    np.testing.assert_array_equal(smooth_at(lum, points, sigma), want[points[:, 1], points[:, 0]])


@pytest.mark.parametrize("sigma", [REDUCED_SMOOTHING_SIGMA_PX, 13.0, 40.0])
def test_above_it_the_reduced_image_ranks_candidates_like_the_full_blur(sigma):
    lum = _clipped_blob(sigma=1.5 * sigma)
    points = _diagonal()
    want = cv2.GaussianBlur(lum, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    want = want[points[:, 1], points[:, 0]]
    got = smooth_at(lum, points, sigma)
    spread = float(want.max() - want.min())
    assert np.abs(got - want).max() < 0.01 * spread
    # The brightest candidate moves by at most one sample along the line.
    assert abs(int(np.argmax(got)) - int(np.argmax(want))) <= 1


def test_large_clipped_highlights_are_found_by_both_backends_alike():
    pytest.importorskip("torch")
    rig = default_rig()
    config = RandomSceneConfig(roughness=(0.05, 0.08), clip_ratio=(4.0, 8.0),
                               light_radius_m=0.015)
    scene = random_scene(9000, rig, config=config)
    out = render(scene, rig)
    lit = rig.with_light(scene.light.position_m)
    mask = out.object_masks[0]
    a = SRDE(lit, refine=False).estimate(out.views, mask)
    b = SRDE(lit, refine=False, backend="torch").estimate(out.views, mask)
    assert a.ok and b.ok
    # The blob is large: the search smooths on a reduced image in both backends.
    u0, v0, u1, v1 = a.detections[rig.reference].bbox
    assert 0.25 * np.hypot(u1 - u0, v1 - v0) >= REDUCED_SMOOTHING_SIGMA_PX
    np.testing.assert_allclose(b.highlight_centers, a.highlight_centers, atol=1e-3)


def test_a_clipped_highlight_over_most_of_the_region_is_found_at_its_centre():
    # A rough coating under a bright light: the blob is clipped over 70 % of the object,
    # so the region's median is the clipping level; its low quantile is the background.
    from srde_fusion.srde import detect_highlight

    yy, xx = np.mgrid[:120, :160]
    image = np.minimum(4.0 * np.exp(-((xx - 84.0) ** 2 + (yy - 58.0) ** 2) / (2 * 30.0**2)), 1.0)
    region = (np.abs(xx - 80) < 60) & (np.abs(yy - 60) < 45)
    image = np.where(region, image, 0.05)
    assert np.median(image[region]) == 1.0
    det = detect_highlight(image.astype(np.float32), region, encoding="linear")
    assert det.found, det.reason
    np.testing.assert_allclose(det.center_uv, [84.0, 58.0], atol=1.5)
    # A region that is clipped everywhere still has no highlight, with its reason.
    flat = detect_highlight(np.ones((120, 160), np.float32), region, encoding="linear")
    assert not flat.found and "no bright blob" in flat.reason
