from __future__ import annotations

import json
import struct
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from srde_fusion.errors import (
    DisparityError,
    FileFormatError,
    ImageError,
    MaskError,
    RigError,
)
from srde_fusion.geometry import CameraRig
from srde_fusion.io import (
    KITTI_DISPARITY_MAX_PX,
    KITTI_DISPARITY_SCALE,
    labels_from_masks,
    list_scenes,
    masks_from_labels,
    read_disparity,
    read_image,
    read_kitti_disparity,
    read_mask,
    read_middlebury_calib,
    read_opencv_stereo_yaml,
    read_pfm,
    read_scene,
    write_disparity,
    write_image,
    write_kitti_disparity,
    write_mask,
    write_pfm,
    write_scene,
)

RNG_SEED = 1234


def _raw_png(path: Path, array: np.ndarray) -> Path:
    ok, buf = cv2.imencode(".png", array)
    assert ok
    path.write_bytes(buf.tobytes())
    return path


# ---------------------------------------------------------------------- PFM
def test_pfm_reads_bottom_row_first_little_endian(tmp_path):
    path = tmp_path / "le.pfm"
    path.write_bytes(b"Pf\n2 2\n-1.0\n" + struct.pack("<4f", 1, 2, 3, 4))
    np.testing.assert_array_equal(read_pfm(path), [[3, 4], [1, 2]])


def test_pfm_reads_big_endian_colour(tmp_path):
    path = tmp_path / "be.pfm"
    values = np.arange(12, dtype=np.float32)
    path.write_bytes(b"PF\n2 2\n1.0\n" + values.astype(">f4").tobytes())
    out = read_pfm(path)
    assert out.shape == (2, 2, 3) and out.dtype == np.float32
    # Bottom row (stored first) holds 0..5.
    np.testing.assert_array_equal(out[1], [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(out[0], [[6, 7, 8], [9, 10, 11]])


def test_pfm_with_crlf_header(tmp_path):
    path = tmp_path / "crlf.pfm"
    path.write_bytes(b"Pf\r\n2 1\r\n-1.0\r\n" + struct.pack("<2f", 5, 6))
    np.testing.assert_array_equal(read_pfm(path), [[5, 6]])


def test_write_pfm_layout(tmp_path):
    path = write_pfm(tmp_path / "w.pfm", np.array([[1.0, 2.0], [3.0, 4.0]]))
    data = path.read_bytes()
    assert data.startswith(b"Pf\n2 2\n-1.0\n")
    assert struct.unpack("<4f", data[-16:]) == (3.0, 4.0, 1.0, 2.0)


def test_pfm_round_trip_keeps_raw_values(tmp_path):
    rng = np.random.default_rng(RNG_SEED)
    grey = rng.normal(size=(5, 7)).astype(np.float32)
    grey[0, 0], grey[1, 1] = np.inf, np.nan
    colour = rng.normal(size=(4, 3, 3)).astype(np.float32)
    np.testing.assert_array_equal(read_pfm(write_pfm(tmp_path / "g.pfm", grey)), grey)
    np.testing.assert_array_equal(read_pfm(write_pfm(tmp_path / "c.pfm", colour)), colour)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"P6\n2 2\n255\n" + bytes(12), "starting with 'PF' or 'Pf'"),
        (b"Pf\nabc 2\n-1.0\n" + bytes(16), "PFM header"),
        (b"Pf\n2 2\n-1.0\n" + bytes(12), "expected 16 bytes .* got 12"),
        (b"Pf\n2 2\n0.0\n" + bytes(16), "non-zero scale"),
        (b"", "starting with 'PF' or 'Pf'"),
    ],
    ids=["magic", "header", "truncated", "zero-scale", "empty"],
)
def test_read_pfm_malformed(tmp_path, content, match):
    path = tmp_path / "bad.pfm"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=match) as info:
        read_pfm(path)
    assert "bad.pfm" in str(info.value)


def test_read_pfm_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="existing PFM file"):
        read_pfm(tmp_path / "nope.pfm")


def test_write_pfm_bad_shape(tmp_path):
    with pytest.raises(FileFormatError, match=r"\(H, W\) or \(H, W, 3\)"):
        write_pfm(tmp_path / "x.pfm", np.zeros((2, 2, 2)))


# ---------------------------------------------------------------------- disparity files
def test_pfm_disparity_marks_invalid_as_inf(tmp_path):
    d = np.array([[1.5, np.nan], [-2.0, 7.25]], np.float32)
    path = write_disparity(tmp_path / "d.pfm", d)
    raw = read_pfm(path)
    assert np.isposinf(raw[0, 1]) and np.isposinf(raw[1, 0])
    back = read_disparity(path)
    np.testing.assert_array_equal(back, [[1.5, np.nan], [np.nan, 7.25]])
    assert back.dtype == np.float32


