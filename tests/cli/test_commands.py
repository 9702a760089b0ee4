from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from srde_fusion.cli import main
from srde_fusion.io import read_disparity, read_image, read_mask, read_scene, write_scene
from srde_fusion.synthetic import default_rig, render
from srde_fusion.synthetic.faceted import faceted_scene
from srde_fusion.synthetic.scene import rig_lights
from srde_fusion.workflows import srde_scene
from tests.support import FLAT_PX, export_constant_model, run_cli


@pytest.fixture(scope="module")
def flat_backbone(tmp_path_factory):
    """An ONNX 'stereo network' that answers 15 px everywhere."""
    return export_constant_model(tmp_path_factory.mktemp("model") / "flat.onnx", FLAT_PX)


# ---------------------------------------------------------------- demo
def test_demo_end_to_end(tmp_path, capsys):
    code, out, err = run_cli(capsys, "demo", "--out", tmp_path / "demo", "--scale", "0.5")
    assert code == 0, err
    demo = tmp_path / "demo"
    for name in ("fused_disparity.pfm", "fused_disparity.png", "backbone_disparity.pfm",
                 "srde_disparity.pfm", "source.png", "report.json", "figure.png"):
        assert (demo / name).is_file(), name
    assert (demo / "scene" / "rig.json").is_file()
    fused = read_disparity(demo / "fused_disparity.pfm")
    kitti = read_disparity(demo / "fused_disparity.png")
    assert fused.shape == kitti.shape == (240, 320)
    assert np.nanmax(np.abs(fused - kitti)) <= 1 / 512 + 1e-6  # KITTI's 1/256 px steps
    source = read_mask(demo / "source.png")
    report = json.loads((demo / "report.json").read_text())
    assert report["fusion"]["pixels_from_srde"] == int(np.count_nonzero(source))
    assert read_image(demo / "figure.png").shape[2] in (3, 4)
    # The printed table compares the three maps over the full scene and the objects.
    assert "### Full scene" in out and "### Objects (masked)" in out
    for row in ("| backbone |", "| srde |", "| fused |"):
        assert out.count(row) == 2
    assert err == ""
    # The stand-in fails on the glossy objects; the fused map does not.
    scores = report["scores"]
    assert report["fusion"]["n_srde"] >= 1
    assert scores["fused"]["masked"]["epe"] < 0.2 * scores["backbone"]["masked"]["epe"]
    assert scores["fused"]["full"]["epe"] < scores["backbone"]["full"]["epe"]


# ---------------------------------------------------------------- fuse / srde / eval
def test_fuse_command_with_an_onnx_backbone(dataset, flat_backbone, tmp_path, capsys):
    scene = dataset / "scene_0000"
    code, out, err = run_cli(capsys, "fuse", scene, "--backbone", flat_backbone,
                             "--preset", "generic", "--out", tmp_path / "fused")
    assert code == 0, err
    assert out.startswith("object 1: ")
    fused = read_disparity(tmp_path / "fused" / "fused_disparity.pfm")
    source = read_mask(tmp_path / "fused" / "source.png")
    assert np.all(fused[source == 0] == FLAT_PX)  # the backbone's pixels, untouched
    report = json.loads((tmp_path / "fused" / "report.json").read_text())
    assert report["masks"] == "user (scene mask.png)"
    assert "\nmasks: user (scene mask.png)\n" in out  # which masks were used, on the console too
    assert report["fusion"]["pixels_from_srde"] == int(np.count_nonzero(source))


def test_srde_command(dataset, tmp_path, capsys):
    code, out, err = run_cli(capsys, "srde", dataset / "scene_0000", "--out", tmp_path / "s")
    assert code == 0, err
    assert out.startswith("object 1: ok")
    sigma = float(re.search(r"disparity \+- ([0-9.]+) px", out).group(1))
    assert 0.0 < sigma < 0.5  # the refined plane's standard error
    report = json.loads((tmp_path / "s" / "report.json").read_text())
    assert json.dumps(report).count('"disparity_sigma_px"') >= 1
    srde = read_disparity(tmp_path / "s" / "srde_disparity.pfm")
    scene = read_scene(dataset / "scene_0000")
    mask = scene.mask_labels > 0
    assert np.all(np.isnan(srde[~mask]))
    assert np.nanmean(np.abs(srde[mask] - scene.gt_disparity[mask])) < 0.5
    # Without --out nothing is written, and the result is still returned.
    run = srde_scene(dataset / "scene_0000")
    assert run.files == {} and run.fusion.objects[0].srde.ok
    assert run.scores["srde"]["masked"]["epe"] < 0.5  # scored without writing anything
    code, out, err = run_cli(capsys, "srde", dataset / "scene_0000")
    assert code == 0 and "| srde |" in out  # and printed


