"""The highlight search never allocates more than the image, whatever the rig's numbers.

Where a view can show the reference highlight is a segment along its baseline whose
length grows with ``fx * baseline``; only the part inside the image is ever sampled. A
rig with huge but legal numbers ends in a reasoned failure, not a ``MemoryError``.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from srde_fusion.errors import RigError
from srde_fusion.geometry import CameraRig
from srde_fusion.srde import SRDE, HighlightDetection
from srde_fusion.srde.search import BaselineSearch

W, H = 34, 11
# Peak traced allocation of one estimate on the 34x11 image, bytes: the views and masks
# are a few kB; an unbounded search asked for gigabytes.
MAX_TRACED_BYTES = 20_000_000


def _views(n: int) -> list[np.ndarray]:
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    blob = np.exp(-((uu - 17.0) ** 2 + (vv - 5.0) ** 2) / (2 * 1.5**2))
    image = np.clip(20 + 235 * blob, 0, 255).astype(np.uint8)
    return [np.repeat(image[:, :, None], 3, axis=2)] * n


def _hostile_rigs() -> dict[str, CameraRig]:
    # Legal, but fx * baseline is about 3e8 px: the segment spans 1e8 image widths.
    return {
        "long focal, long baseline": CameraRig.grid(3, 3, baseline_m=300.0, fx=999_999.0,
                                                    image_size=(W, H)),
        "long focal, stereo": CameraRig.stereo(500.0, fx=999_999.0, image_size=(W, H)),
        "short focal, long baseline": CameraRig.grid(1, 3, baseline_m=400.0, fx=1.0,
                                                     image_size=(W, H)),
    }


@pytest.mark.parametrize("name", list(_hostile_rigs()))
def test_hostile_rigs_end_in_a_reason_within_bounded_memory(name):
    rig = _hostile_rigs()[name]
    mask = np.zeros((H, W), bool)
    mask[1:10, 6:28] = True
    srde = SRDE(rig, light=[0.3, -0.5, 0.0], mask_erosion_px=0, refine=False)
    tracemalloc.start()
    try:
        result = srde.estimate(_views(rig.n_cameras), mask)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MAX_TRACED_BYTES
    if not result.ok:
        assert result.reason and result.status in ("no_highlight", "too_few_views",
                                                   "inconsistent", "at_infinity")


@pytest.mark.parametrize("build, match", [
    (lambda: CameraRig.grid(3, 3, baseline_m=0.1, fx=1e300, image_size=(W, H)),
     "intrinsics.fx: expected a focal length in pixels below"),
    (lambda: CameraRig.grid(3, 3, baseline_m=0.1 * 1e9, fx=500.0, image_size=(W, H)),
     r"cameras\[0\].center: expected a position within 1000 m"),
])
def test_rigs_beyond_the_physical_ranges_never_reach_the_search(build, match):
    with pytest.raises(RigError, match=match):
        build()


def _forced(rig: CameraRig, *, fx: float | None = None, scale: float | None = None
            ) -> CameraRig:
    """The rig with numbers the constructor refuses, as if built some other way."""
    if fx is not None:
        object.__setattr__(rig.intrinsics, "fx", fx)
        object.__setattr__(rig.intrinsics, "fy", fx)
    if scale is not None:
        centers = rig.centers_m * scale
        centers.setflags(write=False)
        object.__setattr__(rig, "_centers", centers)
    return rig


@pytest.mark.parametrize("fx, scale", [(1e300, None), (None, 1e9), (1e300, 1e9),
                                       (1e12, 1e3), (np.inf, None)])
def test_the_search_itself_is_bounded_whatever_the_numbers(fx, scale):
    rig = _forced(CameraRig.grid(3, 3, baseline_m=0.1, fx=500.0, image_size=(W, H)),
                  fx=fx, scale=scale)
    search = BaselineSearch(rig, np.array([0.3, -0.5, 0.0]), (0.2, 10.0))
    det = HighlightDetection(True, np.array([17.0, 5.0]), 9, (15, 3, 20, 8), 1.0, "")
    region = np.ones((H, W), bool)
    tracemalloc.start()
    try:
        with np.errstate(over="raise", invalid="raise", divide="raise"):  # none may escape
            found = [search.candidates(j, det, region) for j in range(9) if j != rig.reference]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MAX_TRACED_BYTES
    for cand in found:
        # at most the samples of a segment across the image, two per pixel
        assert cand is None or cand.w_v.size <= 2 * (W + H) + 8
