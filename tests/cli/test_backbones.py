"""``--spec spec.json``: a model's conventions from a file, on every command that runs one."""

from __future__ import annotations

import json

import numpy as np
import pytest
from srde_fusion.adapters import StereoSpec, preset

from srde_fusion.cli import main
from srde_fusion.cli.backbones import spec_from_file
from srde_fusion.errors import BackboneError
from srde_fusion.io import read_disparity, read_mask
from tests.support import export_constant_model, run_cli

# The model below answers this negative flow everywhere; the spec turns it into 15 px.
FLOW_PX = -30.0


@pytest.fixture(scope="module")
def flow_model(tmp_path_factory):
    """An ONNX 'stereo network' with RAFT-like conventions: negative flow, twice the scale."""
    return export_constant_model(tmp_path_factory.mktemp("model") / "flow.onnx", FLOW_PX,
                                 output_name="flow")


def write_spec(folder, data, name="spec.json"):
    path = folder / name
    path.write_text(json.dumps(data))
    return path


def test_a_spec_file_holds_any_field_and_a_preset_base(tmp_path):
    spec = spec_from_file(write_spec(tmp_path, {
        "channel_order": "BGR", "mean": [123.7, 116.3, 103.5], "std": [58.4, 57.1, 57.4],
        "pad_multiple": 16, "output": "disp_up", "output_sign": -1, "input_size": [640, 480],
        "input_names": ["l", "r"], "extra_inputs": {"iters": 12}}, "my_net.json"))
    assert spec == StereoSpec(name="my_net", channel_order="BGR", mean=(123.7, 116.3, 103.5),
                              std=(58.4, 57.1, 57.4), pad_multiple=16, output="disp_up",
                              output_sign=-1.0, input_size=(640, 480), input_names=("l", "r"),
                              extra_inputs={"iters": 12})
    # a preset is the base; the file's fields override it, the others stay the preset's
    spec = spec_from_file(write_spec(tmp_path, {"preset": "raft-stereo", "pad_multiple": 8}))
    assert spec == preset("raft-stereo").replace(pad_multiple=8)
    assert spec.name == "raft-stereo" and spec.output_sign == -1.0
    assert spec_from_file('{"preset": "crestereo"}') == preset("crestereo")


@pytest.mark.parametrize("data, match", [
    ({"pad_multiple": 8, "padding": 8, "sign": -1},
     r"spec.json: expected StereoSpec fields \(name, input_names, .*call, channel_order, .*"
     r"input_size.*\) or 'preset', got unknown 'padding', 'sign'"),
    ({"pad_multiple": 0}, r"spec.json: pad_multiple: expected an integer >= 1, got 0"),
    ({"channel_order": "RBG"}, r"spec.json: channel_order: expected one of RGB, BGR.*, got 'RBG'"),
    ({"output_sign": 2}, r"spec.json: output_sign: expected 1 or -1, got 2"),
    ({"value_scale": "255"}, r"spec.json: value_scale: expected a number, got '255'"),
    ({"mean": [1, 2]}, r"spec.json: mean: expected 3 numbers \(one per channel\)"),
    ({"preset": "igev3"}, r"spec.json: spec: expected one of the presets generic, igev, .*"
                          r"got 'igev3'"),
    ({"name": 3}, r"spec.json: name: expected a string, got 3"),
    ([1, 2], r"spec.json: expected a JSON object of StereoSpec fields, got list"),
])
def test_spec_file_errors_name_the_file_and_the_field(tmp_path, data, match):
    with pytest.raises(BackboneError, match=match):
        spec_from_file(write_spec(tmp_path, data))


def test_spec_file_unreadable(tmp_path):
    with pytest.raises(BackboneError, match="spec file: expected an existing spec.json"):
        spec_from_file(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{pad_multiple: 8}")
    with pytest.raises(BackboneError, match="bad.json: expected valid JSON"):
        spec_from_file(tmp_path / "bad.json")


def test_fuse_and_eval_run_a_model_with_its_spec_file(dataset, flow_model, tmp_path, capsys):
    scene = dataset / "scene_0000"
    spec = write_spec(tmp_path, {"preset": "generic", "output_sign": -1, "output_scale": 0.5})
    code, out, err = run_cli(capsys, "fuse", scene, "--backbone", flow_model, "--spec", spec,
                             "--out", tmp_path / "o")
    assert code == 0, err
    fused = read_disparity(tmp_path / "o" / "fused_disparity.pfm")
    source = read_mask(tmp_path / "o" / "source.png")
    np.testing.assert_array_equal(fused[source == 0], -FLOW_PX * 0.5)
    # without the spec the model's negative flow is refused, naming the field to set
    code, out, err = run_cli(capsys, "fuse", scene, "--backbone", flow_model, "--out",
                             tmp_path / "o2")
    assert code == 2 and "output_sign" in err
    code, out, err = run_cli(capsys, "eval", dataset, "--backbone", flow_model, "--spec", spec,
                             "--jobs", "1", "--quiet", "--out", tmp_path / "e")
    assert code == 0, err
    record = json.loads((tmp_path / "e" / "eval.json").read_text())["settings"]
    assert record["spec"]["output_sign"] == -1.0 and record["spec"]["output_scale"] == 0.5
    assert record["preset"] is None


def test_spec_errors_stop_every_command_before_it_runs(dataset, flow_model, tmp_path, capsys):
    spec = write_spec(tmp_path, {"pad_multiple": 8, "sign": -1})
    for argv in (("fuse", dataset / "scene_0000", "--backbone", flow_model, "--out",
                  tmp_path / "o"),
                 ("eval", dataset, "--backbone", flow_model, "--out", tmp_path / "o"),
                 ("demo", "--out", tmp_path / "o")):
        code, out, err = run_cli(capsys, *argv, "--spec", spec)
        assert code == 2 and out == ""
        assert err.startswith(f"srde-fusion {argv[0]}: error: {spec}: expected StereoSpec "
                              f"fields") and "got unknown 'sign'" in err
        assert err.count("\n") == 1
        assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as info:  # one or the other
        main(["fuse", str(dataset / "scene_0000"), "--backbone", "default", "--preset", "igev",
              "--spec", str(spec), "--out", str(tmp_path / "o")])
    assert info.value.code == 2 and "not allowed with argument" in capsys.readouterr().err
    code, out, err = run_cli(capsys, "fuse", dataset / "scene_0000", "--disparity",
                             dataset / "scene_0000" / "gt_disparity.pfm", "--spec", spec,
                             "--out", tmp_path / "o")
    assert code == 2 and "--preset/--spec: expected with --backbone" in err


def test_demo_takes_a_spec(tmp_path, capsys):
    spec = write_spec(tmp_path, {"preset": "igev", "name": "stand-in via spec"})
    code, out, err = run_cli(capsys, "demo", "--scale", "0.5", "--spec", spec, "--out",
                             tmp_path / "d", "--quiet")
    assert code == 0, err
    assert (tmp_path / "d" / "fused_disparity.pfm").is_file()