def test_eval_command(dataset, tmp_path, capsys):
    code, out, err = run_cli(capsys, "eval", dataset, "--backbone", "default",
                             "--out", tmp_path / "e", "--quiet")
    assert code == 0, err
    assert "2 scene(s), 2 object(s)" in out
    assert "### Full scene" in out and "### Objects (masked)" in out
    assert "±" in out
    data = json.loads((tmp_path / "e" / "eval.json").read_text())
    masked = data["summary"]["fused"]["masked"]["epe"]["mean"]
    assert masked < 0.2 * data["summary"]["backbone"]["masked"]["epe"]["mean"]
    assert len(data["scenes"]) == 2
    md = (tmp_path / "e" / "eval.md").read_text()
    assert md.startswith("## ")
    # how the folder was made, and every stereo-benchmark threshold, are in it
    assert data["settings"] == {"dataset": str(dataset), "backbone": "default", "preset": None,
                                "spec": None, "masks": "user", "srde_method": "default",
                                "device": "cpu", "jobs": data["run"]["jobs"]}
    assert "- masks: user" in md and "| fused |" in md and "| hybrid |" not in md
    assert all(f"| {k} " in md for k in ("bad0.5", "bad1", "bad2", "bad3", "bad4", "d1"))


# ---------------------------------------------------------------- bad input
def assert_one_line_error(code, out, err, command, match):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"srde-fusion {command}: error: ")
    assert match in lines[0]
    assert "Traceback" not in err


@pytest.mark.parametrize("argv, command, match", [
    (["fuse", "no/such/scene", "--backbone", "default", "--out", "x"], "fuse",
     "expected a scene folder"),
    (["srde", "no/such/scene"], "srde", "expected a scene folder"),
    (["eval", "no/such/dataset", "--backbone", "default"], "eval", "expected a dataset folder"),
    (["demo", "--seed", "seven"], "demo", "invalid int value"),
    (["demo", "--scale", "9"], "demo", "scale: expected a factor in [0.1, 4]"),
    (["fuse", "x", "--out", "y"], "fuse", "--backbone"),
    (["srde", "x", "--light", "1,2"], "srde", "expected X,Y,Z in metres"),
    (["srde", "x", "--max-faces", "4"], "srde", "--max-faces: invalid choice"),
])
def test_bad_input_exits_2_with_one_line(capsys, tmp_path, monkeypatch, argv, command, match):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        code = main(argv)
        raise SystemExit(code)
    code = info.value.code
    out, err = capsys.readouterr()
    assert_one_line_error(code, out, err, command, match)


def test_bad_backbone_file_exits_2(dataset, tmp_path, capsys):
    (tmp_path / "junk.onnx").write_bytes(b"junk")
    code, out, err = run_cli(capsys, "fuse", dataset / "scene_0000", "--backbone",
                             tmp_path / "junk.onnx", "--out", tmp_path / "o")
    assert_one_line_error(code, out, err, "fuse", "junk.onnx")


def test_scene_without_light_exits_2(dataset, flat_backbone, tmp_path, capsys):
    scene = read_scene(dataset / "scene_0000")
    folder = write_scene(tmp_path / "dark", scene.views, scene.rig.with_light(None),
                         mask=scene.mask_labels)
    code, out, err = run_cli(capsys, "fuse", folder, "--backbone", flat_backbone,
                             "--out", tmp_path / "o")
    assert_one_line_error(code, out, err, "fuse", "light: expected a light position")


def test_eval_user_masks_needs_masks(dataset, flat_backbone, tmp_path, capsys):
    scene = read_scene(dataset / "scene_0000")
    write_scene(tmp_path / "ds" / "a", scene.views, scene.rig, gt_disparity=scene.gt_disparity)
    code, out, err = run_cli(capsys, "eval", tmp_path / "ds", "--backbone", flat_backbone,
                             "--quiet", "--strict")
    assert_one_line_error(code, out, err, "eval", "expected a mask.png for --masks user")


