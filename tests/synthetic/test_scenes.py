import json
from dataclasses import replace

import numpy as np
import pytest

from srde_fusion import CameraRig, LightError, RigError, SceneError, SRDEError
from srde_fusion.geometry import plane_disparity
from srde_fusion.imaging import luminance
from srde_fusion.synthetic import (
    Light,
    Material,
    PlanarObject,
    RandomSceneConfig,
    Scene,
    random_scene,
    relit,
    render,
    scene_from_dict,
    scene_to_dict,
)

# Tolerances (one table): float32 ground truth against float64 geometry.
DISPARITY_RTOL = 1e-5
HIGHLIGHT_TOL_PX = 1.0


@pytest.fixture(scope="module")
def rig():
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, fy=600.0, image_size=(640, 480))


@pytest.fixture(scope="module")
def small_rig():
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=300.0, fy=300.0, image_size=(320, 240))


def _tilted_plate(**kw):
    defaults = dict(
        shape="rectangle",
        center_m=(0.05, -0.03, 1.0),
        normal=(0.15, 0.1, -1.0),
        size_m=(0.4, 0.3),
        rotation_rad=0.3,
    )
    defaults.update(kw)
    return PlanarObject(**defaults)


def _light_reflected_at(obj, local_m=(0.0, 0.0), distance_m=1.0):
    """A light whose mirror point for the reference camera (origin) is at ``local_m``."""
    point = obj.to_world(np.asarray(local_m))
    n = np.asarray(obj.normal)
    view = -point / np.linalg.norm(point)
    reflected = 2.0 * (n @ view) * n - view
    return tuple(point + distance_m * reflected)


def _mirror_point(obj, light_m, center_m):
    """Where the line from a camera centre to the virtual light crosses the plane."""
    n = np.asarray(obj.normal)
    c = float(n @ np.asarray(obj.center_m))
    virtual = light_m - 2.0 * (light_m @ n - c) * n
    s = (c - center_m @ n) / ((virtual - center_m) @ n)
    return center_m + s * (virtual - center_m)


def test_points_on_the_object_project_into_its_mask(small_rig):
    rng = np.random.default_rng(0)
    objects = (
        _tilted_plate(),
        PlanarObject("ellipse", (-0.3, 0.15, 0.8), (-0.1, 0.05, -1.0), (0.15, 0.1), 0.5),
        PlanarObject(
            "polygon",
            (0.35, 0.2, 1.2),
            (0.0, -0.2, -1.0),
            (0.2, 0.2),
            0.0,
            vertices_m=((0.1, 0.0), (0.03, 0.09), (-0.08, 0.06), (-0.08, -0.06), (0.03, -0.09)),
        ),
    )
    scene = Scene(objects, Light((0.4, -0.3, -0.1)))
    out = render(scene, small_rig)
    for k, obj in enumerate(objects, start=1):
        local = rng.uniform(-0.5, 0.5, size=(400, 2)) * obj.size_m
        # Keep points at least ~2 px from the outline so rounding cannot cross an edge.
        keep = obj.inner_distance_m(local) > 0.01
        points = obj.to_world(local[keep])
        assert np.all(obj.contains(points))
        uv = np.rint(small_rig.project(points)).astype(int)
        assert np.all(out.instance_mask[uv[:, 1], uv[:, 0]] == k)
    # Points just outside an outline are not that object.
    obj = objects[1]
    outside = obj.to_world(np.array([[0.09, 0.0], [0.0, -0.065]]))
    uv = np.rint(small_rig.project(outside)).astype(int)
    assert np.all(out.instance_mask[uv[:, 1], uv[:, 0]] != 2)


