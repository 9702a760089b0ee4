"""The fast paths give what the straightforward computations give.

Pixel windows of the plane geometry against per-pixel rays, the shifted-slice clip of
the search region against a per-pixel gather, the 8-bit clipping test against
``saturation_mask``, and a dataset evaluated by worker processes against the same
dataset evaluated in one process.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.cli import main
from srde_fusion.cli.backbones import backbone_from
from srde_fusion.errors import SRDEError
from srde_fusion.evaluation import BackboneLoader, evaluate_dataset
from srde_fusion.geometry import Plane, incidence_angle_deg, plane_depth, plane_disparity
from srde_fusion.imaging import SATURATION_LEVEL_U8, saturation_mask
from srde_fusion.srde import shifted_window
from srde_fusion.srde.estimator import _in_box, _mask_box

# Grid rays and per-pixel rays differ only in the order of float64 operations; arccos
# near a head-on ray (0 deg) turns that into a few 1e-12 deg absolute.
RAY_REL_TOL = 1e-12
RAY_ABS_TOL = 1e-9

WINDOWS = [(0, 0, 640, 480), (100, 50, 260, 51), (613, 401, 640, 480), (5, 7, 6, 8)]


@pytest.fixture
def tilted_plane(rig3x3) -> Plane:
    return Plane.from_point_normal([0.05, -0.02, 1.1], [0.3, -0.2, -1.0],
                                   rig3x3.reference_center_m)


def _window_uv(window) -> np.ndarray:
    u0, v0, u1, v1 = window
    vv, uu = np.mgrid[v0:v1, u0:u1]
    return np.stack([uu, vv], axis=-1).astype(np.float64)


@pytest.mark.parametrize("window", WINDOWS)
def test_plane_window_matches_per_pixel_rays(rig3x3, tilted_plane, window):
    uv = _window_uv(window)
    for fn in (plane_depth, plane_disparity, incidence_angle_deg):
        got = fn(tilted_plane, rig3x3, window=window)
        assert got.shape == uv.shape[:2]
        np.testing.assert_allclose(got, fn(tilted_plane, rig3x3, uv), rtol=RAY_REL_TOL,
                                   atol=RAY_ABS_TOL)


def test_full_window_is_the_default_grid(rig3x3, tilted_plane):
    full = (0, 0, *rig3x3.image_size)
    for fn in (plane_depth, incidence_angle_deg):
        np.testing.assert_array_equal(fn(tilted_plane, rig3x3, window=full),
                                      fn(tilted_plane, rig3x3))


@pytest.mark.parametrize("fn", [plane_depth, plane_disparity, incidence_angle_deg])
def test_window_and_uv_together_is_an_error(rig3x3, tilted_plane, fn):
    with pytest.raises(SRDEError, match="window: expected either uv or window, got both"):
        fn(tilted_plane, rig3x3, [[1.0, 2.0]], window=(0, 0, 4, 4))


def _shifted_by_gather(mask, shift, box):
    u0, v0, u1, v1 = box
    h, w = mask.shape
    vv, uu = np.mgrid[v0:v1, u0:u1]
    su, sv = uu - shift[0], vv - shift[1]
    inside = (su >= 0) & (su < w) & (sv >= 0) & (sv < h)
    out = np.zeros(uu.shape, dtype=bool)
    out[inside] = mask[sv[inside], su[inside]]
    return out


@given(seed=st.integers(0, 2**16), du=st.integers(-40, 40), dv=st.integers(-40, 40),
       u0=st.integers(0, 30), v0=st.integers(0, 20), bw=st.integers(1, 30), bh=st.integers(1, 25))
def test_shifted_window_matches_a_per_pixel_gather(seed, du, dv, u0, v0, bw, bh):
    mask = np.random.default_rng(seed).random((24, 32)) < 0.5
    box = (u0, v0, min(u0 + bw, 32), min(v0 + bh, 24))
    if box[2] <= box[0] or box[3] <= box[1]:
        box = (0, 0, 32, 24)
    np.testing.assert_array_equal(shifted_window(mask, (du, dv), box),
                                  _shifted_by_gather(mask, (du, dv), box))


def test_mask_box_and_box_map_round_trip():
    mask = np.zeros((30, 40), dtype=bool)
    mask[4:9, 10:13] = True
    mask[12, 20] = True
    box, inside = _mask_box(mask)
    assert box == (10, 4, 21, 13)
    values = np.arange(int(inside.sum()), dtype=np.float32)
    in_box = _in_box(values, box, inside)
    assert in_box.dtype == np.float32 and in_box.shape == (9, 11)
    out = np.full(mask.shape, np.nan, np.float32)
    out[4:13, 10:21] = in_box
    np.testing.assert_array_equal(np.isfinite(out), mask)
    np.testing.assert_array_equal(out[mask], values)  # row-major order, like mask indexing


@pytest.mark.parametrize("channels", [None, 3])
def test_clipping_test_matches_saturation_mask(channels):
    shape = (50, 60) if channels is None else (50, 60, channels)
    image = np.random.default_rng(3).integers(240, 256, shape).astype(np.uint8)
    crop = image[7:41, 3:55]  # strided, as the detectors see it
    # The OpenCV range test in saturation_mask against the plain definition.
    expected = crop >= SATURATION_LEVEL_U8
    expected = expected if channels is None else expected.any(axis=2)
    np.testing.assert_array_equal(saturation_mask(crop), expected)
    as_float = crop.astype(np.float32) / 255.0
    np.testing.assert_array_equal(saturation_mask(as_float), expected)


# ---------------------------------------------------------------- parallel evaluation
def _scores_only(evaluation) -> dict:
    data = evaluation.to_dict()
    del data["run"]
    for scene in data["scenes"]:
        del scene["seconds"]
    return data


def test_parallel_evaluation_gives_the_serial_numbers(dataset):
    loader = BackboneLoader(functools.partial(backbone_from, "default", None, threads=1))
    serial = evaluate_dataset(dataset, loader, progress=False, jobs=1)
    parallel = evaluate_dataset(dataset, loader, progress=False, jobs=2)
    assert (serial.jobs, parallel.jobs) == (1, 2)
    assert [s.name for s in parallel.scenes] == [s.name for s in serial.scenes]
    assert _scores_only(parallel) == _scores_only(serial)
    assert parallel.scenes_per_second == pytest.approx(2 / parallel.wall_s)
    assert parallel.to_dict()["run"]["jobs"] == 2


def test_a_bad_scene_is_recorded_in_parallel_too_and_raised_with_strict(dataset, tmp_path):
    import shutil

    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    (data / "scene_0000" / "rig.json").write_text("{")
    loader = BackboneLoader(functools.partial(backbone_from, "default", None, threads=1))
    evaluation = evaluate_dataset(data, loader, progress=False, jobs=2)
    assert [s.name for s in evaluation.scenes] == ["scene_0001"]
    assert [(f.name, f.error) for f in evaluation.failures] == [("scene_0000", "RigError")]
    with pytest.raises(SRDEError, match="rig.json: expected valid JSON"):
        evaluate_dataset(data, loader, progress=False, jobs=1, strict=True)


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True])
def test_bad_jobs_raise(dataset, jobs):
    with pytest.raises(SRDEError, match="jobs: expected a positive integer"):
        evaluate_dataset(dataset, lambda left, right: left[..., 0] * 0.0, jobs=jobs)


def test_unpicklable_backbone_with_jobs_raises(dataset):
    with pytest.raises(SRDEError, match="expected a picklable backbone or a BackboneLoader"):
        evaluate_dataset(dataset, lambda left, right: left[..., 0] * 0.0, jobs=2,
                         progress=False)


def test_eval_command_rejects_zero_jobs(dataset, capsys):
    code = main(["eval", str(dataset), "--backbone", "default", "--jobs", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "--jobs: expected a positive number of worker processes, got 0" in err[0]