def test_eval_keeps_going_past_a_bad_scene(dataset, flat_backbone, tmp_path, capsys):
    ds = tmp_path / "ds"
    for name in ("scene_0000", "scene_0001"):
        scene = read_scene(dataset / name)
        write_scene(ds / name, scene.views, scene.rig, mask=scene.mask_labels,
                    gt_disparity=scene.gt_disparity)
    (ds / "scene_0001" / "cam4.png").write_bytes(b"not an image")
    code, out, err = run_cli(capsys, "eval", ds, "--backbone", flat_backbone, "--quiet",
                             "--out", tmp_path / "e", "--jobs", "1")
    assert code == 1
    assert "1 scene(s), 1 object(s)" in out and "1 scene(s) failed" in out
    assert "| scene_0001 | FileFormatError |" in out and "expected a readable" in out
    assert "could not be evaluated" in err
    report = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert [s["name"] for s in report["scenes"]] == ["scene_0000"]  # nothing computed is lost
    assert report["failures"][0]["name"] == "scene_0001"
    assert not (tmp_path / "e" / ".srde-fusion.lock").exists()


def test_eval_checks_and_locks_its_output_folder_first(dataset, tmp_path, capsys):
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / ".srde-fusion.lock").write_text("123\n")
    code, out, err = run_cli(capsys, "eval", dataset, "--backbone", "default", "--quiet",
                             "--out", tmp_path / "e")
    assert_one_line_error(code, out, err, "eval", "expected a folder no other run is writing")
    (tmp_path / "file").write_text("")
    code, out, err = run_cli(capsys, "eval", dataset, "--backbone", "default", "--quiet",
                             "--out", tmp_path / "file" / "e")
    assert_one_line_error(code, out, err, "eval", "could not create or write the output folder")


def test_every_command_has_help(capsys):
    for command in ("demo", "fuse", "srde", "eval"):
        with pytest.raises(SystemExit) as info:
            main([command, "--help"])
        assert info.value.code == 0
        assert f"usage: srde-fusion {command}" in capsys.readouterr().out


def test_version(capsys):
    import srde_fusion

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"srde-fusion {srde_fusion.__version__}"


def test_fuse_command_on_an_existing_disparity_file(dataset, tmp_path, capsys):
    from srde_fusion.io import write_disparity

    scene = read_scene(dataset / "scene_0000")
    write_disparity(tmp_path / "disp.png", np.full(scene.gt_disparity.shape, 15.0, np.float32))
    code, out, err = run_cli(capsys, "fuse", scene.path, "--disparity", tmp_path / "disp.png",
                             "--out", tmp_path / "o")
    assert code == 0, err
    fused = read_disparity(tmp_path / "o" / "fused_disparity.pfm")
    source = read_mask(tmp_path / "o" / "source.png")
    assert np.all(fused[source == 0] == 15.0) and np.count_nonzero(source) > 0
    with pytest.raises(SystemExit) as info:  # argparse's own exit for a usage error
        main(["fuse", str(scene.path), "--disparity", str(tmp_path / "disp.png"),
              "--backbone", "default", "--out", str(tmp_path / "o2")])
    assert info.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_device_option_fails_early_without_the_device(dataset, tmp_path, capsys):
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this machine has CUDA")
    code, out, err = run_cli(capsys, "fuse", dataset / "scene_0000", "--backbone", "default",
                             "--device", "cuda", "--out", tmp_path / "o")
    assert_one_line_error(code, out, err, "fuse", "got ['CUDAExecutionProvider']")
    assert not (tmp_path / "o").exists()
    code, out, err = run_cli(capsys, "fuse", dataset / "scene_0000", "--backbone", "default",
                             "--device", "tpu", "--out", tmp_path / "o")
    assert_one_line_error(code, out, err, "fuse", "--device: expected cpu or cuda[:N], got 'tpu'")


def test_verbose_says_what_is_done_and_quiet_keeps_stderr_for_errors(dataset, tmp_path, capsys):
    code, out, err = run_cli(capsys, "fuse", "-vv", dataset / "scene_0000", "--disparity",
                             dataset / "scene_0000" / "gt_disparity.pfm", "--out", tmp_path / "o")
    assert code == 0, err
    assert "srde-fusion: scene_0000: masks user (scene mask.png); using the given disparity" in err
    assert "srde-fusion: fusing 1 object(s)" in err and "srde-fusion: object 1: srde" in err
    code, out, err = run_cli(capsys, "fuse", "--quiet", dataset / "scene_0000", "--disparity",
                             dataset / "scene_0000" / "gt_disparity.pfm", "--out", tmp_path / "o")
    assert code == 0 and err == ""


