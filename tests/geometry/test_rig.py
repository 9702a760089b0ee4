from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.errors import LightError, RigError
from srde_fusion.geometry import RIG_FORMAT, Camera, CameraRig, Intrinsics

B_M = 0.085


# ---------------------------------------------------------------------- constructors
def test_grid_3x3_is_the_paper_array(rig3x3):
    assert rig3x3.n_cameras == 9
    assert rig3x3.camera_names == [f"cam{i}" for i in range(9)]
    assert rig3x3.reference == 4 and rig3x3.stereo_pair == (4, 5)
    assert rig3x3.baseline_m == pytest.approx(B_M)
    expected = [[(c - 1) * B_M, (r - 1) * B_M, 0.0] for r in range(3) for c in range(3)]
    np.testing.assert_allclose(rig3x3.centers_m, expected)
    np.testing.assert_array_equal(rig3x3.reference_center_m, [0.0, 0.0, 0.0])
    assert (rig3x3.width, rig3x3.height) == (640, 480)
    assert rig3x3.image_encoding == "srgb" and rig3x3.light is None


def test_grid_even_count_reference_left_of_centre():
    rig = CameraRig.grid(2, 4, baseline_m=0.05, fx=100.0)
    # Centre of a 2x4 grid: row 0, column 1 (left of/above the centre).
    assert rig.reference == 1 and rig.stereo_pair == (1, 2)
    np.testing.assert_allclose(rig.centers_m[0], [-0.05, 0.0, 0.0])
    np.testing.assert_allclose(rig.centers_m[7], [0.10, 0.05, 0.0])


def test_grid_defaults_principal_point_to_image_centre():
    rig = CameraRig.grid(1, 2, baseline_m=0.1, fx=50.0, image_size=(101, 60))
    k = rig.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == (50.0, 50.0, 50.0, 29.5)


def test_focal_length_from_mm_and_pixel_size():
    rig = CameraRig.grid(3, 3, baseline_m=B_M, focal_length_mm=8.0, pixel_size_um=3.45)
    assert rig.intrinsics.fx == pytest.approx(8.0e-3 / 3.45e-6)
    assert rig.intrinsics.fy == rig.intrinsics.fx
    k = Intrinsics.from_focal_length(12.0, 4.0, 10.0, 20.0)
    assert (k.fx, k.fy, k.cx, k.cy) == (3000.0, 3000.0, 10.0, 20.0)
    np.testing.assert_array_equal(k.matrix, [[3000, 0, 10], [0, 3000, 20], [0, 0, 1]])


def test_stereo_rig():
    rig = CameraRig.stereo(
        0.12, fx=700.0, fy=710.0, image_size=(320, 240), light_position_m=[0.0, -0.2, 0.0]
    )
    assert rig.camera_names == ["left", "right"]
    assert rig.reference == 0 and rig.stereo_pair == (0, 1)
    np.testing.assert_allclose(rig.centers_m, [[0, 0, 0], [0.12, 0, 0]])
    assert rig.intrinsics.fy == 710.0
    np.testing.assert_array_equal(rig.light, [0.0, -0.2, 0.0])


def test_intrinsics_are_stored_as_floats():
    k = Intrinsics(np.float32(600), 600, np.float64(319.5), 239)
    assert all(type(v) is float for v in (k.fx, k.fy, k.cx, k.cy))
    rig = CameraRig(
        (640, 480), k, (Camera("a", np.zeros(3, np.float32)), Camera("b", [np.float32(0.1), 0, 0]))
    )
    # numpy inputs must not break JSON, equality or hashing.
    assert CameraRig.from_json(rig.to_json()) == rig
    assert hash(rig) == hash(CameraRig.from_json(rig.to_json()))
    assert rig.cameras[1].center_m == pytest.approx((0.1, 0.0, 0.0))


def test_centers_are_read_only(rig3x3):
    with pytest.raises(ValueError, match="read-only"):
        rig3x3.centers_m[0, 0] = 1.0


# ---------------------------------------------------------------------- geometry
_points = st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(0.2, 10.0))


