"""Highlight detection on synthetic blobs and discs with known sub-pixel centres."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from srde_fusion.errors import ImageError, MaskError, SRDEError
from srde_fusion.imaging import linear_to_srgb, luminance
from srde_fusion.srde import BLOB_CENTERS, HighlightDetection, detect_highlight

H, W = 96, 128
SUPERSAMPLE = 8


def supersampled(profile, center, shape=(H, W)):
    """Mean of ``profile(r2)`` over SUPERSAMPLE^2 points per pixel (pixel centres at integers)."""
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    vv, uu = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    acc = np.zeros(shape)
    for dv in offsets:
        for du in offsets:
            acc += profile((uu + du - center[0]) ** 2 + (vv + dv - center[1]) ** 2)
    return acc / SUPERSAMPLE ** 2


def gaussian_blob(center, sigma=3.0, peak=0.8, background=0.1):
    """A linear-intensity image: Gaussian blob on a flat background (unclipped if peak<0.9)."""
    return background + peak * supersampled(lambda r2: np.exp(-r2 / (2 * sigma ** 2)), center)


def to_srgb8(linear):
    return np.round(linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255).astype(np.uint8)


def random_centers(n, seed):
    rng = np.random.default_rng(seed)
    return np.array([W / 2, H / 2]) + rng.uniform(-10, 10, size=(n, 2))


# ---------------------------------------------------------------------------- blob detector
@pytest.mark.parametrize("blob_center", BLOB_CENTERS)
def test_blob_centre_of_an_unclipped_gaussian_in_linear_float(blob_center):
    for center in random_centers(5, seed=1):
        image = gaussian_blob(center).astype(np.float32)
        det = detect_highlight(image, encoding="linear", blob_center=blob_center)
        assert det.found and det.reason == ""
        # The lobe fit's model is exact here; a centroid of the light above a level
        # carries a pixel-phase error of a few hundredths of a pixel.
        tol = 2e-3 if blob_center == "lobe" else 0.03
        np.testing.assert_allclose(det.center_uv, center, atol=tol)


def test_blob_centre_of_a_clipped_srgb_highlight():
    for center in random_centers(5, seed=2):
        image = to_srgb8(gaussian_blob(center, sigma=4.0, peak=2.5, background=0.05))
        assert (image == 255).sum() > 20  # the core is clipped
        det = detect_highlight(image)
        np.testing.assert_allclose(det.center_uv, center, atol=0.03)
        assert det.bbox[0] <= center[0] < det.bbox[2] and det.bbox[1] <= center[1] < det.bbox[3]
        assert det.area_px == pytest.approx(np.pi * (4.0 * np.sqrt(2 * np.log(2 * 2.5))) ** 2,
                                            rel=0.2)


def test_blob_lobe_fit_skips_clipped_pixels():
    center = np.array([60.3, 45.8])
    image = to_srgb8(gaussian_blob(center, sigma=4.0, peak=3.0, background=0.05))
    det = detect_highlight(image, blob_center="lobe")
    np.testing.assert_allclose(det.center_uv, center, atol=0.05)


def test_blob_with_noise_stays_sub_pixel():
    rng = np.random.default_rng(3)
    center = np.array([70.4, 41.7])
    linear = gaussian_blob(center, sigma=3.0, peak=2.0, background=0.05)
    linear += rng.normal(0.0, 0.004, linear.shape)
    det = detect_highlight(to_srgb8(linear))
    np.testing.assert_allclose(det.center_uv, center, atol=0.05)


def test_blob_is_searched_only_inside_the_region():
    left, right = np.array([30.2, 40.6]), np.array([95.7, 50.1])
    linear = gaussian_blob(left, peak=0.9) + gaussian_blob(right, peak=0.6) - 0.1
    region = np.zeros((H, W), dtype=bool)
    region[:, 64:] = True
    det = detect_highlight(linear.astype(np.float32), region, encoding="linear")
    np.testing.assert_allclose(det.center_uv, right, atol=0.05)
    whole = detect_highlight(linear.astype(np.float32), encoding="linear")
    np.testing.assert_allclose(whole.center_uv, left, atol=0.05)


def test_blob_level_given_explicitly():
    center = np.array([64.2, 47.9])
    image = gaussian_blob(center).astype(np.float32)
    auto = detect_highlight(image, encoding="linear")
    same = detect_highlight(image, encoding="linear", level=auto.level)
    np.testing.assert_array_equal(same.center_uv, auto.center_uv)
    assert auto.level == pytest.approx(0.1 + 0.5 * (auto.score), rel=0.05)
    high = detect_highlight(image, encoding="linear", level=0.8)
    assert high.area_px < auto.area_px
    above = detect_highlight(image, encoding="linear", level=0.95)
    assert not above and "no pixel above the level 0.9500" in above.reason


def test_blank_image_has_no_highlight():
    det = detect_highlight(np.full((H, W, 3), 90, np.uint8))
    assert not det and det.center_uv is None and det.bbox is None and det.area_px == 0
    assert det.reason.startswith("no bright blob: peak")
    assert "min_contrast 0.05" in det.reason


def test_tiny_blob_is_rejected_by_min_area():
    image = np.full((H, W), 0.1, np.float32)
    image[40, 50] = 0.9
    det = detect_highlight(image, encoding="linear", min_contrast=0.01, min_area_px=3)
    assert not det and "fewer than min_area_px 3" in det.reason


def test_empty_region_is_a_failed_detection():
    det = detect_highlight(np.zeros((H, W), np.uint8), np.zeros((H, W), bool))
    assert not det and det.reason == "search region is empty"


def test_white_reference_removes_vignetting_bias():
    center = np.array([60.4, 50.3])
    vv, uu = np.mgrid[0:H, 0:W]
    # A steep gain ramp across the image, as strong vignetting or uneven gain would give.
    gain = 0.4 + 0.6 * uu / W
    scene = gaussian_blob(center, sigma=5.0, peak=0.8, background=0.1)
    image = (scene * gain).astype(np.float32)
    white = (0.9 * gain).astype(np.float32)
    raw = detect_highlight(image, encoding="linear")
    flat = detect_highlight(image, encoding="linear", white_reference=white)
    assert raw.center_uv[0] - center[0] > 0.15  # the ramp pulls the centroid right
    np.testing.assert_allclose(flat.center_uv, center, atol=0.05)


# ---------------------------------------------------------------------------- paper detector
def sharp_disc(center, radius, inside=0.9, outside=0.1):
    """A bright disc with a sharp edge (anti-aliased by supersampling), linear float."""
    return outside + (inside - outside) * supersampled(lambda r2: (r2 <= radius ** 2) * 1.0,
                                                       center)


def test_paper_ring_centroid_of_a_sharp_disc():
    for center in random_centers(4, seed=5):
        image = to_srgb8(sharp_disc(center, radius=9.0))
        det = detect_highlight(image, method="paper")
        assert det.found
        # The rule keeps only the strongest ring pixels, an uneven subset of the ring:
        # its centroid is off by up to half a pixel (the paper's weak point).
        np.testing.assert_allclose(det.center_uv, center, atol=0.6)
        u0, v0, u1, v1 = det.bbox
        assert 18 <= u1 - u0 <= 22 and 18 <= v1 - v0 <= 22  # the ring around the disc
        assert det.score > 1.0
        assert np.isnan(det.level)


def test_paper_drops_components_below_the_minimum_extent():
    image = to_srgb8(sharp_disc((64.0, 48.0), radius=3.0))
    det = detect_highlight(image, method="paper")
    assert not det
    assert "no gradient component with extent >= 10x10 px" in det.reason
    small = detect_highlight(image, method="paper", min_extent_px=5)
    np.testing.assert_allclose(small.center_uv, (64.0, 48.0), atol=0.1)


def test_paper_finds_nothing_on_a_flat_image():
    det = detect_highlight(np.full((H, W), 100, np.uint8), method="paper")
    assert not det and det.reason.startswith("no pixel with gradient above mu + 1.5 sigma")


def test_paper_on_a_region_matches_the_full_image_computation():
    """Cropping to the region (plus margin) must not change what the paper's rule selects."""
    center = np.array([70.3, 44.6])
    image = to_srgb8(sharp_disc(center, radius=8.0) + 0.05 * np.sin(np.arange(W) / 3.0))
    region = np.zeros((H, W), dtype=bool)
    region[25:70, 45:100] = True
    det = detect_highlight(image, region, method="paper")
    lum = luminance(image)
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(lum, cv2.CV_32F, 0, 1, ksize=3)
    grad = np.sqrt(gx * gx + gy * gy)
    mean = cv2.boxFilter(grad, cv2.CV_32F, (15, 15))
    std = np.sqrt(np.maximum(cv2.boxFilter(grad * grad, cv2.CV_32F, (15, 15)) - mean ** 2, 0))
    mask = (grad > mean + 1.5 * std) & region
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    ok = [i for i in range(1, n) if stats[i, 2] >= 10 and stats[i, 3] >= 10]
    best = max(ok, key=lambda i: stats[i, 4])
    vv, uu = np.nonzero(labels == best)
    np.testing.assert_allclose(det.center_uv, [uu.mean(), vv.mean()], atol=1e-9)
    assert det.area_px == stats[best, 4]