@pytest.mark.parametrize(
    "obj, depth_at_center",
    [
        (PlanarObject("rectangle", (0, 0, 1), (0, 0, -1), (0.4, 0.2)), 0.1),
        (PlanarObject("ellipse", (0, 0, 1), (0, 0, -1), (0.4, 0.2)), 0.1),
        (
            PlanarObject(
                "triangle",
                (0, 0, 1),
                (0, 0, -1),
                (0.2, 0.2),
                vertices_m=((0, 0.1), (0.1, -0.1), (-0.1, -0.1)),
            ),
            0.2 / (1 + 5**0.5),
        ),
    ],
)
def test_inner_distance(obj, depth_at_center):
    if obj.shape == "triangle":
        inner = obj.inner_distance_m(np.array([0.0, -0.1 + depth_at_center]))
        assert inner == pytest.approx(depth_at_center)
    else:
        assert obj.inner_distance_m(np.zeros(2)) == pytest.approx(depth_at_center, rel=1e-3)
    assert obj.inner_distance_m(np.array([0.5, 0.5])) < 0


def test_object_appears_where_projected_in_every_view(small_rig):
    obj = _tilted_plate(material=Material(diffuse_rgb=(0.8, 0.8, 0.8), specular=0.0))
    scene = Scene((obj,), Light((0.5, 0.0, 0.0)), ambient=0.5)
    out = render(scene, small_rig)
    inner = obj.to_world(np.array([[0.15, 0.1], [-0.15, -0.1], [0.1, -0.1]]))
    outer = obj.to_world(np.array([[0.26, 0.0], [0.0, 0.2]]))
    for cam, view in enumerate(out.views):
        grey = luminance(view)
        uv_in = np.rint(small_rig.project(inner, camera=cam)).astype(int)
        uv_out = np.rint(small_rig.project(outer, camera=cam)).astype(int)
        assert np.all(grey[uv_in[:, 1], uv_in[:, 0]] > 0.2)
        assert np.all(grey[uv_out[:, 1], uv_out[:, 0]] < 0.01)


def test_disparity_is_the_analytic_plane_disparity(rig):
    obj = _tilted_plate()
    out = render(Scene((obj,), Light((0.3, -0.3, 0.0))), rig)
    mask = out.instance_mask == 1
    assert mask.sum() > 10_000
    expected = plane_disparity(obj.plane, rig)
    np.testing.assert_allclose(out.disparity_px[mask], expected[mask], rtol=DISPARITY_RTOL)
    np.testing.assert_allclose(
        out.depth_m[mask], rig.disparity_to_depth(expected)[mask], rtol=DISPARITY_RTOL
    )
    # Background at infinity: zero disparity, infinite depth.
    assert np.all(out.disparity_px[~mask] == 0)
    assert np.all(np.isinf(out.depth_m[~mask]))
    assert out.disparity_px.dtype == np.float32 and out.instance_mask.dtype == np.int32


def test_virtual_light_is_the_mirrored_light_and_projects_to_highlight_uv(rig):
    obj = _tilted_plate()
    light = np.array([0.3, -0.3, 0.05])
    out = render(Scene((obj,), Light(tuple(light))), rig)
    n = np.asarray(obj.normal)
    d = light @ n - n @ np.asarray(obj.center_m)
    virtual = light - 2 * d * n
    np.testing.assert_allclose(out.virtual_lights_m[0], virtual, atol=1e-12)
    # Equidistant from the plane, on the other side.
    assert out.planes[0].signed_distance(virtual) == pytest.approx(-d)
    assert out.highlight_uv.shape == (1, rig.n_cameras, 2)
    for cam in range(rig.n_cameras):
        np.testing.assert_allclose(out.highlight_uv[0, cam], rig.project(virtual, camera=cam))
        # The virtual light and the mirror point lie on one ray.
        mirror = _mirror_point(obj, light, rig.centers_m[cam])
        np.testing.assert_allclose(
            rig.project(mirror, camera=cam), out.highlight_uv[0, cam], atol=1e-9
        )


def _peak_position(view):
    grey = luminance(view)
    top = grey >= grey.max() - 1e-6
    rows, cols = np.nonzero(top)
    return np.array([cols.mean(), rows.mean()]), grey.max()


