"""Faceted objects: the ridge/valley split, rendered 2- and 3-face objects, fusion's edge."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from srde_fusion.errors import SceneError, SRDEError
from srde_fusion.fusion import DEFAULT_BORDER_CHECK, border_band, fuse, read_estimate, textured_mask
from srde_fusion.fusion.checks import border_stats, nearest_face
from srde_fusion.geometry import Plane, plane_depth, plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.srde import faces as faces_module
from srde_fusion.srde import lights as lights_module
from srde_fusion.srde.assignment import AssignmentContext
from srde_fusion.srde.candidates import gather_candidates
from srde_fusion.srde.faces import FACE_RULES, choose_faces, split_faces
from srde_fusion.srde.highlight import search_box
from srde_fusion.srde.refine import refine_plane
from srde_fusion.srde.refine.radius import RADIUS_NOTE
from srde_fusion.synthetic import default_rig, random_scene, render
from srde_fusion.synthetic.faceted import faceted_scene
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

#: Per-face masked EPE the issue asks for, pixels.
FACE_EPE_PX = 0.05

#: A face whose masked EPE exceeds this is wrong, pixels (benchmarks/faceted.py's bound).
WRONG_FACE_PX = 0.5

# Seeds of benchmarks/faceted.py's scenes (2 faces ridge, 2 faces valley, 3 faces ridge).
RIDGE_SEED, VALLEY_SEED, THREE_SEED = 31001, 32001, 33008
# A 3-face scene whose middle face two planes left out (benchmarks/faceted.py's 3-face seed 15).
LEFT_OUT_SEED = 33015
# A 3-face scene whose set of planes is reached twice (a pair and a third, in two
# orders): one set, not two rival ones.
REORDERED_SEED = 33003
# A 3-face scene whose lowest face's diffuse shading is a faint, broad candidate blob in
# the reference view: a glow, not a highlight no face explains.
GLOW_SEED = 33013
# A 3-face scene where a face is seen in 2 views only (its pieced set would be 1.7 px off:
# read with its lamp a point, its refinement moves it by more than a pixel).
TWO_VIEW_SEED = 33001
# A 3-face scene whose third face shows its own highlight in 2 views only, solved.
TWO_VIEW_FACE_SEED = 33014
# A valley whose edge cuts one face's highlights in 6 of 9 views (the cut blobs are no
# face's left out).
CUT_SEED = 32002
# A ridge (benchmarks/faceted.py's held-out scenes) with four sets of face planes of
# equal support: the first two (valley rule, one plane 2.5 px off) fail their lobe fits,
# the third is confirmed.
SECOND_SET_SEED = 51004
# A 3-face scene (held-out seed) whose best-ranked set is two planes, one of them 2 px off
# a face, and fails its lobe fit; a set of three with as many highlights on their own
# faces (less net support) is confirmed.
LARGER_SET_SEED = 53001
# A 3-face scene whose two best-ranked sets (equal support) both fail.
BOTH_SETS_FAIL_SEED = 33019
# A valley whose right set of face planes ranks below sets with a wrong plane, which fail.
NEXT_RANK_SEED = 32007
# A ridge of three faces whose middle face, read on the part the start planes gave it (787
# px of a neighbour inside), came out 0.15 px off; read again on the part the refined
# planes give it, 0.04 px. Two sets of starting planes then end on the same three faces.
SECOND_READING_SEED = 33009
# A ridge (seeds 121000+) whose second face's start plane, proposed from its highlights in
# three other views, predicts the face's own reference highlight beyond the tolerance;
# its refined plane meets it.
FINAL_PLANE_SEED = 121016
# A valley whose plane explaining the most highlights (6, one light's) is pixels off both
# faces and outweighed by the evidence against it; the right split explains 6.
CREDIBLE_BAR_SEED = 32018
# A 3-face ridge whose outer faces' highlights are cut by the faces' edges in most views:
# their centroids lie 1.8-7 px inside the part left, no proposed plane comes within 0.9
# px of either face, and no set of three planes splits the mask. Centred on their arcs,
# the cut blobs propose every face's plane within 0.3 px.
CUT_CENTRES_SEED = 33005
# A ridge (seeds 91000+) whose second face is lit by the first face's lamp too.
LAMP_DIFFUSE_SEED = 91012
#: That face's fit from its true plane with the other lamp's diffuse light rendered
#: (0.0064 px measured; 0.0057 px on images rendered without that lamp), pixels.
LAMP_DIFFUSE_EPE_PX = 0.015
# A 3-face ridge whose third face's highlights are cut by the outline and by its edge:
# no plane proposed from its centres comes within 24 px of it, and every other try
# fails. The middle face's plane (0.13 px off) turned about the outline's chord at
# their edge gives it within 0.3 px, and its lobe fit within 0.002 px.
HINGE_SEED = 33017
# A 3-face ridge whose end face, small and lit near the object's outline, has blobs whole
# but predicted within a blob radius of the outline: its own plane explains none of its
# highlights unless those predictions take candidates (faces.NEAR_OUTLINE_TRY).
NEAR_OUTLINE_SEED = 83000
# A valley whose faces both have their own highlights away from the outline, which that
# try solved with a face 0.34 px off (5.7 % of the mask on the wrong face) while the
# other lamps' diffuse light was left to the level.
NEAR_OUTLINE_WRONG_SEED = 52005
# A ridge whose faces are lit near the outline, the blobs there cut by it: every try
# fails (its one plane is ambiguous) until the cut blobs, centred on their arcs, are
# matched near the outline too (faces.RECENTRED_NEAR_OUTLINE_TRY).
RECENTRED_NEAR_OUTLINE_SEED = 91017
# A flat object under three lights (multi_light.py's seeds 52000 +) whose blobs make
# sets of two faces that all fail (face_split).
FLAT_FACES_FAIL_SEED = 52300
# A 3-face scene whose third face's highlight centres give a plane 0.9 px off; its lobe
# fit moves it by 1.5 px onto the face, explaining the images 24x better than its start.
MOVED_FACE_SEED = 33002
# A valley whose second face's lobe fit, read up to the edge its planes draw, does not
# converge; without the band where the two planes are within 1 px it moves the face's
# plane by 1.1 px onto the face.
RETRY_SEED = 32012
# A valley (held-out seed) whose first face's highlight lies on the outline in three
# views: its mirror point just off the mask, its blob's near half on the object.
OUTLINE_HIGHLIGHT_SEED = 52007
# A valley whose second face's reference highlight lies near the edge its highlights'
# planes draw, so that face's fit leaves it out; the refined planes move the edge away
# from it, and it was then taken for a highlight no face explains (face_split).
EDGE_MOVED_SEED = 32017
# A 3-face scene whose middle face's lobe fit settles with a standard error of 0.22 px
# (within SAME_PLANE_PX / 2, not within a third of it).
UNCERTAIN_FACE_SEED = 33007
# A valley (seeds first run after the rules were drawn) whose highlights the reference
# view's candidates explain as one plane, which the one-plane path refuses
# (inconsistent); every view's candidates then split it into its two faces.
ONE_PLANE_REFUSED_SEED = 62009
# A 3-face scene (held-out seed) whose third face, its light seen in 2 views, was moved
# 1.03 px by its lobe fit (4.3x cheaper than its start) to 0.63 px off the face: its part
# held a strip of the neighbouring face past the edge margin. Read without the band where
# the edge lies if the planes are that far off, the fit lands 0.63 px from the move.
# The last try, its cut blobs recentred and matched near the outline, solves it: 0.038
# / 0.003 / 0.015 px (an earlier one does when a face is read again with its lamp's
# radius fitted: 0.017 / 0.002 / 0.058 px).
EDGE_PULLED_SEED = 53012
# A 3-face ridge (a set first run with the last faces try) whose end face, its light seen
# in two views, was moved 3.86 px by its lobe fit to a plane 0.66 px off the face, with a
# standard error of 0.161 px; read without the band by the edge, its fit is not confirmed.
UNCHECKED_MOVE_SEED = 143009
# A 3-face ridge whose end face's light is seen in three views of one column: read with
# its lamp a point, the face's plane moved 0.78 px from its centres' plane (0.07 px off
# the face) to 0.38 px off; with the lamp's radius fitted it stays within the target.
RADIUS_RETRY_SEED = 103015
# A 3-face ridge whose end face the point light's fit leaves loose (standard error
# 0.19 px): read with the lamp's radius fitted (6.9 mm, saving 98 % of the point light's
# cost) it is pinned down.
LOOSE_FACE_SEED = 73018
# A 2-face ridge whose valley set has a loose face that a 16.3 mm radius (lamps of
# 2-8 mm) pins down, saving 71 % of the point light's cost: that set is pixels off.
LOOSE_WRONG_SEED = 111008
# A ridge of 22 deg (seeds first run after the rules above) whose first face's plane the
# images pin down loosely (standard error 0.09 px) and came out 0.37 px off: the shallow
# edge then put 6 % of the mask on the wrong face. Its planes' standard errors leave 7 %
# of the mask to either face.
OPEN_EDGE_SEED = 61001
# A valley whose first face's lobe fit, read up to 2 px from the faces' edge, settles
# 0.85 px off with a standard error of 0.53 px (moving its plane by less than 0.5 px).
UNPINNED_SEED = 32008
# A 3-face scene that the one-plane several-light SRDE once answered with one plane 7.9 px
# off on a face (the joint lobe fit's plane, with 16 blobs on the object unexplained).
ONE_PLANE_SEED = 33000
# Faces taken as their own masks (benchmarks/faceted.py's "each lit face alone") that the
# one-plane path once solved 9.3 and 6.0 px off: (seed, faces, convex, face). The face's
# highlights are one virtual light, explained as its own light's (a plane with the other
# light behind it) and as the other light's; the lobes tell them apart once the light
# behind a plane is not rendered on it.
TURNED_FACES = [(31008, 2, True, 1), (31013, 2, True, 1)]
# Faces alone (seeds of a set first run after the rules above) whose highlights, given to
# the face's own light, are reflected near the outline in most views: that plane was never
# scored in full, and another light's plane through the same centres was kept although
# its lobe fit failed, 13.0 and 29.1 px off. (seed, faces, convex, face, answer): 61017's
# lobe fit finds the face's plane 0.08 px off, whose highlights all lie at the outline,
# and the object is refused as "inconsistent" (with the renderer's lamp samples a spiral
# alone it was solved, 0.08 px off).
SAME_CENTRES_FACES = [(61017, 2, True, 1, "inconsistent"), (62011, 2, False, 1, "ok")]
# Faces alone (seeds first run after the rules above, 71000+) whose centres' best plane
# gives the face's highlights to the other light, confirmed by that light's lobe fit, 4.9
# and 3.5 px off; the face's own light's plane through the same centres explains them all
# once the predictions near the outline count. (seed, faces, convex, face, answer): 72018
# was "ambiguous" until a joint lobe fit with a negative light intensity was refused (a
# start's fit with one had contended); now its own plane, 0.0004 px off at worst.
CONFIRMED_OTHER_LIGHT_FACES = [(71017, 2, True, 0, "ok"), (72018, 2, False, 0, "ok")]
# A face of a valley, alone (seeds 81000+), whose large clipped blobs' centres give 3 of its
# highlights to the other light's plane, 16 px off; the lobe fit does not confirm it.
UNCONFIRMED_OTHER_LIGHT_FACE = (82011, 2, False, 0)
# A ridge (seeds 81000+) that the reference view's candidates show as one plane: the
# one-plane path answered it with its geometric plane (its lobe fit refused), 0.4 and 2.4
# px off the two faces, one light's highlights explained.
UNCONFIRMED_ONE_PLANE_SEED = 81009
# A 3-face ridge (seeds 111000+) whose end face keeps its own highlights in one view once
# its plane is refitted to them (moved 0.86 px): every try failed, and the object was
# refused ("face 1 of 2 ..." from a two-plane set). From the set's own planes every face
# is within the target.
SET_PLANES_SEED = 113014
# A 3-face ridge (seeds 151000+) whose end face's blobs are cut by the outline in all
# three of its views: its lobe fit lands within the target, but the centres, pulled into
# the face, were missed by 3-4 px and every set was refused for that.
CUT_MISS_SEED = 153004
# A 3-face ridge whose end face (face 0) is measured in two views: as a point light its
# lamp (6.9 mm, not in the rig) tilted the face 0.33 px off; with the radius fitted in
# the second reading, 0.018 px.
RADIUS_SEED = 113001
# A 2-face ridge (benchmarks/faceted.py seeds 81000 +) whose valley set also passes once
# its faces' lamp radii are fitted (24.5 mm for lamps of 2.8 and 7.4 mm).
BOTH_SETS_PASS_SEED = 81000
# Faces alone (seeds 91000+) whose own light's plane, from clean centres, left its lobe
# fit nothing to improve while the other lamp's diffuse light was left to the level
# (refused as "does not improve", 0.05 % above its start's cost): the other light's
# confirmed plane, 10.9 and 1.9 px off, then won unopposed. With every lamp's diffuse
# light rendered, their own fits improve on their starts.
SETTLED_START_FACES = [(92016, 2, False, 1), (93002, 3, True, 1)]
# A face of three, alone, whose highlights are its own light's (the third of three), once
# solved 2.4 px off from the fit started from the other two lights' planes only.
THIRD_LIGHT_FACE = (63017, 3, True, 2)
# A face of three, alone, that each light's single-light plane starts a lobe fit from:
# three fits, three planes. Only the first two were compared, and the face went to
# another light's plane, 12.2 px off, though the third plane was 57 times cheaper than it
# on its own samples (seeds 61000+). Judged pair by pair it was left ambiguous until each
# plane was rendered with every fit's light in front of it.
THREE_FITS_FACE = (63013, 3, True, 2)
# A face alone (seeds 71000+) once solved 7.0 px off on the other light's plane by the
# lobes' judge (test_each_plane_is_judged_with_its_own_light).
OWN_LIGHT_JUDGED_FACE = (71014, 2, True, 0)
# Faces alone whose two lobe fits end on two planes, each with no cost on the other's
# samples (it renders none of the lights placed there); the pair was always left open.
# Judged on the samples where both have a cost, each is solved.
ONE_SIDED_FACES = [(31000, 2, True, 1), (33010, 3, True, 2)]
# A face of three, alone, once solved 1.9 px off by a lobe fit whose plane explained no
# blob on the object.
NOTHING_EXPLAINED = (33004, 3, True, 2)
# Faces alone whose refined planes the images did not pin down (disparity standard errors
# of 0.37 and 0.16 px), once solved 10.3 and 1.0 px off.
UNPINNED_FACES = [(32019, 2, False, 0), (33001, 3, True, 2)]


@pytest.fixture(scope="module")
def rig():
    return default_rig()


def _rendered(rig, seed, n_faces, convex, *, physics=None):
    faceted = faceted_scene(seed, rig, n_faces=n_faces, convex=convex)
    rendering = render(faceted.scene, rig, physics=physics, supersample=2)
    return faceted, rendering, rig.with_lights(rig_lights(faceted.scene))


def test_a_face_beside_another_faces_lamp_is_fitted_with_that_lamps_diffuse_light(rig):
    # A ridge (seed 91012) whose second face is lit by the first face's lamp too: that
    # lamp's diffuse light varies over the surface, and the windows of different views
    # lie on different parts of it. Left to the constant level, it biased the face's
    # fit 0.09 px off (about four standard errors); rendered with an intensity of its
    # own (the lamp known as another light), the fit ends where it does on images
    # rendered without that lamp.
    faceted, rendering, lit = _rendered(rig, LAMP_DIFFUSE_SEED, 2, True,
                                        physics=Physics.faithful())
    face = 1
    part = rendering.instance_mask == face + 1
    truth = rendering.planes[face]
    lights = np.array([light.position_m for light in faceted.scene.lights])
    others = np.delete(lights, face, axis=0)

    def epe(**kwargs):
        refined = refine_plane(rendering.views, lit, lights[face], part, truth, **kwargs)
        assert refined.ok, refined.reason
        return float(np.mean(np.abs(plane_disparity(refined.plane, lit)[part]
                                    - rendering.disparity_px[part])))

    assert epe(other_lights_m=others) <= LAMP_DIFFUSE_EPE_PX
    assert epe() > 4 * LAMP_DIFFUSE_EPE_PX  # the lamp unknown: its diffuse light unmodelled


def _alone(rig, seed, n_faces, convex, face):
    """One face of a faithful render as its own mask, every face's light known.

    Returns ``(result, rendering)`` of the one-plane several-light SRDE.
    """
    _, rendering, lit = _rendered(rig, seed, n_faces, convex, physics=Physics.faithful())
    return SRDE(lit).estimate(rendering.views, rendering.instance_mask == face + 1), rendering


def _three_faces_within_the_target(rig, seed):
    """A 3-face ridge's faithful render, solved with three faces within FACE_EPE_PX.

    Returns ``(result, rendering, lit rig)``.
    """
    _, rendering, lit = _rendered(rig, seed, 3, True, physics=Physics.faithful())
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 3
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    return result, rendering, lit


def _face_epes(disparity, rendering, n_faces):
    return [float(np.mean(np.abs(disparity[rendering.instance_mask == k + 1]
                                 - rendering.disparity_px[rendering.instance_mask == k + 1])))
            for k in range(n_faces)]


@pytest.mark.parametrize("convex", [True, False])
def test_split_rule_matches_the_visible_face(rig, convex):
    # Exact planes: the rule of the object's kind labels every pixel with the face the
    # renderer's rays hit (but for the pixels the edge runs through); the other rule
    # labels nearly every pixel with the wrong face.
    faceted = faceted_scene(5, rig, n_faces=2, convex=convex)
    truth = render(faceted.scene, rig).instance_mask
    box = search_box(truth > 0, 0)
    u0, v0, u1, v1 = box
    inside = truth[v0:v1, u0:u1] > 0
    planes = [face.plane for face in faceted.scene.objects]
    right, wrong = ("ridge", "valley") if convex else ("valley", "ridge")
    labels = split_faces(planes, rig, box, inside, right)
    crop = truth[v0:v1, u0:u1]
    assert np.count_nonzero(labels != crop) <= 0.01 * inside.sum()
    flipped = split_faces(planes, rig, box, inside, wrong)
    assert np.count_nonzero(flipped != crop) >= 0.9 * inside.sum()
    assert set(FACE_RULES) == {"ridge", "valley"}


def _split_by_gathering(planes, rig, box, inside, rule):
    """The split as first written: every depth filled, then the picked one gathered."""
    fill = -np.inf if rule == "ridge" else np.inf
    stack = []
    for plane in planes:
        z = np.asarray(plane_depth(plane, rig, window=box), dtype=np.float64)
        stack.append(np.where(np.isfinite(z) & (z > 0), z, fill))
    stack = np.stack(stack)
    pick = np.argmax(stack, axis=0) if rule == "ridge" else np.argmin(stack, axis=0)
    seen = np.isfinite(np.take_along_axis(stack, pick[None], axis=0)[0])
    return np.where(inside & seen, pick + 1, 0).astype(np.uint8)


@pytest.mark.parametrize("seed", range(6))
def test_split_with_kept_depths_is_the_split_computed_afresh(rig, seed):
    # Planes at random tilts, some turned from the camera over part of the box (their
    # rays miss them there): the kept depths of a pool of planes, read for pair after
    # pair under both rules, give the labels of the split as first written.
    rng = np.random.default_rng(seed)
    box = (200, 150, 360, 290)
    inside = rng.random((140, 160)) < 0.9
    pool = [Plane.from_point_normal([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05),
                                     rng.uniform(0.5, 1.0)],
                                    [rng.uniform(-8.0, 8.0), rng.uniform(-8.0, 8.0), -1.0],
                                    towards_m=(0.0, 0.0, 0.0)) for _ in range(4)]
    kept = faces_module._KeptPerPlane(rig, np.zeros((1, 3)), box)
    missed = [~np.isfinite(plane_depth(plane, rig, window=box)) for plane in pool]
    assert any(m.any() and not m.all() for m in missed)
    for rule in FACE_RULES:
        for planes in (pool[:2], pool[1:4], pool[::-1], [pool[0], pool[2]]):
            expected = _split_by_gathering(planes, rig, box, inside, rule)
            assert np.array_equal(split_faces(planes, rig, box, inside, rule), expected)
            assert np.array_equal(split_faces(planes, rig, box, inside, rule,
                                              depth=kept.depth), expected)


@pytest.mark.parametrize("seed", range(8))
def test_the_edge_test_at_points_is_the_edge_map_read_there(seed):
    # Parts of up to three faces with holes and the mask's outline, points on and off
    # the box: the test at the points is the dilated map read at them, pixel for pixel.
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    box = (100, 40, 100 + w, 40 + h)
    vv, uu = np.mgrid[0:h, 0:w]
    labels = np.where(uu * rng.uniform(-1, 1) + vv * rng.uniform(-1, 1) > rng.uniform(-20, 40),
                      1, 2).astype(np.uint8)
    labels[(uu - rng.uniform(0, w)) ** 2 + (vv - rng.uniform(0, h)) ** 2 < 150] = 3
    labels[rng.random((h, w)) < 0.1] = 0
    uv = np.stack([rng.uniform(box[0] - 5, box[2] + 5, 400),
                   rng.uniform(box[1] - 5, box[3] + 5, 400)], axis=1)
    for edge_px in (1.0, 2.5, 4.0, 6.3):
        expected = faces_module._label_at(faces_module._near_other_face(labels, edge_px), box,
                                          uv) > 0
        found = faces_module._near_other_face_at(labels, box, uv, edge_px)
        assert expected.any() and not expected.all()
        assert np.array_equal(found, expected)


def test_split_leaves_pixels_outside_the_mask_unlabelled(rig):
    faceted = faceted_scene(5, rig, n_faces=3, convex=True)
    truth = render(faceted.scene, rig).instance_mask
    box = search_box(truth > 0, 0)
    u0, v0, u1, v1 = box
    inside = truth[v0:v1, u0:u1] > 0
    labels = split_faces([f.plane for f in faceted.scene.objects], rig, box, inside, "ridge")
    assert np.all(labels[~inside] == 0)
    assert set(np.unique(labels[inside]).tolist()) == {1, 2, 3}
    assert np.count_nonzero(labels != truth[v0:v1, u0:u1]) <= 0.01 * inside.sum()


@pytest.mark.parametrize(("seed", "convex", "rule"), [(RIDGE_SEED, True, "ridge"),
                                                      (VALLEY_SEED, False, "valley"),
                                                      (CUT_SEED, False, "valley")])
def test_two_faces_are_solved_within_the_target(rig, seed, convex, rule):
    _, rendering, lit = _rendered(rig, seed, 2, convex, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert result.faces is not None and result.faces.rule == rule
    assert len(result.faces.faces) == 2
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    # The plane reported is the largest face's; the report lists every face.
    largest = max(result.faces.faces, key=lambda f: f.n_px)
    assert result.plane == largest.plane
    record = result.to_dict()
    assert record["faces"]["rule"] == rule and len(record["faces"]["faces"]) == 2
    # Each refined face reports its own standard error, well inside the face's target.
    refined = [(face, entry) for face, entry in zip(result.faces.faces,
                                                    record["faces"]["faces"], strict=True)
               if face.refinement is not None and face.refinement.ok]
    assert refined
    assert result.disparity_sigma_px == max(f.refinement.disparity_sigma_px for f, _ in refined)
    for face, entry in refined:
        assert entry["disparity_sigma_px"] == face.refinement.disparity_sigma_px
        assert 0.0 < entry["disparity_sigma_px"] < FACE_EPE_PX
    assert sum(f.n_px for f in result.faces.faces) == int(mask.sum())


@pytest.mark.parametrize("seed", [THREE_SEED, REORDERED_SEED, GLOW_SEED, TWO_VIEW_FACE_SEED])
def test_three_faces_are_solved_within_the_target(rig, seed):
    _three_faces_within_the_target(rig, seed)


def _gathered(srde, rendering, mask):
    """Every view's highlight candidates of a render, as ``SRDE.estimate`` gathers them."""
    return gather_candidates(srde, srde.backend.prepare(rendering.views), srde._erode(mask))


