"""HybridStereo.stream: one fused map per frame from a fixed rig, with the frame rate."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from srde_fusion.errors import ImageError
from srde_fusion.fusion import FrameTiming, HybridStereo, StreamStats
from srde_fusion.synthetic import default_rig, random_scene, render

N_FRAMES = 3


@pytest.fixture(scope="module")
def line():
    """A sorting line: one rig and light, one glossy object, frames differing by sensor noise."""
    rig = default_rig().scaled(0.5)
    scene = random_scene(3, rig, n_objects=1, background="textured")
    rig = rig.with_light(scene.light.position_m)
    renderings = [render(scene, rig, noise_seed=k) for k in range(N_FRAMES)]
    truth = renderings[0].disparity_px

    def backbone(left, right):  # right on the background, nothing on the glossy object
        out = truth.copy()
        out[renderings[0].instance_mask > 0] = 5.0
        return out

    return rig, backbone, [r.views for r in renderings], truth


def test_a_stream_gives_what_frame_by_frame_calls_give(line):
    rig, backbone, frames, truth = line
    model = HybridStereo(backbone, rig)
    expected = [HybridStereo(backbone, rig)(views) for views in frames]
    stream = model.stream(frames)
    results = list(stream)
    assert len(results) == N_FRAMES
    for got, want in zip(results, expected, strict=True):
        np.testing.assert_array_equal(got.disparity, want.disparity)
        np.testing.assert_array_equal(got.source, want.source)
        assert [o.status for o in got.objects] == [o.status for o in want.objects] == ["srde"]
    # SRDE's plane, not the backbone's 5 px, on the object
    inside = results[0].source > 0
    assert np.nanmean(np.abs(results[0].disparity[inside] - truth[inside])) < 0.05


def test_the_rig_work_is_done_once_for_the_stream(line):
    rig, backbone, frames, _ = line
    model = HybridStereo(backbone, rig)
    stream = model.stream(frames)
    srde = model._srde
    assert srde is not None  # built before the first frame
    list(stream)
    assert model._srde is srde


def test_stream_stats_add_up(line):
    rig, backbone, frames, _ = line
    stream = HybridStereo(backbone, rig).stream(frames)
    assert stream.stats == StreamStats() and math.isnan(stream.stats.fps)
    assert stream.last_timing is None
    timings = []
    for _ in stream:
        timings.append(stream.last_timing)
        assert stream.stats.frames == len(timings)
    stats = stream.stats
    assert stats.busy_s == pytest.approx(sum(t.total_s for t in timings))
    assert stats.backbone_s == pytest.approx(sum(t.backbone_s for t in timings))
    assert stats.busy_s == pytest.approx(stats.backbone_s + stats.masks_s + stats.fusion_s)
    assert stats.fps == pytest.approx(N_FRAMES / stats.busy_s)
    assert stats.wall_s >= stats.busy_s > 0 and stats.wall_fps <= stats.fps
    assert all(t.masks_s > 0 and t.fusion_s > 0 for t in timings)
    assert stats.summary().startswith(f"{N_FRAMES} frames, ")


def test_each_stage_is_timed_where_it_runs(line):
    rig, _, frames, _ = line
    nap_s = 0.05

    def slow_backbone(left, right):
        time.sleep(nap_s)
        return np.full(left.shape[:2], 5.0, np.float32)

    stream = HybridStereo(slow_backbone, rig, masker=lambda views, rig: []).stream(frames[:1])
    next(stream)
    assert stream.last_timing.backbone_s >= nap_s
    assert FrameTiming(1.0, 2.0, 3.0).total_s == 6.0


def test_frames_are_read_one_at_a_time_and_a_bad_frame_raises_there(line):
    rig, backbone, frames, _ = line
    read = []

    def source():
        for k, views in enumerate(frames[:2]):
            read.append(k)
            yield views
        read.append("bad")
        yield [v[:-1] for v in frames[2]]

    stream = HybridStereo(backbone, rig).stream(source())
    assert read == []
    next(stream)
    assert read == [0]
    next(stream)
    with pytest.raises(ImageError):
        next(stream)
    assert read == [0, 1, "bad"] and stream.stats.frames == 2