@pytest.mark.parametrize("lobe", ["ggx", "blinn_phong"])
def test_brightest_pixel_is_the_projected_virtual_light(rig, lobe):
    mat = Material(diffuse_rgb=(0.2, 0.2, 0.2), roughness=0.01, lobe=lobe, f0=0.04)
    obj = _tilted_plate(material=mat)
    light = Light(_light_reflected_at(obj, (0.03, -0.02)), radius_m=0.002)
    # A first render finds the exposure that keeps the peak below clipping.
    probe = render(Scene((obj,), light, exposure=1e-3), rig)
    _, peak = _peak_position(probe.views[rig.reference])
    scene = Scene((obj,), light, exposure=1e-3 * 0.8 / peak)
    out = render(scene, rig)
    for cam, view in enumerate(out.views):
        where, value = _peak_position(view)
        assert value < 0.99, "highlight must not clip in this test"
        assert np.linalg.norm(where - out.highlight_uv[0, cam]) <= HIGHLIGHT_TOL_PX, cam


def test_lobes_differ_in_shape(small_rig):
    light = Light(_light_reflected_at(_tilted_plate()), radius_m=0.0)
    views = {}
    for lobe in ("ggx", "blinn_phong"):
        obj = _tilted_plate(material=Material(roughness=0.03, lobe=lobe))
        views[lobe] = luminance(render(Scene((obj,), light, exposure=0.05), small_rig).views[4])
    assert np.abs(views["ggx"] - views["blinn_phong"]).max() > 0.01


def test_light_radius_widens_and_dims_the_highlight_keeping_its_energy(small_rig):
    obj = _tilted_plate(material=Material(diffuse_rgb=(0.0, 0.0, 0.0), roughness=0.01))
    peaks, areas, energies = [], [], []
    for radius in (0.0, 0.03):
        light = Light(_light_reflected_at(obj), radius_m=radius)
        out = render(Scene((obj,), light, ambient=0.0, exposure=0.02), small_rig)
        grey = luminance(out.views[small_rig.reference])
        assert grey.max() < 0.99  # nothing clips, so sums are energies
        peaks.append(grey.max())
        areas.append(int((grey > 0.5 * grey.max()).sum()))
        energies.append(grey.sum())
    assert peaks[1] < 0.8 * peaks[0]
    assert areas[1] > 1.2 * areas[0]
    # Widening redistributes the lobe; 8-bit quantisation of the dim tail costs a little.
    assert energies[1] == pytest.approx(energies[0], rel=0.05)


