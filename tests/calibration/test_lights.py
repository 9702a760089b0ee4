"""Calibrating several lights: highlights sorted to lights by geometry, each light solved."""

from __future__ import annotations

import json

import numpy as np
import pytest

from srde_fusion.calibration import (
    MAX_IMAGE_READ_LIGHTS,
    Board,
    CaptureMatch,
    HighlightGrouping,
    HighlightSet,
    PlatePose,
    calibrate_light_files,
    estimate_light,
    estimate_lights,
    find_plate_highlight_candidates,
    group_highlights,
    leave_out_contradicted_sets,
    match_captures,
)
from srde_fusion.calibration.captures import _light_index
from srde_fusion.errors import LightError
from srde_fusion.geometry import CameraRig, RigLight
from srde_fusion.synthetic import highlight_normal, plate_scene, render
from tests.support import run_cli, write_capture_folders

# Three lights about 1 m from the plates, 12-17 cm apart, mostly side by side: their
# highlights lie side by side on the plate's free centre.
LIGHTS_M = np.array([[0.15, -0.35, 0.1], [0.30, -0.33, 0.05], [0.02, -0.37, 0.08]])
# Three plate poses, tilted differently (each aimed at the lights' mean).
PLATES = (
    dict(center_m=(0.03, 0.02, 1.0)),
    dict(center_m=(-0.08, 0.05, 0.9), aim_m=(-0.06, 0.06, 0.9), rotation_rad=0.1),
    dict(center_m=(0.1, -0.03, 1.1), aim_m=(0.08, -0.02, 1.1), rotation_rad=-0.1),
)
# An A3 plate: room on its free centre for three highlights moving across the array.
PLATE_SIZE_M = (0.42, 0.297)
# Bound on each light's error, metres; measured 0.5-1.4 mm on these renderings (2x2
# supersampling), like the single light's 1.2 mm (tests/calibration/test_light.py).
DETECTED_TOL_M = 0.005
# Mahalanobis radius of 3 sigma in 3D (chi-square, 3 degrees of freedom, 99.7 %).
SIGMA3_3D = 3.763


@pytest.fixture(scope="module")
def board() -> Board:
    return Board.corner_layout(plate_size_m=PLATE_SIZE_M)


def _captures(rig, board, lights_m, plates=PLATES, aim_at_m=None):
    """Render the plates lit by ``lights_m``, each aimed at ``aim_at_m`` (the lights' mean)."""
    out = []
    aim_at_m = np.mean(lights_m, axis=0) if aim_at_m is None else aim_at_m
    for spec in plates:
        kw = dict(spec)
        aim = kw.pop("aim_m", None)
        if aim is not None:
            kw["normal"] = highlight_normal(aim, aim_at_m)
        scene = plate_scene(board, rig, lights_m, **kw)
        rendering = render(scene, rig, supersample=2)
        truth = PlatePose.from_center_normal(kw["center_m"], scene.objects[0].normal,
                                             rotation_rad=kw.get("rotation_rad", 0.0))
        out.append((rendering.views, truth, rendering))
    return out


@pytest.fixture(scope="module")
def two(rig3x3, board):
    return _captures(rig3x3, board, LIGHTS_M[:2])


@pytest.fixture(scope="module")
def three(rig3x3, board):
    return _captures(rig3x3, board, LIGHTS_M)


def _nearest(position_m, lights_m):
    k = int(np.argmin(np.linalg.norm(lights_m - position_m, axis=1)))
    return k, float(np.linalg.norm(lights_m[k] - position_m))


# ---------------------------------------------------------------------- detection
def test_every_highlight_on_the_plate_is_found(three, rig3x3, board):
    views, truth, rendering = three[0]
    candidates, notes = find_plate_highlight_candidates(views, rig3x3, board, truth,
                                                        max_per_view=3)
    assert len(candidates) == len(notes) == 9
    found = 0
    for view, cands in enumerate(candidates):
        assert len(cands) <= 4
        for light in range(3):
            d = np.linalg.norm(cands - rendering.highlight_uv_by_light[light, 0, view], axis=1)
            found += bool(d.size and d.min() < 0.5)
    assert found >= 18  # most; the others sit on a marker or by the edge (noted)