def test_on_a_terminal_commands_say_what_they_do_by_default(dataset, tmp_path, capsys,
                                                           monkeypatch):
    args = ("fuse", dataset / "scene_0000", "--disparity",
            dataset / "scene_0000" / "gt_disparity.pfm", "--out", tmp_path / "o")
    code, _, err = run_cli(capsys, *args)
    assert code == 0 and err == ""  # redirected: stderr only for warnings and errors
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    code, _, err = run_cli(capsys, *args)
    assert code == 0
    assert "srde-fusion: fusing 1 object(s)" in err
    assert "srde-fusion: writing the results into" in err
    assert "object 1: srde" not in err  # each object's decision only with -v


def test_fuse_a_folder_of_scenes_in_one_call(dataset, flat_backbone, tmp_path, capsys):
    ds = tmp_path / "ds"
    for name in ("scene_0000", "scene_0001"):
        scene = read_scene(dataset / name)
        write_scene(ds / name, scene.views, scene.rig, mask=scene.mask_labels)
    (ds / "scene_0001" / "cam4.png").write_bytes(b"broken")
    code, out, err = run_cli(capsys, "fuse", ds, "--backbone", flat_backbone, "--preset",
                             "generic", "--out", tmp_path / "o", "--quiet")
    assert code == 1
    assert "scene_0001: failed - FileFormatError:" in out
    assert "1 scene(s) fused, 1 object(s): SRDE used on 1, backbone kept on 0; 1 scene(s) " \
        "failed" in out
    assert (tmp_path / "o" / "scene_0000" / "fused_disparity.pfm").is_file()
    assert not (tmp_path / "o" / "scene_0001").exists()
    code, out, err = run_cli(capsys, "fuse", ds, "--disparity", ds / "x.pfm", "--out",
                             tmp_path / "o2")
    assert_one_line_error(code, out, err, "fuse", "expected --backbone for a folder of scenes")


def test_fuse_a_kitti_folder_frame_by_frame(flat_backbone, tmp_path, capsys):
    from srde_fusion.geometry import CameraRig
    from srde_fusion.io import write_disparity, write_image
    from srde_fusion.synthetic import random_scene, render

    # A fixed rig and light (a sorting line): one glossy object, two frames of sensor noise.
    rig = CameraRig.stereo(0.3, fx=320.0, image_size=(320, 240), names=("image_2", "image_3"))
    scene = random_scene(2, rig, n_objects=1, background="textured")
    light = scene.light.position_m
    root = tmp_path / "kitti"
    fx, cx, cy = rig.intrinsics.fx, rig.intrinsics.cx, rig.intrinsics.cy
    for k, frame in enumerate(("000000_10", "000001_10")):
        rendering = render(scene, rig.with_light(light), noise_seed=k)
        for folder, view in zip(("image_2", "image_3"), rendering.views, strict=True):
            (root / folder).mkdir(parents=True, exist_ok=True)
            write_image(root / folder / f"{frame}.png", view)
        (root / "disp_occ_0").mkdir(exist_ok=True)
        write_disparity(root / "disp_occ_0" / f"{frame}.png", rendering.disparity_px)
    (root / "calib_cam_to_cam.txt").write_text("".join(
        f"{key}: {fx} 0 {cx} {-fx * x} 0 {fx} {cy} 0 0 0 1 0\n"
        for key, x in (("P_rect_02", 0.0), ("P_rect_03", 0.3))))
    # --light=X,Y,Z: a negative X would otherwise read as an option
    light_arg = "--light=" + ",".join(f"{v:.9f}" for v in light)
    code, out, err = run_cli(capsys, "fuse", root, "--backbone", "default", light_arg, "--out",
                             tmp_path / "o")
    assert code == 0, err
    assert "2 scene(s) fused, 2 object(s): SRDE used on 2, backbone kept on 0" in out
    assert "fusing" in err  # the progress bar
    for frame in ("000000_10", "000001_10"):
        report = json.loads((tmp_path / "o" / frame / "report.json").read_text())
        assert report["fusion"]["n_srde"] == 1
        # SRDE's plane on the object, from the KITTI calibration's rig and the given light
        assert report["scores"]["fused"]["masked"]["epe"] < 0.1
    # one frame on its own, as KITTI_DIR/<frame>
    code, out, err = run_cli(capsys, "fuse", root / "000001_10", "--backbone", "default",
                             light_arg, "--out", tmp_path / "one", "--quiet")
    assert code == 0 and "object 1: srde" in out, out
    # without a light (the calibration file has none) every frame fails, and says why
    code, out, err = run_cli(capsys, "fuse", root, "--backbone", flat_backbone, "--out",
                             tmp_path / "o3", "--quiet")
    assert code == 1 and "000000_10: failed - LightError: light: expected a light" in out


