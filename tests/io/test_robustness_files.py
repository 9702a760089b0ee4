"""Robustness of the file readers: truncated, garbled and hand-edited files.

Every reader either returns what the file holds or raises an SRDEError subclass whose
message names the file and the problem; no OSError, UnicodeDecodeError, struct or numpy
error escapes, and OpenCV prints nothing of its own on stderr.
"""

from __future__ import annotations

import copy
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from srde_fusion.errors import FileFormatError, RigError, SRDEError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import (
    list_scenes,
    read_disparity,
    read_image,
    read_kitti_disparity,
    read_mask,
    read_pfm,
    read_scene,
    write_disparity,
    write_kitti_disparity,
    write_scene,
)

H, W = 12, 16

# A name longer than any file system allows: the OS refuses to look it up (ENAMETOOLONG).
TOO_LONG_NAME = "x" * 5000


@pytest.fixture(scope="module")
def rig() -> CameraRig:
    return CameraRig.stereo(0.1, fx=40.0, image_size=(W, H), names=("cam0", "cam1"),
                            light_position_m=(0.05, -0.3, 0.0))


@pytest.fixture(scope="module")
def valid_bytes(tmp_path_factory, rig) -> dict[str, bytes]:
    """Bytes of valid files of every kind the library reads."""
    folder = tmp_path_factory.mktemp("valid")
    rng = np.random.default_rng(0)
    disparity = rng.uniform(0.5, 30.0, (H, W)).astype(np.float32)
    disparity[0, 0] = np.nan
    out = {
        "pfm": write_disparity(folder / "d.pfm", disparity).read_bytes(),
        "kitti": write_kitti_disparity(folder / "d.png", disparity).read_bytes(),
        "npy": write_disparity(folder / "d.npy", disparity).read_bytes(),
        "rig": rig.to_json().encode(),
    }
    ok, png = cv2.imencode(".png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    assert ok
    out["png"] = png.tobytes()
    return out


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# ------------------------------------------------------------------ truncation, every cut
@pytest.mark.parametrize("kind, reader, suffix", [
    ("pfm", read_pfm, ".pfm"),
    ("pfm", read_disparity, ".pfm"),
    ("kitti", read_kitti_disparity, ".png"),
    ("kitti", read_disparity, ".png"),
    ("npy", read_disparity, ".npy"),
    ("png", read_image, ".png"),
    ("png", read_mask, ".png"),
])
def test_a_truncated_file_is_a_file_format_error(tmp_path, valid_bytes, kind, reader, suffix):
    data = valid_bytes[kind]
    # Every cut through the header, then a spread of cuts through the payload.
    cuts = sorted(set(range(0, min(len(data), 40))) | set(np.linspace(40, len(data) - 1, 25,
                                                                        dtype=int).tolist()))
    path = tmp_path / f"cut{suffix}"
    for cut in cuts:
        _write(path, data[:cut])
        with pytest.raises(FileFormatError, match=r"cut\.(pfm|png|npy): expected "):
            reader(path)


def test_decoder_complaints_do_not_reach_stderr(tmp_path, valid_bytes, capfd):
    # OpenCV logs a broken PNG from C++ straight to file descriptor 2; a command must
    # still fail with exactly one line.
    path = _write(tmp_path / "broken.png", valid_bytes["png"][:60])
    for reader in (read_image, read_mask, read_kitti_disparity):
        with pytest.raises(FileFormatError, match="undecodable data"):
            reader(path)
    assert capfd.readouterr().err == ""


# ------------------------------------------------------------------ garbled headers
@pytest.mark.parametrize("content, match", [
    (b"", "starting with 'PF' or 'Pf'"),
    (b"P6\n2 2\n255\n", "starting with 'PF' or 'Pf'"),
    (b"Pf", "PFM header"),
    (b"Pf\n-2 2\n-1\n", "PFM header"),
    (b"Pf\n2 x\n-1\n", "PFM header"),
    (b"Pf\n0 2\n-1\n", "positive width/height"),
    (b"Pf\n2 2\n0\n" + bytes(16), "non-zero scale"),
    (b"Pf\n2 2\n-1e999\n" + bytes(16), "non-zero scale"),
    (b"Pf\n2 2\n1.2.3\n" + bytes(16), "numeric PFM scale"),
    # A header that promises far more data than the file holds (no huge allocation).
    (b"Pf\n99999999999 99999999999\n-1\n" + bytes(16), "truncated file"),
    (b"PF\n2 2\n-1\n" + bytes(16), r"expected 48 bytes .* got 16 \(truncated file\)"),
])
def test_garbled_pfm_headers(tmp_path, content, match):
    with pytest.raises(FileFormatError, match=match):
        read_pfm(_write(tmp_path / "bad.pfm", content))


def test_colour_pfm_is_not_a_disparity_map(tmp_path):
    path = _write(tmp_path / "rgb.pfm", b"PF\n2 2\n-1\n" + bytes(48))
    assert read_pfm(path).shape == (2, 2, 3)
    with pytest.raises(FileFormatError, match=r"single-channel \(H, W\)"):
        read_disparity(path)


def test_disparity_png_that_is_not_kitti(tmp_path, valid_bytes):
    path = _write(tmp_path / "colour.png", valid_bytes["png"])
    with pytest.raises(FileFormatError, match="16-bit KITTI"):
        read_disparity(path)


@pytest.mark.parametrize("array, match", [
    (np.zeros((2, 3, 4), np.float32), r"single-channel \(H, W\)"),
    (np.array(["a", "b"]), r"single-channel \(H, W\)"),
    (np.zeros((3, 3), complex), r"single-channel \(H, W\)"),
])
def test_npy_that_is_not_a_disparity_map(tmp_path, array, match):
    path = tmp_path / "d.npy"
    np.save(path, array)
    with pytest.raises(FileFormatError, match=match):
        read_disparity(path)


def test_npy_with_pickled_objects_is_refused(tmp_path):
    path = tmp_path / "objects.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(FileFormatError, match="numpy .npy array, got an unreadable file"):
        read_disparity(path)


# ------------------------------------------------------------------ paths the OS refuses
@pytest.mark.parametrize("reader", [read_pfm, read_disparity, read_kitti_disparity, read_image,
                                    read_mask])
def test_a_name_too_long_to_look_up_is_a_missing_file(reader):
    with pytest.raises(FileFormatError, match="expected an existing .* got no such file"):
        reader(TOO_LONG_NAME + ".png")


def test_folders_and_rigs_with_names_too_long_to_look_up():
    with pytest.raises(FileFormatError, match="expected a scene folder, got no such directory"):
        read_scene(TOO_LONG_NAME)
    with pytest.raises(FileFormatError, match="expected a dataset folder, got no such directory"):
        list_scenes(TOO_LONG_NAME)
    with pytest.raises(RigError, match="expected an existing rig.json"):
        CameraRig.from_json(TOO_LONG_NAME)
    # A JSON text that does not start with "{" is taken for a path: still a RigError.
    with pytest.raises(RigError, match="expected an existing rig.json"):
        CameraRig.from_json(json.dumps(list(range(2000))))


def test_a_folder_given_as_a_file(tmp_path):
    for reader in (read_pfm, read_image, read_mask):
        with pytest.raises(FileFormatError, match="got no such file"):
            reader(tmp_path)
    with pytest.raises(RigError, match="expected an existing rig.json"):
        CameraRig.from_json(tmp_path)


# ------------------------------------------------------------------ rig.json, field by field
def _key_paths(data, prefix=()):
    """Every key path of a nested JSON value: ("intrinsics", "fx"), ("cameras", 0), ..."""
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(
        data, list) else ()
    for key, value in items:
        yield (*prefix, key)
        yield from _key_paths(value, (*prefix, key))


def _edited(data, path, value):
    out = copy.deepcopy(data)
    target = out
    for key in path[:-1]:
        target = target[key]
    if value is _DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return out


_DELETE = object()
# JSON values of every type, and numbers that no field accepts everywhere.
_REPLACEMENTS = (None, True, "text", [], {}, [1.0], math.nan, math.inf, -1.0, 0, 1e308,
                 [math.nan, 0.0, 0.0])


def test_every_edit_of_a_rig_json_is_accepted_or_a_rig_error(rig):
    base = rig.to_dict()
    accepted = 0
    for path in _key_paths(base):
        for value in (*_REPLACEMENTS, _DELETE):
            text = json.dumps(_edited(base, path, value))
            try:
                CameraRig.from_json(text)
                accepted += 1
            except RigError as exc:
                message = str(exc)
                # The message names the edited field (a camera centre that breaks the
                # stereo pair's geometry is reported as the pair's problem).
                field = str(path[-1]) if isinstance(path[-1], str) else str(path[-2])
                assert field in message or "stereo_pair: expected" in message, (
                    path, value, message)
                assert "expected" in message or "key(s)" in message, message
    # Plausible edits stay valid (a principal point of 0, a light 1 m to the left): the
    # loop above must not have refused everything.
    assert accepted > 0


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.update(extra=1), r"rig: unknown key\(s\) \['extra'\]"),
    (lambda d: d["intrinsics"].update(skew=0.0), r"intrinsics: unknown key\(s\) \['skew'\]"),
    (lambda d: d["cameras"][0].update(rotation=[0, 0, 0]),
     r"cameras\[0\]: unknown key\(s\) \['rotation'\]"),
    (lambda d: d["light"].update(radius=0.01), r"light: unknown key\(s\) \['radius'\]"),
    (lambda d: d.pop("intrinsics"), r"rig: missing key\(s\) \['intrinsics'\]"),
    (lambda d: d["intrinsics"].pop("fy"), r"intrinsics: missing key\(s\) \['fy'\]"),
    (lambda d: d["cameras"][1].pop("center"), r"cameras\[1\]: missing key\(s\) \['center'\]"),
    (lambda d: d["intrinsics"].update(fx="600"), r"intrinsics.fx: expected a number, got str"),
    (lambda d: d["intrinsics"].update(fx=-600.0), "intrinsics.fx: expected a positive number"),
    (lambda d: d["intrinsics"].update(cx=math.nan), "intrinsics.cx: expected a finite number"),
    (lambda d: d.update(image_size=[W, -H]), "image_size: expected .* two positive integers"),
    (lambda d: d.update(image_size=[16.0, 12.0]), "image_size: expected .* two positive integers"),
    (lambda d: d.update(reference=-1), r"reference: expected a camera index in \[0, 1\]"),
    (lambda d: d.update(reference=True), r"reference: expected a camera index"),
    (lambda d: d.update(stereo_pair=[0, 0]), "stereo_pair: expected the partner camera 0"),
    (lambda d: d["cameras"][1].update(center=[-0.1, 0.0, 0.0]),
     "expected the partner camera 1 to lie to the right"),
    (lambda d: d["cameras"][1].update(center=[0.1, 0.0, 0.05]),
     r"cameras\[1\].center: expected z = 0 m"),
    (lambda d: d["cameras"][1].update(name="cam0"), "cameras: expected unique names"),
    (lambda d: d["light"].update(position=[0.0, math.nan, 0.0]),
     r"light.position\[1\]: expected a finite number"),
    (lambda d: d["light"].update(position=[0.0, 0.0]), "light.position: expected a list of 3"),
    (lambda d: d.update(format="srde-rig/2"), "format: expected 'srde-rig/1'"),
    (lambda d: d.update(image_encoding="gamma2.2"), "image_encoding: expected one of"),
])
def test_hand_edited_rig_json(tmp_path, rig, edit, match):
    data = rig.to_dict()
    edit(data)
    # NaN travels through JSON as the non-standard token NaN, as Python writes it.
    path = _write(tmp_path / "rig.json", json.dumps(data).encode())
    with pytest.raises(RigError, match=match):
        CameraRig.from_json(path)