@given(_points, st.integers(0, 8))
def test_project_backproject_round_trip(rig3x3, point, camera):
    p = np.array(point)
    uv = rig3x3.project(p, camera)
    depth = p[2] - rig3x3.centers_m[camera, 2]
    np.testing.assert_allclose(rig3x3.backproject(uv, depth, camera), p, atol=1e-9)


@given(st.lists(_points, min_size=1, max_size=5))
def test_project_matches_camera_matrix(rig3x3, points):
    p = np.array(points)
    uvw = p @ rig3x3.intrinsics.matrix.T
    np.testing.assert_allclose(rig3x3.project(p), uvw[:, :2] / uvw[:, 2:], rtol=1e-12)


def test_project_behind_camera_is_nan(rig3x3):
    uv = rig3x3.project([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.isnan(uv[:2]).all()
    np.testing.assert_allclose(uv[2], [319.5, 239.5])


def test_rays(rig3x3):
    np.testing.assert_allclose(
        rig3x3.rays([[319.5, 239.5], [919.5, 839.5]]), [[0, 0, 1], [1, 1, 1]]
    )


def test_disparity_is_the_stereo_pair_shift(rig3x3):
    point = np.array([0.3, -0.1, 1.7])
    u_ref = rig3x3.project(point, 4)[0]
    u_partner = rig3x3.project(point, 5)[0]
    d = rig3x3.depth_to_disparity(1.7)
    assert d == pytest.approx(600.0 * B_M / 1.7)
    assert u_ref - u_partner == pytest.approx(d)


@given(st.floats(0.05, 100.0))
def test_disparity_depth_round_trip(rig3x3, depth_m):
    d = rig3x3.depth_to_disparity(depth_m)
    assert rig3x3.disparity_to_depth(d) == pytest.approx(depth_m, rel=1e-12)


def test_disparity_depth_invalid_values_are_nan(rig3x3):
    out = rig3x3.depth_to_disparity(np.array([0.0, -1.0, np.nan, 2.0]))
    assert np.isnan(out[:3]).all() and out[3] == pytest.approx(25.5)
    back = rig3x3.disparity_to_depth(np.array([0.0, -3.0, 25.5]))
    assert np.isnan(back[:2]).all() and back[2] == pytest.approx(2.0)


# ---------------------------------------------------------------------- derived rigs
def test_scaled_follows_the_pixel_grid(rig3x3):
    half = rig3x3.scaled(0.5)
    assert half.image_size == (320, 240)
    k = half.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == (300.0, 300.0, 159.5, 119.5)
    point = np.array([0.2, 0.1, 1.5])
    # Pixel centres at integers: u_half + 0.5 = (u + 0.5) / 2.
    np.testing.assert_allclose(half.project(point) + 0.5, (rig3x3.project(point) + 0.5) / 2)
    assert half.depth_to_disparity(1.5) == pytest.approx(rig3x3.depth_to_disparity(1.5) / 2)
    np.testing.assert_array_equal(half.centers_m, rig3x3.centers_m)
    with pytest.raises(RigError, match="factor: expected a positive number, got 0"):
        rig3x3.scaled(0)


def test_with_light(rig3x3):
    lit = rig3x3.with_light(np.array([0.1, -0.4, 0.2]))
    assert lit.light_position_m == (0.1, -0.4, 0.2)
    assert rig3x3.light_position_m is None
    assert lit.with_light(None) == rig3x3
    with pytest.raises(RigError, match=r"light_position_m: expected a list of 3 numbers"):
        rig3x3.with_light([1.0, 2.0])
    with pytest.raises(RigError, match=r"light_position_m\[2\]: expected a finite number"):
        rig3x3.with_light([1.0, 2.0, np.inf])


def test_subset(rig3x3):
    row = rig3x3.subset([3, 4, 5])
    assert row.camera_names == ["cam3", "cam4", "cam5"]
    assert row.reference == 1 and row.stereo_pair == (1, 2)
    np.testing.assert_allclose(row.centers_m[:, 0], [-B_M, 0.0, B_M])
    with pytest.raises(RigError, match=r"expected the stereo pair \[4, 5\] to be kept"):
        rig3x3.subset([3, 4])
    with pytest.raises(
        RigError, match=r"indices: expected camera indices in \[0, 8\], got \[-1, 4, 5\]"
    ):
        rig3x3.subset([-1, 4, 5])
    with pytest.raises(RigError, match=r"indices: expected camera indices in \[0, 8\]"):
        rig3x3.subset([4, 5, 9])
    with pytest.raises(RigError, match="unique names"):
        rig3x3.subset([4, 4, 5])


# ---------------------------------------------------------------------- serialisation
def test_json_round_trip_string_and_file(rig3x3, tmp_path):
    rig = rig3x3.with_light([0.1, -0.4, 0.2])
    text = rig.to_json()
    assert json.loads(text)["format"] == RIG_FORMAT
    assert CameraRig.from_json(text) == rig
    path = tmp_path / "rig.json"
    assert rig.to_json(path) == path.read_text()
    assert CameraRig.from_json(path) == rig
    assert CameraRig.from_json(str(path)) == rig


def test_to_dict_layout(rig3x3):
    data = rig3x3.to_dict()
    assert data == {
        "format": "srde-rig/1",
        "image_size": [640, 480],
        "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5},
        "cameras": [
            {"name": f"cam{i}", "center": list(c)}
            for i, c in enumerate(map(tuple, rig3x3.centers_m))
        ],
        "reference": 4,
        "stereo_pair": [4, 5],
        "image_encoding": "srgb",
    }


def test_from_dict_optional_keys_and_focal_length_form(rig3x3):
    data = rig3x3.to_dict()
    del data["image_encoding"]
    assert CameraRig.from_dict(data).image_encoding == "srgb"
    data["image_encoding"] = "linear"
    assert CameraRig.from_dict(data).image_encoding == "linear"
    data["intrinsics"] = {"focal_length_mm": 6.0, "pixel_size_um": 2.0, "cx": 319.5, "cy": 239.5}
    assert CameraRig.from_dict(data).intrinsics.fx == pytest.approx(3000.0)


def _edited(rig: CameraRig, edit) -> dict:
    data = copy.deepcopy(rig.to_dict())
    edit(data)
    return data


def _set(path, value):
    def edit(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return edit


def _delete(*path):
    def edit(data):
        target = data
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return edit


_NOT_COPLANAR = [-0.085, -0.085, 0.01]

RIG_JSON_ERRORS = [
    ("unknown-key", _set(("colour",), "red"), r"rig: unknown key\(s\) \['colour'\]"),
    ("missing-key", _delete("stereo_pair"), r"rig: missing key\(s\) \['stereo_pair'\]"),
    ("not-object", lambda d: d.clear() or d.update({"x": 1}), r"unknown key\(s\) \['x'\]"),
    ("format", _set(("format",), "srde-rig/2"), r"format: expected 'srde-rig/1', got 'srde-rig/2'"),
    ("size-type", _set(("image_size",), "640x480"), r"image_size: expected \[width, height\]"),
    ("size-float", _set(("image_size",), [640.0, 480]), "two positive integers"),
    ("size-zero", _set(("image_size",), [640, 0]), "two positive integers"),
    ("intr-unknown", _set(("intrinsics", "skew"), 0.0), r"intrinsics: unknown key\(s\) \['skew'\]"),
    ("intr-missing", _delete("intrinsics", "cy"), r"intrinsics: missing key\(s\) \['cy'\]"),
    (
        "fx-nan",
        _set(("intrinsics", "fx"), float("nan")),
        "intrinsics.fx: expected a finite number, got nan",
    ),
    (
        "fx-negative",
        _set(("intrinsics", "fx"), -600.0),
        "intrinsics.fx: expected a positive number",
    ),
    ("fy-zero", _set(("intrinsics", "fy"), 0), "intrinsics.fy: expected a positive number"),
    ("cx-string", _set(("intrinsics", "cx"), "319.5"), "intrinsics.cx: expected a number, got str"),
    ("cx-bool", _set(("intrinsics", "cx"), True), "intrinsics.cx: expected a number, got bool"),
    (
        "focal-mm-missing",
        _set(("intrinsics",), {"focal_length_mm": 6.0, "cx": 1.0, "cy": 1.0}),
        r"intrinsics: missing key\(s\) \['pixel_size_um'\]",
    ),
    (
        "pixel-negative",
        _set(
            ("intrinsics",), {"focal_length_mm": 6.0, "pixel_size_um": -2.0, "cx": 1.0, "cy": 1.0}
        ),
        "pixel_size_um: expected a positive number",
    ),
    ("cameras-type", _set(("cameras",), {"cam0": [0, 0, 0]}), "cameras: expected a list"),
    ("camera-key", _set(("cameras", 2, "rotation"), [0, 0, 0]), r"cameras\[2\]: unknown key"),
    (
        "camera-missing",
        _delete("cameras", 1, "center"),
        r"cameras\[1\]: missing key\(s\) \['center'\]",
    ),
    (
        "camera-name",
        _set(("cameras", 0, "name"), ""),
        r"cameras\[0\].name: expected a non-empty string",
    ),
    (
        "center-len",
        _set(("cameras", 0, "center"), [0, 0]),
        r"cameras\[0\].center: expected a list of 3",
    ),
    (
        "center-type",
        _set(("cameras", 0, "center"), [0, "a", 0]),
        r"cameras\[0\].center\[1\]: expected a number",
    ),
    ("duplicate-name", _set(("cameras", 1, "name"), "cam0"), "expected unique names"),
    (
        "one-camera",
        _set(("cameras",), [{"name": "a", "center": [0, 0, 0]}]),
        "at least 2 cameras, got 1",
    ),
    (
        "reference-range",
        _set(("reference",), 9),
        r"reference: expected a camera index in \[0, 8\], got 9",
    ),
    (
        "reference-negative",
        _set(("reference",), -1),
        r"reference: expected a camera index in \[0, 8\]",
    ),
    ("reference-type", _set(("reference",), 4.0), r"reference: expected a camera index .* got 4.0"),
    ("reference-bool", _set(("reference",), True), "reference: expected a camera index"),
    (
        "pair-type",
        _set(("stereo_pair",), "4,5"),
        "stereo_pair: expected a list of two camera indices",
    ),
    (
        "pair-len",
        _set(("stereo_pair",), [4, 5, 6]),
        r"stereo_pair: expected two camera indices in \[0, 8\]",
    ),
    (
        "pair-range",
        _set(("stereo_pair",), [4, 9]),
        r"stereo_pair: expected two camera indices in \[0, 8\]",
    ),
    (
        "pair-not-reference",
        _set(("stereo_pair",), [3, 4]),
        "expected the reference camera 4 first, got",
    ),
    (
        "partner-left",
        _set(("stereo_pair",), [4, 3]),
        r"partner camera 3 to lie to the right .* dx = -0.085 m",
    ),
    (
        "partner-below",
        _set(("stereo_pair",), [4, 8]),
        r"partner camera 8 .* dy = 0\), got dx = 0.085 m, dy = 0.085 m",
    ),
    ("partner-itself", _set(("stereo_pair",), [4, 4]), "partner camera 4 to lie to the right"),
    (
        "not-coplanar",
        _set(("cameras", 0, "center"), _NOT_COPLANAR),
        r"cameras\[0\].center: expected z = 0 m like the reference camera .* got z = 0.01 m",
    ),
    (
        "encoding",
        _set(("image_encoding",), "gamma2.2"),
        r"image_encoding: expected one of \['srgb', 'linear'\], got 'gamma2.2'",
    ),
    ("light-key", _set(("light",), {"pos": [0, 0, 0]}), r"light: unknown key\(s\) \['pos'\]"),
    ("light-missing", _set(("light",), {}), r"light: missing key\(s\) \['position'\]"),
    (
        "light-nan",
        _set(("light",), {"position": [0, float("nan"), 0]}),
        r"light.position\[1\]: expected a finite number",
    ),
]


@pytest.mark.parametrize(
    ("edit", "match"),
    [(e, m) for _, e, m in RIG_JSON_ERRORS],
    ids=[name for name, _, _ in RIG_JSON_ERRORS],
)
def test_rig_json_validation(rig3x3, edit, match):
    data = _edited(rig3x3, edit)
    with pytest.raises(RigError, match=match):
        CameraRig.from_dict(data)
    # The same error through the JSON text.
    with pytest.raises(RigError, match=match):
        CameraRig.from_json(json.dumps(data))


def test_from_dict_not_a_dict():
    with pytest.raises(RigError, match="rig: expected an object, got list"):
        CameraRig.from_dict([1, 2])


def test_from_json_errors(tmp_path):
    with pytest.raises(RigError, match="rig JSON: expected valid JSON"):
        CameraRig.from_json("{not json")
    bad = tmp_path / "rig.json"
    bad.write_text('{"format": ')
    with pytest.raises(RigError, match="rig.json: expected valid JSON"):
        CameraRig.from_json(bad)
    with pytest.raises(RigError, match="expected an existing rig.json"):
        CameraRig.from_json(tmp_path / "missing.json")


# ---------------------------------------------------------------------- direct construction
_K = Intrinsics(100.0, 100.0, 31.5, 23.5)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cameras": (("a", (0, 0, 0)), ("b", (0.1, 0, 0)))}, r"cameras\[0\]: expected a Camera"),
        (
            {"cameras": (Camera(1, (0, 0, 0)), Camera("b", (0.1, 0, 0)))},
            r"cameras\[0\].name: expected a non-empty string, got 1",
        ),
        ({"stereo_pair": 1}, "stereo_pair: expected two camera indices"),
        ({"stereo_pair": (0, True)}, "stereo_pair: expected two camera indices"),
        ({"intrinsics": {"fx": 1}}, "intrinsics: expected an Intrinsics, got dict"),
        ({"image_size": (64.0, 48)}, "two positive integers"),
        ({"light_position_m": (0, 0)}, r"light.position: expected a list of 3 numbers"),
    ],
    ids=["camera-type", "name-type", "pair-int", "pair-bool", "intrinsics", "size", "light"],
)
def test_constructor_validation(kwargs, match):
    args = {
        "image_size": (64, 48),
        "intrinsics": _K,
        "cameras": (Camera("a", (0, 0, 0)), Camera("b", (0.1, 0, 0))),
    }
    args.update(kwargs)
    with pytest.raises(RigError, match=match):
        CameraRig(**args)


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((0, 3, B_M), {"fx": 100.0}, "rows: expected a positive integer, got 0"),
        ((3, 1, B_M), {"fx": 100.0}, "cols: expected at least 2 columns"),
        ((3, True, B_M), {"fx": 100.0}, "cols: expected a positive integer, got True"),
        ((3, 3, -B_M), {"fx": 100.0}, "baseline_m: expected a positive number"),
        ((3, 3, B_M), {}, "fx: expected a focal length in pixels"),
        ((3, 3, B_M), {"fx": 100.0, "focal_length_mm": 8.0, "pixel_size_um": 3.0}, "got both"),
        ((3, 3, B_M), {"focal_length_mm": 8.0}, "expected both focal_length_mm and pixel_size_um"),
        ((3, 3, B_M), {"fx": float("nan")}, "intrinsics.fx: expected a finite number"),
        ((3, 3, B_M), {"fx": 100.0, "image_size": 640}, r"image_size: expected \(width, height\)"),
        (
            (3, 3, B_M),
            {"fx": 100.0, "image_size": ("a", 4)},
            r"image_size: expected \(width, height\)",
        ),
        ((3, 3, B_M), {"fx": 100.0, "image_encoding": "raw"}, "image_encoding: expected one of"),
    ],
    ids=[
        "rows",
        "cols",
        "cols-bool",
        "baseline",
        "no-focal",
        "both-focal",
        "half-focal",
        "nan-fx",
        "size",
        "size-type",
        "encoding",
    ],
)
def test_grid_validation(args, kwargs, match):
    with pytest.raises(RigError, match=match):
        CameraRig.grid(*args, **kwargs)