# ---------------------------------------------------------------------------- result and errors
def test_detection_truthiness():
    assert not HighlightDetection.missing("why")
    assert HighlightDetection(True, np.zeros(2), 1, (0, 0, 1, 1), 1.0, "")


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"image": np.zeros((H, W), np.int16)}, ImageError, "dtype uint8 or float"),
    ({"image": np.zeros((H, W, 4), np.uint8)}, ImageError, r"shape \(H, W\) or \(H, W, 3\)"),
    ({"image": [[0, 1], [1, 0]]}, ImageError, "expected a numpy array"),
    ({"region": np.ones((H, W + 1), bool)}, MaskError, r"region: expected shape \(96, 128\)"),
    ({"region": np.ones((H, W), object)}, MaskError, "bool or integer mask"),
    ({"method": "ring"}, SRDEError, r"method: expected one of \['blob', 'paper'\]"),
    ({"encoding": "gamma"}, SRDEError, "encoding: expected one of"),
    ({"blob_center": "peak"}, SRDEError, "blob_center: expected one of"),
    ({"window": 14}, SRDEError, "window: expected an odd integer >= 3"),
    ({"window": 1}, SRDEError, "window: expected an odd integer >= 3"),
    ({"k": float("nan")}, SRDEError, "k: expected a finite number"),
    ({"min_extent_px": 0}, SRDEError, "min_extent_px: expected a positive integer"),
    ({"min_area_px": 2.5}, SRDEError, "min_area_px: expected a positive integer"),
    ({"min_contrast": 1.5}, SRDEError, r"min_contrast: expected a number in \[0, 1\)"),
    ({"level": float("inf")}, SRDEError, "level: expected a finite number"),
    ({"white_reference": np.ones((H, W - 2), np.float32)}, SRDEError,
     "white_reference: expected the image's size 128x96, got 126x96"),
    ({"white_reference": np.full((H, W), 2.0, np.float32)}, ImageError,
     r"white_reference: expected float values in \[0, 1\]"),
])
def test_input_errors(kwargs, error, match):
    args = {"image": np.zeros((H, W), np.uint8)}
    args.update(kwargs)
    image = args.pop("image")
    with pytest.raises(error, match=match):
        detect_highlight(image, **args)