@pytest.mark.parametrize("content, match", [
    (b"", "expected valid JSON"),
    (b"{", "expected valid JSON"),
    (b"\xff\xfe\x00{", "expected valid JSON"),
    (b"[1, 2]", "rig: expected an object, got list"),
    (b"null", "rig: expected an object, got NoneType"),
    (b"{" * 100_000, "expected valid JSON"),
])
def test_garbled_rig_json(tmp_path, content, match):
    with pytest.raises(RigError, match=match):
        CameraRig.from_json(_write(tmp_path / "rig.json", content))


def test_truncated_rig_json_at_every_cut(tmp_path, valid_bytes):
    data = valid_bytes["rig"]
    path = tmp_path / "rig.json"
    # The one cut that leaves valid JSON is the whole text minus trailing whitespace.
    for cut in range(len(data.rstrip())):
        with pytest.raises(RigError, match="rig.json: expected valid JSON"):
            CameraRig.from_json(_write(path, data[:cut]))


# ------------------------------------------------------------------ scene folders
@pytest.fixture()
def scene_dir(tmp_path, rig) -> Path:
    rng = np.random.default_rng(1)
    views = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    mask = np.zeros((H, W), np.int32)
    mask[2:10, 3:12] = 1
    return write_scene(tmp_path / "scene", views, rig, mask=mask,
                       gt_disparity=np.full((H, W), 4.0, np.float32))


