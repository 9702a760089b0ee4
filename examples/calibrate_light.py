"""Calibrate the light of a camera array from captures of an ArUco plate.

What a real calibration looks like, end to end, with rendered captures standing in for
photographs:

1. print the plate (``board.png``; ``board.json`` describes it);
2. hold it in front of the array so that the light's highlight falls on its free
   centre, and take one capture (one image per camera) per plate pose; tilt the plate
   differently between captures;
3. ``srde-fusion calibrate-light CAPTURE_DIR ... --board board.json --rig rig.json``,
   here through the library call behind it, which writes the light into ``rig.json``.

Usage: ``python examples/calibrate_light.py [OUT_DIR]`` (a temporary folder by default).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from srde_fusion.calibration import (
    Board,
    calibrate_light_files,
    write_board,
)
from srde_fusion.geometry import CameraRig
from srde_fusion.io import write_image
from srde_fusion.synthetic import default_rig, highlight_normal, plate_scene, render

# The light to be found: above and to the right of the array, about 1.1 m from the plates.
TRUE_LIGHT_M = np.array([0.2, -0.45, 0.1])
# Plate poses: (centre, where on the plate the highlight should fall, in-plane rotation).
PLATE_POSES = (
    ((0.03, 0.02, 1.0), (0.03, 0.02, 1.0), 0.0),
    ((-0.08, 0.05, 0.9), (-0.06, 0.06, 0.9), 0.2),
    ((0.1, -0.03, 1.1), (0.08, -0.02, 1.1), -0.15),
)


def make_captures(out: Path, rig: CameraRig, board: Board) -> list[Path]:
    """Render one capture folder per plate pose, images named after the cameras."""
    folders = []
    for k, (center, aim, rotation) in enumerate(PLATE_POSES):
        normal = highlight_normal(aim, TRUE_LIGHT_M, rig.reference_center_m)
        scene = plate_scene(board, rig, TRUE_LIGHT_M, center_m=center, normal=normal,
                            rotation_rad=rotation)
        views = render(scene, rig, supersample=2).views
        folder = out / f"capture{k}"
        folder.mkdir(parents=True, exist_ok=True)
        for name, view in zip(rig.camera_names, views, strict=True):
            write_image(folder / f"{name}.png", view)
        folders.append(folder)
    return folders


def main(out: Path) -> None:
    rig = default_rig()  # the paper's 3x3 array; no light known yet
    board = Board.corner_layout()  # A4 plate, 5 cm markers in the corners
    _, board_json = write_board(board, out, dpi=100)
    rig_json = out / "rig.json"
    rig.to_json(rig_json)
    captures = make_captures(out, rig, board)
    print(f"wrote {board_json.name}, board.png, rig.json and {len(captures)} capture folders "
          f"to {out}")

    calibration = calibrate_light_files(captures, board_json, rig_json)
    estimate, calibrated = calibration.estimate, calibration.rig
    print(estimate.summary())
    error_m = np.linalg.norm(estimate.position_m - TRUE_LIGHT_M)
    paper_m = np.linalg.norm(estimate.closed_form_position_m - TRUE_LIGHT_M)
    rays = estimate.geometric_position_m  # None when no capture's images could be read
    rays_m = np.linalg.norm((estimate.position_m if rays is None else rays) - TRUE_LIGHT_M)
    print(f"true light:  ({', '.join(f'{v:+.4f}' for v in TRUE_LIGHT_M)}) m")
    print(f"error: {error_m * 1000:.1f} mm (from the highlight centres' rays alone: "
          f"{rays_m * 1000:.1f} mm; their intersection before the joint refinement: "
          f"{paper_m * 1000:.1f} mm)")
    stored = CameraRig.from_json(rig_json).light_position_m
    print(f"rig.json now holds the light {np.round(stored, 4).tolist()} "
          f"(previous file kept as rig.json.bak); SRDE(rig) uses it")
    assert calibrated.light_position_m == stored


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(Path(tmp))