def test_a_binary_mask_is_split_unless_kept_as_one(dataset, tmp_path, capsys):
    from srde_fusion.io import write_mask

    scene = read_scene(dataset / "scene_0000")
    labels = scene.mask_labels
    binary = np.zeros_like(labels, dtype=np.uint8)
    binary[labels > 0] = 255
    # a second, separate blob: two components in one 0/255 mask
    binary[5:25, 5:25] = 255
    write_mask(tmp_path / "binary.png", binary)
    given = dataset / "scene_0000" / "gt_disparity.pfm"
    base = ["fuse", dataset / "scene_0000", "--disparity", given, "--mask", tmp_path / "binary.png"]
    code, out, _ = run_cli(capsys, *base, "--out", tmp_path / "split")
    assert code == 0 and "object 2:" in out and "binary mask split into 2 objects" in out
    code, out, _ = run_cli(capsys, *base, "--mask-as-one", "--out", tmp_path / "one")
    assert code == 0 and "object 1:" in out and "object 2:" not in out
    code, _, err = run_cli(capsys, "fuse", dataset / "scene_0000", "--disparity", given,
                           "--mask-as-one", "--out", tmp_path / "x")
    assert code == 2 and "--mask-as-one: expected --mask FILE" in err


def test_srde_and_fuse_commands_with_max_faces(tmp_path, capsys):
    # A box seen on an edge, one mask for both faces: --max-faces 3 gives each face its
    # plane (the fused map carries the edge); the rig lists both lights.
    rig = default_rig()
    faceted = faceted_scene(31001, rig, n_faces=2, convex=True)
    rendering = render(faceted.scene, rig, supersample=2)
    lit = rig.with_lights(rig_lights(faceted.scene))
    mask = rendering.instance_mask > 0
    scene = write_scene(tmp_path / "box", rendering.views, lit, mask=mask,
                        gt_disparity=rendering.disparity_px)
    code, out, err = run_cli(capsys, "srde", scene, "--max-faces", "3", "--out", tmp_path / "s")
    assert code == 0, err
    assert out.startswith("object 1: ok")
    sigma = float(re.search(r"disparity \+- ([0-9.]+) px", out).group(1))
    assert 0.0 < sigma < 0.5  # the refined plane's standard error
    report = json.loads((tmp_path / "s" / "report.json").read_text())
    assert json.dumps(report).count('"disparity_sigma_px"') >= 1
    srde = read_disparity(tmp_path / "s" / "srde_disparity.pfm")
    for k in (1, 2):
        part = rendering.instance_mask == k
        assert np.mean(np.abs(srde[part] - rendering.disparity_px[part])) < 0.05
    # The given map is right along the outline and wrong deeper inside the object.
    inner = np.zeros_like(mask)
    inner[8:-8, 8:-8] = mask[:-16, 8:-8] & mask[16:, 8:-8] & mask[8:-8, :-16] & mask[8:-8, 16:]
    disparity = np.where(inner, 1.0, rendering.disparity_px).astype(np.float32)
    np.save(tmp_path / "given.npy", disparity)
    code, out, err = run_cli(capsys, "fuse", scene, "--disparity", tmp_path / "given.npy",
                             "--max-faces", "3", "--out", tmp_path / "f")
    assert code == 0, err
    assert "object 1: srde" in out and "2 faces' stretches" in out, out
    fused = read_disparity(tmp_path / "f" / "fused_disparity.pfm")
    assert np.mean(np.abs(fused[mask] - rendering.disparity_px[mask])) < 0.05
