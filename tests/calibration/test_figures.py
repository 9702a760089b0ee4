"""The light calibration's figures: one per capture, one in 3D, and the residuals they show."""

from __future__ import annotations

import numpy as np
import pytest

from srde_fusion.calibration import (
    Board,
    capture_figure,
    estimate_light,
    highlight_residuals_px,
    light_figure,
    write_calibration_figures,
)
from srde_fusion.calibration.figures import _nice_factor, _panel_grid
from srde_fusion.cli import main
from srde_fusion.errors import LightError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import read_image, write_image
from srde_fusion.synthetic import highlight_normal, plate_scene, render

LIGHT_M = np.array([0.15, -0.35, 0.1])
# Three cameras in a row keep the renders quick; two plate poses, one tilted.
RIG = CameraRig.grid(1, 3, baseline_m=0.085, fx=600.0, image_size=(640, 480))
PLATES = (dict(center_m=(0.03, 0.02, 1.0)),
          dict(center_m=(-0.08, 0.05, 0.9), normal=highlight_normal((-0.06, 0.06, 0.9), LIGHT_M),
               rotation_rad=0.2))


@pytest.fixture(scope="module")
def calibration():
    board = Board.corner_layout()
    captures = [render(plate_scene(board, RIG, LIGHT_M, **kw), RIG).views for kw in PLATES]
    return captures, estimate_light(captures, RIG, board), board


def test_residuals_are_those_the_estimate_reports(calibration):
    captures, estimate, board = calibration
    residuals = np.concatenate([highlight_residuals_px(estimate, c, RIG)[1]
                                for c in range(estimate.n_captures)])
    used = np.all(np.isfinite(residuals), axis=1)
    assert used.sum() == estimate.n_rays
    rms = np.sqrt(np.mean(np.sum(residuals[used] ** 2, axis=1)))
    assert rms == pytest.approx(estimate.highlight_residual_px, rel=1e-9)
    # the prediction is where the light's mirror image across the plate projects
    predicted, _ = highlight_residuals_px(estimate, 0, RIG)
    mirror = estimate.plate_poses[0].plane.mirror(estimate.position_m)
    np.testing.assert_allclose(predicted[2], RIG.project(mirror, 2))


def test_write_calibration_figures(calibration, tmp_path):
    captures, estimate, board = calibration
    files = write_calibration_figures(tmp_path / "fig", captures, estimate, RIG, board)
    assert [f.name for f in files] == ["capture_0.png", "capture_1.png", "light_3d.png"]
    for f in files:
        image = read_image(f)
        assert image.ndim == 3 and min(image.shape[:2]) > 300
        assert image.std() > 10  # not a blank page
    with pytest.raises(LightError, match="expected the 2 captures the estimate was made from, "
                                         "got 1"):
        write_calibration_figures(tmp_path / "fig", captures[:1], estimate, RIG, board)


def test_capture_figure_panels_follow_the_array(calibration):
    captures, estimate, board = calibration
    fig = capture_figure(captures[1], estimate, 1, RIG, board)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert len(titles) == RIG.n_cameras
    assert titles[0].startswith("cam0: 4 markers") and "highlight residual" in titles[0]
    with pytest.raises(LightError, match=r"capture: expected an index in \[0, 1\], got 2"):
        capture_figure(captures[1], estimate, 2, RIG, board)
    assert len(light_figure(estimate, RIG, board).axes) == 1
    assert _panel_grid(CameraRig.grid(3, 3, baseline_m=0.1, fx=100.0)) == [
        (r, c) for r in range(3) for c in range(3)]
    assert _panel_grid(RIG) == [(0, 0), (0, 1), (0, 2)]


@pytest.mark.parametrize("value, factor", [(1.0, 1.0), (7.3, 5.0), (499.0, 200.0), (0.3, 0.2)])
def test_residual_magnification_is_a_1_2_5_step(value, factor):
    assert _nice_factor(value) == pytest.approx(factor)


def test_calibrate_light_command_writes_the_figures(calibration, tmp_path, capsys):
    captures, _, board = calibration
    board.to_json(tmp_path / "board.json")
    RIG.to_json(tmp_path / "rig.json")
    dirs = []
    for c, views in enumerate(captures):
        dirs.append(tmp_path / f"capture{c}")
        dirs[-1].mkdir()
        for name, view in zip(RIG.camera_names, views, strict=True):
            write_image(dirs[-1] / f"{name}.png", view)
    code = main(["calibrate-light", *map(str, dirs), "--board", str(tmp_path / "board.json"),
                 "--rig", str(tmp_path / "rig.json"), "--dry-run", "--figure",
                 str(tmp_path / "fig")])
    out = capsys.readouterr().out
    assert code == 0
    assert f"wrote {tmp_path / 'fig'}/: capture_0.png, capture_1.png, light_3d.png" in out
