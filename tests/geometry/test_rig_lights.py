"""Several known lights in the rig: rig.json forms, round trips, the single-light API."""

from __future__ import annotations

import json

import numpy as np
import pytest

from srde_fusion.errors import LightError, RigError
from srde_fusion.geometry import CameraRig, RigLight

_OLD_RIG_JSON = """{
  "format": "srde-rig/1",
  "image_size": [640, 480],
  "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5},
  "cameras": [{"name": "left", "center": [0.0, 0.0, 0.0]},
              {"name": "right", "center": [0.1, 0.0, 0.0]}],
  "reference": 0,
  "stereo_pair": [0, 1],
  "light": {"position": [0.1, -0.4, 0.2]}
}"""


@pytest.fixture
def stereo() -> CameraRig:
    return CameraRig.stereo(0.1, fx=600.0, image_size=(640, 480))


def test_an_old_single_light_file_reads_as_one_light_and_writes_back_byte_identical(tmp_path):
    rig = CameraRig.from_json(_OLD_RIG_JSON)
    assert rig.light_position_m == (0.1, -0.4, 0.2)
    assert rig.lights == (RigLight((0.1, -0.4, 0.2)),)
    np.testing.assert_array_equal(rig.light, [0.1, -0.4, 0.2])
    written = rig.to_json(tmp_path / "rig.json")
    assert json.loads(written)["light"] == {"position": [0.1, -0.4, 0.2]}
    again = CameraRig.from_json(tmp_path / "rig.json")
    assert again == rig
    assert again.to_json() == written
    assert (tmp_path / "rig.json").read_text() == written


def test_a_position_alone_and_one_point_light_are_the_same_rig(stereo):
    a = stereo.with_light((0.3, -0.2, 0.1))
    b = stereo.with_lights([RigLight((0.3, -0.2, 0.1))])
    c = CameraRig.stereo(0.1, fx=600.0, light_position_m=(0.3, -0.2, 0.1))
    assert a == b == c
    assert a.to_json() == b.to_json() == c.to_json()


def test_several_lights_round_trip_with_radius_and_name(stereo, tmp_path):
    lights = (RigLight((0.3, -0.2, 0.1), radius_m=0.005, name="right lamp"),
              RigLight((-0.3, -0.2, 0.1)),
              RigLight((0.0, -0.5, 0.0), radius_m=0.0))
    rig = stereo.with_lights(lights)
    assert rig.lights == lights and rig.light_position_m == (0.3, -0.2, 0.1)
    np.testing.assert_array_equal(rig.light_positions_m, [lt.position_m for lt in lights])
    data = json.loads(rig.to_json(tmp_path / "rig.json"))
    assert data["light"] == [
        {"position": [0.3, -0.2, 0.1], "radius_m": 0.005, "name": "right lamp"},
        {"position": [-0.3, -0.2, 0.1]},
        {"position": [0.0, -0.5, 0.0], "radius_m": 0.0},
    ]
    again = CameraRig.from_json(tmp_path / "rig.json")
    assert again == rig and again.lights == lights
    # Derived rigs keep the lights.
    assert rig.scaled(0.5).lights == lights and rig.subset([0, 1]).lights == lights


def test_one_light_with_a_radius_is_the_single_object_form(stereo):
    rig = stereo.with_lights([RigLight((0.3, -0.2, 0.1), radius_m=0.01)])
    assert json.loads(rig.to_json())["light"] == {"position": [0.3, -0.2, 0.1], "radius_m": 0.01}
    assert CameraRig.from_json(rig.to_json()).lights[0].radius_m == 0.01


def test_with_light_replaces_every_light_and_none_removes_them(stereo):
    rig = stereo.with_lights([(0.3, -0.2, 0.1), (-0.3, -0.2, 0.1)])
    one = rig.with_light((0.0, -0.4, 0.0))
    assert one.lights == (RigLight((0.0, -0.4, 0.0)),)
    dark = rig.with_light(None)
    assert dark.lights == () and dark.light is None and dark == stereo
    assert stereo.with_lights([]) == stereo
    assert stereo.light_positions_m.shape == (0, 3)


def _with_light_entry(value):
    data = json.loads(_OLD_RIG_JSON)
    data["light"] = value
    return data


