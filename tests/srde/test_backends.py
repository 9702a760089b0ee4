"""The numpy backend's brightness search: smoothing read at the candidates only."""

import cv2
import numpy as np
import pytest

from srde_fusion.srde import SRDE
from srde_fusion.srde.backends import (
    REDUCED_SMOOTHING_SIGMA_PX,
    sample_grid,
    smooth_at,
    smooth_samples_at,
)
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
def test_above_it_a_grid_of_pixels_ranks_candidates_like_the_full_blur(sigma):
    lum = _clipped_blob(sigma=1.5 * sigma)
    points = _diagonal()
    u0, v0, u1, v1 = box = (3, 7, 290, 236)  # the search's crop, inside the image
    want = cv2.GaussianBlur(lum[v0:v1, u0:u1], (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    want = want[points[:, 1] - v0, points[:, 0] - u0]
    rows, cols, step = sample_grid(box, sigma)
    assert 3 * step <= sigma < 6 * step
    got = smooth_samples_at(lum[rows, cols], (rows, cols, step), points, sigma)
    spread = float(want.max() - want.min())
    assert np.abs(got - want).max() < 0.01 * spread
    # The brightest candidate moves by at most one sample along the line.
    assert abs(int(np.argmax(got)) - int(np.argmax(want))) <= 1


def test_small_blobs_and_boxes_too_small_for_a_grid_smooth_every_pixel():
    assert sample_grid((0, 0, 300, 200), 0.99 * REDUCED_SMOOTHING_SIGMA_PX) is None
    rows, cols, step = sample_grid((10, 20, 14, 24), REDUCED_SMOOTHING_SIGMA_PX)
    assert step == 2 and len(range(300)[rows]) == len(range(300)[cols]) == 2
    assert sample_grid((10, 20, 13, 40), REDUCED_SMOOTHING_SIGMA_PX) is None


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
