"""LampTally: a lamp the rig lists that no solved object sees is named across frames."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from srde_fusion.errors import SRDEError
from srde_fusion.fusion import HybridStereo, LampTally
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import RandomSceneConfig, default_rig, random_scene, relit, render
from srde_fusion.synthetic.physics import Physics
from srde_fusion.synthetic.scene import rig_lights

#: A line's three lamps and exposure (the dark-lamp benchmark's first three-lamp scene) ...
LINE_SEED = 12300
#: ... and two objects passing under them (``benchmarks/lamp_watch.py``'s), each solved
#: with the third lamp off and the rig still listing it; on each, the plane puts that
#: lamp's highlights on the object in two or more views, where the images are dark.
OBJECT_SEEDS = (20004, 20016)
NAMES = ("left", "right", "top")


@pytest.fixture(scope="module")
def frames():
    """``(rig, rendering)`` per object: its third lamp off, the rig naming all three."""
    rig = default_rig()
    line = random_scene(LINE_SEED, rig, config=RandomSceneConfig(n_lights=3))
    lamps = tuple(dataclasses.replace(lamp, name=name)
                  for lamp, name in zip(rig_lights(line), NAMES, strict=True))
    listed = rig.with_lights(lamps)
    out = []
    for seed in OBJECT_SEEDS:
        scene = relit(random_scene(seed, rig), line)
        scene = dataclasses.replace(scene, light=None, lights=scene.lights[:2])
        out.append((listed, render(scene, rig, physics=Physics.faithful(), supersample=2)))
    return out


def test_a_lamp_no_solved_object_sees_is_named_after_two_objects(frames):
    results = [SRDE(rig).estimate(out.views, out.object_masks[0]) for rig, out in frames]
    assert all(r.ok for r in results), [r.reason for r in results]
    tally = LampTally.for_rig(frames[0][0])
    one = tally.added([results[0]])
    # One object alone could have the lamp hidden from it.
    assert one.dark == (0, 0, 1) and one.unseen == () and one.warning() == ""
    two = one.added([results[1]])
    assert (two.frames, two.solved, two.dark) == (2, 2, (0, 0, 2))
    assert two.seen[:2] != (0, 0) and two.seen[2] == 0
    assert two.unseen == (2,)
    warning = two.warning()
    assert warning.startswith("top: seen on none of the 2 object(s) solved over 2 frame(s)")
    assert "switched off" in warning and "left" not in warning and "right" not in warning


def test_lamps_that_are_lit_are_not_named(frames):
    # The same images with the rig put right: every lamp it lists is lit.
    tally = LampTally.for_rig(frames[0][0].with_lights(frames[0][0].lights[:2]))
    for rig, out in frames:
        lit = rig.with_lights(rig.lights[:2])
        tally = tally.added([SRDE(lit).estimate(out.views, out.object_masks[0])])
    assert tally.solved == 2 and tally.dark == (0, 0)
    assert tally.unseen == () and tally.warning() == ""


def test_results_without_an_assignment_of_every_lamp_are_not_counted(frames):
    rig, out = frames[0]
    mask = out.object_masks[0]
    one_lamp = SRDE(rig.with_lights(rig.lights[:1])).estimate(out.views, mask)
    background = np.zeros_like(mask)
    background[:40, :40] = True  # no object and no highlight there
    refused = SRDE(rig).estimate(out.views, background)
    assert not refused.ok
    tally = LampTally.for_rig(rig).added([one_lamp, refused])
    assert (tally.frames, tally.solved, tally.seen, tally.dark) == (1, 0, (0, 0, 0), (0, 0, 0))


def test_a_refusal_for_a_lamp_that_may_be_dark_is_counted_apart():
    # Two lamps listed, the second off: the lit lamp's blobs read as either lamp's, each
    # reading needing the other dark; refused, and which lamp is dark is not counted.
    rig = default_rig()
    scene = random_scene(12207, rig, config=RandomSceneConfig(n_lights=2))
    out = render(dataclasses.replace(scene, lights=scene.lights[:1]), rig,
                 physics=Physics.faithful(), supersample=2)
    listed = rig.with_lights(rig_lights(scene))
    result = SRDE(listed).estimate(out.views, out.object_masks[0])
    assert result.status == "ambiguous"
    tally = LampTally.for_rig(listed).added([result])
    assert (tally.solved, tally.refused_dark, tally.dark) == (0, 1, (0, 0))


def test_the_stream_counts_which_lamps_its_objects_see(frames):
    rig = frames[0][0]
    masks = iter([out.object_masks[0]] for _, out in frames)
    model = HybridStereo(lambda left, right: np.full(left.shape[:2], 5.0, np.float32), rig,
                         masker=lambda views, rig: next(masks))
    stream = model.stream(out.views for _, out in frames)
    assert stream.lamps == LampTally.for_rig(rig)
    results = list(stream)
    # SRDE's result counts, whatever fusion then made of it (this backbone is no check).
    assert [o.estimate.ok for r in results for o in r.objects] == [True, True]
    assert stream.lamps.frames == 2 and stream.lamps.unseen == (2,)
    assert stream.lamps.warning().startswith("top:")


def test_a_tally_needs_one_count_per_lamp():
    with pytest.raises(SRDEError, match="one count per lamp"):
        LampTally(("a", "b"), seen=(1,))


@pytest.mark.parametrize(("refused", "solved", "warned"),
                         [(24, 2, True), (3, 0, True), (3, 3, True), (2, 0, False),
                          (3, 4, False), (1, 34, False)])
def test_refusals_for_a_lamp_that_may_be_dark_warn_when_they_outnumber_the_solved(
        refused, solved, warned):
    # Two lamps listed and one dark: each lamp's reading needs the other dark, nearly
    # every object is refused and none names the lamp; the stream says a lamp may be off.
    tally = LampTally(("left", "right"), frames=40, solved=solved, seen=(solved, 0),
                      refused_dark=refused)
    assert tally.unseen == () and tally.doubted is warned
    warning = tally.warning()
    assert bool(warning) is warned
    if warned:
        assert warning.startswith(f"{refused} object(s) over 40 frame(s) were refused")
        assert "is a lamp switched off" in warning