def _faces_context(srde, rendering, mask, **options):
    """The faces' assignment context on a render's candidates (``options`` to the context)."""
    return _gathered(srde, rendering, mask).context(srde, mask, all_lights_in_front=False,
                                                    **options)


def _record(monkeypatch, name: str) -> list:
    """Record what each call of ``faces.<name>`` returns, in the list returned."""
    returned = []
    function = getattr(faces_module, name)

    def recorded(*args, **kwargs):
        returned.append(function(*args, **kwargs))
        return returned[-1]

    monkeypatch.setattr(faces_module, name, recorded)
    return returned


def _record_tries(monkeypatch) -> list:
    """Each try's ``faces._estimate_faces`` result: the reference's planes, all views', turned."""
    return _record(monkeypatch, "_estimate_faces")


def _without_same_centres(monkeypatch) -> None:
    """No other light's plane through the best plane's centres is ever found."""
    monkeypatch.setattr(AssignmentContext, "same_centres_other_light",
                        lambda self, best: None)


def _ranked_sets(srde, rendering, mask):
    """The sets of face planes ``choose_faces`` ranks for ``mask``, and their context."""
    gathered = _gathered(srde, rendering, mask)
    context = gathered.context(srde, mask, all_lights_in_front=False)
    scores = [s for s in (context.score(p) for p in context.proposals()) if s is not None]
    u0, v0, u1, v1 = box = search_box(mask, 0)
    ranked, _, _ = choose_faces(context, scores, max_faces=3, min_views=srde.min_views, box=box,
                                inside=mask[v0:v1, u0:u1])
    return context, ranked


