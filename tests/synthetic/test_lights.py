"""Several lights in the renderer: scene checks, where each highlight lands, ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from srde_fusion import CameraRig, LightError, SceneError
from srde_fusion.calibration import Board
from srde_fusion.imaging import luminance, srgb_to_linear
from srde_fusion.srde import detect_highlight
from srde_fusion.synthetic import (
    Light,
    Material,
    Physics,
    PlanarObject,
    Scene,
    highlights_on_objects,
    plate_scene,
    random_scene,
    render,
    render_dataset,
    rig_lights,
    scene_from_dict,
    scene_to_dict,
)
from tests.support import run_cli

# Tolerances (one table).
#: A rendered highlight's detected centre against the projected virtual light: the lobe's
#: peak sits at the mirror direction; cosine and distance falloff move its centroid by a
#: few tenths of a pixel at this roughness.
CENTER_TOL_PX = 0.5
#: Linear radiance of two lights against the sum of each alone: each of the four 8-bit
#: images is off by up to half a code value (in linear units, at its own level), plus
#: float32 round-off.
ROUNDOFF = 1e-5


@pytest.fixture(scope="module")
def rig():
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=400.0, image_size=(320, 240))


def _plate(roughness=0.01):
    return PlanarObject("rectangle", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.2, 0.9),
                        material=Material(diffuse_rgb=(0.2, 0.2, 0.2), roughness=roughness))


# Two lights beside the array, each mirrored into the big plate in every view.
_LIGHTS = (Light((0.3, -0.25, 0.0), radius_m=0.0, intensity=1.0),
           Light((-0.25, 0.2, 0.05), radius_m=0.0, intensity=1.0))


# ---------------------------------------------------------------------- the scene
def test_a_scene_takes_a_light_or_lights_and_keeps_the_first_as_light():
    a = Scene((_plate(),), _LIGHTS[0])
    assert a.lights == (_LIGHTS[0],)
    b = Scene((_plate(),), lights=_LIGHTS)
    assert b.light == _LIGHTS[0] and b.lights == _LIGHTS
    assert Scene((_plate(),), _LIGHTS[0], lights=list(_LIGHTS)) == b
    assert scene_from_dict(json.loads(json.dumps(scene_to_dict(b)))) == b
    assert "lights" not in scene_to_dict(a)  # the single-light description is unchanged


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(), r"light: expected a Light, got NoneType"),
    (dict(light=_LIGHTS[1], lights=_LIGHTS), r"light: expected the first of lights"),
    (dict(lights=(_LIGHTS[0], (0, 0, 0))), r"lights\[1\]: expected a Light, got tuple"),
    (dict(lights=_LIGHTS * 9), r"lights: expected a sequence of at most 16 Light"),
    (dict(lights="lamp"), r"lights: expected a sequence"),
])
def test_scene_lights_are_checked(kwargs, match):
    with pytest.raises(LightError, match=match):
        Scene((_plate(),), **kwargs)


# ---------------------------------------------------------------------- rendering
@pytest.mark.parametrize("physics", [None, Physics(fresnel="exact", light="sampled",
                                                   light_samples=16,
                                                   masking="height_correlated",
                                                   diffuse_transmittance=True)],
                         ids=["model", "faithful-without-noise"])
def test_each_light_adds_its_own_light_and_the_ambient_counts_once(rig, physics):
    lights = (Light((0.3, -0.25, 0.0), radius_m=0.01), Light((-0.25, 0.2, 0.05), radius_m=0.0))
    common = dict(ambient=0.2, exposure=0.3)
    both = render(Scene((_plate(0.03),), lights=lights, **common), rig, physics=physics)
    each = [render(Scene((_plate(0.03),), light, **common), rig, physics=physics)
            for light in lights]
    # Ambient alone: a light too faint to register (a light behind the plate would leave
    # the plate unlit, which the renderer treats as uncoated for the ambient term).
    dark = render(Scene((_plate(0.03),), Light((0.3, -0.25, 0.0), intensity=1e-12), **common),
                  rig, physics=physics)
    def linear(code):
        return srgb_to_linear(code.astype(np.float32) / 255.0)

    for view in (0, 4, 8):
        codes = [r.views[view] for r in (both, *each, dark)]
        lin = [linear(c) for c in codes]
        half_step = sum(0.5 * (linear(np.minimum(c.astype(np.int32) + 1, 255)) - linear(c))
                        for c in codes)
        unclipped = np.all([c < 255 for c in codes[:3]], axis=0)
        assert unclipped.mean() > 0.95
        error = np.abs(lin[0] - (lin[1] + lin[2] - lin[3]))
        assert np.all(error[unclipped] <= half_step[unclipped] + ROUNDOFF)
        # The ambient term is seen (and would show if it were counted twice).
        assert lin[3].mean() > 3 * half_step.mean()


def test_each_lights_highlight_is_where_its_virtual_light_projects(rig):
    out = render(Scene((_plate(),), lights=_LIGHTS, exposure=0.5), rig)
    assert out.n_lights == 2
    assert out.virtual_lights_by_light_m.shape == (2, 1, 3)
    assert out.highlight_uv_by_light.shape == (2, 1, 9, 2)
    assert out.highlight_on_object.all()
    np.testing.assert_array_equal(out.highlight_uv, out.highlight_uv_by_light[0])
    np.testing.assert_array_equal(out.virtual_lights_m, out.virtual_lights_by_light_m[0])
    # Each virtual light is its light mirrored in the plane z = 1.
    for light, virtual in zip(_LIGHTS, out.virtual_lights_by_light_m[:, 0], strict=True):
        np.testing.assert_allclose(virtual, np.array(light.position_m) * [1, 1, -1] + [0, 0, 2])
    h, w = out.views[0].shape[:2]
    vv, uu = np.mgrid[0:h, 0:w]
    for view in range(9):
        for light in range(2):
            u, v = out.highlight_uv_by_light[light, 0, view]
            disc = (uu - u) ** 2 + (vv - v) ** 2 < 12 ** 2
            det = detect_highlight(out.views[view], disc)
            assert det.found, det.reason
            assert np.hypot(*(det.center_uv - (u, v))) < CENTER_TOL_PX
        # The two highlights are the two brightest places of the view.
        lum = luminance(out.views[view])
        for light in range(2):
            u, v = np.rint(out.highlight_uv_by_light[light, 0, view]).astype(int)
            assert lum[v, u] > np.percentile(lum, 99)


def test_a_sphere_light_draws_a_wider_highlight_than_a_point(rig):
    lights = (Light((0.3, -0.25, 0.0), radius_m=0.0), Light((-0.25, 0.2, 0.05), radius_m=0.03))
    for physics in (None, Physics(light="sampled", light_samples=32)):
        # Exposed so that neither highlight clips (a clipped point looks wide too).
        out = render(Scene((_plate(0.004),), lights=lights, exposure=0.002), rig,
                     physics=physics)
        lum = luminance(out.views[4])
        h, w = lum.shape
        vv, uu = np.mgrid[0:h, 0:w]
        areas = []
        for light in range(2):
            u, v = out.highlight_uv_by_light[light, 0, 4]
            disc = (uu - u) ** 2 + (vv - v) ** 2 < 20 ** 2
            peak = lum[disc].max()
            areas.append(int(np.sum(disc & (lum > 0.5 * (peak + np.median(lum))))))
        assert lum.max() < 1.0
        assert areas[1] > 4 * areas[0]


def test_highlights_off_the_object_or_hidden_are_marked(rig):
    small = PlanarObject("rectangle", (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.2, 0.2))
    # The first light's highlight lands on the small plate, the second's far beside it.
    lights = (Light((0.05, 0.0, 0.0)), Light((0.9, 0.0, 0.0)))
    seen = highlights_on_objects(Scene((small,), lights=lights), rig)
    assert seen[0, 0].all() and not seen[1, 0].any()
    # A plate in front, covering the right half of the view, hides part of it.
    blocker = PlanarObject("rectangle", (0.2, 0.0, 0.5), (0.0, 0.0, -1.0), (0.4, 0.6))
    seen = highlights_on_objects(Scene((small, blocker), lights=lights), rig)
    assert not seen[0, 0].all()
    # A light behind the plane puts no highlight on it.
    behind = highlights_on_objects(Scene((small,), Light((0.0, 0.0, 2.0))), rig)
    assert not behind.any()


# ---------------------------------------------------------------------- random scenes
def test_random_scenes_place_several_lights(rig):
    one = random_scene(5, rig)
    assert random_scene(5, rig, n_lights=1) == one  # the default is one light, as before
    counts = set()
    for seed in range(6):
        scene = random_scene(seed, rig, n_lights=(2, 4))
        assert scene == random_scene(seed, rig, n_lights=(2, 4))
        counts.add(len(scene.lights))
        positions = np.array([lt.position_m for lt in scene.lights])
        gaps = np.linalg.norm(positions[:, None] - positions[None], axis=2)
        assert gaps[np.triu_indices(len(positions), 1)].min() >= 0.1
        seen = render(scene, rig.with_lights(rig_lights(scene))).highlight_on_object
        assert seen[0].all()  # the first light's highlight is always on every object
    assert counts <= {2, 3, 4} and len(counts) > 1


def test_random_scenes_can_require_every_highlight_on_every_object(rig):
    scene = random_scene(2, rig, n_lights=3, n_objects=2, all_highlights_on_objects=True)
    assert len(scene.lights) == 3
    assert highlights_on_objects(scene, rig).all()


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(n_lights=0), r"n_lights: expected an integer in \[1, 16\]"),
    (dict(n_lights=(3, 2)), r"n_lights: expected an integer in \[1, 16\] or \(min, max\)"),
    (dict(n_lights=(1, 2, 3)), r"n_lights: expected"),
    (dict(n_lights=2.5), r"n_lights: expected"),
    (dict(all_highlights_on_objects="yes"), r"all_highlights_on_objects: expected a bool"),
    (dict(light_spacing_m=(0.3, 0.1)), r"light_spacing_m: expected min <= max"),
])
def test_random_scene_light_options_are_checked(rig, kwargs, match):
    with pytest.raises(SceneError, match=match):
        random_scene(0, rig, **kwargs)


def test_a_dataset_with_several_lights_writes_them_all(tmp_path, rig):
    folders = render_dataset(tmp_path / "data", n_scenes=1, seed=1, rig=rig, n_lights=2,
                             progress=False)
    written = CameraRig.from_json(folders[0] / "rig.json")
    meta = json.loads((folders[0] / "scene.json").read_text())
    scene = scene_from_dict(meta["scene"])
    assert [lt.position_m for lt in written.lights] == [lt.position_m for lt in scene.lights]
    truth = meta["lights_ground_truth"]
    assert np.array(truth["virtual_lights_m"]).shape == (2, 1, 3)
    assert np.array(truth["highlight_uv"]).shape == (2, 1, 9, 2)
    assert np.array(truth["highlight_on_object"]).shape == (2, 1, 9)


# ---------------------------------------------------------------------- plates
def test_a_plate_lit_by_two_lights_shows_two_highlights(rig):
    board = Board.corner_layout()
    lights = [(0.25, -0.3, 0.0), (0.1, -0.35, 0.05)]
    scene = plate_scene(board, rig, lights, center_m=(0.0, 0.0, 0.6))
    assert len(scene.lights) == 2
    out = render(scene, rig)
    assert out.highlight_on_object.all()
    lum = luminance(out.views[4])
    for light in range(2):
        u, v = np.rint(out.highlight_uv_by_light[light, 0, 4]).astype(int)
        assert lum[v, u] > 0.9 * lum.max()
    with pytest.raises(LightError, match=r"light_position_m\[1\]: expected"):
        plate_scene(board, rig, [(0.25, -0.3, 0.0), (0.1, -0.35, np.nan)],
                    center_m=(0.0, 0.0, 0.6))


def test_render_command_places_several_lights(tmp_path, capsys):
    small = CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, image_size=(320, 240))
    small.to_json(tmp_path / "rig.json")
    code, out, _ = run_cli(capsys, "render", tmp_path / "data", "--scenes", "1", "--lights",
                           "2", "3", "--all-highlights", "--rig", tmp_path / "rig.json",
                           "--quiet")
    assert code == 0, out
    written = CameraRig.from_json(tmp_path / "data" / "scene_0000" / "rig.json")
    assert 2 <= len(written.lights) <= 3
    meta = json.loads((tmp_path / "data" / "scene_0000" / "scene.json").read_text())
    assert np.all(meta["lights_ground_truth"]["highlight_on_object"])
    code, _, err = run_cli(capsys, "render", tmp_path / "bad", "--scenes", "1", "--lights",
                           "1", "2", "3", "--quiet")
    assert code != 0 and "n_lights: expected" in err