def _remove(path: Path) -> None:
    path.unlink()


@pytest.mark.parametrize("damage, error, match", [
    (lambda d: _remove(d / "cam1.png"), FileFormatError, r"missing \['cam1'\]"),
    (lambda d: shutil.copy(d / "cam0.png", d / "cam2.png"), FileFormatError,
     r"got extra \['cam2.png'\]"),
    (lambda d: shutil.copy(d / "cam0.png", d / "cam0.jpg"), FileFormatError,
     "expected one image for camera 'cam0' file, got 2"),
    (lambda d: _remove(d / "rig.json"), FileFormatError, "expected a scene folder with rig.json"),
    (lambda d: _write(d / "rig.json", b'{"format": "srde-rig/1"'), RigError,
     "rig.json: expected valid JSON"),
    (lambda d: _write(d / "cam1.png", (d / "cam1.png").read_bytes()[:50]), FileFormatError,
     "cam1.png: expected a readable 8-bit image, got undecodable data"),
    (lambda d: _write(d / "mask.png", b"\x89PNG garbage"), FileFormatError,
     "mask.png: expected a readable mask image"),
    (lambda d: _write(d / "gt_disparity.pfm", (d / "gt_disparity.pfm").read_bytes()[:30]),
     FileFormatError, r"gt_disparity.pfm: expected .* \(truncated file\)"),
    (lambda d: _write(d / "scene.json", b"[1"), FileFormatError,
     "scene.json: expected valid JSON"),
    (lambda d: _write(d / "scene.json", b"[1]"), FileFormatError,
     "scene.json: expected a JSON object, got list"),
    (lambda d: cv2.imwrite(str(d / "cam0.png"), np.zeros((H, W + 1, 3), np.uint8)),
     FileFormatError, "cam0.png: expected the rig's image size 16x12, got 17x12"),
    (lambda d: cv2.imwrite(str(d / "cam0.png"), np.zeros((H, W), np.uint16)),
     FileFormatError, "cam0.png: expected an 8-bit image, got dtype uint16"),
    (lambda d: cv2.imwrite(str(d / "mask.png"), np.zeros((H + 1, W), np.uint8)),
     FileFormatError, "mask.png: expected the rig's image size 16x12, got 16x13"),
])
def test_damaged_scene_folders(scene_dir, damage, error, match):
    damage(scene_dir)
    with pytest.raises(error, match=match):
        read_scene(scene_dir)


