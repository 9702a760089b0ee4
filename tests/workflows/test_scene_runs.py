"""The scene-folder workflows, called as library functions."""

from __future__ import annotations

import json

import numpy as np
import pytest

from srde_fusion.errors import SRDEError
from srde_fusion.io import read_scene
from srde_fusion.workflows import fuse_scene, run_demo, srde_scene
from tests.support import FLAT_PX, flat


def test_run_demo_with_a_callable_backbone(tmp_path):
    run = run_demo(tmp_path, backbone=flat, scale=0.5, seed=3, n_objects=1)
    assert run.scene_dir == tmp_path / "scene"
    assert read_scene(run.scene_dir).rig.light_position_m is not None
    outside = run.fusion.source == 0
    assert np.all(run.fusion.disparity[outside] == np.float32(FLAT_PX))
    assert set(run.files) >= {"fused_pfm", "figure_png", "report_json"}


def test_fuse_scene_with_a_mask_file_and_auto_mask(dataset, tmp_path):
    scene = read_scene(dataset / "scene_0001")
    labels = scene.mask_labels
    np.save(tmp_path / "mask.npy", labels)
    with_file = fuse_scene(scene.path, tmp_path / "a", backbone=flat, mask=tmp_path / "mask.npy")
    auto = fuse_scene(scene.path, tmp_path / "b", backbone=flat, auto_mask=True)
    assert with_file.fusion.objects[0].pixel_count == int(np.count_nonzero(labels))
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert report["masks"].startswith("auto")
    assert len(auto.fusion.objects) >= 1


def test_an_output_folder_never_mixes_two_runs(dataset, tmp_path):
    out = tmp_path / "out"
    fuse_scene(dataset / "scene_0000", out, backbone=flat)
    assert (out / "backbone_disparity.pfm").is_file()
    # SRDE alone into the same folder: the fused maps of the first run are not left behind
    run = srde_scene(dataset / "scene_0000", out)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["depth.pfm", "disparity_color.png", "figure.png", "points.ply",
                     "report.json", "source.png", "srde_disparity.pfm", "srde_disparity.png"]
    assert any("left by an earlier run" in note for note in run.notes)
    report = json.loads((out / "report.json").read_text())
    assert sorted(report["files"].values()) == names


def test_fuse_a_disparity_map_the_pipeline_already_made(dataset, tmp_path):
    from srde_fusion.io import write_disparity

    scene = read_scene(dataset / "scene_0000")
    h, w = scene.gt_disparity.shape
    write_disparity(tmp_path / "pipeline.pfm", np.full((h, w), FLAT_PX / 2, np.float32))
    run = fuse_scene(scene.path, tmp_path / "out", disparity=tmp_path / "pipeline.pfm",
                     disparity_scale=2.0)
    outside = run.fusion.source == 0
    assert np.all(run.fusion.disparity[outside] == np.float32(FLAT_PX))
    assert run.fusion.objects[0].used_srde


def test_fuse_scene_needs_exactly_one_disparity_source(dataset, tmp_path):
    with pytest.raises(SRDEError, match="backbone, disparity: expected exactly one .* got neither"):
        fuse_scene(dataset / "scene_0000", tmp_path)
    with pytest.raises(SRDEError, match="got both"):
        fuse_scene(dataset / "scene_0000", tmp_path, backbone=flat, disparity=tmp_path / "d.pfm")
    with pytest.raises(SRDEError, match="disparity_scale: expected a positive number"):
        fuse_scene(dataset / "scene_0000", tmp_path, disparity=tmp_path / "d.pfm",
                   disparity_scale=0)


def test_depth_and_point_cloud_outputs_agree_with_the_disparity(dataset, tmp_path):
    from srde_fusion.io import read_disparity, read_pfm

    run = fuse_scene(dataset / "scene_0000", tmp_path / "out", backbone=flat)
    rig = read_scene(dataset / "scene_0000").rig
    fused = read_disparity(tmp_path / "out" / "fused_disparity.pfm")
    depth = read_pfm(tmp_path / "out" / "depth.pfm")
    valid = np.isfinite(fused)
    np.testing.assert_allclose(depth[valid], rig.intrinsics.fx * rig.baseline_m / fused[valid],
                               rtol=1e-6)
    data = (tmp_path / "out" / "points.ply").read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert f"element vertex {int(valid.sum())}".encode() in header
    assert len(body) == int(valid.sum()) * (3 * 4 + 3)  # xyz float32 + rgb uint8
    points = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    np.testing.assert_allclose(points["xyz"][:, 2] - rig.reference_center_m[2],
                               depth[valid], rtol=1e-5)
    assert set(run.files) >= {"depth_pfm", "points_ply", "color_png"}


def test_point_cloud_reads_back_with_a_standard_ply_reader(dataset, tmp_path):
    # plyfile (dev extra) parses the header and the binary body on its own terms: what
    # Open3D, MeshLab and CloudCompare users will open.
    from plyfile import PlyData

    from srde_fusion.io import read_disparity

    fuse_scene(dataset / "scene_0000", tmp_path / "out", backbone=flat)
    fused = read_disparity(tmp_path / "out" / "fused_disparity.pfm")
    ply = PlyData.read(str(tmp_path / "out" / "points.ply"))
    vertex = ply["vertex"]
    assert ply.text is False and ply.byte_order == "<"
    assert vertex.count == int(np.isfinite(fused).sum())
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "red", "green", "blue"]
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    assert np.all(np.isfinite(xyz)) and np.all(xyz[:, 2] > 0)
    assert vertex["red"].dtype == np.uint8