def test_nearest_object_wins(small_rig):
    back = PlanarObject("rectangle", (0.0, 0.0, 1.5), (0.0, 0.0, -1.0), (0.6, 0.6))
    front = PlanarObject("ellipse", (0.0, 0.0, 0.8), (0.0, 0.0, -1.0), (0.1, 0.1))
    for order in ((back, front), (front, back)):
        out = render(Scene(order, Light((0.5, 0.0, 0.0))), small_rig)
        centre = (small_rig.height // 2, small_rig.width // 2)
        assert out.instance_mask[centre] == order.index(front) + 1
        assert out.depth_m[centre] == pytest.approx(0.8)
        assert out.instance_mask[centre[0], centre[1] + 40] == order.index(back) + 1


def test_texture_orientation_row0_is_top_col0_is_left(small_rig):
    texture = np.array([[0.0, 1.0], [1.0, 0.0]])  # dark top-left and bottom-right
    plate = PlanarObject(
        "rectangle",
        (0.0, 0.0, 1.0),
        (0.0, 0.0, -1.0),
        (0.4, 0.4),
        material=Material(diffuse_rgb=(1.0, 1.0, 1.0), specular=0.0),
        texture=texture,
    )
    out = render(Scene((plate,), Light((0.5, 0.0, -0.1)), ambient=0.3), small_rig)
    grey = luminance(out.views[small_rig.reference])
    uv = np.rint(
        small_rig.project(
            plate.to_world(np.array([[-0.1, -0.1], [0.1, -0.1], [-0.1, 0.1], [0.1, 0.1]]))
        )
    ).astype(int)
    tl, tr, bl, br = grey[uv[:, 1], uv[:, 0]]
    assert tl < 0.01 and br < 0.01
    assert tr > 0.1 and bl > 0.1


def test_fine_texture_is_filtered_not_aliased(small_rig):
    # One-texel checkerboard, ~10 texels per pixel: the image must show its mean, grey.
    checker = (np.indices((1024, 1024)).sum(axis=0) % 2).astype(np.float32)
    plate = PlanarObject(
        "rectangle",
        (0.0, 0.0, 1.0),
        (0.1, 0.0, -1.0),
        (0.3, 0.3),
        material=Material(diffuse_rgb=(1.0, 1.0, 1.0), specular=0.0),
        texture=checker,
    )
    half = PlanarObject(
        "rectangle",
        (0.0, 0.0, 1.0),
        (0.1, 0.0, -1.0),
        (0.3, 0.3),
        material=Material(diffuse_rgb=(0.5, 0.5, 0.5), specular=0.0),
    )
    light = Light((0.5, 0.0, -0.1))
    textured = luminance(render(Scene((plate,), light, ambient=0.3), small_rig).views[4])
    uniform = luminance(render(Scene((half,), light, ambient=0.3), small_rig).views[4])
    inner = np.zeros(textured.shape, dtype=bool)
    inner[100:140, 140:180] = True
    assert np.abs(textured[inner] - uniform[inner]).max() < 0.03


def test_textured_background_has_ground_truth_and_is_view_consistent(small_rig):
    obj = _tilted_plate()
    scene = Scene(
        (obj,),
        Light((0.3, -0.3, 0.0)),
        background="textured",
        background_seed=5,
        ambient=0.3,
        exposure=0.5,
    )
    out = render(scene, small_rig)
    assert np.all(np.isfinite(out.depth_m)) and np.all(out.disparity_px > 0)
    background = out.instance_mask == 0
    # The background never hides the object.
    bare = render(replace(scene, background="none"), small_rig)
    np.testing.assert_array_equal(out.instance_mask, bare.instance_mask)
    # A background point has the same colour in the partner view (world-anchored texture).
    rows, cols = np.nonzero(background)
    pick = np.random.default_rng(1).choice(rows.size, 300, replace=False)
    uv = np.column_stack([cols[pick], rows[pick]]).astype(float)
    points = small_rig.backproject(uv, out.depth_m[rows[pick], cols[pick]])
    partner = small_rig.stereo_pair[1]
    uv2 = small_rig.project(points, camera=partner)
    # The partner pixel is exactly d px to the left on the same row.
    np.testing.assert_allclose(
        uv[:, 0] - uv2[:, 0], out.disparity_px[rows[pick], cols[pick]], rtol=1e-5
    )
    ref = out.views[small_rig.reference].astype(float)
    other = out.views[partner].astype(float)
    inside = (uv2[:, 0] >= 0) & (uv2[:, 0] <= small_rig.width - 1)
    # Exact correspondences only where the partner pixel lands on a pixel centre.
    x = uv2[inside, 0]
    left = np.floor(x).astype(int)
    right = np.minimum(left + 1, small_rig.width - 1)
    f = (x - left)[:, None]
    r = rows[pick][inside]
    interp = (1 - f) * other[r, left] + f * other[r, right]
    diff = np.abs(interp - ref[r, cols[pick][inside]]).mean(axis=1)
    assert np.median(diff) < 6.0
    # Different seed, different background.
    other_scene = render(
        Scene(
            (obj,),
            Light((0.3, -0.3, 0.0)),
            background="textured",
            background_seed=6,
            ambient=0.3,
            exposure=0.5,
        ),
        small_rig,
    )
    assert not np.array_equal(other_scene.views[0], out.views[0])


def test_supersampling_smooths_edges_but_keeps_ground_truth(small_rig):
    obj = _tilted_plate(material=Material(diffuse_rgb=(0.8, 0.8, 0.8), specular=0.0))
    scene = Scene((obj,), Light((0.5, 0.0, 0.0)), ambient=0.5)
    sharp = render(scene, small_rig)
    smooth = render(scene, small_rig, supersample=3)
    np.testing.assert_array_equal(sharp.disparity_px, smooth.disparity_px)
    np.testing.assert_array_equal(sharp.instance_mask, smooth.instance_mask)
    ref = small_rig.reference

    def levels(view):
        return np.unique(luminance(view)).size

    assert levels(smooth.views[ref]) > levels(sharp.views[ref])


def test_noise_and_determinism(small_rig):
    obj = _tilted_plate()
    scene = Scene((obj,), Light((0.3, -0.3, 0.0)), noise_std=0.01)
    a, b = render(scene, small_rig), render(scene, small_rig)
    for va, vb in zip(a.views, b.views, strict=True):
        np.testing.assert_array_equal(va, vb)
    c = render(scene, small_rig, noise_seed=3)
    assert not np.array_equal(a.views[0], c.views[0])
    clean = render(Scene((obj,), Light((0.3, -0.3, 0.0))), small_rig)
    assert not np.array_equal(a.views[0], clean.views[0])


# ------------------------------------------------------------------ random scenes
def _check_random_scene(scene, rig, margin_m):
    light = np.asarray(scene.light.position_m)
    k = rig.intrinsics
    for c in rig.centers_m:
        rel = light - c
        if rel[2] > 0:  # in front of this camera: must project outside the image
            u = k.fx * rel[0] / rel[2] + k.cx
            v = k.fy * rel[1] / rel[2] + k.cy
            assert not (0 <= u < rig.width and 0 <= v < rig.height)
    ring = (
        margin_m
        * 0.99
        * np.column_stack(
            [np.cos(np.linspace(0, 2 * np.pi, 16)), np.sin(np.linspace(0, 2 * np.pi, 16))]
        )
    )
    for obj in scene.objects:
        assert obj.plane.signed_distance(light) > 0  # lit from the front
        for c in rig.centers_m:
            local = obj.local_coords(_mirror_point(obj, light, c))
            assert np.all(obj.contains_local(local + ring))
        tilt = np.degrees(np.arccos(-obj.normal[2]))
        assert tilt <= 30.0 + 1e-9


@pytest.mark.parametrize("seed", range(12))
def test_random_scene_conditions(rig, seed):
    scene = random_scene(seed, rig)
    _check_random_scene(scene, rig, 0.02)
    assert scene == random_scene(seed, rig)


@pytest.mark.parametrize("seed", range(3))
def test_random_scene_several_objects(small_rig, seed):
    scene = random_scene(
        seed,
        small_rig,
        n_objects=3,
        size_m=(0.12, 0.2),
        distance_m=(0.9, 1.4),
        highlight_margin_m=0.015,
    )
    assert len(scene.objects) == 3
    _check_random_scene(scene, small_rig, 0.015)
    out = render(scene, small_rig)
    ref = small_rig.reference
    for k in range(1, 4):
        assert (out.instance_mask == k).sum() > 100
        # Each highlight is visible on its own object in the reference view and clips.
        u, v = np.rint(out.highlight_uv[k - 1, ref]).astype(int)
        assert out.instance_mask[v, u] == k
        for cam, view in enumerate(out.views):
            u, v = np.rint(out.highlight_uv[k - 1, cam]).astype(int)
            assert view[v, u].max() == 255, (k, cam)


@pytest.mark.parametrize("seed", range(3))
def test_random_scene_exposure_dark_diffuse_clipped_highlight(small_rig, seed):
    rig = small_rig
    scene = random_scene(seed, rig, background="textured", lobe="blinn_phong")
    out = render(scene, rig)
    ref = rig.reference
    view = out.views[ref]
    mask = out.instance_mask == 1
    u, v = np.rint(out.highlight_uv[0, ref]).astype(int)
    assert view[v, u].min() >= 250  # white-ish clipped core
    grey = luminance(view)
    far = mask & (np.hypot(*np.meshgrid(np.arange(rig.width) - u, np.arange(rig.height) - v)) > 60)
    if far.sum() > 200:
        assert 0.005 < np.median(grey[far]) < 0.3
    background = ~mask
    assert np.all(out.disparity_px[background] > 0)
    assert np.std(grey[background]) > 0.01  # the background has texture to match


def test_random_scene_is_deterministic_and_seed_dependent(small_rig):
    a = random_scene(7, small_rig, background="textured")
    assert a == random_scene(7, small_rig, background="textured")
    assert a != random_scene(8, small_rig, background="textured")
    rig_light = small_rig.with_light(a.light.position_m)
    assert rig_light.light_position_m == a.light.position_m


def test_scene_dict_round_trip(small_rig):
    scene = random_scene(3, small_rig, n_objects=2, background="textured", size_m=(0.12, 0.2))
    data = json.loads(json.dumps(scene_to_dict(scene)))
    assert scene_from_dict(data) == scene
    with pytest.raises(SceneError, match="scene: expected a dict as written by scene_to_dict"):
        scene_from_dict({"objects": []})
    data["objects"][0]["shape"] = "disc"
    with pytest.raises(SceneError, match="shape: expected one of"):
        scene_from_dict(data)


def test_random_scene_options(small_rig):
    scene = random_scene(
        1, small_rig, roughness=0.01, light_radius_m=0.004, shapes=("ellipse",), lobe="blinn_phong"
    )
    obj = scene.objects[0]
    assert obj.shape == "ellipse" and obj.material.lobe == "blinn_phong"
    assert obj.material.roughness == 0.01 and scene.light.radius_m == 0.004


def test_random_scene_stereo_rig():
    rig = CameraRig.stereo(0.12, fx=500.0, image_size=(400, 300))
    scene = random_scene(2, rig)
    _check_random_scene(scene, rig, 0.02)
    out = render(scene, rig)
    assert len(out.views) == 2


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    "make, error, match",
    [
        (lambda: Material(lobe="phong"), SceneError, "material.lobe: expected one of"),
        (lambda: Material(roughness=0.0), SceneError, "material.roughness: expected a number > 0"),
        (
            lambda: Material(diffuse_rgb=(1.2, 0, 0)),
            SceneError,
            r"diffuse_rgb\[0\]: expected a number <= 1",
        ),
        (lambda: Material(f0=-0.1), SceneError, "material.f0"),
        (
            lambda: PlanarObject("disc", (0, 0, 1), (0, 0, -1), (0.1, 0.1)),
            SceneError,
            "shape: expected one of",
        ),
        (
            lambda: PlanarObject("rectangle", (0, 0, 1), (0, 0, 0), (0.1, 0.1)),
            SceneError,
            "normal: expected a non-zero vector",
        ),
        (
            lambda: PlanarObject("rectangle", (0, 0, 1), (0, 0, -1), (0.1, 0.0)),
            SceneError,
            "size_m: expected two positive extents",
        ),
        (
            lambda: PlanarObject("rectangle", (0, 1), (0, 0, -1), (0.1, 0.1)),
            SceneError,
            "center_m: expected 3 numbers",
        ),
        (
            lambda: PlanarObject("polygon", (0, 0, 1), (0, 0, -1), (0.1, 0.1)),
            SceneError,
            "vertices_m: expected",
        ),
        (
            lambda: PlanarObject(
                "polygon",
                (0, 0, 1),
                (0, 0, -1),
                (0.1, 0.1),
                vertices_m=((0, 0), (1, 0), (0.2, 0.2), (0, 1)),
            ),
            SceneError,
            "convex polygon",
        ),
        (
            lambda: PlanarObject(
                "triangle",
                (0, 0, 1),
                (0, 0, -1),
                (0.1, 0.1),
                vertices_m=((0, 0), (1, 0), (1, 1), (0, 1)),
            ),
            SceneError,
            "expected 3 vertices",
        ),
        (
            lambda: PlanarObject(
                "rectangle", (0, 0, 1), (0, 0, -1), (0.1, 0.1), texture=np.full((4, 4), 2.0)
            ),
            SceneError,
            "texture: expected",
        ),
        (
            lambda: PlanarObject(
                "rectangle", (0, 0, 1), (0, 0, -1), (0.1, 0.1), texture=np.zeros((4, 4, 2))
            ),
            SceneError,
            r"texture: expected shape",
        ),
        (lambda: Light((0, 0, 0), radius_m=-1.0), LightError, "light.radius_m"),
        (lambda: Light((0, 0, float("nan"))), LightError, "light.position_m"),
        (
            lambda: Light((0, 0, 0), intensity=0.0),
            LightError,
            "light.intensity: expected a number > 0",
        ),
        (lambda: Scene((), Light((0, 0, 0))), SceneError, "objects: expected a non-empty"),
        (lambda: Scene((_tilted_plate(),), (0, 0, 0)), LightError, "light: expected a Light"),
        (
            lambda: Scene((_tilted_plate(),), Light((0, 0, 0)), background="sky"),
            SceneError,
            "background: expected one of",
        ),
        (
            lambda: Scene((_tilted_plate(),), Light((0, 0, 0)), exposure=0),
            SceneError,
            "exposure: expected a number > 0",
        ),
    ],
)
def test_bad_scene_descriptions(make, error, match):
    with pytest.raises(error, match=match):
        make()
    assert issubclass(error, SRDEError)


