"""A stereo rig on a sorting line: a KITTI-layout folder, read frame by frame, fused as a stream.

Rendered frames stand in for the line's camera: a two-camera rig (320x240, 30 cm
baseline), one light, a flat glossy plate sliding a little between frames on a
textured belt. The script writes them the way KITTI stores stereo frames, which
``srde-fusion fuse`` and ``read_scene`` read:

    OUT_DIR/image_2/00000N_10.png      left views (the reference camera)
    OUT_DIR/image_3/00000N_10.png      right views
    OUT_DIR/disp_occ_0/00000N_10.png   ground truth (KITTI 16-bit PNG)
    OUT_DIR/calib_cam_to_cam.txt       P_rect_02 / P_rect_03: the rig, without a light

plus ``light.txt`` (the light, ``X,Y,Z`` in metres, for ``--light``) and ``my_net.json``
(a model's conventions for ``--spec``). It then reads the frames back and fuses them
with ``HybridStereo.stream``, printing each frame's objects and the frames per second.

Usage: ``python examples/kitti_stream.py [OUT_DIR]`` (a temporary folder by default).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from srde_fusion.adapters import load_backbone

from srde_fusion import HybridStereo, evaluate, read_scene
from srde_fusion.geometry import CameraRig
from srde_fusion.io import list_scenes, write_disparity, write_image
from srde_fusion.synthetic import random_scene, render

BASELINE_M = 0.3
FX_PX = 320.0
SCENE_SEED = 2
# The plate slides along its own surface between frames (metres): its plane, hence its
# highlight's virtual light, stays; its outline moves.
SLIDE_M = (-0.01, 0.0, 0.01)


def write_kitti_folder(out: Path) -> np.ndarray:
    """Render the frames into a KITTI-layout folder; return the light (array frame, m)."""
    rig = CameraRig.stereo(BASELINE_M, fx=FX_PX, image_size=(320, 240),
                           names=("image_2", "image_3"))
    scene = random_scene(SCENE_SEED, rig, n_objects=1, background="textured")
    light_m = np.asarray(scene.light.position_m)
    plate = scene.objects[0]
    along = np.cross(plate.normal, (0.0, 1.0, 0.0))  # a direction in the plate's plane
    along /= np.linalg.norm(along)
    for k, slide in enumerate(SLIDE_M):
        moved = dataclasses.replace(plate, center_m=tuple(np.add(plate.center_m, slide * along)))
        rendering = render(dataclasses.replace(scene, objects=(moved, *scene.objects[1:])),
                           rig.with_light(light_m), noise_seed=k)
        frame = f"{k:06d}_10"
        for folder, view in zip(("image_2", "image_3"), rendering.views, strict=True):
            (out / folder).mkdir(parents=True, exist_ok=True)
            write_image(out / folder / f"{frame}.png", view)
        (out / "disp_occ_0").mkdir(exist_ok=True)
        write_disparity(out / "disp_occ_0" / f"{frame}.png", rendering.disparity_px)
    i = rig.intrinsics
    # KITTI's rectified projections: P = K [I | t], camera 3 at x = B, so P3[0, 3] = -fx B.
    (out / "calib_cam_to_cam.txt").write_text("".join(
        f"{key}: {i.fx} 0 {i.cx} {-i.fx * x} 0 {i.fy} {i.cy} 0 0 0 1 0\n"
        for key, x in (("P_rect_02", 0.0), ("P_rect_03", BASELINE_M))))
    (out / "light.txt").write_text(",".join(f"{v:.6f}" for v in light_m) + "\n")
    # The stand-in follows IGEV's conventions; a spec file says so, field by field.
    (out / "my_net.json").write_text(json.dumps({"preset": "igev", "name": "my-net",
                                                 "pad_multiple": 32}, indent=2) + "\n")
    return light_m


def main(out: Path) -> None:
    light_m = write_kitti_folder(out)
    frames = list_scenes(out)  # OUT_DIR/000000_10, ...: KITTI frames are scenes
    print(f"wrote a KITTI-layout folder of {len(frames)} frames, light.txt and my_net.json "
          f"to {out}")

    scenes = [read_scene(frame) for frame in frames]
    rig = scenes[0].rig  # from calib_cam_to_cam.txt; KITTI files have no light
    model = HybridStereo(load_backbone("default"), rig, light=light_m)
    stream = model.stream(scene.views for scene in scenes)
    for scene, result in zip(scenes, stream, strict=True):
        objects = ", ".join(f"object {o.index}: {o.status}" for o in result.objects) or "none"
        inside = result.source > 0
        epe = (evaluate(result.disparity, scene.gt_disparity, inside)["epe"] if inside.any()
               else float("nan"))
        print(f"{scene.name}: {objects}; EPE on the objects {epe:.3f} px")
    print(stream.stats.summary())


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(Path(tmp))
