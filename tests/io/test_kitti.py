"""KITTI-layout folders read as scenes: calibration files, frames, ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from srde_fusion.errors import FileFormatError, RigError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import (
    is_kitti_folder,
    kitti_frames,
    list_scenes,
    read_disparity,
    read_kitti_calib,
    read_scene,
    write_disparity,
    write_image,
)

W, H = 64, 40
FX, CX, CY = 70.0, 31.5, 19.5
# KITTI's projections place cameras 2 and 3 relative to camera 0: both have an x offset
# (P[0, 3] = -fx * x) and millimetre y/z offsets left by the rectification.
X2_M, X3_M = -0.06, 0.47
BASELINE_M = X3_M - X2_M


def projection(x_m: float, y_m: float = 0.0, z_m: float = 0.0) -> str:
    p = np.array([[FX, 0, CX, -FX * x_m], [0, FX, CY, -FX * y_m], [0, 0, 1, -z_m]])
    return " ".join(f"{v:.9e}" for v in p.ravel())


def calib_text(keys=("P_rect_02", "P_rect_03")) -> str:
    return (f"calib_time: 09-Jan-2012 13:57:47\nS_rect_02: {W} {H}\n"
            f"{keys[0]}: {projection(X2_M, 0.0003, 0.0027)}\n"
            f"{keys[1]}: {projection(X3_M, -0.003, 0.0027)}\n")


def make_kitti(root, frames=("000000_10", "000001_10"), *, calib="global", gt=True, seed=0):
    """Write a KITTI-layout folder: image_2/, image_3/, disp_occ_0/ and a calibration."""
    rng = np.random.default_rng(seed)
    truth = {}
    for frame in frames:
        for folder in ("image_2", "image_3"):
            (root / folder).mkdir(parents=True, exist_ok=True)
            write_image(root / folder / f"{frame}.png",
                        rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        if gt:
            (root / "disp_occ_0").mkdir(exist_ok=True)
            d = rng.uniform(1.0, 30.0, (H, W)).astype(np.float32)
            d[:5] = np.nan  # KITTI's ground truth is sparse: 0 = no value
            write_disparity(root / "disp_occ_0" / f"{frame}.png", d)
            truth[frame] = d
        if calib == "per-frame":
            (root / "calib_cam_to_cam").mkdir(exist_ok=True)
            (root / "calib_cam_to_cam" / f"{frame.split('_')[0]}.txt").write_text(calib_text())
        elif calib == "object":
            (root / "calib").mkdir(exist_ok=True)
            (root / "calib" / f"{frame.split('_')[0]}.txt").write_text(calib_text(("P2", "P3")))
    if calib == "global":
        (root / "calib_cam_to_cam.txt").write_text(calib_text())
    return truth


def test_kitti_calibration_gives_the_colour_cameras_rig(tmp_path):
    path = tmp_path / "calib_cam_to_cam.txt"
    path.write_text(calib_text())
    rig = read_kitti_calib(path, image_size=(W, H))
    assert rig.camera_names == ["image_2", "image_3"] and rig.reference == 0
    assert rig.baseline_m == pytest.approx(BASELINE_M, abs=1e-9)
    i = rig.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy) == pytest.approx((FX, FX, CX, CY))
    assert rig.light_position_m is None
    # a point seen at disparity d by the pair is at z = fx B / d, as KITTI's devkit computes it
    np.testing.assert_allclose(rig.disparity_to_depth(np.array([10.0])), FX * BASELINE_M / 10.0)
    (tmp_path / "obj.txt").write_text(calib_text(("P2", "P3")))
    assert read_kitti_calib(tmp_path / "obj.txt", image_size=(W, H)).baseline_m == rig.baseline_m


@pytest.mark.parametrize("text, match", [
    ("P0: 1 2 3\n", r"expected the rectified projections P_rect_02 and P_rect_03 or P2 and P3"),
    (f"P2: {projection(0.0)}\nP3: 1 2 3\n", r"P3: expected 12 numbers"),
    (f"P2: {projection(0.0)}\nP3: {projection(0.0).replace('7.0', '9.0', 1)}\n",
     r"expected P2 and P3 to share one camera matrix"),
    (f"P2: {projection(0.5)}\nP3: {projection(0.0)}\n",
     r"expected camera 3 to the right of camera 2"),
])
def test_kitti_calibration_errors(tmp_path, text, match):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match):
        read_kitti_calib(path, image_size=(W, H))
    with pytest.raises(FileFormatError, match="expected an existing KITTI calibration"):
        read_kitti_calib(tmp_path / "missing.txt", image_size=(W, H))


@pytest.mark.parametrize("calib", ["global", "per-frame", "object"])
def test_a_kitti_folder_is_a_dataset_of_frames(tmp_path, calib):
    root = tmp_path / "training"
    truth = make_kitti(root, calib=calib)
    # the _11 frames are the next instants in time, not benchmark frames
    write_image(root / "image_2" / "000000_11.png", np.zeros((H, W, 3), np.uint8))
    write_image(root / "image_3" / "000000_11.png", np.zeros((H, W, 3), np.uint8))
    assert is_kitti_folder(root) and not is_kitti_folder(tmp_path)
    assert kitti_frames(root) == ["000000_10", "000001_10"]
    assert list_scenes(root) == [root / "000000_10", root / "000001_10"]
    scene = read_scene(root / "000001_10")
    assert scene.name == "000001_10" and scene.metadata["format"] == "kitti"
    assert scene.rig.baseline_m == pytest.approx(BASELINE_M)
    np.testing.assert_array_equal(scene.views[1], read_scene(root / "000001_10").views[1])
    # KITTI's 16-bit PNG keeps 1/256 px; its 0 (no value) is NaN
    np.testing.assert_allclose(scene.gt_disparity, truth["000001_10"], atol=1 / 512)
    assert np.isnan(scene.gt_disparity[:5]).all()
    with pytest.raises(FileFormatError, match=r"expected one scene, got a KITTI folder of 2 "
                                              r"frames: read one as .*000000_10"):
        read_scene(root)


def test_a_rig_json_beside_image_2_gives_the_rig_and_the_light(tmp_path):
    root = tmp_path / "kitti"
    make_kitti(root, frames=("000000_10",), calib="global", gt=False)
    rig = CameraRig.stereo(0.54, fx=FX, image_size=(W, H), light_position_m=(0.1, -0.5, 0.2),
                           names=("image_2", "image_3"))
    rig.to_json(root / "rig.json")
    scene = read_scene(root / "000000_10")
    assert scene.rig == rig and scene.gt_disparity is None
    assert scene.metadata["rig_from"] == "rig.json"
    CameraRig.stereo(0.54, fx=FX, image_size=(W + 2, H)).to_json(root / "rig.json")
    with pytest.raises(FileFormatError, match=r"000000_10.png: expected the image size of .*"
                                              r"rig.json, 66x40, got 64x40"):
        read_scene(root / "000000_10")
    (root / "rig.json").write_text('{"format": "srde-rig/1"}')
    with pytest.raises(RigError, match="rig.json"):
        read_scene(root / "000000_10")


def test_kitti_folder_errors(tmp_path):
    root = tmp_path / "kitti"
    make_kitti(root, frames=("000000_10",), calib="none")
    with pytest.raises(FileFormatError, match=r"expected the rig of frame 000000_10 in rig.json "
                                              r"or a KITTI calibration file, got none of"):
        read_scene(root / "000000_10")
    (root / "calib_cam_to_cam.txt").write_text(calib_text())
    with pytest.raises(FileFormatError, match=r"expected image_2/000009_10.png, got no such"):
        read_scene(root / "000009_10")
    write_image(root / "image_3" / "000000_10.png", np.zeros((H + 1, W, 3), np.uint8))
    with pytest.raises(FileFormatError, match=r"image_3/000000_10.png: expected the size of "
                                              r"000000_10.png, 64x40, got 64x41"):
        read_scene(root / "000000_10")
    (root / "image_3" / "000000_10.png").unlink()
    with pytest.raises(FileFormatError, match="with none in common"):
        list_scenes(root)


def test_kitti_ground_truth_reads_back(tmp_path):
    root = tmp_path / "kitti"
    truth = make_kitti(root, frames=("000003_10",))
    # the file itself: read_disparity agrees with what read_scene hands out
    np.testing.assert_array_equal(read_disparity(root / "disp_occ_0" / "000003_10.png"),
                                  read_scene(root / "000003_10").gt_disparity)
    assert np.nanmax(np.abs(read_scene(root / "000003_10").gt_disparity
                            - truth["000003_10"])) <= 1 / 512