def test_kitti_round_trip_and_raw_values(tmp_path):
    d = np.array([[0.0, 1.0 / KITTI_DISPARITY_SCALE, 12.5], [np.nan, 255.99, 0.001]], np.float32)
    path = write_disparity(tmp_path / "d.png", d)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    # NaN is invalid (0); 0 px and 0.001 px are valid and kept so as the smallest step (1).
    np.testing.assert_array_equal(raw, [[1, 1, 3200], [0, 65533, 1]])
    back = read_kitti_disparity(path)
    expected = np.array([[1, 1, 3200], [np.nan, 65533, 1]], np.float32) / 256.0
    np.testing.assert_array_equal(back, expected)


@given(arrays(np.float32, (3, 4), elements=st.floats(1.0 / 64, 255.0, width=32)))
def test_kitti_quantisation_error_at_most_half_step(d):
    with tempfile.TemporaryDirectory() as tmp:
        back = read_disparity(write_disparity(Path(tmp) / "k.png", d))
    assert np.all(np.abs(back - d) <= 0.5 / KITTI_DISPARITY_SCALE + 1e-6)


def test_kitti_write_too_large(tmp_path):
    d = np.full((2, 2), KITTI_DISPARITY_MAX_PX + 0.5, np.float32)
    with pytest.raises(FileFormatError, match="16-bit KITTI PNG"):
        write_kitti_disparity(tmp_path / "k.png", d)


def test_kitti_read_8bit_refused(tmp_path):
    path = _raw_png(tmp_path / "k8.png", np.full((3, 3), 7, np.uint8))
    with pytest.raises(FileFormatError, match="16-bit KITTI disparity PNG.*got dtype uint8"):
        read_kitti_disparity(path)


def test_kitti_read_colour_refused(tmp_path):
    path = _raw_png(tmp_path / "k3.png", np.full((3, 3, 3), 7, np.uint16))
    with pytest.raises(FileFormatError, match="single-channel"):
        read_disparity(path)


def test_npy_round_trip(tmp_path):
    d = np.array([[np.nan, 2.0], [3.0, 4.5]], np.float32)
    np.testing.assert_array_equal(read_disparity(write_disparity(tmp_path / "d.npy", d)), d)


def test_npy_errors(tmp_path):
    np.save(tmp_path / "cube.npy", np.zeros((2, 2, 2), np.float32))
    with pytest.raises(FileFormatError, match=r"\(H, W\) real disparity map.*\(2, 2, 2\)"):
        read_disparity(tmp_path / "cube.npy")
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    with pytest.raises(FileFormatError, match="junk.npy: expected a numpy .npy array"):
        read_disparity(tmp_path / "junk.npy")


def test_disparity_unknown_extension(tmp_path):
    with pytest.raises(FileFormatError, match=r"one of \['.pfm', '.png', '.npy'\], got '.exr'"):
        write_disparity(tmp_path / "d.exr", np.zeros((2, 2), np.float32))
    with pytest.raises(FileFormatError, match="got 'no extension'"):
        read_disparity(tmp_path / "d")


def test_write_disparity_validates_array(tmp_path):
    with pytest.raises(DisparityError, match=r"disparity_px: expected shape \(H, W\)"):
        write_disparity(tmp_path / "d.pfm", np.zeros(4, np.float32))


# ---------------------------------------------------------------------- images
def test_image_rgb_round_trip_and_channel_order(tmp_path):
    rng = np.random.default_rng(RNG_SEED)
    image = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    image[0, 0] = (255, 0, 0)
    path = write_image(tmp_path / "i.png", image)
    np.testing.assert_array_equal(read_image(path), image)
    # On disk the file follows OpenCV's BGR order.
    assert cv2.imread(str(path))[0, 0].tolist() == [0, 0, 255]


def test_image_grey_and_float(tmp_path):
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    np.testing.assert_array_equal(read_image(write_image(tmp_path / "g.png", grey)), grey)
    as_float = np.array([[0.0, 0.5], [1.0, 0.25]], np.float32)
    back = read_image(write_image(tmp_path / "f.png", as_float))
    np.testing.assert_array_equal(back, [[0, 128], [255, 64]])


def test_image_rgba(tmp_path):
    bgra = np.zeros((3, 3, 4), np.uint8)
    bgra[..., 0] = 200  # blue
    bgra[..., 3] = 255
    rgb = read_image(_raw_png(tmp_path / "opaque.png", bgra))
    assert rgb.shape == (3, 3, 3) and rgb[0, 0].tolist() == [0, 0, 200]
    bgra[1, 1, 3] = 10
    with pytest.raises(FileFormatError, match="alpha channel with transparency"):
        read_image(_raw_png(tmp_path / "transparent.png", bgra))