def test_bad_render_arguments(small_rig):
    scene = Scene((_tilted_plate(),), Light((0.3, 0, 0)))
    with pytest.raises(SceneError, match="supersample: expected an integer in"):
        render(scene, small_rig, supersample=0)
    with pytest.raises(SceneError, match="scene: expected a Scene"):
        render("scene", small_rig)
    with pytest.raises(RigError, match="rig: expected a CameraRig"):
        render(scene, {"fx": 1})
    with pytest.raises(SceneError, match="noise_seed"):
        render(scene, small_rig, noise_seed=-1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(n_objects=0), "n_objects: expected a positive integer"),
        (dict(background="wall"), "background: expected one of"),
        (dict(lobe="phong"), "lobe: expected one of"),
        (dict(roughness=(0.03, 0.01)), r"roughness: expected min <= max"),
        (dict(distance_m=(-1.0, 1.0)), r"distance_m\[0\]: expected a number > 0"),
        (dict(shapes=("square",)), "shapes: expected a non-empty subset"),
        (dict(max_tilt_deg=95), "max_tilt_deg: expected a number <= 89"),
        (
            dict(size_m=(0.01, 0.02), max_attempts=20),
            "random_scene: expected to find a valid scene",
        ),
    ],
)
def test_bad_random_scene_arguments(small_rig, kwargs, match):
    with pytest.raises(SceneError, match=match):
        random_scene(0, small_rig, **kwargs)


