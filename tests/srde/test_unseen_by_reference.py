"""Objects whose reference view shows no highlight, solved from the views that do.

Objects of a fixed two-lamp line (``benchmarks/lamp_watch.py``'s) tilted so that every
lamp's highlight misses the object in the reference view and lands on it, near the
outline, in a few other views.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from srde_fusion.srde import SRDE
from srde_fusion.srde.candidates import find_candidates
from srde_fusion.synthetic import RandomSceneConfig, default_rig, random_scene, relit, render
from srde_fusion.synthetic.scene import rig_lights

#: The line: the several-light benchmark's first two-lamp scene's lamps and exposure.
LINE_SEED = 12200
#: Both lamps' highlights on the object, in views 6-8 only.
BOTH_LAMPS = 20011
#: Only the first lamp's highlights on the object, in views 6 and 7.
ONE_LAMP = 20079
ACCURATE_PX = 0.01
DARK_REFERENCE = "lights: the reference view shows no highlight on the object"


@pytest.fixture(scope="module")
def line():
    rig = default_rig()
    scene = random_scene(LINE_SEED, rig, config=RandomSceneConfig(n_lights=2))
    return rig, scene, rig.with_lights(rig_lights(scene))


def _rendered(line, seed, lit):
    rig, scene, listed = line
    scene = relit(random_scene(seed, rig), scene)
    out = render(dataclasses.replace(scene, light=None, lights=scene.lights[:lit]), rig)
    srde = SRDE(listed)
    assert not find_candidates(out.views[rig.reference], srde._erode(out.object_masks[0]),
                               srde.config, object_region=True)
    return out


def _epe(result, out):
    mask = out.object_masks[0]
    return float(np.mean(np.abs(result.disparity[mask] - out.disparity_px[mask])))


def test_two_lamps_seen_by_the_other_views_give_the_plane(line):
    rig, _, listed = line
    out = _rendered(line, BOTH_LAMPS, lit=2)
    result = SRDE(listed).estimate(out.views, out.object_masks[0])
    assert result.ok, result.reason
    assert _epe(result, out) < ACCURATE_PX
    assert result.lights.explained_lights == [0, 1]
    assert all(np.isnan(a.centers_uv[rig.reference]).all() for a in result.lights.assignments)


def test_one_lamp_s_blobs_away_from_the_reference_are_not_tied_to_a_lamp(line):
    # Two lamps, the blobs of one: each lamp's reading of them puts the other's highlights
    # where the views are dark; only a dark listed lamp would tell them apart.
    _, _, listed = line
    out = _rendered(line, ONE_LAMP, lit=2)
    result = SRDE(listed).estimate(out.views, out.object_masks[0])
    assert result.status == "ambiguous"
    assert result.reason.startswith(DARK_REFERENCE)


def test_a_listed_lamp_that_is_off_is_a_refusal_not_a_wrong_plane(line):
    # The second lamp off, the rig still listing it: the first lamp's blobs read as the
    # dark lamp's give a plane 2.3 px off that needs no lamp dark.
    _, _, listed = line
    out = _rendered(line, BOTH_LAMPS, lit=1)
    result = SRDE(listed).estimate(out.views, out.object_masks[0])
    assert result.status == "ambiguous"
    assert result.reason.startswith(DARK_REFERENCE)
    assert "light 1's on the best plane" in result.reason


def test_one_light_rig_takes_the_other_views(line):
    rig, _, listed = line
    out = _rendered(line, ONE_LAMP, lit=1)
    result = SRDE(listed.with_lights(listed.lights[:1])).estimate(out.views,
                                                                 out.object_masks[0])
    assert result.ok, result.reason
    assert _epe(result, out) < 0.05
    assert not result.used_views[rig.reference]