def test_image_16bit_refused(tmp_path):
    path = _raw_png(tmp_path / "i16.png", np.zeros((3, 3, 3), np.uint16))
    with pytest.raises(FileFormatError, match="expected an 8-bit image, got dtype uint16"):
        read_image(path)


def test_image_bad_data_and_missing(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(
        FileFormatError, match="bad.png: expected a readable 8-bit image, got undecodable"
    ):
        read_image(tmp_path / "bad.png")
    with pytest.raises(FileFormatError, match="existing 8-bit image file"):
        read_image(tmp_path / "missing.png")


def test_write_image_validates(tmp_path):
    with pytest.raises(ImageError, match="expected dtype uint8 or float"):
        write_image(tmp_path / "x.png", np.zeros((3, 3), np.int32))


# ---------------------------------------------------------------------- masks
def test_mask_labels_round_trip(tmp_path):
    labels = np.zeros((5, 6), np.int32)
    labels[1:3, 1:3] = 1
    labels[3:, 4:] = 3
    back = read_mask(write_mask(tmp_path / "m.png", labels))
    assert back.dtype == np.int32
    np.testing.assert_array_equal(back, labels)


def test_binary_255_mask_is_one_object(tmp_path):
    raw = np.zeros((4, 4), np.uint8)
    raw[1:3, 1:3] = 255
    labels = read_mask(_raw_png(tmp_path / "m.png", raw))
    assert set(np.unique(labels).tolist()) == {0, 1}
    assert int(labels.sum()) == 4


def test_mask_with_255_among_other_labels_keeps_it(tmp_path):
    raw = np.array([[0, 1], [255, 2]], np.uint8)
    np.testing.assert_array_equal(read_mask(_raw_png(tmp_path / "m.png", raw)), raw)


def test_mask_16bit_and_colour(tmp_path):
    raw16 = np.array([[0, 300], [2, 0]], np.uint16)
    np.testing.assert_array_equal(read_mask(_raw_png(tmp_path / "m16.png", raw16)), raw16)
    grey3 = np.repeat(np.array([[0, 1], [2, 0]], np.uint8)[..., None], 3, axis=2)
    np.testing.assert_array_equal(read_mask(_raw_png(tmp_path / "g3.png", grey3)), grey3[..., 0])
    grey3[0, 0, 1] = 9
    with pytest.raises(FileFormatError, match="3 channels that differ"):
        read_mask(_raw_png(tmp_path / "c3.png", grey3))


def test_masks_from_labels_and_back():
    labels = np.array([[0, 2, 2], [5, 0, 2]])
    masks = masks_from_labels(labels)
    assert [m.dtype for m in masks] == [np.dtype(bool)] * 2
    np.testing.assert_array_equal(masks[0], labels == 2)
    np.testing.assert_array_equal(masks[1], labels == 5)
    assert masks_from_labels(np.zeros((2, 2), np.int32)) == []
    np.testing.assert_array_equal(labels_from_masks(masks), [[0, 1, 1], [2, 0, 1]])


def test_mask_errors(tmp_path):
    with pytest.raises(MaskError, match="expected labels >= 0"):
        masks_from_labels(np.array([[0, -1]]))
    with pytest.raises(MaskError, match="integer labels"):
        masks_from_labels(np.array([[0.0, 1.0]]))
    with pytest.raises(MaskError, match="non-overlapping"):
        labels_from_masks([np.eye(2, dtype=bool), np.ones((2, 2), bool)])
    with pytest.raises(MaskError, match=r"masks\[1\]: expected shape \(2, 2\)"):
        labels_from_masks([np.eye(2, dtype=bool), np.ones((3, 2), bool)])
    with pytest.raises(MaskError, match="non-empty sequence"):
        labels_from_masks([])
    with pytest.raises(MaskError, match="at most 255 objects"):
        write_mask(tmp_path / "m.png", np.array([[0, 256]]))


# ---------------------------------------------------------------------- Middlebury
# Middlebury 2014 "Adirondack" calibration.
MIDDLEBURY_CALIB = """cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]
cam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]
doffs=209.059
baseline=176.252
width=2880
height=1988
ndisp=280
isint=0
vmin=33
vmax=218
dyavg=0
dymax=0
"""


def test_middlebury_calib(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(MIDDLEBURY_CALIB)
    calib = read_middlebury_calib(path)
    rig = calib.rig
    assert rig.image_size == (2880, 1988)
    assert rig.camera_names == ["cam0", "cam1"]
    assert rig.intrinsics.fx == 4161.221 and rig.intrinsics.cx == 1445.577
    assert rig.baseline_m == pytest.approx(0.176252)
    assert calib.doffs_px == pytest.approx(209.059)
    assert (calib.ndisp, calib.vmin, calib.vmax) == (280, 33.0, 218.0)
    assert calib.extras == {"isint": "0", "dyavg": "0", "dymax": "0"}
    # Middlebury: Z = baseline * f / (d + doffs); the rig must give the same depth.
    d_file = np.array([[100.0, np.nan]], np.float32)
    z_mm = 176.252 * 4161.221 / (100.0 + 209.059)
    z_rig = rig.disparity_to_depth(calib.to_rig_disparity(d_file))
    assert z_rig[0, 0] * 1000.0 == pytest.approx(z_mm, rel=1e-6)
    assert np.isnan(z_rig[0, 1])


def test_middlebury_calib_image_size_keyword(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(
        "\n".join(
            line
            for line in MIDDLEBURY_CALIB.splitlines()
            if not line.startswith(("width", "height"))
        )
    )
    assert read_middlebury_calib(path, image_size=(2880, 1988)).rig.image_size == (2880, 1988)
    with pytest.raises(FileFormatError, match="expected width and height in the file"):
        read_middlebury_calib(path)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda s: s.replace("baseline=176.252\n", ""), r"missing \['baseline'\]"),
        (
            lambda s: s.replace("cam0=[4161.221 0 1445.577;", "cam0=[4161.221 0;"),
            "cam0: expected a 3x3 matrix",
        ),
        (lambda s: s.replace("doffs=209.059", "doffs=200"), "doffs = cx1 - cx0 = 209.059"),
        (
            lambda s: s.replace(
                "0 4161.221 984.686; 0 0 1]\ndoffs", "0 4000 984.686; 0 0 1]\ndoffs"
            ),
            "rectified cameras with equal fy",
        ),
        (lambda s: s.replace("ndisp=280", "ndisp=many"), "ndisp: expected a number"),
        (lambda s: s + "garbage line\n", "expected 'key=value'"),
        (lambda s: s.replace("baseline=176.252", "baseline=-1"), "positive baseline in mm"),
    ],
    ids=["no-baseline", "matrix", "doffs", "not-rectified", "number", "syntax", "baseline"],
)
def test_middlebury_calib_errors(tmp_path, edit, match):
    path = tmp_path / "calib.txt"
    path.write_text(edit(MIDDLEBURY_CALIB))
    with pytest.raises(FileFormatError, match=match):
        read_middlebury_calib(path)