RIG_JSON_LIGHT_ERRORS = [
    ("empty-list", [], r"light: expected one light object or a non-empty list of them"),
    ("not-object", "lamp", r"light: expected an object \{position, radius_m\?, name\?\} or a "
                           r"list of them, got str"),
    ("entry-not-object", [{"position": [0, -1, 0]}, 3], r"light\[1\]: expected an object"),
    ("unknown-key", [{"position": [0, -1, 0]}, {"position": [1, -1, 0], "radius": 1}],
     r"light\[1\]: unknown key\(s\) \['radius'\]"),
    ("missing-position", [{"radius_m": 0.01}], r"light\[0\]: missing key\(s\) \['position'\]"),
    ("radius-mm", {"position": [0, -1, 0], "radius_m": 5.0},
     r"light.radius_m: expected a radius in \[0, 1\] m \(metres, not millimetres\), got 5"),
    ("radius-negative", [{"position": [0, -1, 0], "radius_m": -0.001}],
     r"light\[0\].radius_m: expected a radius in \[0, 1\] m"),
    ("radius-nan", [{"position": [0, -1, 0], "radius_m": float("nan")}],
     r"light\[0\].radius_m: expected a finite number"),
    ("radius-text", [{"position": [0, -1, 0], "radius_m": "5mm"}],
     r"light\[0\].radius_m: expected a number, got str"),
    ("radius-bool", [{"position": [0, -1, 0], "radius_m": True}],
     r"light\[0\].radius_m: expected a number, got bool"),
    ("name-empty", [{"position": [0, -1, 0], "name": " "}],
     r"light\[0\].name: expected a non-empty string"),
    ("name-number", [{"position": [0, -1, 0], "name": 7}],
     r"light\[0\].name: expected a non-empty string .* got 7"),
    ("name-long", [{"position": [0, -1, 0], "name": "x" * 500}],
     r"light\[0\].name: expected a non-empty string of at most 128 characters"),
    ("names-twice", [{"position": [0, -1, 0], "name": "a"}, {"position": [1, -1, 0], "name": "a"}],
     r"light names: expected unique names, got \['a', 'a'\]"),
    ("same-place", [{"position": [0, -1, 0]}, {"position": [0, -1, 0.0005]}],
     r"light\[1\].position: expected a light at least 1 mm from every other, got 0.5 mm from "
     r"light\[0\]"),
    ("far", [{"position": [0, -1, 0]}, {"position": [0, -1e4, 0]}],
     r"light\[1\].position: expected a position within 1000 m"),
    ("position-short", [{"position": [0, -1]}],
     r"light\[0\].position: expected a list of 3 numbers"),
    ("too-many", [{"position": [i, -1, 0]} for i in range(17)],
     r"light: expected at most 16 lights, got 17"),
]


@pytest.mark.parametrize(("value", "match"), [(v, m) for _, v, m in RIG_JSON_LIGHT_ERRORS],
                         ids=[name for name, _, _ in RIG_JSON_LIGHT_ERRORS])
def test_hostile_light_entries_are_refused_with_the_field_named(value, match, tmp_path):
    data = _with_light_entry(value)
    with pytest.raises(RigError, match=match):
        CameraRig.from_dict(data)
    # From a file, the message names the file first.
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RigError, match=rf"^{path}: .*") as info:
        CameraRig.from_json(path)
    assert info.match(match)


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(radius_m=-1.0), r"light.radius_m: expected a radius in \[0, 1\] m"),
    (dict(radius_m=2.0), r"light.radius_m: expected a radius in \[0, 1\] m"),
    (dict(name=""), r"light.name: expected a non-empty string"),
    (dict(name=3), r"light.name: expected a non-empty string"),
])
def test_a_rig_light_built_in_code_is_checked(kwargs, match):
    with pytest.raises(LightError, match=match):
        RigLight((0.0, -1.0, 0.0), **kwargs)


def test_lights_given_in_code_are_checked(stereo):
    with pytest.raises(LightError, match=r"lights: expected a sequence of RigLight"):
        stereo.with_lights(3.0)
    with pytest.raises(LightError, match=r"got 0 mm from light\[0\]"):
        stereo.with_lights([(0.0, -1.0, 0.0), (0.0, -1.0, 0.0)])
    with pytest.raises(LightError, match=r"lights\[1\]: expected a position within 1000 m"):
        stereo.with_lights([(0.0, -1.0, 0.0), (0.0, -1e4, 0.0)])
    with pytest.raises(LightError, match=r"light_position_m: expected the first light's "
                                         r"position \[0.0, -1.0, 0.0\] \(or None\)"):
        CameraRig(stereo.image_size, stereo.intrinsics, stereo.cameras, 0, (0, 1), "srgb",
                  (0.5, -1.0, 0.0), (RigLight((0.0, -1.0, 0.0)),))
    with pytest.raises(LightError, match=r"lights\[0\]: expected a RigLight, got tuple"):
        CameraRig(stereo.image_size, stereo.intrinsics, stereo.cameras, lights=((0, 0, 1),))