def test_a_clipped_blob_covering_most_of_the_region():
    # A very glossy object close to its light: one clipped blob fills most of the
    # search region, so the region's median is the blob's own level. The single-light
    # detector says so (its centre would be cut by the outline); the several-lights
    # candidates of the object's own region read the background low and find the blob.
    from srde_fusion.srde.candidates import find_candidates
    from srde_fusion.srde.config import DetectorConfig
    center = np.array([64.3, 47.6])
    image = to_srgb8(gaussian_blob(center, sigma=10.0, peak=6.0, background=0.05))
    region = np.zeros((H, W), bool)
    region[30:66, 44:86] = True
    assert np.median(luminance(image)[region]) >= 0.9
    assert "no bright blob" in detect_highlight(image, region).reason
    assert find_candidates(image, region, DetectorConfig()) == []
    found = find_candidates(image, region, DetectorConfig(), object_region=True)
    assert len(found) == 1
    np.testing.assert_allclose(found[0].center_uv, center, atol=0.5)
    # A region that is clipped all over still shows no highlight.
    white = np.full((H, W, 3), 255, np.uint8)
    assert find_candidates(white, region, DetectorConfig(), object_region=True) == []


def test_region_background_is_the_median_unless_the_median_is_clipped():
    from srde_fusion.srde.highlight import region_background
    values = np.linspace(0.0, 0.6, 101, dtype=np.float32)
    assert region_background(values, 0.6, 0.05) == np.median(values)
    mostly_clipped = np.concatenate([np.full(70, 1.0), np.linspace(0.1, 0.5, 30)])
    assert region_background(mostly_clipped, 1.0, 0.05) == pytest.approx(
        np.quantile(mostly_clipped, 0.1))
    # a bright median with a peak that stands out keeps the median
    bright = np.concatenate([np.full(70, 0.92), np.full(30, 1.0)])
    assert region_background(bright, 1.0, 0.05) == pytest.approx(0.92)