def test_middlebury_calib_size_mismatch_and_missing(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(MIDDLEBURY_CALIB)
    with pytest.raises(FileFormatError, match=r"image_size \(100, 80\) to match"):
        read_middlebury_calib(path, image_size=(100, 80))
    with pytest.raises(FileFormatError, match="existing Middlebury calib.txt"):
        read_middlebury_calib(tmp_path / "none.txt")


# ---------------------------------------------------------------------- OpenCV YAML
def _write_opencv_yaml(
    path: Path, *, t=(-60.0, 0.0, 0.0), d=(0.0,) * 5, r=None, size=None, skip=()
) -> Path:
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    entries = {
        "K1": k,
        "D1": np.array([d]),
        "K2": k,
        "D2": np.zeros((1, 5)),
        "R": np.eye(3) if r is None else r,
        "T": np.array(t, dtype=np.float64).reshape(3, 1),
    }
    for name, value in entries.items():
        if name not in skip:
            fs.write(name, value)
    if size is not None:
        fs.write("image_width", size[0])
        fs.write("image_height", size[1])
    fs.release()
    return path


def test_opencv_yaml_in_mm(tmp_path):
    path = _write_opencv_yaml(tmp_path / "stereo.yml", size=(640, 480))
    with pytest.warns(UserWarning, match="rectified images assumed") as record:
        rig = read_opencv_stereo_yaml(path, units_per_m=1000.0)
    assert len(record) == 1
    assert rig.image_size == (640, 480)
    assert rig.baseline_m == pytest.approx(0.06)
    assert (rig.intrinsics.fx, rig.intrinsics.cx, rig.intrinsics.cy) == (500.0, 320.0, 240.0)
    np.testing.assert_allclose(rig.centers_m[1], [0.06, 0.0, 0.0])


@pytest.mark.parametrize("form", ["matrix", "sequence"])
def test_opencv_yaml_image_size_in_file_and_m_names(tmp_path, form):
    # cv2's stereo_calib sample names the camera matrices M1/M2.
    path = tmp_path / "s.yml"
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (
        ("M1", k),
        ("M2", k),
        ("R", np.eye(3)),
        ("T", np.array([[-0.1], [0], [0]])),
    ):
        fs.write(name, value)
    if form == "matrix":
        fs.write("image_size", np.array([[640, 480]], np.int32))
    else:
        fs.startWriteStruct("imageSize", cv2.FILE_NODE_SEQ)
        fs.write("", 640)
        fs.write("", 480)
        fs.endWriteStruct()
    fs.release()
    with pytest.warns(UserWarning, match="rectified images assumed"):
        rig = read_opencv_stereo_yaml(path)
    assert rig.image_size == (640, 480) and rig.baseline_m == pytest.approx(0.1)


def test_opencv_yaml_does_not_guess_mm(tmp_path):
    path = _write_opencv_yaml(tmp_path / "stereo.yml")
    with pytest.warns(UserWarning) as record:
        rig = read_opencv_stereo_yaml(path, image_size=(640, 480))
    assert rig.baseline_m == pytest.approx(60.0)
    messages = [str(w.message) for w in record]
    assert any("units_per_m=1000" in m for m in messages)


def test_opencv_yaml_warns_about_ignored_calibration(tmp_path):
    angle = 0.01
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    path = _write_opencv_yaml(tmp_path / "s.yml", t=(-0.06, 0, 0), d=(0.1, 0, 0, 0, 0), r=rot)
    with pytest.warns(UserWarning, match="non-zero distortion D1/D2, rotation R.* ignored"):
        read_opencv_stereo_yaml(path, image_size=(640, 480))


@pytest.mark.parametrize(
    ("kwargs", "call_kwargs", "match"),
    [
        ({"t": (0.06, 0.0, 0.0)}, {"image_size": (640, 480)}, "to the right of the first"),
        ({"skip": ("T",)}, {"image_size": (640, 480)}, "matrix named T"),
        ({"skip": ("K1",)}, {"image_size": (640, 480)}, "matrix named K1 or M1"),
        ({}, {}, "expected an image size"),
    ],
    ids=["left", "no-T", "no-K1", "no-size"],
)
def test_opencv_yaml_errors(tmp_path, kwargs, call_kwargs, match):
    path = _write_opencv_yaml(
        tmp_path / "s.yml", t=kwargs.get("t", (-0.06, 0, 0)), skip=kwargs.get("skip", ())
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        with pytest.raises(FileFormatError, match=match):
            read_opencv_stereo_yaml(path, **call_kwargs)


def test_opencv_yaml_bad_files(tmp_path):
    (tmp_path / "bad.yml").write_text("%YAML:1.0\nK1: [unclosed\n  : : :\n")
    with pytest.raises(FileFormatError, match="bad.yml: expected an OpenCV FileStorage"):
        read_opencv_stereo_yaml(tmp_path / "bad.yml", image_size=(640, 480))
    with pytest.raises(FileFormatError, match="existing OpenCV stereo calibration file"):
        read_opencv_stereo_yaml(tmp_path / "none.yml")
    with pytest.raises(RigError, match="units_per_m: expected a positive number"):
        read_opencv_stereo_yaml(_write_opencv_yaml(tmp_path / "s.yml"), units_per_m=0)


def test_opencv_yaml_prefers_the_rectified_projections(tmp_path):
    # A real cv2.stereoRectify of two slightly different, slightly rotated cameras.
    k1 = np.array([[700.0, 0.0, 330.0], [0.0, 702.0, 236.0], [0.0, 0.0, 1.0]])
    k2 = np.array([[712.0, 0.0, 318.0], [0.0, 709.0, 244.0], [0.0, 0.0, 1.0]])
    d = np.array([[0.05, -0.02, 0.0, 0.0, 0.0]])
    rot, _ = cv2.Rodrigues(np.array([0.004, -0.01, 0.002]))
    t = np.array([[-120.0], [1.5], [0.8]])  # millimetres
    r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(k1, d, k2, d, (640, 480), rot, t,
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    path = tmp_path / "rectified.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (("K1", k1), ("D1", d), ("K2", k2), ("D2", d), ("R", rot), ("T", t),
                        ("R1", r1), ("R2", r2), ("P1", p1), ("P2", p2), ("Q", q)):
        fs.write(name, value)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.release()
    with pytest.warns(UserWarning, match=r"rectified projections P1/P2 are used") as record:
        rig = read_opencv_stereo_yaml(path, units_per_m=1000.0)
    assert len(record) == 1
    k = rig.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == (p1[0, 0], p1[1, 1], p1[0, 2], p1[1, 2])
    assert k.fx != k1[0, 0] and k.cx != k1[0, 2]  # not K1's
    assert rig.baseline_m == pytest.approx(np.linalg.norm(t) / 1000.0, rel=1e-9)


def test_opencv_yaml_malformed_matrix_nodes_are_errors_not_crashes(tmp_path):
    header = "%YAML:1.0\n---\n"
    k = ("K1: !!opencv-matrix\n   rows: 3\n   dt: d\n"
         "   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\n")
    (tmp_path / "no_cols.yml").write_text(header + k)
    with pytest.raises(FileFormatError, match=r"K1: expected an opencv-matrix with rows, cols, "
                       r"dt and data, got none for cols"):
        read_opencv_stereo_yaml(tmp_path / "no_cols.yml", image_size=(640, 480))
    short = k.replace("rows: 3\n", "rows: 3\n   cols: 4\n")
    (tmp_path / "short.yml").write_text(header + short)
    with pytest.raises(FileFormatError, match=r"K1: expected 3 x 4 data values, got 9"):
        read_opencv_stereo_yaml(tmp_path / "short.yml", image_size=(640, 480))


# ---------------------------------------------------------------------- scene folders
def _scene_inputs(rig: CameraRig):
    rng = np.random.default_rng(RNG_SEED)
    w, h = rig.image_size
    views = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(rig.n_cameras)]
    gt = rng.uniform(1.0, 30.0, (h, w)).astype(np.float32)
    gt[0, :3] = np.nan
    labels = np.zeros((h, w), np.int32)
    labels[2:8, 2:10] = 1
    labels[12:20, 15:30] = 2
    return views, gt, labels


def test_scene_round_trip(tmp_path, small_stereo_rig):
    rig = small_stereo_rig.with_light([0.05, -0.3, 0.1])
    views, gt, labels = _scene_inputs(rig)
    meta = {"virtual_light_m": [0.1, 0.2, 1.5], "planes": [{"normal": [0, 0, -1], "offset_m": -1}]}
    folder = write_scene(
        tmp_path / "scene_a", views, rig, mask=labels, gt_disparity=gt, metadata=meta
    )
    assert sorted(p.name for p in folder.iterdir()) == [
        "cam0.png",
        "cam1.png",
        "gt_disparity.pfm",
        "mask.png",
        "rig.json",
        "scene.json",
    ]
    scene = read_scene(folder)
    assert scene.name == "scene_a" and scene.path == folder
    assert scene.rig == rig
    assert len(scene.views) == 2
    for got, want in zip(scene.views, views, strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(scene.mask_labels, labels)
    np.testing.assert_array_equal(scene.gt_disparity, gt)
    assert scene.metadata == meta
    assert [int(m.sum()) for m in scene.masks] == [48, 120]


def test_scene_minimal_and_mask_list(tmp_path, small_stereo_rig):
    views, _, labels = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig, mask=[labels == 1, labels == 2])
    scene = read_scene(folder)
    np.testing.assert_array_equal(scene.mask_labels, labels)
    assert scene.gt_disparity is None and scene.metadata == {}
    bare = write_scene(tmp_path / "bare", views, small_stereo_rig)
    assert read_scene(bare).mask_labels is None and read_scene(bare).masks == []


def test_scene_npy_ground_truth_and_jpeg_view(tmp_path, small_stereo_rig):
    views, gt, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig)
    np.save(folder / "gt_disparity.npy", gt)
    write_image(folder / "cam1.jpg", views[1])
    (folder / "cam1.png").unlink()
    scene = read_scene(folder)
    np.testing.assert_array_equal(scene.gt_disparity, gt)
    assert scene.views[1].shape == views[1].shape