def test_random_scene_bad_seed_and_rig(small_rig):
    with pytest.raises(SceneError, match="seed: expected a non-negative integer"):
        random_scene(-1, small_rig)
    with pytest.raises(RigError, match="rig: expected a CameraRig"):
        random_scene(0, None)


# ------------------------------------------------------------------ command
def test_render_command_writes_scene_folders(tmp_path, small_rig):
    from srde_fusion.cli import main
    from srde_fusion.io import read_scene

    rig_path = tmp_path / "rig.json"
    small_rig.to_json(rig_path)
    out = tmp_path / "data"
    code = main(
        ["render", str(out), "--scenes", "2", "--seed", "4", "--rig", str(rig_path), "--quiet"]
    )
    assert code == 0
    folders = sorted(p for p in out.iterdir() if p.is_dir())
    assert [p.name for p in folders] == ["scene_0000", "scene_0001"]
    data = read_scene(folders[0])
    assert len(data.views) == small_rig.n_cameras
    assert data.rig.light_position_m is not None
    meta = json.loads((folders[0] / "scene.json").read_text())
    scene = random_scene(meta["seed"], small_rig)
    assert tuple(meta["scene"]["light"]["position_m"]) == scene.light.position_m
    expected = render(scene, small_rig.with_light(scene.light.position_m))
    np.testing.assert_allclose(data.gt_disparity, expected.disparity_px, rtol=1e-6)