# ---------------------------------------------------------------------- grouping
def test_exact_highlights_group_into_one_set_per_light(rig3x3):
    pose = PlatePose.from_center_normal((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    virtual = np.array([[0.3, 0.2, 2.0], [-0.2, -0.25, 2.1], [0.05, 0.3, 1.9]])
    rng = np.random.default_rng(0)
    # Shuffled per view, a view missing one light, and a stray reflection in one view.
    cands = []
    for view in range(9):
        c = [rig3x3.project(v, view) for v in virtual if not (view == 2 and v[0] < 0)]
        if view == 5:
            c.append([100.0, 50.0])
        cands.append(np.array(c)[rng.permutation(len(c))])
    grouping = group_highlights(cands, rig3x3, pose, min_views=3)
    assert grouping and len(grouping.sets) == 3
    got = sorted((s.virtual_light_m.round(9).tolist(), s.views) for s in grouping.sets)
    want = sorted((v.tolist(), tuple(i for i in range(9) if not (i == 2 and v[0] < 0)))
                  for v in virtual)
    assert got == want
    assert [len(u) for u in grouping.unmatched_px] == [0, 0, 0, 0, 0, 1, 0, 0, 0]


def test_a_centre_pulled_off_its_highlight_is_left_out_of_its_set(rig3x3):
    """One centre a pixel off (a neighbour's flank pulled it) tilts the whole set's fit.

    Without it the other centres fit their virtual light three times better or more, so
    it is left out; centres that are all a little noisy keep every view.
    """
    pose = PlatePose.from_center_normal((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    virtual = np.array([0.3, 0.2, 2.0])
    exact = np.array([rig3x3.project(virtual, view) for view in range(9)])
    # Centres good to a hundredth of a pixel, as on renders, and one half a pixel off.
    pulled = exact + np.random.default_rng(0).normal(scale=0.01, size=exact.shape)
    pulled[8] += [0.5, 0.25]
    grouping = group_highlights([c[None] for c in pulled], rig3x3, pose, min_views=3)
    (found,) = grouping.sets
    assert found.views == tuple(range(8)) and found.residual_px < 0.02
    assert np.linalg.norm(found.virtual_light_m - virtual) < 1e-3
    assert len(grouping.unmatched_px[8]) == 1
    # Real centres are good to a few tenths of a pixel: noise alone drops no view.
    noisy = exact + np.random.default_rng(1).normal(scale=0.3, size=exact.shape)
    (kept,) = group_highlights([c[None] for c in noisy], rig3x3, pose, min_views=3).sets
    assert kept.views == tuple(range(9))


def test_highlights_that_pair_either_way_are_ambiguous(rig3x3):
    """On a stereo pair, two highlights on one image row can triangulate either way."""
    stereo = CameraRig.stereo(0.1, fx=600.0, image_size=(640, 480))
    pose = PlatePose.from_center_normal((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    # Same row, 10 px apart with 30 px disparity: crossed pairs meet at 1.5 m and 3 m,
    # both behind the plate, so the plate does not tell the pairings apart.
    virtual = np.array([[0.0, 0.1, 2.0], [0.1 / 3, 0.1, 2.0]])
    cands = [np.array([stereo.project(v, view) for v in virtual]) for view in range(2)]
    grouping = group_highlights(cands, stereo, pose, min_views=2)
    assert not grouping and grouping.sets == ()
    assert "ambiguous highlights: two sets of 2 views share the highlights" in grouping.reason
    # On different rows they do not: the vertical position tells them apart.
    virtual[1, 1] = 0.2
    cands = [np.array([stereo.project(v, view) for v in virtual]) for view in range(2)]
    assert len(group_highlights(cands, stereo, pose, min_views=2).sets) == 2
    # Nor when a crossed pair would meet in front of the plate, where no mirror image is.
    virtual = np.array([[0.3, 0.1, 2.0], [-0.2, 0.1, 2.0]])
    cands = [np.array([stereo.project(v, view) for v in virtual]) for view in range(2)]
    assert len(group_highlights(cands, stereo, pose, min_views=2).sets) == 2


def test_a_point_in_front_of_the_plate_is_no_virtual_light(rig3x3):
    pose = PlatePose.from_center_normal((0.0, 0.0, 1.0), (0.0, 0.0, -1.0))
    cands = [rig3x3.project([0.1, 0.0, 0.8], view)[None] for view in range(9)]
    grouping = group_highlights(cands, rig3x3, pose, min_views=2)
    assert grouping and grouping.sets == ()


# ---------------------------------------------------------------------- across captures
def _exact_sets(rig, poses, lights_m, noise_px=0.0, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for pose in poses:
        sets = []
        for light in lights_m:
            v = light - 2.0 * (pose.plane.n @ light - pose.plane.offset_m) * pose.plane.n
            centers = np.array([rig.project(v, i) for i in range(rig.n_cameras)])
            centers += rng.normal(scale=noise_px, size=centers.shape)
            sets.append(HighlightSet(centers, np.zeros(rig.n_cameras, int), v, 0.0))
        out.append(sets)
    return out


def test_captures_are_matched_to_lights_by_their_rays(rig3x3, two):
    poses = [truth for _, truth, _ in two]
    sets = _exact_sets(rig3x3, poses, LIGHTS_M[:2])
    sets[1] = sets[1][::-1]  # the second capture lists the lights the other way round
    matches, reason = match_captures(sets, poses, rig3x3, 2, max_ray_distance_m=0.01)
    assert reason == ""
    assert [m.lights for m in matches] == [(0, 1), (1, 0), (0, 1)]
    assert matches[1].ray_distance_m < 1e-6 and matches[1].runner_up_distance_m > 0.03


def test_lights_too_close_for_the_captures_are_an_ambiguity(rig3x3, two):
    poses = [truth for _, truth, _ in two]
    close = np.array([LIGHTS_M[0], LIGHTS_M[0] + [0.004, 0.0, 0.0]])
    sets = _exact_sets(rig3x3, poses, close, noise_px=0.3)
    matches, reason = match_captures(sets, poses, rig3x3, 2, max_ray_distance_m=0.01)
    assert matches == ()
    assert "ambiguous assignment of highlight sets to lights" in reason


def test_highlights_of_another_lamp_do_not_triangulate(rig3x3, two):
    poses = [truth for _, truth, _ in two]
    sets = _exact_sets(rig3x3, poses, LIGHTS_M[:2])
    sets[2] = _exact_sets(rig3x3, poses[2:], LIGHTS_M[[0, 2]])[0]  # a lamp moved
    matches, reason = match_captures(sets, poses, rig3x3, 2, max_ray_distance_m=0.01)
    assert matches == ()
    assert "capture 2: expected its 2 highlight sets to fit the lights" in reason
    assert "do not triangulate" in reason


def test_more_sets_than_lights_or_no_capture_with_all(rig3x3, two):
    poses = [truth for _, truth, _ in two]
    sets = _exact_sets(rig3x3, poses, LIGHTS_M[:2])
    assert "expected at most 1 lights, got 2" in match_captures(
        sets, poses, rig3x3, 1, max_ray_distance_m=0.01)[1]
    assert "expected a capture showing all 3 lights" in match_captures(
        sets, poses, rig3x3, 3, max_ray_distance_m=0.01)[1]


def test_each_set_is_checked_against_its_lights_other_captures(rig3x3, two):
    poses = [truth for _, truth, _ in two]
    sets = _exact_sets(rig3x3, poses, LIGHTS_M[:2])
    # Capture 2's second set: two views of the first lamp's highlight, 10 px aside.
    centers = np.full((9, 2), np.nan)
    centers[[5, 8]] = sets[2][0].centers_px[[5, 8]] + [10.0, 0.0]
    candidates = np.full(9, -1)
    candidates[[5, 8]] = 1
    sets[2][1] = HighlightSet(centers, candidates, sets[2][0].virtual_light_m, 0.0)
    empty = tuple(np.zeros((0, 2)) for _ in range(9))
    groupings = [HighlightGrouping(tuple(s), empty) for s in sets]
    matches = [CaptureMatch((0, 1), 0.0, np.inf) for _ in sets]
    kept, kept_matches, left_out = leave_out_contradicted_sets(
        groupings, matches, poses, rig3x3, 2, max_residual_m=0.01)
    assert [len(g.sets) for g in kept] == [2, 2, 1]
    assert [m.lights for m in kept_matches] == [(0, 1), (0, 1), (0,)]
    ((capture, light, views, note),) = left_out
    assert (capture, light, views) == (2, 1, (5, 8))
    assert "captures [0, 1] place it" in note
    assert [len(u) for u in kept[2].unmatched_px] == [0, 0, 0, 0, 0, 1, 0, 0, 1]
    # With two captures the set of fewer views is checked against the other's light ...
    two_left = leave_out_contradicted_sets(groupings[1:], matches[1:], poses[1:], rig3x3, 2,
                                           max_residual_m=0.01)
    assert [len(g.sets) for g in two_left[0]] == [2, 1]
    assert [(c, j, v) for c, j, v, _ in two_left[2]] == [(1, 1, (5, 8))]
    # ... while two sets of as many views both stay: which one is wrong, nothing tells.
    moved = HighlightSet(sets[0][1].centers_px + [10.0, 0.0], sets[0][1].candidates,
                         sets[0][1].virtual_light_m, 0.0)
    apart = [HighlightGrouping((sets[0][0], moved), empty), groupings[1]]
    both = leave_out_contradicted_sets(apart, matches[:2], poses[:2], rig3x3, 2,
                                       max_residual_m=0.01)
    assert [len(g.sets) for g in both[0]] == [2, 2] and both[2] == ()
    # The second lamp's own two highlights 4 px aside are within the bound (a plate pose
    # 0.1 deg off moves sets that far).
    near = _exact_sets(rig3x3, poses, LIGHTS_M[:2])
    own = np.full((9, 2), np.nan)
    own[[5, 8]] = near[2][1].centers_px[[5, 8]] + [4.0, 0.0]
    near[2][1] = HighlightSet(own, candidates, near[2][1].virtual_light_m, 0.0)
    near_groupings = [HighlightGrouping(tuple(x), empty) for x in near]
    assert leave_out_contradicted_sets(near_groupings, matches, poses, rig3x3, 2,
                                       max_residual_m=0.01)[2] == ()
    # Exact sets everywhere: nothing is left out.
    exact = [HighlightGrouping(tuple(s), empty) for s in _exact_sets(rig3x3, poses,
                                                                     LIGHTS_M[:2])]
    assert leave_out_contradicted_sets(exact, matches, poses, rig3x3, 2,
                                       max_residual_m=0.01)[2] == ()


# ---------------------------------------------------------------------- the whole calibration
@pytest.mark.parametrize("n_lights", [2, 3])
def test_every_light_is_recovered_within_its_uncertainty(n_lights, two, three, rig3x3, board):
    captures = two if n_lights == 2 else three
    truth = LIGHTS_M[:n_lights]
    est = estimate_lights([v for v, _, _ in captures], rig3x3, board, n_lights=n_lights)
    assert est.n_lights == n_lights
    assert est.positions_m[:, 0].tolist() == sorted(est.positions_m[:, 0])  # left to right
    nearest = [_nearest(e.position_m, truth) for e in est.lights]
    assert sorted(k for k, _ in nearest) == list(range(n_lights))  # one estimate per light
    for e, (k, error) in zip(est.lights, nearest, strict=True):
        assert error < DETECTED_TOL_M
        assert e.sigma_distance(truth[k]) < SIGMA3_3D
        assert e.refined and e.n_captures == 3 and e.n_rays >= 10
        fit = e.photometric
        if n_lights > MAX_IMAGE_READ_LIGHTS:  # one plate plane cannot tell three lamps apart
            assert fit is None and e.geometric_position_m is None
            continue
        # Each light is read from its highlights' images too, from the captures showing it
        # (a capture whose lobe fit fails gives none, and says why).
        assert fit.n_used >= 1 and e.geometric_position_m is not None
        assert all((p is None) == bool(r) for p, r in zip(fit.capture_positions_m, fit.reasons,
                                                           strict=True))
        np.testing.assert_allclose(
            e.position_m, np.mean([p for p in fit.capture_positions_m if p is not None], axis=0))
        # One plate plane moved both lights: the move is in the covariance as a bias, so the
        # rays' light lies within one sigma of the images' along it.
        move = e.position_m - e.geometric_position_m
        assert move @ np.linalg.solve(e.position_cov_m2, move) < 1.0
        assert "their move from the rays' light" in e.uncertainty
    # The evidence: each capture's sets and the light each one went to (a highlight right
    # beside a brighter one is left out, with a note, so a capture may miss a light).
    complete = 0
    for grouping, match, notes in zip(est.groupings, est.matches, est.view_notes,
                                      strict=True):
        assert len(grouping.sets) == len(match.lights) <= n_lights
        assert len(set(match.lights)) == len(match.lights)
        complete += len(match.lights) == n_lights
        if len(match.lights) < n_lights:
            assert any("touches a brighter highlight" in n for view in notes for n in view)
    assert complete >= 2
    assert f"{n_lights} light(s) from 3 plate pose(s)" in est.summary()
    # Counting the lights gives the same.
    counted = estimate_lights([v for v, _, _ in captures], rig3x3, board)
    np.testing.assert_allclose(counted.positions_m, est.positions_m)


def test_one_light_the_multi_light_way_agrees_with_the_single_light_way(rig3x3, board):
    captures = _captures(rig3x3, board, LIGHTS_M[:1])
    views = [v for v, _, _ in captures]
    single = estimate_light(views, rig3x3, board)
    multi = estimate_lights(views, rig3x3, board, n_lights=1)
    assert multi.n_lights == 1
    # One light is read from its highlights' images either way: the same light.
    assert multi.lights[0].photometric is not None
    assert np.linalg.norm(multi.positions_m[0] - single.position_m) < 1e-3
    # and from the rays alone, the same rays' light
    rays = estimate_lights(views, rig3x3, board, n_lights=1, photometric=False)
    np.testing.assert_allclose(rays.positions_m[0], single.geometric_position_m)
    assert _nearest(multi.positions_m[0], LIGHTS_M[:1])[1] < DETECTED_TOL_M


# Two lamps 5 cm apart: their highlights merge into one blob on every plate pose.
CLOSE_M = np.array([LIGHTS_M[0], LIGHTS_M[0] + [0.05, 0.0, 0.0]])


@pytest.fixture(scope="module")
def close_lamps(rig3x3, board):
    """The plates lit by both close lamps, then by each alone (the plates aimed alike)."""
    aim = CLOSE_M.mean(axis=0)
    together = [v for v, _, _ in _captures(rig3x3, board, CLOSE_M)]
    alone = [[v for v, _, _ in _captures(rig3x3, board, CLOSE_M[k], aim_at_m=aim)]
             for k in range(2)]
    return together, alone


def test_counting_one_light_that_no_lobe_fit_confirms_is_refused(close_lamps, rig3x3, board):
    """Two lamps 5 cm apart merge their highlights: counting sees one lamp between them.

    Its blob is no single lamp's lobe, and the lobe fit on the plate says so in every
    capture; told there is one light, the rays' light is kept with those reasons.
    """
    close = CLOSE_M
    views = close_lamps[0]
    with pytest.raises(LightError, match=r"counted one light, but its highlight fits one "
                                         r"lamp's lobe in none of the 3 captures .*give the "
                                         r"number of lights.*calibrate each lamp alone"):
        estimate_lights(views, rig3x3, board)
    # Told there are two, no capture shows them apart: refused, with what to do.
    with pytest.raises(LightError, match=r"expected a capture showing all 2 lights .*lamps "
                                         r"close together merge their highlights on every "
                                         r"pose: .*--light K"):
        estimate_lights(views, rig3x3, board, n_lights=2)
    told = estimate_lights(views, rig3x3, board, n_lights=1)
    light = told.lights[0]
    assert light.photometric.n_used == 0 and light.geometric_position_m is None
    assert all(r.startswith("the lobe fit did not confirm") for r in light.photometric.reasons)
    # between the lamps, as the rays put it
    assert np.linalg.norm(light.position_m - close.mean(axis=0)) < 0.02


def test_a_light_never_in_a_view_with_another_is_refused(board):
    """Two lamps along nearly one direction from the plates merge their highlights.

    The merged blob's centre is the image of a point between the two lamps, as
    consistent across views and plate poses as a lamp's; told three lamps, it came back as
    the third light, 0.13 m from both, while the second lamp's own highlight was never
    found. It never shows in a view where the lamp beside it shows on its own.
    """
    rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, fy=600.0, image_size=(640, 480))
    lamps = np.array([[-0.3798, 0.1566, -0.1827], [-0.3397, 0.2263, -0.4121],
                      [-0.5487, 0.4009, -0.1793]])
    plates = [((-0.0548, -0.0503, 1.0825), (-0.0397, -0.0359, 1.0825), 0.0188),
              ((0.0322, -0.0593, 1.0356), (0.0579, -0.0485, 1.0356), 0.0647),
              ((0.0109, 0.0266, 1.0335), (-0.0081, 0.0119, 1.0335), 0.0689)]
    views = [render(plate_scene(board, rig, lamps, center_m=center, rotation_rad=turn,
                                normal=highlight_normal(aim, lamps.mean(axis=0),
                                                        rig.reference_center_m)), rig).views
             for center, aim, turn in plates]
    with pytest.raises(LightError, match=r"expected every two lights to show in a common view "
                                         r"of some capture, got two that never do \(capture 0: "
                                         r".*merged highlight of two lamps"):
        estimate_lights(views, rig, board, n_lights=3)


def test_a_set_the_lights_other_captures_contradict_is_left_out(rig3x3, board):
    """Part of one lamp's highlight, displaced by a marker's edge, posed as another lamp.

    In the second capture two views of the first lamp's highlight (where its blob
    touches a marker) fit a virtual light of their own; the matching gave them to the
    lamp the capture did not show, and their rays pulled it 0.11 m along its other two
    captures' bundles, the mean ray distance staying within its 10 mm bound. Solved from
    the other two captures, that lamp puts its highlights 11 px from those two.
    """
    lamps = np.array([[-0.1113, -0.2058, 0.099], [-0.29, -0.1098, 0.3662],
                      [-0.2251, -0.2493, -0.0088]])
    plates = [((-0.0932, 0.0362, 1.0464), (-0.0781, 0.0292, 1.0464), -0.1228),
              ((0.084, 0.0097, 0.9598), (0.0802, 0.0008, 0.9598), 0.1164),
              ((-0.0759, 0.0596, 0.9533), (-0.0883, 0.0602, 0.9533), -0.1296)]
    views = [render(plate_scene(board, rig3x3, lamps, center_m=center, rotation_rad=turn,
                                light_radius_m=0.003,
                                normal=highlight_normal(aim, lamps.mean(axis=0),
                                                        rig3x3.reference_center_m)),
                    rig3x3).views
             for center, aim, turn in plates]
    found = estimate_lights(views, rig3x3, board, n_lights=3, photometric=False)
    errors = [_nearest(p, lamps)[1] for p in found.positions_m]
    assert max(errors) < DETECTED_TOL_M
    assert sorted(_nearest(p, lamps)[0] for p in found.positions_m) == [0, 1, 2]
    assert len(found.left_out) == 1
    assert found.left_out[0].startswith("capture 1, light ")
    assert "set left out" in found.summary()
    # The light that lost the set keeps its two captures' rays only, and says why.
    k = int(found.left_out[0].split("light ")[1].split(":")[0])
    light = found.lights[k]
    assert light.n_captures == 3 and len(light.views_used[1]) == 0
    assert any("set left out" in r for r in light.view_reasons[1])
    # With the first two captures only, nothing tells which of the two is wrong.
    with pytest.raises(LightError, match=r"got a light seen only in capture 0; its set in "
                                         r"capture 1 was left out: its highlights in views"):
        estimate_lights(views[:2], rig3x3, board, n_lights=3, photometric=False)


def test_a_capture_with_a_moved_lamp_is_refused(rig3x3, board, two):
    moved = _captures(rig3x3, board, LIGHTS_M[[0, 2]], plates=PLATES[2:])
    views = [v for v, _, _ in two[:2]] + [moved[0][0]]
    with pytest.raises(LightError, match=r"capture 2: expected its 2 highlight sets to fit"):
        estimate_lights(views, rig3x3, board, n_lights=2)


def test_estimate_lights_input_errors(rig3x3, board, two):
    views = [two[0][0]]
    with pytest.raises(LightError, match=r"n_lights: expected an integer in \[1, 16\]"):
        estimate_lights(views, rig3x3, board, n_lights=0)
    with pytest.raises(LightError, match=r"match_tolerance_px: expected a positive number"):
        estimate_lights(views, rig3x3, board, match_tolerance_px=-1.0)
    with pytest.raises(LightError, match=r"expected at most 1 lights, got 2"):
        estimate_lights(views, rig3x3, board, n_lights=1)


# ---------------------------------------------------------------------- files and command
@pytest.fixture(scope="module")
def capture_dirs(tmp_path_factory, two, rig3x3, board):
    root = tmp_path_factory.mktemp("lights")
    board.to_json(root / "board.json")
    return root, write_capture_folders(root, rig3x3, [views for views, _, _ in two])


def test_calibrate_light_writes_every_light_keeping_names_and_radii(capture_dirs, rig3x3,
                                                                     tmp_path, capsys):
    root, dirs = capture_dirs
    rig_path = tmp_path / "rig.json"
    # The rig already knows two lamps roughly (names, measured radii), right one first.
    rig3x3.with_lights([RigLight((0.33, -0.3, 0.0), radius_m=0.01, name="right"),
                        RigLight((0.1, -0.3, 0.0), radius_m=0.004, name="left")]
                       ).to_json(rig_path)
    code, out, err = run_cli(capsys, "calibrate-light", *dirs, "--board", root / "board.json",
                             "--rig", rig_path, "--figure", tmp_path / "fig")
    assert code == 0, err
    for k in range(2):  # one figure folder per light
        assert (tmp_path / "fig" / f"light{k}" / "light_3d.png").is_file()
        assert (tmp_path / "fig" / f"light{k}" / "capture_0.png").is_file()
    assert "2 light(s) from 3 plate pose(s)" in out and "wrote 2 lights into" in out
    assert "the plate cannot measure it" in out
    written = CameraRig.from_json(rig_path)
    assert [lt.name for lt in written.lights] == ["right", "left"]
    assert [lt.radius_m for lt in written.lights] == [0.01, 0.004]
    for light, k in zip(written.lights, (1, 0), strict=True):
        assert np.linalg.norm(light.position - LIGHTS_M[k]) < DETECTED_TOL_M
    assert len(json.loads((tmp_path / "rig.json.bak").read_text())["light"]) == 2
    # Counted ("auto") into a rig without lights: two new lights, left to right.
    bare = tmp_path / "bare.json"
    rig3x3.to_json(bare)
    calibration = calibrate_light_files(dirs, root / "board.json", bare, n_lights="auto",
                                        write=False)
    assert len(calibration.rig.lights) == 2 and len(calibration.estimates) == 2
    assert calibration.rig.lights[0].position_m[0] < calibration.rig.lights[1].position_m[0]
    assert calibration.rig.lights[0].radius_m is None
    # One light asked of captures showing two: refused, not a guess.
    code, _, err = run_cli(capsys, "calibrate-light", *dirs, "--board", root / "board.json",
                           "--rig", bare, "--lights", "1", "--dry-run")
    assert code == 2
    with pytest.raises(SystemExit):  # argparse refuses the flag itself
        run_cli(capsys, "calibrate-light", *dirs, "--board", root / "board.json", "--rig",
                bare, "--lights", "none")
    assert "expected a positive number of lights or 'auto'" in capsys.readouterr().err


def test_close_lamps_calibrated_one_at_a_time(close_lamps, rig3x3, board, tmp_path,
                                              capsys):
    """Each lamp of the merging pair, captured alone, is calibrated into its own entry."""
    _, alone = close_lamps
    board.to_json(tmp_path / "board.json")
    rig_path = tmp_path / "rig.json"
    # rig.json knows both lamps roughly, named, with measured radii.
    rough = [RigLight((0.1, -0.3, 0.0), radius_m=0.004, name="left"),
             RigLight((0.25, -0.3, 0.0), radius_m=0.006, name="right")]
    rig3x3.with_lights(rough).to_json(rig_path)
    for k, name in enumerate(("left", "right")):
        root = tmp_path / name
        root.mkdir()
        dirs = write_capture_folders(root, rig3x3, alone[k])
        before = CameraRig.from_json(rig_path)
        # by name on the command line, by index through the library (same light)
        code, out, err = run_cli(capsys, "calibrate-light", *dirs, "--board",
                                 tmp_path / "board.json", "--rig", rig_path, "--light", name,
                                 "--figure", tmp_path / f"fig_{name}")
        assert code == 0, err
        assert (tmp_path / f"fig_{name}" / "light_3d.png").is_file()
        assert f"wrote light {k} ({name}) into" in out and "the other 1 light(s)" in out
        after = CameraRig.from_json(rig_path)
        assert after.lights[1 - k] == before.lights[1 - k]  # the other lamp untouched
        assert (after.lights[k].name, after.lights[k].radius_m) == (name, rough[k].radius_m)
        assert np.linalg.norm(after.lights[k].position - CLOSE_M[k]) < DETECTED_TOL_M
        again = calibrate_light_files(dirs, tmp_path / "board.json", rig_path, light=k,
                                      write=False)
        assert again.light_index == k and again.backup is None
        np.testing.assert_allclose(again.rig.lights[k].position, after.lights[k].position)
    assert len(list(tmp_path.glob("rig.json.bak*"))) == 2  # one backup per write
    # A rig without lights takes a lamp as its first; one with one light, as its second.
    left, right = (sorted((tmp_path / name).iterdir()) for name in ("left", "right"))
    bare = tmp_path / "bare.json"
    rig3x3.to_json(bare)
    first = calibrate_light_files(left, tmp_path / "board.json", bare, light=0, write=False)
    assert len(first.rig.lights) == 1 and first.rig.lights[0].radius_m is None
    first.rig.to_json(bare)
    second = calibrate_light_files(right, tmp_path / "board.json", bare, light=1, write=False)
    assert second.rig.lights[0] == first.rig.lights[0] and len(second.rig.lights) == 2
    assert np.linalg.norm(second.rig.lights[1].position - CLOSE_M[1]) < DETECTED_TOL_M
    # The same lamp added again is one light listed twice: refused.
    with pytest.raises(LightError, match=r"one light listed twice"):
        calibrate_light_files(left, tmp_path / "board.json", rig_path, light=2, write=False)


def test_one_lamp_alone_input_errors(capture_dirs, rig3x3, tmp_path):
    root, dirs = capture_dirs
    rig_path = tmp_path / "rig.json"
    rig3x3.with_lights([RigLight((0.1, -0.3, 0.0), name="left"),
                        RigLight((0.3, -0.3, 0.0))]).to_json(rig_path)
    board_path = root / "board.json"
    with pytest.raises(LightError, match=r"light: expected an index 0-1 of the rig's 2 "
                                         r"light\(s\), or 2 to add one, got 3"):
        calibrate_light_files(dirs, board_path, rig_path, light=3)
    with pytest.raises(LightError, match=r"light: expected the name of one of the rig's "
                                         r"lights \('left'\) or an index, got 'right'"):
        calibrate_light_files(dirs, board_path, rig_path, light="right")
    with pytest.raises(LightError, match=r"expected n_lights None or 1, got 2"):
        calibrate_light_files(dirs, board_path, rig_path, light=0, n_lights=2)
    with pytest.raises(LightError, match=r"light: expected 0 to add the rig's first light, "
                                         r"got True"):
        bare = tmp_path / "bare.json"
        rig3x3.to_json(bare)
        calibrate_light_files(dirs, board_path, bare, light=True)


def test_a_lamp_is_chosen_by_name_before_index(rig3x3):
    """The command line gives every ``--light`` as text: a light named "1" is that light,
    digits that name no light are an index, and anything else is an unknown name."""
    rig = rig3x3.with_lights([RigLight((0.1, -0.3, 0.0), name="1"),
                              RigLight((0.3, -0.3, 0.0), name="front")])
    assert _light_index(rig, "1") == 0  # the name, not index 1
    assert _light_index(rig, "front") == 1
    assert _light_index(rig, "0") == 0 and _light_index(rig, "2") == 2  # indices; 2 adds one
    with pytest.raises(LightError, match=r"expected an index 0-1 of the rig's 2 light\(s\), "
                                         r"or 2 to add one, got 5"):
        _light_index(rig, "5")
    with pytest.raises(LightError, match=r"lights \('1', 'front'\) or an index, got 'back'"):
        _light_index(rig, "back")


def test_a_stereo_pair_that_cannot_tell_two_lamps_apart_says_so(board):
    """Two lamps at the cameras' height: both highlights on one image row, 28 px apart
    with about 30 px disparity, so each can pair with either in the other view, and
    both pairings put a mirror image behind the plate. Reported, not guessed."""
    stereo = CameraRig.stereo(0.1, fx=600.0, image_size=(640, 480))
    lights = np.array([[0.35, 0.0, 0.1], [0.44, 0.0, 0.1]])
    scene = plate_scene(board, stereo, lights, center_m=(0.05, 0.0, 0.9), roughness=0.0015,
                        light_radius_m=0.001)
    rendering = render(scene, stereo, supersample=2)
    assert rendering.highlight_on_object.all()
    with pytest.raises(LightError, match=r"capture 0: ambiguous highlights: two sets of 2 "
                                         r"views share the highlights of"):
        estimate_lights([rendering.views], stereo, board, n_lights=2)


@pytest.fixture(scope="module")
def lamp0_only(rig3x3, board):
    """Captures with only the first lamp on (the plates aimed as for two lamps)."""
    return [views for views, _, _ in _captures(rig3x3, board, LIGHTS_M[0], PLATES[1:],
                                               aim_at_m=LIGHTS_M[:2].mean(axis=0))]


def test_counting_refuses_captures_that_disagree_on_the_count(two, lamp0_only, rig3x3, board):
    views = [two[0][0], *lamp0_only]
    with pytest.raises(LightError, match=r"expected every capture to show the same number of "
                                         r"lights when counting them, got \[2, 1, 1\]"):
        estimate_lights(views, rig3x3, board)


def test_a_light_seen_in_one_capture_only_is_not_trusted(two, lamp0_only, rig3x3, board):
    views = [two[0][0], *lamp0_only]
    with pytest.raises(LightError, match=r"expected every light in at least 2 of the 3 "
                                         r"captures .* got a light seen only in capture 0"):
        estimate_lights(views, rig3x3, board, n_lights=2)
    # Seen in two captures, it is.
    est = estimate_lights([two[0][0], two[1][0], lamp0_only[1]], rig3x3, board, n_lights=2)
    for e in est.lights:
        assert _nearest(e.position_m, LIGHTS_M[:2])[1] < DETECTED_TOL_M