def test_scene_missing_view(tmp_path, small_stereo_rig):
    views, _, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig)
    (folder / "cam1.png").unlink()
    with pytest.raises(FileFormatError, match=r"one image per camera .*missing \['cam1'\]"):
        read_scene(folder)


def test_scene_extra_camera_image(tmp_path, small_stereo_rig):
    views, _, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig)
    write_image(folder / "cam2.png", views[0])
    write_image(folder / "preview.png", views[0])  # not named like a camera: fine
    with pytest.raises(FileFormatError, match=r"got extra \['cam2.png'\]"):
        read_scene(folder)


def test_scene_two_files_for_one_camera(tmp_path, small_stereo_rig):
    views, _, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig)
    write_image(folder / "cam0.jpg", views[0])
    with pytest.raises(FileFormatError, match=r"expected one image for camera 'cam0' file, got 2"):
        read_scene(folder)


def test_scene_size_mismatch(tmp_path, small_stereo_rig):
    views, gt, labels = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig, mask=labels, gt_disparity=gt)
    write_image(folder / "cam1.png", views[1][:-1])
    with pytest.raises(FileFormatError, match=r"cam1.png: expected the rig's .* 32x24, got 32x23"):
        read_scene(folder)
    write_image(folder / "cam1.png", views[1])
    write_mask(folder / "mask.png", labels[:, :-2])
    with pytest.raises(FileFormatError, match=r"mask.png: expected the rig's .* 32x24, got 30x24"):
        read_scene(folder)
    write_mask(folder / "mask.png", labels)
    write_disparity(folder / "gt_disparity.pfm", gt[:-4])
    with pytest.raises(FileFormatError, match=r"gt_disparity.pfm: expected .* 32x24, got 32x20"):
        read_scene(folder)