def test_render_command_bad_input(tmp_path, capsys):
    from srde_fusion.cli import main

    code = main(["render", str(tmp_path / "x"), "--scenes", "0", "--quiet"])
    assert code == 2
    assert "n_scenes: expected a positive integer" in capsys.readouterr().err


# ---------------------------------------------------------------- RandomSceneConfig
def test_random_scene_takes_a_config_or_its_fields_as_keywords():
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(320, 240))
    config = RandomSceneConfig(n_objects=2, background="textured")
    assert random_scene(4, rig, config=config) == random_scene(4, rig, n_objects=2,
                                                               background="textured")
    # keywords override the config's fields
    assert random_scene(4, rig, config=config, n_objects=1) == random_scene(
        4, rig, background="textured")
    assert RandomSceneConfig(roughness=0.02).roughness == (0.02, 0.02)


@pytest.mark.parametrize(("options", "message"), [
    ({"n_objectz": 2}, r"n_objectz: expected one of the RandomSceneConfig options"),
    ({"config": "textured"}, r"config: expected a RandomSceneConfig, got str"),
    ({"max_attempts": 0}, r"max_attempts: expected a positive integer, got 0"),
])
def test_random_scene_options_are_checked_with_their_name(options, message):
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, image_size=(320, 240))
    with pytest.raises(SceneError, match=message):
        random_scene(0, rig, **options)