def test_grey_and_colour_views_may_be_mixed_in_a_scene(scene_dir, rig):
    cv2.imwrite(str(scene_dir / "cam1.png"), np.full((H, W), 90, np.uint8))
    scene = read_scene(scene_dir)
    assert scene.views[0].shape == (H, W, 3) and scene.views[1].shape == (H, W)


def test_a_dataset_without_scenes(tmp_path, scene_dir):
    with pytest.raises(FileFormatError, match=r"got none \(it is itself a scene folder\)"):
        list_scenes(scene_dir)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileFormatError, match="expected sub-folders holding rig.json, got none"):
        list_scenes(tmp_path / "empty")


# ------------------------------------------------------------------ random bytes (hypothesis)
_PREFIXES = (b"", b"PF\n", b"Pf\n", b"Pf\n4 3\n", b"Pf\n4 3\n-1.0\n", b"PF\n4 3\n1.0\n",
             b"\x89PNG\r\n\x1a\n", b"\x93NUMPY\x01\x00", b"{", b'{"format": "srde-rig/1", ')


def _garbage():
    return st.tuples(st.sampled_from(_PREFIXES), st.binary(max_size=300)).map(
        lambda parts: parts[0] + parts[1])


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    """A folder whose files each hypothesis example overwrites."""
    return tmp_path_factory.mktemp("scratch")