def test_a_set_the_image_refuses_gives_way_to_the_next(rig):
    _, rendering, lit = _rendered(rig, SECOND_SET_SEED, 2, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    result = srde.estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    # The set the highlight centres rank first is not the one solved.
    context, ranked = _ranked_sets(srde, rendering, mask)
    assert len(ranked) >= 2
    solved = [face.plane for face in result.faces.faces]
    assert max(min(context.plane_gap_px(s.plane, p) for p in solved)
               for s in ranked[0].scores) > 1.0


def test_sets_the_centres_cannot_tell_apart_are_all_tried_whatever_their_order(rig,
                                                                              monkeypatch):
    # Each face's highlights read as either light's give two planes of equal support:
    # four sets tie here, and only the ridge of the right planes passes the image. Put
    # last among the ties, it must still be tried and taken.
    _, rendering, lit = _rendered(rig, SECOND_SET_SEED, 2, True, physics=Physics.faithful())
    chosen = choose_faces

    def right_set_last(*args, **kwargs):
        ranked, why, pool = chosen(*args, **kwargs)
        tied = [s for s in ranked if s.value == ranked[0].value]
        assert len(tied) == 4 and [s.rule for s in tied].count("ridge") == 1
        order = sorted(tied, key=lambda s: s.rule == "ridge") + ranked[len(tied):]
        return order, why, pool

    monkeypatch.setattr(faces_module, "choose_faces", right_set_last)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.ok, result.reason
    assert result.faces.rule == "ridge"
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX


def test_a_larger_set_as_good_on_the_highlights_is_tried_when_the_best_fails(rig):
    _, rendering, lit = _rendered(rig, LARGER_SET_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    _, ranked = _ranked_sets(srde, rendering, mask)
    assert len(ranked[0].scores) == 2
    result = srde.estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 3
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX


def test_the_next_rank_is_tried_when_every_set_of_the_best_fails(rig, monkeypatch):
    # A valley whose right set holds 7 highlights on their own faces; a wrong plane that
    # takes another face's highlight ranks wrong sets at 8, and their lobe fits fail.
    _, rendering, lit = _rendered(rig, NEXT_RANK_SEED, 2, False, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    result = srde.estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert result.faces.rule == "valley"
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    context, ranked = _ranked_sets(srde, rendering, mask)
    solved = [face.plane for face in result.faces.faces]
    taken = [s for s in ranked if len(s.scores) == 2 and all(
        min(context.plane_gap_px(a.plane, p) for p in solved) <= 0.5 for a in s.scores)]
    assert taken and taken[0].value[0] < ranked[0].value[0]
    monkeypatch.setattr(faces_module, "RANKS_TRIED", 1)
    # (Its cut blobs centred on their arcs and its planes turned about the outline's
    # chords, the last tries, also find the right set.)
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    monkeypatch.setattr(faces_module, "HINGE_TRY", False)
    result = srde.estimate(rendering.views, mask)
    assert result.status == "inconsistent", result.reason


def test_each_face_is_read_again_on_the_part_the_refined_planes_give_it(rig, monkeypatch):
    _, rendering, lit = _three_faces_within_the_target(rig, SECOND_READING_SEED)
    monkeypatch.setattr(faces_module, "SECOND_READING", False)
    first = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert first.ok, first.reason
    assert max(_face_epes(first.disparity, rendering, 3)) > 0.1  # the middle face


def test_a_face_the_refined_planes_leave_no_part_keeps_its_first_reading(rig, monkeypatch):
    # Refined planes can give a face (almost) none of the mask; its second reading would
    # read an empty part. It keeps its first, and the split's size check decides.
    _, rendering, lit = _rendered(rig, SECOND_READING_SEED, 3, True, physics=Physics.faithful())
    calls = []
    read_again = faces_module._read_again

    def spy(*args):
        calls.append(args)
        return read_again(*args)

    monkeypatch.setattr(faces_module, "_read_again", spy)
    assert SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0).ok
    srde, views, mask, faces, results, modelled, labels, box, context = calls[-1]
    squeezed = labels.copy()
    kept = np.argwhere(labels == 2)[:faces_module.MIN_FACE_PX - 1]
    squeezed[squeezed == 2] = 1
    squeezed[tuple(kept.T)] = 2
    out, read = read_again(srde, views, mask, faces, results, modelled, squeezed, box, context)
    assert out[1] is faces[1] and read[1] is results[1]
    # The third face's part is untouched: read again as in the solve.
    _, before = read_again(srde, views, mask, faces, results, modelled, labels, box, context)
    assert read[2] is not results[2] and read[2].plane == before[2].plane

def test_two_sets_that_end_on_the_same_faces_are_one_answer(rig, monkeypatch):
    # Two sets of starting planes on SECOND_READING_SEED are both confirmed, and their
    # refined faces agree within 0.5 px: not two answers.
    _, rendering, lit = _rendered(rig, SECOND_READING_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    agreed = _record(monkeypatch, "_same_faces")
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and agreed and all(agreed), result.reason
    monkeypatch.setattr(faces_module, "_same_faces", lambda *args: False)
    # (The last try, cut blobs recentred and matched near the outline, then solves it with
    # one set: 0.013 / 0.031 / 0.030 px.)
    monkeypatch.setattr(faces_module, "RECENTRED_NEAR_OUTLINE_TRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert not result.ok, result.reason


def test_every_failed_set_is_named(rig):
    _, rendering, lit = _rendered(rig, BOTH_SETS_FAIL_SEED, 3, True, physics=Physics.faithful())
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    # The status and reason are the best-ranked set's; the others' reasons follow.
    assert result.status in ("inconsistent", "too_few_views"), result.reason
    assert result.reason.startswith("face ")
    assert "(and 1 other set(s) of face planes failed: face " in result.reason


def _three_faces_solved(rig, seed):
    """A 3-face ridge's rendering, rig, mask and answer, every face within the target."""
    _, rendering, lit = _rendered(rig, seed, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 3
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    return rendering, lit, mask, result


def test_a_set_that_fails_from_its_refitted_planes_is_solved_from_its_own(rig, monkeypatch):
    # (Its end face's blobs are cut too: a set that the cut allowance passes solves it
    # before every try has failed.)
    monkeypatch.setattr(faces_module, "CUT_MISS_ALLOWED", False)
    rendering, lit, mask, result = _three_faces_solved(rig, SET_PLANES_SEED)
    note = next(n for n in result.notes if n.startswith("faces: solved from the set's own"))
    assert "face 3's refit moved its plane" in note
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert not refused.ok


def _face_near_border(rig, depth_px: float):
    """A face lit in the middle row of views, and its part: the border ``depth_px``
    below where its plane reflects the light toward the first view used."""
    plane = Plane((0.0, 0.0, -1.0), -0.6)  # facing the cameras at z = 0.6 m
    light = np.array([0.05, -0.3, 0.0])
    virtual = plane.mirror(light)
    used = np.zeros(rig.n_cameras, dtype=bool)
    used[[3, 4, 5]] = True
    centers = np.full((rig.n_cameras, 2), np.nan)
    for j in np.flatnonzero(used):
        centers[j] = rig.project(virtual, camera=int(j))
    face = faces_module.FaceResult(1, plane, 0, virtual, centers, used, 0.0, 0, None, ())
    points, _ = faces_module.reflection_points(plane, virtual, rig.centers_m[used])
    v_lit = float(np.max(rig.project(points)[:, 1]))
    box = (0, 0, rig.width, rig.height)
    part = np.zeros((rig.height, rig.width), dtype=bool)
    part[:int(round(v_lit + depth_px)), :] = True
    return face, light, part, box


@pytest.mark.parametrize("allowed", [True, False])
def test_a_highlight_cut_by_the_faces_border_may_be_missed_toward_it(rig, monkeypatch,
                                                                    allowed):
    monkeypatch.setattr(faces_module, "CUT_MISS_ALLOWED", allowed)
    reach_px = 14.0
    face, light, part, box = _face_near_border(rig, depth_px=10.0)
    assert faces_module._worst_miss_px(rig, light, face, part, box, reach_px) < 1e-6
    # The cut blobs' centres, pulled 4 px into the part (up, away from the border).
    pulled = dataclasses.replace(face, highlight_centers=face.highlight_centers
                                 - np.array([0.0, 4.0]))
    miss = faces_module._worst_miss_px(rig, light, pulled, part, box, reach_px)
    assert miss == (0.0 if allowed else pytest.approx(4.0, abs=0.05))
    # Pulled toward the border instead, a cut does not explain them.
    pushed = dataclasses.replace(face, highlight_centers=face.highlight_centers
                                 + np.array([0.0, 4.0]))
    assert faces_module._worst_miss_px(rig, light, pushed, part, box,
                                       reach_px) == pytest.approx(4.0, abs=0.05)
    # Nor are blobs far from the border, or missed by more than a blob radius.
    _, _, deep, _ = _face_near_border(rig, depth_px=40.0)
    assert faces_module._worst_miss_px(rig, light, pulled, deep, box,
                                       reach_px) == pytest.approx(4.0, abs=0.05)
    far = dataclasses.replace(face, highlight_centers=face.highlight_centers
                              - np.array([0.0, 20.0]))
    assert faces_module._worst_miss_px(rig, light, far, part, box,
                                       reach_px) == pytest.approx(20.0, abs=0.05)


def test_an_end_face_whose_blobs_the_outline_cuts_is_solved(rig, monkeypatch):
    rendering, lit, mask, _ = _three_faces_solved(rig, CUT_MISS_SEED)
    monkeypatch.setattr(faces_module, "CUT_MISS_ALLOWED", False)
    readings = _record(monkeypatch, "_checked_face")
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert not refused.ok
    assert any(r.refused_by == "miss" for r in readings)


def test_a_face_the_lobe_fit_does_not_pin_down_is_refused(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, UNPINNED_SEED, 2, False, physics=Physics.faithful())
    monkeypatch.setattr(faces_module, "FACE_EDGE_MARGIN_PX", 2.0)
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    first = tries[0]
    assert first.status == "inconsistent", first.reason
    assert "leaves its plane uncertain by" in first.reason
    sigma_px = float(first.reason.split("uncertain by ")[1].split(" px")[0])
    assert sigma_px > faces_module.MAX_FACE_SIGMA_PX
    # The second try (every view's candidates, the proposed planes beside their refits)
    # finds a set whose faces the lobe fits pin down, even at this margin.
    assert len(tries) == 2 and result is tries[1] and result.ok, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX


def test_the_refinement_reads_each_face_away_from_its_neighbours(rig, monkeypatch):
    # The lobe fit's mask for a face leaves out FACE_EDGE_MARGIN_PX next to the other
    # face's part (drawn before refinement, and again for the second reading; the refined
    # edge moves by a pixel or so); the pieced disparity still covers the whole mask.
    _, rendering, lit = _rendered(rig, RIDGE_SEED, 2, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    seen = []
    finish = SRDE._finish

    def spy(self, face_mask, *args, **kwargs):
        seen.append(face_mask.copy())
        return finish(self, face_mask, *args, **kwargs)

    monkeypatch.setattr(SRDE, "_finish", spy)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    u0, v0, u1, v1 = result.box
    labels = result.faces.labels_box
    assert len(seen) == 4  # each face read twice, in order
    for f, face_mask in zip((1, 2, 1, 2), seen, strict=True):
        part = labels == f
        read = face_mask[v0:v1, u0:u1]
        other = ((labels > 0) & ~part).astype(np.uint8)
        distance = cv2.distanceTransform(1 - other, cv2.DIST_L2, 5)
        assert np.all(distance[read] > 1.0)
        assert np.count_nonzero(part & ~read) > 0
    assert np.all(np.isfinite(result.disparity[v0:v1, u0:u1][labels > 0]))


def test_a_highlight_cut_by_the_outline_is_its_face_s_not_a_face_left_out(rig):
    # Another plane explains those three cut blobs with the other light; they are the
    # face's own light's, predicted within a blob radius of the outline.
    _, rendering, lit = _rendered(rig, OUTLINE_HIGHLIGHT_SEED, 2, False,
                                  physics=Physics.faithful())
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 2
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX


def test_a_highlight_the_face_s_fit_left_out_near_the_edge_is_still_explained(rig):
    _, rendering, lit = _rendered(rig, EDGE_MOVED_SEED, 2, False, physics=Physics.faithful())
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 2
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX


def test_faces_are_tried_again_when_the_one_plane_path_refuses_the_object(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, ONE_PLANE_REFUSED_SEED, 2, False,
                                  physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    # The first try finds no split (one plane); the one-plane path refuses the object.
    assert tries[0] is None
    assert SRDE(lit).estimate(rendering.views, mask).status == "inconsistent"
    assert len(tries) == 2 and result is tries[1]
    assert result.ok and len(result.faces.faces) == 2, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    # Without max_faces, or when the one-plane path succeeds, faces are not tried again
    # (test_max_faces_leaves_single_plane_objects_as_they_were).


def test_faces_are_tried_again_when_the_one_plane_is_not_confirmed(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, UNCONFIRMED_ONE_PLANE_SEED, 2, True,
                                  physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    # The one-plane path's plane gives every highlight to one light, and its lobe fit is
    # refused: that is no answer (its geometric plane is pixels off a face).
    one = SRDE(lit).estimate(rendering.views, mask)
    assert one.status == "inconsistent", (one.status, one.reason)
    assert "did not confirm the plane" in one.reason
    geometric = SRDE(lit, refine=False).estimate(rendering.views, mask)
    assert geometric.ok and max(_face_epes(geometric.disparity, rendering, 2)) > 1.0
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert tries[0] is None  # the reference view's candidates show one plane
    assert len(tries) == 2 and result is tries[1]
    assert result.ok and len(result.faces.faces) == 2, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX


def test_a_face_left_out_is_refused(rig, monkeypatch):
    # Three faces whose two outer faces' planes, split by the ridge rule, cover the whole
    # mask: the middle face's highlights (in 7 views, near the split's edge in the
    # reference view) are explained by neither plane. Pieced together, the two planes
    # would put the middle face 0.5 px and more off: a reasoned failure instead.
    _, rendering, lit = _rendered(rig, LEFT_OUT_SEED, 3, True, physics=Physics.faithful())
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    first = tries[0]
    assert first.status == "face_split", first.reason
    assert "none of the 2 faces explains" in first.reason
    # The second try (every view's candidates, the proposed planes beside their refits)
    # finds the middle face's plane, and the three faces pass.
    assert len(tries) == 2 and result is tries[1] and result.ok, result.reason
    assert len(result.faces.faces) == 3
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX


@pytest.mark.parametrize(("seed", "convex", "rule", "status", "said"), [
    # Judged by the start planes alone, the face's own highlight in the reference view is
    # explained by no face, and the right split was refused as leaving it out.
    (FINAL_PLANE_SEED, True, "FINAL_PLANES_EXPLAIN", "face_split",
     "none of the 2 faces explains"),
    # A set of faces must explain more highlights than one plane does; measured against a
    # plane the one-plane path itself refuses (more evidence against it than half what it
    # explains), the right split was dropped and the object refused.
    (CREDIBLE_BAR_SEED, False, "CREDIBLE_BAR", "inconsistent",
     "evidence against the best plane"),
])
def test_a_right_split_a_rule_once_refused_is_solved(rig, monkeypatch, seed, convex, rule,
                                                       status, said):
    _, rendering, lit = _rendered(rig, seed, 2, convex, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and len(result.faces.faces) == 2, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    monkeypatch.setattr(faces_module, rule, False)
    # (The last try, cut blobs centred on their arcs, solves the valley without the rule:
    # 0.0024 / 0.0142 px.)
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert refused.status == status, refused.reason
    assert said in refused.reason


def test_cut_highlights_centred_on_their_arcs_solve_three_faces(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, CUT_CENTRES_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    gathered = _gathered(srde, rendering, mask)
    recentred = gathered.recentred(rendering.views, srde.config.encoding)
    # Cut blobs move, each onto the true highlight nearest to it (some lights' mirror
    # points lie just off the object, their blobs' near part on it).
    moved, before_px, after_px = 0, [], []
    for j, (before, after) in enumerate(zip(gathered.centers_uv, recentred.centers_uv,
                                            strict=True)):
        truth = rendering.highlight_uv_by_light[:, :, j].reshape(-1, 2)
        for a, b in zip(before, after, strict=True):
            if not np.array_equal(a, b):
                moved += 1
                before_px.append(np.nanmin(np.linalg.norm(truth - a, axis=1)))
                after_px.append(np.nanmin(np.linalg.norm(truth - b, axis=1)))
    assert moved >= 8
    assert all(b < a for a, b in zip(before_px, after_px, strict=True))
    assert np.median(before_px) > 2.0 and np.median(after_px) < 0.5
    result = srde.estimate(rendering.views, mask)
    assert result.ok and len(result.faces.faces) == 3, result.reason
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    # Geometric only, nothing pins the faces down beyond the recentred centres.
    assert not SRDE(lit, max_faces=3, refine=False).estimate(rendering.views, mask).ok
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    # (The tries from the sets' own planes, made when every other try fails, are off too.)
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert not refused.ok


def test_a_face_turned_about_its_neighbour_s_edge_solves_three_faces(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, HINGE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    context = _faces_context(srde, rendering, mask)
    proposed = [s for s in (context.score(p) for p in context.proposals(
        anchors=tuple(range(rig.n_cameras)))) if s is not None]
    faceted = faceted_scene(HINGE_SEED, rig, n_faces=3, convex=True)
    third = faceted.scene.objects[2].plane
    assert min(context.plane_gap_px(s.plane, third) for s in proposed) > 5.0
    _, turned = faces_module._hinge_scores(context, proposed, mask, srde.min_views)
    assert min(context.plane_gap_px(s.plane, third) for s in turned) < 0.3
    result = srde.estimate(rendering.views, mask)
    assert result.ok and len(result.faces.faces) == 3, result.reason
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    monkeypatch.setattr(faces_module, "HINGE_TRY", False)
    # (The tries from the sets' own planes, made when every other try fails, are off too.)
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    assert not SRDE(lit, max_faces=3).estimate(rendering.views, mask).ok


def test_an_end_face_lit_near_the_outline_is_solved_by_the_last_try(rig, monkeypatch):
    tries = _record(monkeypatch, "_near_outline_try")
    _, rendering, lit = _three_faces_within_the_target(rig, NEAR_OUTLINE_SEED)
    assert len(tries) == 1 and tries[0] is not None and tries[0].ok
    # The end face's own plane explains fewer than min_views of its highlights unless
    # those predicted near the outline take candidates.
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    end_face = faceted_scene(NEAR_OUTLINE_SEED, rig, n_faces=3, convex=True).scene.objects[0]
    own = [int((_faces_context(srde, rendering, mask, near_outline=near_outline)
                .score(end_face.plane, at_least=0).matched[0] >= 0).sum())
           for near_outline in (False, True)]
    assert own[0] < srde.min_views <= own[1], own
    monkeypatch.setattr(faces_module, "NEAR_OUTLINE_TRY", False)
    assert not srde.estimate(rendering.views, mask).ok


def test_the_near_outline_try_answers_only_for_a_face_that_needs_it(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, NEAR_OUTLINE_WRONG_SEED, 2, False,
                                  physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    tries = _record(monkeypatch, "_near_outline_try")
    recentred = _record(monkeypatch, "_recentred_try")
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    # The try of cut blobs centred on their arcs solves it (0.035 / 0.005 px) before the
    # near-outline try is reached.
    assert result.ok and result is recentred[-1], result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    assert tries == []
    # Without it, the near-outline try runs and does not answer: every face of its set is
    # seen away from the outline, so none needs it.
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    # (The tries from the sets' own planes, made when every other try fails, are off too.)
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    tries.clear()
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert tries == [None] and not refused.ok
    # Answering regardless, it takes its set. (While the other lamps' diffuse light was
    # left to the level, that set had a face 0.34 px off; now both are within 0.02 px.)
    monkeypatch.setattr(faces_module, "_own_light_views", lambda context, face: 0)
    taken = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert taken.ok and taken is tries[-1]
    assert max(_face_epes(taken.disparity, rendering, 2)) <= FACE_EPE_PX


def test_cut_blobs_recentred_and_matched_near_the_outline_solve_the_faces(rig, monkeypatch):
    faceted, rendering, lit = _rendered(rig, RECENTRED_NEAR_OUTLINE_SEED, 2, True,
                                        physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    srde = SRDE(lit, max_faces=3)
    tries = _record(monkeypatch, "_recentred_try")
    result = srde.estimate(rendering.views, mask)
    assert result.ok and len(result.faces.faces) == 2, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    assert len(tries) == 2 and tries[0] is None and tries[1] is result
    # Each face's own plane explains more of its own light's highlights with both: cut
    # blobs recentred and predictions near the outline matched.
    gathered = _gathered(srde, rendering, mask)
    recentred = gathered.recentred(rendering.views, srde.config.encoding)
    for k, face in enumerate(faceted.scene.objects):
        own = {(cut, near): int((candidates.context(srde, mask, all_lights_in_front=False,
                                                    near_outline=near)
                                 .score(face.plane, at_least=0).matched[k] >= 0).sum())
               for cut, candidates in ((False, gathered), (True, recentred))
               for near in (False, True)}
        assert own[True, True] > max(own[False, True], own[True, False]), own
    monkeypatch.setattr(faces_module, "RECENTRED_NEAR_OUTLINE_TRY", False)
    # (Without that try, the tries from the sets' own planes solve it as well, 0.015 /
    # 0.003 px, now that its cut blobs may be missed toward the outline.)
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    assert not SRDE(lit, max_faces=3).estimate(rendering.views, mask).ok


def test_a_lamp_radius_the_rig_does_not_know_is_fitted_on_a_face_seen_in_few_views(
        rig, monkeypatch):
    faceted, rendering, lit = _rendered(rig, RADIUS_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and len(result.faces.faces) == 3, result.reason
    epes = _face_epes(result.disparity, rendering, 3)
    assert max(epes) <= FACE_EPE_PX
    # The end face, its light measured in two of nine views, says what radius it fitted:
    # the lamp's, to within a fifth.
    end = min(result.faces.faces, key=lambda f: np.mean(np.abs(
        plane_disparity(f.plane, rig)[rendering.instance_mask == 1]
        - rendering.disparity_px[rendering.instance_mask == 1])))
    assert np.count_nonzero(end.used_views) == 2
    fitted = [n for n in end.notes if n.startswith(RADIUS_NOTE)]
    assert len(fitted) == 1, end.notes
    radius_mm = float(fitted[0].split("fitted ")[1].split(" mm")[0])
    assert radius_mm == pytest.approx(1000 * faceted.scene.lights[end.light].radius_m, rel=0.2)
    # Every face's second reading searched the radius, and each says what it took: a
    # fitted radius, or a point light where no radius saved MIN_COST_GAIN of its cost.
    for face in result.faces.faces:
        said = [n for n in face.notes if n.startswith("refinement: the light's radius is not")]
        assert len(said) == 1 and ("; fitted " in said[0] or "; kept a point light" in said[0])
    # As a point light, the same face came out 0.33 px off.
    monkeypatch.setattr(faces_module, "FIT_RADIUS", False)
    point = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert point.ok
    assert _face_epes(point.disparity, rendering, 3)[0] > 0.2
    # A rig that knows the lamps' radii uses them as they are.
    known = rig.with_lights(rig_lights(faceted.scene, radii=True))
    monkeypatch.setattr(faces_module, "FIT_RADIUS", True)
    told = SRDE(known, max_faces=3).estimate(rendering.views, mask)
    assert told.ok
    assert not any("radius is not known" in n for f in told.faces.faces for n in f.notes)
    assert max(_face_epes(told.disparity, rendering, 3)) <= FACE_EPE_PX


def test_two_sets_that_both_pass_leave_the_object_ambiguous(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, BOTH_SETS_PASS_SEED, 2, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.status == "ambiguous", result.reason
    # (The two sets tie: which one the ranking puts first is down to rounding.)
    assert ("ridge and valley" in result.reason or "valley and ridge" in result.reason) \
        and "the image confirms both" in result.reason
    # Asked again from every view's candidates, the valley set ranks alone first, and
    # passes: a guess, 1.1-1.9 px off.
    monkeypatch.setattr(faces_module, "AMBIGUITY_FINAL", False)
    guessed = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert guessed.ok and guessed.faces.rule == "valley"
    assert min(_face_epes(guessed.disparity, rendering, 2)) > 1.0


def test_a_face_of_three_pieced_off_from_two_views_is_read_with_the_lamps_radius(
        rig, monkeypatch):
    # Read with its lamp a point, the lobe fit moves a face's plane by more than
    # SAME_PLANE_PX and explains the images barely better there than at its start:
    # neither plane is trusted.
    _, rendering, lit = _rendered(rig, TWO_VIEW_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    monkeypatch.setattr(faces_module, "RADIUS_RETRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.status == "inconsistent", result.reason
    assert "the photometric refinement moved its plane by" in result.reason
    # Read again with the lamp's radius fitted, that face stands; the face seen in two
    # views is then loose, until it too is read with its lamp's radius (7.5 mm, saving
    # 91 % of the point light's cost): 0.011 / 0.005 / 0.113 px.
    monkeypatch.setattr(faces_module, "RADIUS_RETRY", True)
    monkeypatch.setattr(faces_module, "RETRY_SEARCHES", {"move": {}})
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert refused.status == "inconsistent", refused.reason
    assert refused.reason.startswith("face 3 of 3: the photometric refinement leaves its "
                                     "plane uncertain by")
    monkeypatch.undo()
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and max(_face_epes(result.disparity, rendering, 3)) <= WRONG_FACE_PX


def test_a_loose_face_is_pinned_by_the_lamps_radius_only_where_it_explains_the_images(
        rig, monkeypatch):
    _, rendering, lit = _rendered(rig, LOOSE_FACE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    monkeypatch.setattr(faces_module, "RETRY_SEARCHES", {"move": {}})
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert refused.status == "inconsistent", refused.reason
    assert "the photometric refinement leaves its plane uncertain by" in refused.reason
    # Taken wherever it saves MIN_COST_GAIN, a radius that merely helps pins a wrong
    # set's loose face down, and that set is taken.
    _, rendering, lit = _rendered(rig, LOOSE_WRONG_SEED, 2, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    monkeypatch.setattr(faces_module, "RETRY_SEARCHES", {"move": {}, "uncertain": {}})
    wrong = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert wrong.ok and min(_face_epes(wrong.disparity, rendering, 2)) > WRONG_FACE_PX
    monkeypatch.undo()
    splits = _record(monkeypatch, "_solve_split")
    right = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert right.ok and max(_face_epes(right.disparity, rendering, 2)) <= FACE_EPE_PX
    # The wrong set is refused, and its reason says the radius was not taken and why
    # (its saving, measured at 71 %, short of the bar).
    bar = f"{faces_module.LOOSE_FACE_RADIUS_GAIN:.0%} needed"
    short = [s.reason for s in splits if not s.ok and bar in s.reason]
    assert short and all("read again with the lamp's radius fitted" in r and
                         f"{RADIUS_NOTE}; kept a point light (the cheapest radius" in r
                         for r in short), [s.reason for s in splits]


def test_a_face_the_lobe_fit_moves_decisively_stands(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, MOVED_FACE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    asked = _record(monkeypatch, "lobes_prefer")
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert len(result.faces.faces) == 3
    moved = [f for f in result.faces.faces
             if any(note.startswith("refinement: moved the plane by") for note in f.notes)]
    assert len(moved) == 1 and True in asked
    # Every face within 0.1 px at its worst pixel; the moved one's mean error a tenth of
    # its start's or less (0.054 px from 0.82) and within 0.1 px.
    truth = rendering.disparity_px
    for k in range(3):
        part = rendering.instance_mask == k + 1
        gaps = [np.max(np.abs(plane_disparity(f.plane, rig)[part] - truth[part]))
                for f in result.faces.faces]
        assert min(gaps) <= 0.1
    part = max(range(3), key=lambda k: np.count_nonzero(
        result.faces.labels_box[rendering.instance_mask[result.box[1]:result.box[3],
                                                        result.box[0]:result.box[2]] == k + 1]
        == moved[0].label))
    epe = _face_epes(result.disparity, rendering, 3)[part]
    face = rendering.instance_mask == part + 1
    # The start is the first reading's (the second starts from the plane the first moved
    # to).
    monkeypatch.setattr(faces_module, "SECOND_READING", False)
    first = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    start = next(f.refinement.initial_plane for f in first.faces.faces if f.label == moved[0].label)
    start_epe = float(np.mean(np.abs(plane_disparity(start, rig)[face] - truth[face])))
    assert epe <= min(0.1, 0.1 * start_epe)


def test_a_face_the_lobe_fit_does_not_confirm_is_read_again_away_from_the_edge(rig,
                                                                               monkeypatch):
    _, rendering, lit = _rendered(rig, RETRY_SEED, 2, False, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    read = []
    solve = faces_module._solve_face

    def spy(face_set, face_mask, *args, **kwargs):
        read.append(int(face_mask.sum()))
        return solve(face_set, face_mask, *args, **kwargs)

    monkeypatch.setattr(faces_module, "_solve_face", spy)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    # Two faces, the second read twice: the second time on fewer pixels. That reading
    # moves the face by 1.1 px, so it is read a third time, without the band where the
    # edge lies if the planes are that far off, to check the move holds there.
    assert len(read) == 4 and read[3] < read[2] < read[1]
    assert max(_face_epes(result.disparity, rendering, 2)) <= FACE_EPE_PX
    monkeypatch.setattr(faces_module, "RETRY_EDGE_PX", 0.0)  # no band: no second reading
    # (A set of the next rank, read once, is confirmed here: within 0.05 px. Only the
    # best rank's sets are tried, to see them fail.)
    monkeypatch.setattr(faces_module, "RANKS_TRIED", 1)
    # (So is the last try's, cut blobs centred on their arcs: 0.022 / 0.010 px.)
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    # (The tries from the sets' own planes, made when every other try fails, are off too.)
    monkeypatch.setattr(faces_module, "SET_PLANES_RETRY", False)
    read.clear()
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    # Each face read once, and the set fails; the sets of the second try (every view's
    # candidates proposing) fail too, planes turned about the outline's chords make no
    # set, the last try's set (highlights near the outline matched) is not taken, every
    # face of it seen away from the outline, and the first try's reason is the answer.
    assert len(tries) == 4 and not tries[1].ok and tries[2] is None and result is tries[0]
    assert len(read) > 2 and read[:2] == [2477, 9553]
    assert result.status == "inconsistent", result.reason
    assert "did not confirm its plane" in result.reason


def test_a_move_that_does_not_hold_away_from_the_edge_is_refused(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, EDGE_PULLED_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    # An earlier try solves it once a face its lamp's point fit moves is read with the
    # radius fitted (0.017 / 0.002 / 0.058 px); without that, the last try, cut blobs
    # recentred and matched near the outline (0.038 / 0.003 / 0.015 px).
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and max(_face_epes(result.disparity, rendering, 3)) <= WRONG_FACE_PX
    monkeypatch.setattr(faces_module, "RADIUS_RETRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok and max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX
    monkeypatch.setattr(faces_module, "RECENTRED_NEAR_OUTLINE_TRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.status == "inconsistent", (result.status, result.reason)
    assert "the move rests on pixels by the edge" in result.reason


def test_a_move_nothing_away_from_the_edge_confirms_needs_a_tight_fit(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, UNCHECKED_MOVE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.status == "inconsistent", (result.status, result.reason)
    assert "nothing read away from the faces' edge confirms the move" in result.reason
    # Without the limit the first try's set stands, its end face more than 0.5 px off.
    monkeypatch.setattr(faces_module, "UNCHECKED_MOVE_MAX_SIGMA_PX", math.inf)
    taken = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert taken.ok and max(_face_epes(taken.disparity, rendering, 3)) > 0.5
    # Every try failing, the tries from the sets' own planes find a set whose end face,
    # seen in two views, is 0.85 px off with a standard error of 0.10 px: refused too.
    monkeypatch.undo()
    monkeypatch.setattr(faces_module, "SET_PLANES_MAX_SIGMA_PX", math.inf)
    own = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert own.ok and max(_face_epes(own.disparity, rendering, 3)) > 0.5
    assert any(n.startswith("faces: solved from the set's own planes") for n in own.notes)


def test_a_face_the_point_lights_fit_tilts_is_read_again_with_the_lamps_radius(
        rig, monkeypatch):
    faceted, rendering, lit = _rendered(rig, RADIUS_RETRY_SEED, 3, True,
                                        physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    readings = []  # (radius fitted, passed, reason) of every reading of a face of a set
    checked = faces_module._checked_face

    def spy(*args, **kwargs):
        out = checked(*args, **kwargs)
        readings.append((kwargs.get("radius_search") is not None, out.face is not None,
                         out.result.reason))
        return out

    monkeypatch.setattr(faces_module, "_checked_face", spy)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    # (0.024 / 0.006 / 0.052 px: the end face, its lamp's highlight in two views, just
    # beyond the target)
    assert max(_face_epes(result.disparity, rendering, 3)) <= 0.06
    moved = [i for i, (radius, passed, reason) in enumerate(readings)
             if not radius and not passed and "moved its plane by" in reason]
    assert moved and readings[moved[0] + 1][:2] == (True, True)
    # Without the second reading the set is refused on the point light's move.
    monkeypatch.setattr(faces_module, "RADIUS_RETRY", False)
    refused = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert refused.status == "inconsistent", refused.reason
    assert "moved its plane by 0.79 px" in refused.reason
    # A rig that knows the lamps' radii reads every face with them at once.
    monkeypatch.setattr(faces_module, "RADIUS_RETRY", True)
    readings.clear()
    known = rig.with_lights(rig_lights(faceted.scene, radii=True))
    assert SRDE(known, max_faces=3).estimate(rendering.views, mask).ok
    assert readings and not any(radius for radius, _, _ in readings)


def test_an_edge_the_planes_standard_errors_leave_open_is_refused(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, OPEN_EDGE_SEED, 2, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    # Read a second time on the parts its refined planes draw, the loose face is pinned
    # down and right (0.056 and 0.005 px); its first readings leave the edge open.
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert max(_face_epes(result.disparity, rendering, 2)) <= 0.06
    # (Another set, which CREDIBLE_BAR admits, is solved on first readings too: 0.025 and
    # 0.006 px. The loose set is the one the older bar left.)
    monkeypatch.setattr(faces_module, "SECOND_READING", False)
    monkeypatch.setattr(faces_module, "CREDIBLE_BAR", False)
    # (The last try, cut blobs centred on their arcs, also finds a set read once: 0.003
    # and 0.005 px.)
    monkeypatch.setattr(faces_module, "RECENTRED_TRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.status == "face_split", (result.status, result.reason)
    assert "standard errors leave" in result.reason
    # Without the limit, the split it refuses puts more than 5 % of the mask on the wrong
    # face.
    monkeypatch.setattr(faces_module, "MAX_OPEN_EDGE_FRACTION", 1.0)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    assert result.ok, result.reason
    u0, v0, u1, v1 = result.box
    labels = np.zeros(mask.shape, np.uint8)
    labels[v0:v1, u0:u1] = result.faces.labels_box
    wrong = 0
    for k in range(2):
        seen = labels[rendering.instance_mask == k + 1]
        matched = np.argmax(np.bincount(seen, minlength=3)[1:]) + 1  # its estimated face
        wrong += int(np.count_nonzero(seen != matched))
    assert wrong > 0.05 * mask.sum()


def test_without_the_decisive_image_the_moved_face_is_refused(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, MOVED_FACE_SEED, 3, True, physics=Physics.faithful())
    monkeypatch.setattr(faces_module, "lobes_prefer", lambda *args, **kwargs: False)
    # (The last try, cut blobs recentred and matched near the outline, then solves it:
    # 0.016 / 0.001 / 0.007 px.)
    monkeypatch.setattr(faces_module, "RECENTRED_NEAR_OUTLINE_TRY", False)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.status == "inconsistent", result.reason
    assert "moved its plane by" in result.reason


def test_a_face_within_half_but_not_a_third_of_the_plane_gap_is_refused(rig, monkeypatch):
    _, rendering, lit = _rendered(rig, UNCERTAIN_FACE_SEED, 3, True,
                                  physics=Physics.faithful())
    tries = _record_tries(monkeypatch)
    result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
    # The first try (the reference view's candidates proposing) ends on this face.
    assert len(tries) == 3 and tries[0].status == "inconsistent", tries[0].reason
    sigma_px = float(tries[0].reason.split("uncertain by ")[1].split(" px")[0])
    assert faces_module.MAX_FACE_SIGMA_PX < sigma_px <= faces_module.SAME_PLANE_PX / 2
    # The second (every view's candidates proposing) ends on a moved face; the third
    # (cut blobs centred on their arcs) is confirmed, every face within the target
    # (0.003 / 0.002 / 0.016 px).
    assert not tries[1].ok and "moved its plane by" in tries[1].reason, tries[1].reason
    assert result is tries[2] and result.ok, result.reason
    assert max(_face_epes(result.disparity, rendering, 3)) <= FACE_EPE_PX


def test_one_plane_with_most_blobs_unexplained_is_refused(rig):
    # Without max_faces, no plane explains the blob centres and the lobes of two lights
    # settle on one plane; the blobs it leaves unexplained outweigh what it explains.
    _, rendering, lit = _rendered(rig, ONE_PLANE_SEED, 3, True, physics=Physics.faithful())
    result = SRDE(lit).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.status == "inconsistent", result.reason
    assert "more evidence against it" in result.reason and "max_faces" in result.reason


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face"), TURNED_FACES)
def test_a_face_turned_from_a_light_is_told_from_the_other_light_s_plane(rig, seed, n_faces,
                                                                         convex, face):
    # Both planes explain the highlights; the fit from the face's own plane renders only
    # the light in front of it, and the comparison renders each plane with its own lights.
    _, rendering, lit = _rendered(rig, seed, n_faces, convex, physics=Physics.faithful())
    mask = rendering.instance_mask == face + 1
    result = SRDE(lit).estimate(rendering.views, mask)
    assert result.ok, result.reason
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face", "answer"), SAME_CENTRES_FACES)
def test_centres_another_light_explains_near_the_outline_leave_the_light_open(
        rig, seed, n_faces, convex, face, answer):
    faceted, rendering, lit = _rendered(rig, seed, n_faces, convex, physics=Physics.faithful())
    mask = rendering.instance_mask == face + 1
    srde = SRDE(lit)
    # The centres' best plane gives the highlights to the other light ...
    geometric = SRDE(lit, refine=False).estimate(rendering.views, mask)
    assert geometric.ok and _face_epes(geometric.disparity, rendering, n_faces)[face] > 5.0
    # ... and the face's own light's plane through the same centres explains them all once
    # the predictions near the outline count (within 3 px of the face: centres near the
    # outline are pulled).
    gathered = _gathered(srde, rendering, mask)
    context = gathered.context(srde, mask)
    best = context.score(geometric.lights.plane, at_least=1)
    same = context.same_centres_other_light(best)
    assert same is not None and same.explained_lights.tolist() == [face]
    assert context.plane_gap_px(same.plane, faceted.scene.objects[face].plane) < 3.0
    # The best plane's lobe fit fails; the lobes tell the lights apart: the face's own
    # plane, or a reasoned refusal, never the other light's plane.
    result = srde.estimate(rendering.views, mask)
    assert result.status == answer, (result.status, result.reason)
    if answer == "ok":
        assert any("explain the blob centres alike" in note for note in result.notes)
        assert _face_epes(result.disparity, rendering, n_faces)[face] <= 0.1
    else:
        assert "explain the blob centres alike" in result.reason
        assert "puts every light's highlight off the object or at its outline" in result.reason


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face", "answer"),
                         CONFIRMED_OTHER_LIGHT_FACES)
def test_a_confirmed_plane_does_not_settle_whose_highlights_they_are(
        rig, seed, n_faces, convex, face, answer, monkeypatch):
    # The best plane's own lobe fit confirms it, though it gives the face's highlights to
    # the wrong light: the refinement fits the one light's lobe it is given. The lobes of
    # both lights decide: the face's own plane, or ambiguous where they cannot tell.
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.status == answer, (result.status, result.reason)
    if answer == "ok":
        assert any("explain the blob centres alike" in note for note in result.notes)
        assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX
    else:
        assert "explain the blob centres alike" in result.reason
    # Without the other light's plane through the same centres, the confirmed plane stands,
    # pixels off the face (3.5 and 4.9 px at its worst pixel).
    _without_same_centres(monkeypatch)
    held, _ = _alone(rig, seed, n_faces, convex, face)
    assert held.ok and held.refinement.ok
    assert _face_epes(held.disparity, rendering, n_faces)[face] > 1.0


def test_an_unconfirmed_plane_of_one_lights_highlights_is_refused(rig):
    seed, n_faces, convex, face = UNCONFIRMED_OTHER_LIGHT_FACE
    _, rendering, lit = _rendered(rig, seed, n_faces, convex, physics=Physics.faithful())
    mask = rendering.instance_mask == face + 1
    # The centres' plane (what a single light's fallback would keep) is far off the face.
    geometric = SRDE(lit, refine=False).estimate(rendering.views, mask)
    assert geometric.ok and _face_epes(geometric.disparity, rendering, n_faces)[face] > 5.0
    result = SRDE(lit).estimate(rendering.views, mask)
    assert result.status == "inconsistent", (result.status, result.reason)
    assert "did not confirm the plane that gives the highlights to light 1" in result.reason
    assert result.lights.status == "inconsistent"


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face"), SETTLED_START_FACES)
def test_a_face_whose_start_was_settled_is_confirmed_by_its_own_fit(rig, seed, n_faces,
                                                                    convex, face):
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.ok, (result.status, result.reason)
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX
    assert result.refinement.ok, result.refinement.reason


def test_a_lobe_fit_that_ends_where_it_began_still_contends():
    # A refused fit that ended at or above its start's cost ("does not improve") kept a
    # start that may be the answer, if its lobe explains the images; the lobes' judge
    # then weighs that plane against the other lights' (SETTLED_START_FACES needed it).
    def fit(ok=False, initial=1.0, final=1.0, explains=True):
        return SimpleNamespace(ok=ok, cost_initial=initial, cost_final=final,
                               explains_images=explains)

    settled = lights_module._settled_at_start
    assert settled(fit()) and settled(fit(final=1.005))
    assert not settled(fit(final=0.9))  # refused for another reason after improving
    assert not settled(fit(explains=False))  # a start its lobe does not explain
    assert not settled(fit(ok=True))  # a confirmed fit contends as such
    assert not settled(fit(final=math.inf)) and not settled(fit(initial=math.nan))


def test_every_light_that_could_own_the_centres_starts_a_lobe_fit(rig):
    seed, n_faces, convex, face = THIRD_LIGHT_FACE
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.ok, result.reason
    assert any("three planes explain the blob centres alike" in note for note in result.notes)
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX


def test_each_plane_is_judged_with_its_own_light(rig, monkeypatch):
    # Seeds 71000+: each light's single-light plane starts a fit; rendered on the other
    # fit's samples with that fit's light alone, the face's own plane cost 950x more, and
    # the other light's plane (the face's light behind it: no cost on the face's samples)
    # won, 7 px off. Rendered with its own light there too, the face's plane wins.
    seed, n_faces, convex, face = OWN_LIGHT_JUDGED_FACE
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.ok, (result.status, result.reason)
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX
    monkeypatch.setattr(lights_module, "_judged_lights", lambda main, modelled, mains: modelled)
    alone, _ = _alone(rig, seed, n_faces, convex, face)
    assert alone.ok and _face_epes(alone.disparity, rendering, n_faces)[face] > 1.0


def test_three_lobe_fits_are_all_judged_against_each_other(rig):
    # Every pair of the three fits' planes is judged, each plane rendered on every fit's
    # samples with every fit's light in front of it: the face's own plane beats both.
    seed, n_faces, convex, face = THREE_FITS_FACE
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.ok, (result.status, result.reason)
    assert any("single-light planes of 3 light(s)" in note for note in result.notes)
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face"), ONE_SIDED_FACES)
def test_two_lobe_fits_are_judged_where_both_planes_have_a_cost(rig, seed, n_faces, convex,
                                                                face):
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.ok, (result.status, result.reason)
    assert any("joint fit of one lobe per light" in note for note in result.notes)
    assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX


@pytest.mark.parametrize(("seed", "n_faces", "convex", "face"), UNPINNED_FACES)
def test_a_several_light_plane_the_images_do_not_pin_down_is_refused(rig, seed, n_faces,
                                                                     convex, face, monkeypatch):
    if seed == 32019:
        # Its best plane has another light's plane through the same centres: the lobes of
        # both decide first, and settle on the face's plane (the other light's start,
        # its fit refused for not improving, does not contend: its lobe leaves an RMS
        # residual of 0.071, more than the residual check allows).
        result, rendering = _alone(rig, seed, n_faces, convex, face)
        assert result.ok, (result.status, result.reason)
        assert any("explain the blob centres alike" in note for note in result.notes)
        assert _face_epes(result.disparity, rendering, n_faces)[face] <= FACE_EPE_PX
        # Without that plane, the refined plane is the answer, and it is not pinned down.
        _without_same_centres(monkeypatch)
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.status == "ambiguous", (result.status, result.reason)
    assert "not pinned down" in result.reason
    assert result.refinement is not None and result.refinement.disparity_sigma_px > 0.1


def test_a_turned_plane_whose_fit_is_refused_is_not_ruled_out(rig):
    # One plane for a three-face object: the rival plane has a light behind it and its
    # lobe fit is refused; the best plane's fit alone is no answer.
    _, rendering, lit = _rendered(rig, NOTHING_EXPLAINED[0], 3, True,
                                  physics=Physics.faithful())
    result = SRDE(lit).estimate(rendering.views, rendering.instance_mask > 0)
    assert result.status == "ambiguous", (result.status, result.reason)
    assert "behind it" in result.reason and "do not rule that plane out" in result.reason


def test_a_lobe_fit_plane_that_explains_no_blob_is_refused(rig):
    seed, n_faces, convex, face = NOTHING_EXPLAINED
    result, rendering = _alone(rig, seed, n_faces, convex, face)
    assert result.status == "inconsistent", (result.status, result.reason)
    assert "explains none of the blobs" in result.reason


def test_two_faces_found_with_max_faces_2_on_a_three_face_object_is_refused(rig):
    # Two planes cannot explain the third face's highlights: a reasoned failure.
    _, rendering, lit = _rendered(rig, THREE_SEED, 3, True)
    result = SRDE(lit, max_faces=2).estimate(rendering.views, rendering.instance_mask > 0)
    assert not result.ok
    assert result.reason.startswith("face")


def test_fused_map_carries_the_faces_edge(rig):
    _, rendering, lit = _rendered(rig, RIDGE_SEED, 2, True)
    mask = rendering.instance_mask > 0
    backbone = np.full(mask.shape, 5.0, np.float32)
    fused = fuse(backbone, rendering.views, lit, [mask], SRDE(lit, max_faces=3),
                 border_check=None)
    assert fused.objects[0].status == "srde", fused.objects[0].reason
    epes = _face_epes(fused.disparity, rendering, 2)
    assert max(epes) <= FACE_EPE_PX
    # Across the edge the two faces' disparities differ: one plane could not do this.
    for k, face in enumerate(rendering.planes):
        part = rendering.instance_mask == k + 1
        own = plane_disparity(face, lit)[part]
        assert np.max(np.abs(fused.disparity[part] - own)) <= 5 * FACE_EPE_PX
    assert np.all(fused.disparity[~mask] == 5.0)


def _outline_backbone(rendering, mask, inner_px=8):
    """The true disparity around and along the outline, a wrong flat value deeper inside."""
    size = 2 * inner_px + 1
    inner = cv2.erode(mask.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
    backbone = rendering.disparity_px.astype(np.float32).copy()
    backbone[inner] = np.float32(0.8 * np.median(backbone[mask]))
    return backbone


def test_fused_map_keeps_each_face_under_the_outline_check(rig):
    # The default border check on a faceted object: each face's plane is compared with
    # the backbone on its own stretch of the outline, where it agrees; the largest
    # face's plane extended round the whole outline would not (another face's stretch).
    _, rendering, lit = _rendered(rig, THREE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    backbone = _outline_backbone(rendering, mask)
    fused = fuse(backbone, rendering.views, lit, [mask], SRDE(lit, max_faces=3))
    report = fused.objects[0]
    assert report.status == "srde", report.reason
    assert "3 faces' stretches" in report.reason
    assert abs(report.border_ratio_low - 1.0) < 0.01
    assert abs(report.border_ratio_high - 1.0) < 0.01
    assert max(_face_epes(fused.disparity, rendering, 3)) <= FACE_EPE_PX
    check = DEFAULT_BORDER_CHECK
    textured = textured_mask(rendering.views[lit.reference], check.min_gradient)
    one = border_stats(report.srde.plane, lit, backbone, mask, textured, check)
    assert one.ratio_low < 0.97  # the largest face's plane misses the others' stretches


def test_a_face_contradicted_on_its_own_stretch_falls_back(rig):
    # The backbone puts the middle face's stretch of the outline 1.6 x nearer than it is:
    # that face alone contradicts it (over the whole outline the bulk still agrees).
    _, rendering, lit = _rendered(rig, THREE_SEED, 3, True, physics=Physics.faithful())
    mask = rendering.instance_mask > 0
    backbone = _outline_backbone(rendering, mask)
    middle = nearest_face(rendering.instance_mask.astype(np.uint8)) == 2
    near_middle = middle & border_band(mask, DEFAULT_BORDER_CHECK.width_px)
    backbone[near_middle] *= 1.6
    fused = fuse(backbone, rendering.views, lit, [mask], SRDE(lit, max_faces=3))
    report = fused.objects[0]
    assert report.status == "fallback"
    assert "the worst of its 3 faces' stretches" in report.reason
    assert np.all(fused.disparity[mask] == backbone[mask])
    assert report.srde.ok
    # Pooled over the outline, every pixel with its own face's plane, it would pass.
    check = DEFAULT_BORDER_CHECK
    textured = textured_mask(rendering.views[lit.reference], check.min_gradient)
    estimate = read_estimate(report.srde)
    pooled = border_stats(report.srde.plane, lit, backbone, mask, textured,
                          dataclasses.replace(check, min_px=10 ** 9), (0, 0),
                          estimate.face_planes, estimate.face_labels((0, 0, *lit.image_size)))
    assert pooled.ratio_low <= check.max_behind_ratio


def test_nearest_face_labels_every_pixel_by_the_closest_part():
    labels = np.zeros((7, 9), np.uint8)
    labels[2:5, 2:4] = 1
    labels[2:5, 4:7] = 2
    near = nearest_face(labels)
    assert np.all(near[:, :4] == 1) and np.all(near[:, 4:] == 2)
    assert np.all(nearest_face(np.zeros((3, 3), np.uint8)) == 0)


def test_a_face_without_a_highlight_is_not_a_face(rig):
    # The second face's light is switched off: its face shows no highlight, so only one
    # plane is seen and the object takes the usual one-plane path.
    faceted, _, _ = _rendered(rig, RIDGE_SEED, 2, True)
    scene = dataclasses.replace(faceted.scene, lights=(faceted.scene.lights[0],))
    rendering = render(scene, rig, supersample=2)
    lit = rig.with_lights(rig_lights(scene))
    mask = rendering.instance_mask > 0
    faces = SRDE(lit, max_faces=3).estimate(rendering.views, mask)
    plain = SRDE(lit).estimate(rendering.views, mask)
    assert faces.faces is None
    assert faces.to_dict() == plain.to_dict()


def test_max_faces_leaves_single_plane_objects_as_they_were(rig):
    scene = random_scene(12201, rig, n_lights=2)
    rendering = render(scene, rig)
    lit = rig.with_lights(rig_lights(scene))
    mask = rendering.object_masks[0]
    plain = SRDE(lit).estimate(rendering.views, mask)
    for max_faces in (1, 3):
        other = SRDE(lit, max_faces=max_faces).estimate(rendering.views, mask)
        assert other.faces is None
        assert other.to_dict() == plain.to_dict()
        np.testing.assert_array_equal(other.disparity_box, plain.disparity_box)


def test_a_flat_object_whose_face_sets_fail_is_solved_as_one_plane(rig):
    # A flat object under three lights (seeds of multi_light.py's unseen set 52000 +):
    # its blobs make sets of two faces, and every one fails (face_split). The one-plane
    # path solves it as it does with max_faces=1.
    scene = random_scene(FLAT_FACES_FAIL_SEED, rig, n_lights=3)
    rendering = render(scene, rig, physics=Physics.faithful(), supersample=2)
    lit = rig.with_lights(rig_lights(scene))
    mask = rendering.object_masks[0]
    srde = SRDE(lit, max_faces=3)
    views = srde.backend.prepare(rendering.views)
    tried = faces_module.estimate_faces(srde, views, mask,
                                        gather_candidates(srde, views, srde._erode(mask)))
    assert tried is not None and tried.status == "face_split", tried
    result = srde.estimate(rendering.views, mask)
    plain = SRDE(lit).estimate(rendering.views, mask)
    assert result.ok and result.faces is None, result.reason
    assert result.to_dict() == plain.to_dict()
    assert np.mean(np.abs(result.disparity[mask] - rendering.disparity_px[mask])) < 0.01


@pytest.mark.parametrize(("options", "match"), [
    ({"max_faces": 4}, "max_faces: expected an integer in \\[1, 3\\]"),
    ({"max_faces": 0}, "max_faces"),
    ({"max_faces": True}, "max_faces"),
    ({"max_faces": 2, "method": "paper"}, "faces need method='default'"),
])
def test_max_faces_is_checked(rig, options, match):
    with pytest.raises(SRDEError, match=match):
        SRDE(rig.with_light((0.3, -0.3, 0.1)), **options)


@pytest.mark.parametrize(("options", "match"), [
    ({"n_faces": 4}, "n_faces: expected 2 or 3"),
    ({"convex": 1}, "convex: expected a bool"),
    ({"extra_lights": -1}, "extra_lights"),
    ({"min_views": 0}, "min_views"),
    ({"dihedral_deg": (40.0, 20.0)}, "dihedral_deg"),
])
def test_faceted_scene_options_are_checked(rig, options, match):
    with pytest.raises(SceneError, match=match):
        faceted_scene(0, rig, **options)


def test_faceted_scene_is_deterministic_and_lit(rig):
    a = faceted_scene(7, rig, n_faces=3, convex=False, extra_lights=1)
    b = faceted_scene(7, rig, n_faces=3, convex=False, extra_lights=1)
    assert a == b
    assert a.n_faces == 3 and len(a.scene.lights) == 4 and not a.convex
    assert all(15.0 <= angle <= 60.0 for angle in a.dihedral_deg)


@pytest.mark.slow
@pytest.mark.parametrize(("n_faces", "convex"), [(2, True), (2, False), (3, True)])
def test_no_face_is_ok_and_wrong(rig, n_faces, convex):
    # Over several scenes: no ok result holds a wrong face (a masked EPE above
    # WRONG_FACE_PX; the 0.05 px accuracy target is measured by benchmarks/faceted.py,
    # which finds a face only when its plane is within WRONG_FACE_PX everywhere on it);
    # every failure says why.
    for seed in range(40, 46):
        _, rendering, lit = _rendered(rig, seed, n_faces, convex, physics=Physics.faithful())
        result = SRDE(lit, max_faces=3).estimate(rendering.views, rendering.instance_mask > 0)
        if result.ok and result.faces is not None:
            assert max(_face_epes(result.disparity, rendering, n_faces)) <= WRONG_FACE_PX
        elif not result.ok:
            assert result.reason