def test_render_refuses_a_folder_with_scenes_unless_forced(tmp_path, capsys):
    from srde_fusion.cli import main

    rig = CameraRig.stereo(0.1, fx=100.0, image_size=(64, 48))
    rig.to_json(tmp_path / "rig.json")
    args = ["render", str(tmp_path / "data"), "--scenes", "2", "--rig", str(tmp_path / "rig.json"),
            "--quiet"]
    assert main(args) == 0
    before = (tmp_path / "data" / "scene_0001" / "left.png").read_bytes()
    capsys.readouterr()
    assert main([*args[:3], "1", *args[4:]]) == 2
    err = capsys.readouterr().err
    assert "expected a folder without scene folders, got 2 (scene_0000, scene_0001)" in err
    assert "render --force" in err
    assert (tmp_path / "data" / "scene_0001" / "left.png").read_bytes() == before
    # --force replaces them all: no stale scene_0001 left beside the new scene_0000
    assert main([*args[:3], "1", *args[4:], "--force"]) == 0
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["scene_0000"]


def test_a_replacing_render_that_fails_leaves_the_old_dataset_whole(tmp_path, monkeypatch):
    import srde_fusion.synthetic.datasets as datasets

    rig = CameraRig.stereo(0.1, fx=100.0, image_size=(64, 48))
    datasets.render_dataset(tmp_path, n_scenes=2, rig=rig, progress=False)
    before = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    real_write = datasets.write_scene
    calls = []

    def write_then_fail(folder, *args, **kwargs):
        calls.append(folder)
        if len(calls) == 2:
            raise KeyboardInterrupt  # the user stops it half-way
        return real_write(folder, *args, **kwargs)

    monkeypatch.setattr(datasets, "write_scene", write_then_fail)
    with pytest.raises(KeyboardInterrupt):
        datasets.render_dataset(tmp_path, n_scenes=2, seed=7, rig=rig, progress=False,
                                overwrite=True)
    after = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before  # no new scene swapped in, no staging folder left
    assert all(".render-" in str(folder) for folder in calls)  # rendered aside, not in place


def test_relit_puts_one_scenes_objects_under_anothers_lamps(rig):
    # A line's lamps and exposure stay while objects pass.
    line = random_scene(12300, rig, config=RandomSceneConfig(n_lights=3))
    item = random_scene(20004, rig)
    scene = relit(item, line)
    assert scene.objects == item.objects and scene.background == item.background
    assert scene.lights == line.lights and scene.light == line.lights[0]
    assert scene.exposure == line.exposure != item.exposure
