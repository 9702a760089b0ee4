"""The command on bad input: exit code 2 and exactly one line on stderr, never a traceback.

Run in-process (``srde_fusion.cli.main`` with capfd, which also sees what C libraries
write to the file descriptors) and once as a real process (``python -m srde_fusion.cli``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from srde_fusion.cli import main
from srde_fusion.io import write_scene
from tests.support import box_mask, grid_rig, highlight_views, true_centers


@pytest.fixture(scope="module")
def good_scene(tmp_path_factory) -> Path:
    rig = grid_rig()
    views = highlight_views(true_centers(rig))
    labels = box_mask().astype(np.uint8)
    return write_scene(tmp_path_factory.mktemp("scenes") / "good", views, rig, mask=labels,
                       gt_disparity=np.full((rig.height, rig.width), 20.0, np.float32))


@pytest.fixture()
def scene(tmp_path, good_scene) -> Path:
    """A fresh copy of the good scene, to damage."""
    return Path(shutil.copytree(good_scene, tmp_path / "scene"))


def run(capfd, *argv) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argument errors exit from argparse
        code = exc.code
    out, err = capfd.readouterr()
    return code, out, err


def assert_one_line(code, err, command, match):
    lines = err.splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    prefix = "srde-fusion" + (f" {command}" if command else "")
    assert lines[0].startswith(f"{prefix}: error: "), lines[0]
    assert match in lines[0], lines[0]


def test_the_good_scene_runs(capfd, good_scene):
    code, out, err = run(capfd, "srde", good_scene)
    assert code == 0 and err == ""
    assert out.startswith("object 1: ok")


@pytest.mark.parametrize("argv, command, match", [
    ([], None, "the following arguments are required: COMMAND"),
    (["nope"], None, "argument COMMAND: invalid choice: 'nope'"),
    (["render"], "render", "the following arguments are required: out_dir"),
    (["fuse"], "fuse", "the following arguments are required: scene_dir, --out"),
    (["fuse", "x", "--out", "y"], "fuse", "one of the arguments --backbone --disparity is "
     "required"),
    (["fuse", "x", "--out", "y", "--backbone", "default", "--disparity", "d.pfm"], "fuse",
     "argument --disparity: not allowed with argument --backbone"),
    (["srde"], "srde", "the following arguments are required: scene_dir"),
    (["eval"], "eval", "the following arguments are required: dataset_dir, --backbone"),
    (["calibrate-light"], "calibrate-light", "the following arguments are required"),
    (["make-board"], "make-board", "the following arguments are required"),
    (["train-standin", "--steps", "many"], "train-standin", "invalid int value: 'many'"),
    (["srde", "x", "--light", "0,0"], "srde", "expected X,Y,Z in metres, got '0,0'"),
    (["srde", "x", "--light", "inf,0,0"], "srde", "expected X,Y,Z in metres, got 'inf,0,0'"),
    (["srde", "x", "--method", "best"], "srde", "argument --method: invalid choice: 'best'"),
    (["demo", "--scale", "nan"], "demo", "scale: expected a factor in [0.1, 4], got nan"),
])
def test_argument_errors(capfd, argv, command, match):
    code, _, err = run(capfd, *argv)
    assert_one_line(code, err, command, match)


def _truncate(path: Path, keep: int) -> None:
    path.write_bytes(path.read_bytes()[:keep])


@pytest.mark.parametrize("damage, match", [
    (lambda d: _truncate(d / "cam3.png", 60), "cam3.png: expected a readable 8-bit image, got "
     "undecodable data"),
    (lambda d: _truncate(d / "rig.json", 40), "rig.json: expected valid JSON"),
    (lambda d: (d / "rig.json").write_text((d / "rig.json").read_text().replace(
        '"reference"', '"ref"')), "rig: unknown key(s) ['ref']"),
    (lambda d: (d / "cam8.png").unlink(), "missing ['cam8']"),
    (lambda d: shutil.copy(d / "cam0.png", d / "cam9.png"), "got extra ['cam9.png']"),
    (lambda d: (d / "mask.png").write_bytes(b"not a png"), "mask.png: expected a readable mask "
     "image"),
    (lambda d: _truncate(d / "gt_disparity.pfm", 100), "(truncated file)"),
    (lambda d: (d / "scene.json").write_text("{"), "scene.json: expected valid JSON"),
    (lambda d: cv2.imwrite(str(d / "cam2.png"), np.zeros((10, 10, 3), np.uint8)),
     "cam2.png: expected the rig's image size 200x150, got 10x10"),
    (lambda d: cv2.imwrite(str(d / "mask.png"), np.zeros((150, 200), np.uint8)),
     "masks: expected at least one object (a non-zero label), got none"),
    (lambda d: (d / "rig.json").write_text((d / "rig.json").read_text().replace(
        '"light"', '"unused"')), "rig: unknown key(s) ['unused']"),
])
def test_damaged_scene_folders(capfd, scene, damage, match):
    damage(scene)
    code, _, err = run(capfd, "srde", scene)
    assert_one_line(code, err, "srde", match)


def test_a_scene_without_a_light(capfd, scene):
    rig_json = scene / "rig.json"
    text = rig_json.read_text()
    start = text.index(',\n  "light"')
    rig_json.write_text(text[:start] + "\n}\n")
    code, _, err = run(capfd, "fuse", scene, "--backbone", "default", "--out", scene / "out")
    assert_one_line(code, err, "fuse", "light: expected a light position")


def test_a_mask_file_of_the_wrong_size(capfd, scene, tmp_path):
    cv2.imwrite(str(tmp_path / "small.png"), np.ones((15, 20), np.uint8))
    code, _, err = run(capfd, "srde", scene, "--mask", tmp_path / "small.png")
    assert_one_line(code, err, "srde", "masks[0]: expected shape (150, 200)")


@pytest.mark.parametrize("model, preset, match", [
    (b"", None, "junk.onnx"),
    (os.urandom(2000), None, "junk.onnx"),
    (None, None, "expected an existing .onnx file"),
    (b"x", "sgm", "expected one of the presets"),
])
def test_bad_models(capfd, scene, tmp_path, model, preset, match):
    path = tmp_path / "junk.onnx"
    if model is not None:
        path.write_bytes(model)
    argv = ["fuse", scene, "--backbone", path, "--out", tmp_path / "out"]
    code, _, err = run(capfd, *argv, *(["--preset", preset] if preset else []))
    assert_one_line(code, err, "fuse", match)


@pytest.mark.parametrize("blocker", ["report.json", "figure.png", "srde_disparity.pfm"])
def test_an_output_the_system_refuses(capfd, good_scene, tmp_path, blocker):
    out = tmp_path / "out"
    (out / blocker).mkdir(parents=True)  # a folder where a file must go
    code, _, err = run(capfd, "srde", good_scene, "--out", out)
    assert_one_line(code, err, "srde", blocker)


def test_an_output_folder_that_is_a_file(capfd, good_scene):
    code, _, err = run(capfd, "srde", good_scene, "--out", good_scene / "rig.json")
    assert_one_line(code, err, "srde", "could not create the output folder")


def test_a_dataset_with_a_broken_scene(capfd, good_scene, tmp_path):
    dataset = tmp_path / "dataset"
    shutil.copytree(good_scene, dataset / "a")
    shutil.copytree(good_scene, dataset / "b")
    _truncate(dataset / "b" / "cam0.png", 30)
    # --strict: the first bad scene stops the run, with one line and exit status 2
    code, _, err = run(capfd, "eval", dataset, "--backbone", "default", "--quiet", "--strict")
    assert_one_line(code, err, "eval", "cam0.png: expected a readable 8-bit image")
    # by default the good scene is still evaluated and the bad one listed: exit status 1
    code, out, err = run(capfd, "eval", dataset, "--backbone", "default", "--quiet")
    assert code == 1 and "Traceback" not in err
    assert "| b | FileFormatError |" in out and "cam0.png: expected a readable 8-bit image" in out


def test_as_a_process(tmp_path, good_scene):
    scene = Path(shutil.copytree(good_scene, tmp_path / "scene"))
    _truncate(scene / "cam4.png", 70)
    proc = subprocess.run([sys.executable, "-m", "srde_fusion.cli", "srde", str(scene)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [
        f"srde-fusion srde: error: {scene / 'cam4.png'}: expected a readable 8-bit image, got "
        "undecodable data"]
    assert proc.stdout == ""