def test_scene_ground_truth_ambiguous(tmp_path, small_stereo_rig):
    views, gt, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig, gt_disparity=gt)
    np.save(folder / "gt_disparity.npy", gt)
    with pytest.raises(FileFormatError, match="one ground-truth disparity file, got 2"):
        read_scene(folder)


def test_scene_bad_rig_and_metadata(tmp_path, small_stereo_rig):
    views, _, _ = _scene_inputs(small_stereo_rig)
    folder = write_scene(tmp_path / "s", views, small_stereo_rig)
    (folder / "scene.json").write_text("[1, 2]")
    with pytest.raises(FileFormatError, match="scene.json: expected a JSON object, got list"):
        read_scene(folder)
    (folder / "scene.json").write_text("{oops")
    with pytest.raises(FileFormatError, match="scene.json: expected valid JSON"):
        read_scene(folder)
    (folder / "scene.json").unlink()
    data = json.loads((folder / "rig.json").read_text())
    data["colour"] = "red"
    (folder / "rig.json").write_text(json.dumps(data))
    with pytest.raises(RigError, match=r"rig.json: rig: unknown key\(s\) \['colour'\]"):
        read_scene(folder)
    (folder / "rig.json").unlink()
    with pytest.raises(FileFormatError, match="scene folder with rig.json"):
        read_scene(folder)
    with pytest.raises(FileFormatError, match="expected a scene folder, got no such directory"):
        read_scene(tmp_path / "nothing")