def _only_srde_errors(call) -> None:
    try:
        call()
    except SRDEError:
        pass


@settings(max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(data=_garbage(), suffix=st.sampled_from([".pfm", ".png", ".npy", ".jpg"]))
def test_garbage_bytes_into_the_readers(scratch, data, suffix):
    path = _write(scratch / f"garbage{suffix}", data)
    _only_srde_errors(lambda: read_pfm(path))
    _only_srde_errors(lambda: read_kitti_disparity(path))
    _only_srde_errors(lambda: read_image(path))
    _only_srde_errors(lambda: read_mask(path))
    if suffix != ".jpg":
        _only_srde_errors(lambda: read_disparity(path))
    else:
        with pytest.raises(FileFormatError, match="expected a disparity file ending in"):
            read_disparity(path)


@settings(max_examples=60)
@given(data=_garbage())
def test_garbage_bytes_as_rig_json_and_scene(scratch, data):
    folder = scratch / "scene"
    folder.mkdir(exist_ok=True)
    _write(folder / "rig.json", data)
    with pytest.raises(RigError):
        CameraRig.from_json(folder / "rig.json")
    with pytest.raises(SRDEError):
        read_scene(folder)
    text = data.decode("latin-1")
    _only_srde_errors(lambda: CameraRig.from_json(text))


@settings(max_examples=60)
@given(kind=st.sampled_from(["pfm", "kitti", "npy", "png"]),
       flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), min_size=1,
                      max_size=8))
def test_bit_flips_in_valid_files(scratch, valid_bytes, kind, flips):
    data = bytearray(valid_bytes[kind])
    for position, xor in flips:
        data[position % len(data)] ^= xor
    suffix = {"pfm": ".pfm", "kitti": ".png", "npy": ".npy", "png": ".png"}[kind]
    path = _write(scratch / f"flipped{suffix}", bytes(data))
    _only_srde_errors(lambda: read_disparity(path))
    if kind == "png":
        _only_srde_errors(lambda: read_image(path))
        _only_srde_errors(lambda: read_mask(path))


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=4),
    max_leaves=12)


@settings(max_examples=80)
@given(data=st.data())
def test_random_values_in_a_valid_rig_json(rig, data):
    base = rig.to_dict()
    paths = list(_key_paths(base))
    edited = base
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths))
        try:
            edited = _edited(edited, path, data.draw(_JSON))
        except (KeyError, IndexError, TypeError):  # an earlier edit removed the parent
            continue
    _only_srde_errors(lambda: CameraRig.from_dict(edited))
    _only_srde_errors(lambda: CameraRig.from_json(json.dumps(edited)))


# ------------------------------------------------------------------ longer runs (-m slow)
@pytest.mark.slow
@settings(max_examples=1000, suppress_health_check=[HealthCheck.too_slow])
@given(data=_garbage(), suffix=st.sampled_from([".pfm", ".png", ".npy", ".jpg"]))
def test_garbage_bytes_into_the_readers_many(scratch, data, suffix):
    test_garbage_bytes_into_the_readers.hypothesis.inner_test(scratch=scratch, data=data,
                                                              suffix=suffix)


@pytest.mark.slow
@settings(max_examples=1000)
@given(data=st.data())
def test_random_values_in_a_valid_rig_json_many(rig, data):
    test_random_values_in_a_valid_rig_json.hypothesis.inner_test(rig=rig, data=data)