def test_stereo_validation():
    with pytest.raises(RigError, match="baseline_m: expected a positive number, got 0"):
        CameraRig.stereo(0.0, fx=100.0)
    with pytest.raises(RigError, match="expected unique names"):
        CameraRig.stereo(0.1, fx=100.0, names=("x", "x"))


@pytest.mark.parametrize(("text", "match"), [
    ("[" * 100_000 + "]" * 100_000, "expected JSON nested a few levels deep"),
    ('{"format": ' + "9" * 5000 + "}", "expected valid JSON numbers"),
], ids=["deep", "huge-int"])
def test_hostile_json_is_a_rig_error(tmp_path, text, match):
    (tmp_path / "rig.json").write_text(text)
    with pytest.raises(RigError, match=match):
        CameraRig.from_json(tmp_path / "rig.json")


# ---------------------------------------------------------------------- numbers in range
def _rig_dict(**edits) -> dict:
    data = CameraRig.grid(1, 2, baseline_m=0.1, fx=500.0, image_size=(640, 480)).to_dict()
    for key, value in edits.items():
        section, _, name = key.partition("__")
        if name:
            data[section][name] = value
        else:
            data[section] = value
    return data


@pytest.mark.parametrize("edits, match", [
    (dict(intrinsics__fx=0.0), r"intrinsics.fx: expected a positive number, got 0.0"),
    (dict(intrinsics__fy=-5.0), r"intrinsics.fy: expected a positive number, got -5.0"),
    (dict(intrinsics__fx=1e6), r"intrinsics.fx: expected a focal length in pixels below 1e\+06, "
                               r"got 1e\+06"),
    (dict(intrinsics__fx=1e300), r"intrinsics.fx: expected a focal length .* got 1e\+300"),
    (dict(intrinsics__cx=1e9), r"intrinsics.cx: expected a principal point within 10 image "
                               r"sizes of the 640x480 image \(\[-6400, 7040\] px\), got 1e\+09"),
    (dict(intrinsics__cy=-4801.0), r"intrinsics.cy: expected a principal point .* got -4801"),
    (dict(image_size=[0, 480]), r"image_size: expected \[width, height\] as two positive"),
    (dict(image_size=[20000, 20000]), r"image_size: expected at most 200000000 pixels \(the "
                                      r"image pixel limit\), got 20000x20000 = 400000000"),
    (dict(cameras=[{"name": "cam0", "center": [0.0, 0.0, 0.0]},
                   {"name": "cam1", "center": [1e9, 0.0, 0.0]}]),
     r"cameras\[1\].center: expected a position within 1000 m of the array's origin \(metres, "
     r"not millimetres\), got \[1000000000.0, 0.0, 0.0\]"),
    (dict(cameras=[{"name": "cam0", "center": [0.0, 0.0, 0.0]},
                   {"name": "cam1", "center": [1e-9, 0.0, 0.0]}]),
     r"stereo_pair: expected a baseline of at least 1e-06 m, got 1e-09 m"),
    (dict(light={"position": [0.0, 1e300, 0.0]}),
     r"light.position: expected a position within 1000 m"),
])
def test_rig_numbers_outside_physical_ranges_are_refused(edits, match):
    with pytest.raises(RigError, match=match):
        CameraRig.from_dict(_rig_dict(**edits))


def test_rig_numbers_at_the_edges_of_the_ranges_are_kept():
    rig = CameraRig.from_dict(_rig_dict(intrinsics__fx=999_999.0, intrinsics__cx=-6400.0,
                                        image_size=[20000, 10000],
                                        light={"position": [0.0, -999.0, 0.0]}))
    assert rig.intrinsics.fx == 999_999.0 and rig.image_size == (20000, 10000)


def test_a_light_out_of_range_given_in_code_is_a_light_error():
    rig = CameraRig.grid(1, 2, baseline_m=0.1, fx=500.0)
    with pytest.raises(LightError, match=r"light_position_m: expected a position within 1000 m"):
        rig.with_light([1e4, 0.0, 0.0])
    with pytest.raises(LightError, match=r"light.position: expected a position within 1000 m"):
        CameraRig.grid(1, 2, baseline_m=0.1, fx=500.0, light_position_m=[0.0, 0.0, -2e3])


def test_rig_scaled_far_beyond_the_focal_limit_is_refused():
    rig = CameraRig.grid(1, 2, baseline_m=0.1, fx=500.0)
    with pytest.raises(RigError, match="expected a focal length in pixels below"):
        rig.scaled(1e4)