def test_write_scene_validates(tmp_path, small_stereo_rig):
    views, gt, labels = _scene_inputs(small_stereo_rig)
    with pytest.raises(ImageError, match="expected 2 images"):
        write_scene(tmp_path / "s", views[:1], small_stereo_rig)
    with pytest.raises(ImageError, match="rig's size 32x24, got 16x12"):
        write_scene(tmp_path / "s", [v[::2, ::2] for v in views], small_stereo_rig)
    with pytest.raises(MaskError, match=r"mask: expected shape \(24, 32\)"):
        write_scene(tmp_path / "s", views, small_stereo_rig, mask=labels[:-1])
    with pytest.raises(DisparityError, match=r"gt_disparity: expected shape \(24, 32\)"):
        write_scene(tmp_path / "s", views, small_stereo_rig, gt_disparity=gt[:, :-1])
    with pytest.raises(FileFormatError, match="metadata: expected a JSON-serialisable dict"):
        write_scene(tmp_path / "s", views, small_stereo_rig, metadata={"a": object()})
    with pytest.raises(FileFormatError, match="metadata: expected a JSON-serialisable dict"):
        write_scene(tmp_path / "s", views, small_stereo_rig, metadata={"a": float("nan")})
    with pytest.raises(RigError, match="rig: expected a CameraRig"):
        write_scene(tmp_path / "s", views, {"format": "srde-rig/1"})
    bad_names = CameraRig.stereo(0.1, fx=40.0, image_size=(32, 24), names=("a/b", "c"))
    with pytest.raises(RigError, match="camera name: .*got 'a/b'"):
        write_scene(tmp_path / "s", views, bad_names)
    assert not (tmp_path / "s").exists()


def test_list_scenes(tmp_path, small_stereo_rig):
    views, _, _ = _scene_inputs(small_stereo_rig)
    for name in ("b", "a", "c"):
        write_scene(tmp_path / "data" / name, views, small_stereo_rig)
    (tmp_path / "data" / "notes").mkdir()
    assert [p.name for p in list_scenes(tmp_path / "data")] == ["a", "b", "c"]
    with pytest.raises(FileFormatError, match="sub-folders holding rig.json, got none"):
        list_scenes(tmp_path / "data" / "notes")
    with pytest.raises(FileFormatError, match=r"it is itself a scene folder"):
        list_scenes(tmp_path / "data" / "a")
    with pytest.raises(FileFormatError, match="expected a dataset folder"):
        list_scenes(tmp_path / "missing")


def test_images_declaring_a_huge_size_are_refused_before_decoding(tmp_path):
    import struct
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    # A 60 kB file whose header declares 100000 x 100000 pixels (a decompression bomb).
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    bomb = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 60_000)) + chunk(b"IEND", b""))
    (tmp_path / "bomb.png").write_bytes(bomb)
    with pytest.raises(FileFormatError, match=r"bomb.png: expected a 8-bit image of at most "
                       r"200,000,000 pixels, got a header declaring 100000x100000"):
        read_image(tmp_path / "bomb.png")
    with pytest.raises(FileFormatError, match="mask image of at most"):
        read_mask(tmp_path / "bomb.png")
    write_image(tmp_path / "small.png", np.zeros((30, 40, 3), np.uint8))
    with pytest.raises(FileFormatError, match="at most 1,000 pixels, got a header declaring 40x30"):
        read_image(tmp_path / "small.png", max_pixels=1000)
    assert read_image(tmp_path / "small.png").shape == (30, 40, 3)


