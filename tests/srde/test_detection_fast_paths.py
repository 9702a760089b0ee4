"""The detection path's fast primitives give exactly what the straightforward ones give.

Each primitive is compared, bit for bit, with the computation it replaces: block means
against numpy's reshape-mean, the one-partition median against ``np.median``, the mask
eroded or dilated on its box against the whole mask eroded or dilated, regions computed
inside the moved search box against regions computed over the whole disc, the candidates
of all views at once against one view at a time, the box-corner grazing test against the
per-pixel angles, the plane's disparity in one pass against the gather-and-scatter, a
detection that reads the brightness search's luminance against one that converts the
pixels itself, a region held over its box against the whole array, and the several-lights
dip test of all peak pairs at once against one pair at a time.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.boxes import dilated, eroded
from srde_fusion.geometry import CameraRig, Plane, incidence_angle_deg, plane_disparity
from srde_fusion.imaging import luminance
from srde_fusion.srde import SRDE
from srde_fusion.srde.backends import (
    REDUCED_SMOOTHING_SIGMA_PX,
    DetectionRequest,
    HostFrame,
    NumpyBackend,
)
from srde_fusion.srde.candidates import (
    SEPARATING_DIP,
    _dips,
    _label_maxima,
    _nearest,
    _nonzero,
    _separated_peaks,
    find_candidates,
)
from srde_fusion.srde.config import DetectorConfig
from srde_fusion.srde.estimator import _in_box, _mask_box, _plane_disparity_in_box
from srde_fusion.srde.highlight import (
    HighlightDetection,
    crop_luminance,
    detect_in_view,
    median,
    search_box,
    weighted_centroid,
)
from srde_fusion.srde.search import BaselineSearch
from srde_fusion.synthetic import RandomSceneConfig, random_scene, render


def _blobs(rng, shape, n) -> np.ndarray:
    """A bool mask of ``n`` random ellipses (some may touch or cross the border)."""
    h, w = shape
    mask = np.zeros(shape, np.uint8)
    for _ in range(n):
        center = (int(rng.integers(-5, w + 5)), int(rng.integers(-5, h + 5)))
        axes = (int(rng.integers(1, w // 2 + 2)), int(rng.integers(1, h // 2 + 2)))
        cv2.ellipse(mask, center, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return mask.view(bool)


@given(st.integers(1, 400), st.integers(0, 2 ** 31), st.booleans())
def test_median_is_numpys_median(n, seed, few_values):
    rng = np.random.default_rng(seed)
    values = rng.random(n, dtype=np.float32)
    if few_values:  # many ties, as 8-bit luminance has
        values = np.round(values * 4).astype(np.float32) / 4
    assert median(values) == float(np.median(values))


@given(st.integers(1, 400), st.integers(0, 2 ** 31), st.booleans())
def test_median_in_place_is_numpys_median(n, seed, few_values):
    rng = np.random.default_rng(seed)
    values = rng.random(n, dtype=np.float32)
    if few_values:
        values = np.round(values * 4).astype(np.float32) / 4
    want = float(np.median(values))
    copy = values.copy()
    assert median(copy, overwrite=True) == want
    np.testing.assert_array_equal(np.sort(copy), np.sort(values))  # reordered, not changed


def test_median_of_values_with_nan_is_nan():
    assert np.isnan(median(np.array([0.2, np.nan, 0.1], np.float32)))


@given(st.integers(0, 2 ** 31), st.integers(0, 3))
def test_search_box_is_the_regions_bounding_box(seed, n_blobs):
    rng = np.random.default_rng(seed)
    region = _blobs(rng, (37, 53), n_blobs)
    margin = int(rng.integers(0, 6))
    got = search_box(region, margin)
    if not region.any():
        assert got is None
        return
    rows, cols = np.flatnonzero(region.any(axis=1)), np.flatnonzero(region.any(axis=0))
    assert got == (max(cols[0] - margin, 0), max(rows[0] - margin, 0),
                   min(cols[-1] + 1 + margin, 53), min(rows[-1] + 1 + margin, 37))


@given(st.integers(0, 2 ** 31), st.integers(0, 5))
def test_mask_eroded_on_its_box_is_the_whole_mask_eroded(seed, radius):
    rng = np.random.default_rng(seed)
    rig = CameraRig.stereo(0.1, fx=60.0, image_size=(64, 48))
    mask = _blobs(rng, (48, 64), int(rng.integers(1, 4)))
    srde = SRDE(rig, light=[0.1, -0.2, 0.0], mask_erosion_px=radius)
    want = mask
    if radius:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        want = cv2.erode(mask.view(np.uint8), kernel).view(bool)
    np.testing.assert_array_equal(srde._erode(mask), want)


@given(st.integers(0, 2 ** 31), st.integers(0, 3), st.integers(1, 25), st.booleans())
def test_mask_dilated_near_its_box_is_the_whole_mask_dilated(seed, n_blobs, side, ellipse):
    rng = np.random.default_rng(seed)
    mask = _blobs(rng, (48, 64), n_blobs)
    if rng.random() < 0.3:  # pixels on the image's border
        mask[int(rng.integers(0, 48)), 0] = mask[0, int(rng.integers(0, 64))] = True
    shape = cv2.MORPH_ELLIPSE if ellipse else cv2.MORPH_RECT
    kernel = cv2.getStructuringElement(shape, (side, side))
    want = cv2.dilate(mask.view(np.uint8), kernel).view(bool)
    np.testing.assert_array_equal(dilated(mask, kernel), want)


def test_weighted_centroid_is_the_index_grid_formula():
    rng = np.random.default_rng(3)
    weights = rng.random((17, 23), dtype=np.float32) * (rng.random((17, 23)) > 0.3)
    vv, uu = np.indices(weights.shape, dtype=np.float64)
    total = float(weights.sum())
    want = np.array([(weights * uu).sum() / total, (weights * vv).sum() / total])
    np.testing.assert_array_equal(weighted_centroid(weights), want)


def _search_geometry(seed: int):
    """A rig, a search region, a fake reference detection and its BaselineSearch."""
    rng = np.random.default_rng(seed)
    rig = (CameraRig.grid(3, 3, baseline_m=0.06, fx=200.0, image_size=(160, 120))
           if seed % 2 else CameraRig.stereo(0.09, fx=220.0, image_size=(160, 120)))
    search = _blobs(rng, (120, 160), 1 + seed % 2)
    if not search.any():
        search[60, 80] = True
    vv, uu = np.nonzero(search)
    pick = int(rng.integers(0, uu.size))
    center = np.array([uu[pick] + rng.uniform(-0.5, 0.5), vv[pick] + rng.uniform(-0.5, 0.5)])
    half = rng.integers(1, 40, size=2)
    bbox = (int(center[0] - half[0]), int(center[1] - half[1]),
            int(center[0] + half[0]), int(center[1] + half[1]))
    det = HighlightDetection(True, center, 10, bbox, 1.0, "", 0.5)
    light = [rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(-0.1, 0.2)]
    depth = ((0.2, 10.0), (0.4, 1.5), (0.05, 1e4))[seed % 3]
    return rig, search, det, BaselineSearch(rig, np.asarray(light), depth, seed % 5 == 0)


@given(st.integers(0, 2 ** 31))
def test_candidates_of_all_views_are_each_views_own(seed):
    rig, search, det, geometry = _search_geometry(seed)
    others = [j for j in range(rig.n_cameras) if j != rig.reference]
    together = geometry.all_candidates(others, det, search)
    for j in others:
        alone = geometry.all_candidates([j], det, search)[j]
        assert (together[j] is None) == (alone is None)
        if alone is None:
            continue
        for field in alone.__dataclass_fields__:
            a, b = getattr(alone, field), getattr(together[j], field)
            if isinstance(a, np.ndarray):
                assert a.dtype == b.dtype
                np.testing.assert_array_equal(a, b)
            else:
                assert a == b


@given(st.integers(0, 2 ** 31))
def test_region_inside_the_moved_search_box_is_the_whole_discs(seed):
    rig, search, det, geometry = _search_geometry(seed)
    others = [j for j in range(rig.n_cameras) if j != rig.reference]
    for cand in geometry.all_candidates(others, det, search).values():
        if cand is None:
            continue
        for best in np.flatnonzero(cand.ok)[::7]:
            want = np.asarray(geometry.boxed_region_at(cand, int(best), search)[0])
            got, bbox = geometry.boxed_region_at(cand, int(best), search, search_box(search, 0))
            np.testing.assert_array_equal(np.asarray(got), want)
            np.testing.assert_array_equal(geometry.region_at(cand, int(best), search), want)
            assert bbox == search_box(want, 0)


def _planes(seed: int, rig: CameraRig):
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=3)
    normal[2] = -abs(normal[2]) * rng.uniform(0.0, 3.0)  # some nearly edge-on
    point = [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.3, 3.0)]
    return Plane.from_point_normal(point, normal, rig.reference_center_m)


@given(st.integers(0, 2 ** 31))
def test_grazing_corner_test_never_misses_a_steep_pixel(seed):
    rig = CameraRig.stereo(0.1, fx=80.0, image_size=(96, 72))
    rng = np.random.default_rng(seed)
    plane = _planes(seed, rig)
    u0, v0 = int(rng.integers(0, 90)), int(rng.integers(0, 66))
    box = (u0, v0, int(rng.integers(u0 + 1, 97)), int(rng.integers(v0 + 1, 73)))
    bound = float(rng.choice([30.0, 60.0, 85.0, 89.0]))
    srde = SRDE(rig, light=[0.1, -0.2, 0.0], max_incidence_deg=bound)
    if not srde._grazing_possible(plane, box):
        assert np.all(incidence_angle_deg(plane, rig, window=box) <= bound)


@given(st.integers(0, 2 ** 31))
def test_disparity_in_box_is_plane_disparity_gathered_and_scattered(seed):
    rig = CameraRig.stereo(0.1, fx=80.0, image_size=(96, 72))
    rng = np.random.default_rng(seed)
    mask = _blobs(rng, (72, 96), 2)
    if not mask.any():
        mask[3, 4] = True
    box, inside = _mask_box(mask)
    plane = _planes(seed, rig)
    want = _in_box(plane_disparity(plane, rig, window=box)[inside], box, inside)
    got = _plane_disparity_in_box(plane, rig, box, inside)
    assert got.dtype == want.dtype == np.float32
    np.testing.assert_array_equal(got, want)


@given(st.integers(0, 2 ** 31), st.sampled_from(["rgb8", "grey8", "rgb32", "grey32"]),
       st.sampled_from(["srgb", "linear"]))
def test_crop_luminance_reuses_a_known_box_exactly(seed, kind, encoding):
    rng = np.random.default_rng(seed)
    shape = (40, 50, 3) if kind.startswith("rgb") else (40, 50)
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    if kind.endswith("32"):
        image = (image / 255.0).astype(np.float32)

    def random_box():
        u0, v0 = int(rng.integers(0, 49)), int(rng.integers(0, 39))
        return u0, v0, int(rng.integers(u0 + 1, 51)), int(rng.integers(v0 + 1, 41))

    box, known_box = random_box(), random_box()
    ku0, kv0, ku1, kv1 = known_box
    known = (known_box, luminance(image[kv0:kv1, ku0:ku1], encoding))
    u0, v0, u1, v1 = box
    want = luminance(image[v0:v1, u0:u1], encoding)
    got = crop_luminance(image, box, encoding, known)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(crop_luminance(image, box, encoding), want)


def test_crop_luminance_fills_the_strips_around_a_partial_overlap():
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    box = (10, 10, 40, 30)
    for known_box in [(5, 0, 35, 35), (12, 12, 50, 40), (0, 14, 50, 25), (11, 0, 39, 40)]:
        ku0, kv0, ku1, kv1 = known_box
        known = (known_box, luminance(image[kv0:kv1, ku0:ku1]))
        np.testing.assert_array_equal(crop_luminance(image, box, "srgb", known),
                                      luminance(image[10:30, 10:40]))


@pytest.fixture(scope="module")
def harsh_scene():
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(320, 240))
    config = RandomSceneConfig(roughness=(0.05, 0.08), clip_ratio=(4.0, 8.0),
                               light_radius_m=0.015)
    scene = random_scene(9001, rig, config=config)
    out = render(scene, rig)
    return rig.with_light(scene.light.position_m), out.views, out.object_masks[0]


def test_detection_reading_the_searchs_luminance_is_the_same(harsh_scene):
    rig, views, mask = harsh_scene
    config = DetectorConfig()
    image = views[0]
    region = np.zeros(mask.shape, bool)
    region[60:150, 80:200] = mask[60:150, 80:200]
    bbox = search_box(region, 0)
    want = detect_in_view(image, region, config, level=0.3)
    box = (70, 40, 260, 200)            # holds the detection's crop
    known = (box, luminance(image[box[1]:box[3], box[0]:box[2]]))
    got = detect_in_view(image, region, config, level=0.3, region_bbox=bbox,
                         luminance_crop=known)
    assert want.found and got.found
    np.testing.assert_array_equal(got.center_uv, want.center_uv)
    assert (got.area_px, got.bbox, got.score, got.level) == (
        want.area_px, want.bbox, want.score, want.level)
    # A crop that does not hold the detection's is not used.
    small = ((100, 80, 150, 120), np.zeros((40, 50), np.float32))
    again = detect_in_view(image, region, config, level=0.3, luminance_crop=small)
    np.testing.assert_array_equal(again.center_uv, want.center_uv)


@pytest.fixture(scope="module")
def gentle_scene():
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(320, 240))
    scene = random_scene(9001, rig, config=RandomSceneConfig(roughness=(0.01, 0.02)))
    out = render(scene, rig)
    return rig.with_light(scene.light.position_m), out.views, out.object_masks[0]


@pytest.mark.parametrize("name", ["gentle_scene", "harsh_scene"])
def test_the_numpy_backend_keeps_the_searchs_luminance_for_the_frame(name, request):
    rig, views, mask = request.getfixturevalue(name)
    srde = SRDE(rig, refine=False)
    frame = srde.backend.prepare(views)
    assert isinstance(frame, HostFrame) and frame.luminance_crops == {}
    result = srde._estimate(frame, mask, None)
    assert result.ok
    # A small blob's search converts its crops, which the detection reads again; a large
    # one's reads a grid of pixels, and the detection converts its own crop.
    u0, v0, u1, v1 = result.detections[rig.reference].bbox
    small = 0.25 * np.hypot(u1 - u0, v1 - v0) < REDUCED_SMOOTHING_SIGMA_PX
    assert small == (name == "gentle_scene")
    kept = set(range(rig.n_cameras)) - {rig.reference} if small else set()
    assert set(frame.luminance_crops) == kept
    for j, ((u0, v0, u1, v1), lum) in frame.luminance_crops.items():
        np.testing.assert_array_equal(lum, luminance(views[j][v0:v1, u0:u1]))
    # A fresh frame per estimate: the same result from plain views.
    again = srde.estimate(list(views), mask)
    np.testing.assert_array_equal(again.highlight_centers, result.highlight_centers)
    # Requests without a box find it; with one they skip the search: the same detection.
    backend = NumpyBackend(rig, DetectorConfig())
    region = srde._erode(mask)
    plain = backend.detect(views, [DetectionRequest(rig.reference, region)])[0]
    boxed = backend.detect(views, [DetectionRequest(rig.reference, region, None,
                                                    search_box(region, 0))])[0]
    np.testing.assert_array_equal(plain.center_uv, boxed.center_uv)


def _dips_one_pair(smooth, a, b, top, background) -> bool:
    # The dip test as it was written for one pair of peaks.
    length = float(np.hypot(*(np.asarray(b) - np.asarray(a))))
    steps = max(2, int(np.ceil(length)) + 1)
    t = np.linspace(0.0, 1.0, steps)
    us = np.rint(a[0] + t * (b[0] - a[0])).astype(np.intp)
    vs = np.rint(a[1] + t * (b[1] - a[1])).astype(np.intp)
    return float(smooth[vs, us].min()) < top - SEPARATING_DIP * (top - background)


def _random_peaks(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(5, 60)), int(rng.integers(5, 60))
    smooth = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 2.0)
    m = int(rng.integers(0, 12))
    where = np.stack([rng.uniform(0, w - 1, m), rng.uniform(0, h - 1, m)], axis=1)
    # Some peaks on exact half-pixel positions, where rounding ties are.
    where[: m // 3] = np.round(where[: m // 3] * 2) / 2
    tops = np.sort(rng.uniform(0.3, 1.0, m))[::-1]
    background = float(rng.uniform(0.0, 0.3))
    return smooth, where, tops, background, rng


@given(st.integers(0, 2**32 - 1))
def test_the_dip_pairs_are_the_pairwise_dip_test(seed):
    smooth, where, tops, background, _ = _random_peaks(seed)
    p, q = np.tril_indices(len(where), -1)
    if p.size == 0:
        return
    got = _dips(smooth, where, tops, background, p, q)
    for k in range(p.size):
        assert got[k] == _dips_one_pair(smooth, where[p[k]], where[q[k]], tops[p[k]],
                                        background)


@given(st.integers(0, 2**32 - 1))
def test_separated_peaks_are_the_greedy_choice_over_every_pair(seed):
    # Brightest first, a peak is kept when it dips from every peak kept before it.
    smooth, where, tops, background, rng = _random_peaks(seed)
    max_peaks = int(rng.integers(1, 6))
    want: list[int] = []
    for p in range(len(where)):
        if all(_dips_one_pair(smooth, where[p], where[q], tops[p], background) for q in want):
            want.append(p)
        if len(want) == max_peaks:
            break
    assert _separated_peaks(smooth, where, tops, background, max_peaks) == want


@given(st.integers(0, 2**32 - 1))
def test_label_maxima_are_the_unbuffered_maxima(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20))
    labels = rng.integers(0, n, int(rng.integers(0, 200)))
    values = rng.uniform(0.0, 1.0, labels.size).astype(np.float32)
    want = np.array([max([0.0] + [float(v) for v in values[labels == k]]) for k in range(n)])
    np.testing.assert_array_equal(_label_maxima(labels, values, n), want)


@given(st.integers(0, 2**32 - 1))
def test_nonzero_is_numpys_nonzero_in_raster_order(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(0, 40)), int(rng.integers(1, 40))
    mask = rng.random((h, w)) < rng.choice([0.0, 0.05, 0.5, 1.0])
    # Also a strided crop, as the candidates' box is.
    for m in (mask, mask[1:, 2:]):
        got, want = _nonzero(m), np.nonzero(m)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == np.intp


@given(st.integers(0, 2**31), st.integers(1, 6), st.booleans())
def test_eroded_on_the_masks_box_is_the_whole_frame_eroded(seed, radius, square):
    rng = np.random.default_rng(seed)
    mask = _blobs(rng, (48, 64), int(rng.integers(0, 4)))
    side = 2 * radius + 1
    kernel = (np.ones((side, side), np.uint8) if square
              else cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side)))
    want = cv2.erode(mask.view(np.uint8), kernel).view(bool)
    np.testing.assert_array_equal(eroded(mask, kernel), want)


@given(st.integers(0, 2 ** 31), st.integers(1, 6), st.booleans())
def test_nearest_peak_is_the_first_argmin(seed, n_peaks, on_grid):
    rng = np.random.default_rng(seed)
    vv, uu = np.nonzero(rng.random((23, 31)) < 0.6)
    peaks = rng.uniform(-3.0, 34.0, (n_peaks, 2))
    if on_grid:  # peaks on pixel centres and repeated: ties go to the first peak
        peaks = np.round(peaks)[rng.integers(0, n_peaks, n_peaks)]
    want = np.argmin(np.stack([(uu - p[0]) ** 2 + (vv - p[1]) ** 2 for p in peaks]), axis=0)
    np.testing.assert_array_equal(_nearest(uu, vv, peaks), want)


@given(st.integers(0, 2 ** 31), st.integers(1, 4))
def test_each_candidates_blob_is_its_component_above_its_level(seed, n_blobs):
    """A candidate's blob (area, box, centre) is the component above its level it sits in.

    Blobs apart from each other on a noisy background; each is read from its peak.
    """
    rng = np.random.default_rng(seed)
    h, w = 60, 120
    vv, uu = np.mgrid[0:h, 0:w]
    image = 0.05 + 0.01 * rng.random((h, w))
    for b in range(n_blobs):  # 30 px apart, at most 4.7 px to half maximum
        cu, cv = 15.0 + 30.0 * b + rng.uniform(-3, 3), rng.uniform(20, h - 20)
        s = rng.uniform(1.5, 4.0)
        image += rng.uniform(0.3, 0.9) * np.exp(-((uu - cu) ** 2 + (vv - cv) ** 2) / (2 * s * s))
    image = np.clip(image, 0.0, 1.0).astype(np.float32)
    found = find_candidates(image, np.ones((h, w), bool), DetectorConfig(encoding="linear"))
    assert len(found) == n_blobs
    for d in found:
        above = image > d.level
        _, parts = cv2.connectedComponents(above.view(np.uint8), connectivity=8)
        blob = parts == parts[int(round(d.center_uv[1])), int(round(d.center_uv[0]))]
        x, y, bw, bh = cv2.boundingRect(blob.view(np.uint8))
        assert d.area_px == int(blob.sum())
        assert d.bbox == (x, y, x + bw, y + bh)
        weights = np.where(blob, image - np.float32(d.level), 0.0)[y:y + bh, x:x + bw]
        np.testing.assert_allclose(d.center_uv, weighted_centroid(weights) + [x, y], atol=1e-9)