def test_a_middlebury_folder_reads_as_a_scene(tmp_path):
    from srde_fusion.io import list_scenes, read_scene

    rng = np.random.default_rng(0)
    im0 = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    im1 = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    folder = tmp_path / "data" / "Motorcycle"
    folder.mkdir(parents=True)
    write_image(folder / "im0.png", im0)
    write_image(folder / "im1.png", im1)
    (folder / "calib.txt").write_text(
        "cam0=[100 0 30; 0 100 20; 0 0 1]\ncam1=[100 0 33; 0 100 20; 0 0 1]\n"
        "doffs=3\nbaseline=120\nwidth=60\nheight=40\nndisp=64\n")
    write_disparity(folder / "disp0.pfm", np.full((40, 60), 10.0, np.float32))
    scene = read_scene(folder)
    assert scene.rig.camera_names == ["cam0", "cam1"] and scene.rig.light_position_m is None
    assert scene.rig.baseline_m == pytest.approx(0.12)
    assert np.array_equal(scene.views[0], im0)
    # im1 moved 3 px right: the rig's shared principal point
    assert np.array_equal(scene.views[1][:, 3:], im1[:, :-3])
    np.testing.assert_allclose(scene.gt_disparity, 13.0)  # d + doffs, the rig's convention
    assert scene.metadata["format"] == "middlebury"
    assert list_scenes(tmp_path / "data") == [folder]
    (folder / "im1.png").unlink()
    with pytest.raises(FileFormatError, match="expected im1.png beside calib.txt"):
        read_scene(folder)


def test_ply_round_trip_and_errors(tmp_path):
    from srde_fusion.io import write_ply

    points = np.array([[0.0, 1.0, 2.0], [-1.5, 0.25, 3.0]], np.float32)
    colors = np.array([[255, 0, 10], [1, 2, 3]], np.uint8)
    data = write_ply(tmp_path / "p.ply", points, colors).read_bytes()
    header, body = data.split(b"end_header\n", 1)
    assert header.startswith(b"ply\nformat binary_little_endian 1.0\nelement vertex 2\n")
    rows = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    assert np.array_equal(rows["xyz"], points) and np.array_equal(rows["rgb"], colors)
    with pytest.raises(FileFormatError, match=r"expected points of shape \(N, 3\)"):
        write_ply(tmp_path / "q.ply", points[:, :2])
    with pytest.raises(FileFormatError, match=r"expected uint8 colours of shape \(2, 3\)"):
        write_ply(tmp_path / "q.ply", points, colors.astype(np.float32))


@pytest.mark.parametrize("size, match", [
    ((640.5, 480), r"image_width/image_height: expected \[width, height\] as two positive "
                   r"integers, got \[640.5, 480.0\]"),
    ((-640, 480), r"expected \[width, height\] as two positive integers, got \[-640.0, 480.0\]"),
    ((1e300, 480), r"expected \[width, height\] as two positive integers, got \[1e\+300, 480.0\]"),
    ((30000, 30000), r"image_size: expected at most 200000000 pixels"),
])
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_opencv_yaml_image_size_out_of_range(tmp_path, size, match):
    path = _write_opencv_yaml(tmp_path / "stereo.yml", size=size)
    with pytest.raises(FileFormatError, match=match) as info:
        read_opencv_stereo_yaml(path)
    assert str(path) in str(info.value)


def test_opencv_yaml_focal_length_out_of_range_names_the_file(tmp_path):
    path = tmp_path / "stereo.yml"
    k = np.array([[0.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    t = np.array([[-0.1], [0.0], [0.0]])
    for name, value in (("K1", k), ("K2", k), ("R", np.eye(3)), ("T", t)):
        fs.write(name, value)
    fs.release()
    with pytest.warns(UserWarning), pytest.raises(
            FileFormatError, match=r"stereo.yml: intrinsics.fx: expected a positive number, got 0"):
        read_opencv_stereo_yaml(path, image_size=(640, 480))


@pytest.mark.parametrize("edit, match", [
    (("4161.221 0 1445.577", "4e7 0 1445.577"), r"calib.txt: intrinsics.fx: expected a focal "
                                                r"length in pixels below 1e\+06"),
    (("baseline=176.252", "baseline=1e9"), r"calib.txt: cameras\[1\].center: expected a "
                                           r"position within 1000 m"),
    (("width=2880", "width=288000"), r"calib.txt: image_size: expected at most 200000000 pixels"),
])
def test_middlebury_calib_numbers_out_of_range(tmp_path, edit, match):
    path = tmp_path / "calib.txt"
    text = MIDDLEBURY_CALIB.replace(*edit)
    if "4e7" in edit[1]:  # both cameras, or the reader refuses unequal focal lengths first
        text = text.replace("4161.221 0 1654.636", "4e7 0 1654.636").replace(
            "0 4161.221 984.686", "0 4e7 984.686")
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match):
        read_middlebury_calib(path)
