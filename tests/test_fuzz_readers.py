"""Fuzzers for every reader: mutated valid files give their content or an SRDEError.

Each reader gets a valid file, then seeded mutations of it: byte flips, truncations,
inserted and repeated chunks, and header edits (numbers in the first bytes or in the
text replaced by huge, negative, fractional and non-finite ones). Whatever the bytes,
only :class:`~srde_fusion.errors.SRDEError` (or success) may come out; anything else
is an *escape*, listed with the mutation that caused it. The OpenCV YAML reader runs in
a child process, so that a crash inside OpenCV is reported as an escape rather than
ending the test run.

The default run makes ``DEFAULT_CASES`` cases per reader (about 15 s in all); the slow
run, ``SLOW_CASES``. Counts are printed (``pytest -s``) and returned in the failure
message.
"""

from __future__ import annotations

import json
import random
import re
import subprocess
import sys
import textwrap
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from srde_fusion.calibration import Board
from srde_fusion.errors import RigError, SRDEError
from srde_fusion.geometry import CameraRig, RigLight
from srde_fusion.io import (
    read_disparity,
    read_image,
    read_mask,
    read_middlebury_calib,
    read_scene,
    write_disparity,
    write_image,
    write_scene,
)
from srde_fusion.masks import UserMasks

DEFAULT_CASES = 120
SLOW_CASES = 1500
H, W = 12, 16

# Numbers a header edit puts in place of one of the file's own.
_HOSTILE_NUMBERS = (b"0", b"-1", b"99999999999", b"1e308", b"-1e308", b"nan", b"inf", b"1.5",
                    b"4294967297", b"0x10", b"", b"1" * 60)
_NUMBER = re.compile(rb"-?\d+(\.\d+)?(e[-+]?\d+)?")


# ---------------------------------------------------------------------- mutations
def mutate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Return a mutation of ``data`` and a description of it."""
    kind = rng.choice(("flip", "flips", "truncate", "insert", "repeat", "header", "number",
                       "delete"))
    out = bytearray(data)
    n = len(out)
    if kind == "flip":
        i = rng.randrange(n)
        out[i] ^= 1 << rng.randrange(8)
        return bytes(out), f"bit flip at {i}"
    if kind == "flips":
        where = [rng.randrange(n) for _ in range(rng.randint(2, 16))]
        for i in where:
            out[i] = rng.randrange(256)
        return bytes(out), f"bytes replaced at {where}"
    if kind == "truncate":
        cut = rng.randrange(n)
        return bytes(out[:cut]), f"truncated to {cut} bytes"
    if kind == "insert":
        at, size = rng.randrange(n + 1), rng.randint(1, 64)
        return bytes(out[:at]) + rng.randbytes(size) + bytes(out[at:]), f"{size} bytes at {at}"
    if kind == "repeat":
        a = rng.randrange(n)
        b = min(n, a + rng.randint(1, 256))
        return bytes(out[:b]) + bytes(out[a:b]) * rng.randint(1, 50) + bytes(out[b:]), \
            f"bytes {a}:{b} repeated"
    if kind == "delete":
        a = rng.randrange(n)
        b = min(n, a + rng.randint(1, 32))
        return bytes(out[:a] + out[b:]), f"bytes {a}:{b} deleted"
    numbers = list(_NUMBER.finditer(data))
    if kind == "header":
        numbers = [m for m in numbers if m.start() < 128] or numbers
    if not numbers:
        i = rng.randrange(min(n, 32))
        out[i] = rng.randrange(256)
        return bytes(out), f"header byte {i} replaced"
    m = rng.choice(numbers)
    new = rng.choice(_HOSTILE_NUMBERS)
    return data[:m.start()] + new + data[m.end():], f"{m.group()!r} at {m.start()} -> {new!r}"


def fuzz(reader: Callable[[Path], object], valid: bytes, path: Path, cases: int, seed: int
         ) -> dict:
    """Feed ``cases`` mutations of ``valid``, written to ``path``, to ``reader``."""
    rng = random.Random(seed)
    counts = {"cases": 0, "accepted": 0, "refused": 0, "escaped": 0}
    escapes = []
    for _ in range(cases):
        data, how = mutate(valid, rng)
        path.write_bytes(data)
        counts["cases"] += 1
        try:
            # Overflow on the way counts too: numbers must be checked before arithmetic.
            with warnings.catch_warnings():
                warnings.simplefilter("error", RuntimeWarning)
                reader(path)
            counts["accepted"] += 1
        except SRDEError:
            counts["refused"] += 1
        except Exception as exc:  # an escape: recorded, the test fails below
            counts["escaped"] += 1
            escapes.append(f"{how}: {type(exc).__name__}: {str(exc)[:120]}")
    counts["escapes"] = escapes[:10]
    return counts


# ---------------------------------------------------------------------- valid files
@pytest.fixture(scope="module")
def rig() -> CameraRig:
    return CameraRig.stereo(0.1, fx=40.0, image_size=(W, H), names=("cam0", "cam1"),
                            light_position_m=(0.05, -0.3, 0.0))


@pytest.fixture(scope="module")
def valid(tmp_path_factory, rig) -> dict[str, bytes]:
    """Valid bytes of every file kind a reader takes."""
    folder = tmp_path_factory.mktemp("valid")
    rng = np.random.default_rng(0)
    disparity = rng.uniform(0.5, 30.0, (H, W)).astype(np.float32)
    disparity[0, 0] = np.nan
    labels = np.zeros((H, W), np.uint8)
    labels[2:6, 3:9], labels[7:11, 10:15] = 1, 2
    labels16 = labels.astype(np.uint16) * 300
    board = Board.corner_layout()
    out = {
        "pfm": write_disparity(folder / "d.pfm", disparity).read_bytes(),
        "kitti": write_disparity(folder / "d.png", disparity).read_bytes(),
        "npy": write_disparity(folder / "d.npy", disparity).read_bytes(),
        "png": write_image(folder / "i.png", rng.integers(0, 256, (H, W, 3), np.uint8))
        .read_bytes(),
        "rig": rig.to_json().encode(),
        # Several lights with the optional fields: radius, name.
        "rig_lights": rig.with_lights([RigLight((0.05, -0.3, 0.0), radius_m=0.004, name="a"),
                                       RigLight((-0.2, -0.3, 0.1), name="b"),
                                       RigLight((0.0, 0.4, 0.0), radius_m=0.0)])
        .to_json().encode(),
        "board": board.to_json().encode(),
        "mask_png": cv2.imencode(".png", labels)[1].tobytes(),
        "mask_png16": cv2.imencode(".png", labels16)[1].tobytes(),
        "calib": (b"cam0=[40 0 7.5; 0 40 5.5; 0 0 1]\ncam1=[40 0 9.5; 0 40 5.5; 0 0 1]\n"
                  b"doffs=2\nbaseline=100\nwidth=16\nheight=12\nndisp=32\n"),
        "json": json.dumps({"a": [1, 2.5, {"b": None}], "c": "text"}).encode(),
    }
    np.save(folder / "m.npy", labels)
    out["mask_npy"] = (folder / "m.npy").read_bytes()
    fs = cv2.FileStorage(str(folder / "s.yml"), cv2.FILE_STORAGE_WRITE)
    k = np.array([[40.0, 0.0, 7.5], [0.0, 40.0, 5.5], [0.0, 0.0, 1.0]])
    for name, value in (("K1", k), ("D1", np.zeros((1, 5))), ("K2", k), ("D2", np.zeros((1, 5))),
                        ("R", np.eye(3)), ("T", np.array([[-0.1], [0.0], [0.0]])),
                        ("P1", np.c_[k, np.zeros(3)]), ("P2", np.c_[k, [-4.0, 0.0, 0.0]])):
        fs.write(name, value)
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.release()
    out["yaml"] = (folder / "s.yml").read_bytes()
    return out


def _scene_reader(rig_bytes: bytes, rig: CameraRig, folder: Path, target: str):
    """A reader of a whole scene folder in which the file ``target`` is the fuzzed one."""
    rng = np.random.default_rng(1)
    views = [rng.integers(0, 256, (H, W, 3), np.uint8) for _ in range(2)]
    labels = np.zeros((H, W), np.uint8)
    labels[2:6, 3:9] = 1
    write_scene(folder, views, rig, mask=labels,
                gt_disparity=np.full((H, W), 4.0, np.float32), metadata={"seed": 1})

    def read(path: Path) -> object:
        (folder / target).write_bytes(path.read_bytes())
        return read_scene(folder)

    return read


def _mask_reader(path: Path) -> object:
    rig = CameraRig.stereo(0.1, fx=40.0, image_size=(W, H))
    return UserMasks(path)(None, rig)


READERS: dict[str, tuple[str, str, Callable]] = {
    # name: (valid file kind, suffix, reader)
    "read_image (PNG)": ("png", ".png", read_image),
    "read_mask (8-bit labels)": ("mask_png", ".png", read_mask),
    "read_mask (16-bit labels)": ("mask_png16", ".png", read_mask),
    "UserMasks (PNG labels)": ("mask_png", ".png", _mask_reader),
    "UserMasks (.npy labels)": ("mask_npy", ".npy", _mask_reader),
    "read_disparity (PFM)": ("pfm", ".pfm", read_disparity),
    "read_disparity (KITTI PNG)": ("kitti", ".png", read_disparity),
    "read_disparity (.npy)": ("npy", ".npy", read_disparity),
    "CameraRig.from_json (rig.json)": ("rig", ".json", CameraRig.from_json),
    "CameraRig.from_json (several lights)": ("rig_lights", ".json", CameraRig.from_json),
    "Board.from_json (board.json)": ("board", ".json", Board.from_json),
    "read_middlebury_calib": ("calib", ".txt", read_middlebury_calib),
    "JSON (any rig source)": ("json", ".json", CameraRig.from_json),
}


def _run_all(valid, rig, tmp_path, cases: int) -> dict[str, dict]:
    results = {}
    for i, (name, (kind, suffix, reader)) in enumerate(READERS.items()):
        results[name] = fuzz(reader, valid[kind], tmp_path / f"case{i}{suffix}", cases, seed=i)
    for target in ("rig.json", "cam0.png", "mask.png", "gt_disparity.pfm", "scene.json"):
        kind = {"rig.json": "rig", "cam0.png": "png", "mask.png": "mask_png",
                "gt_disparity.pfm": "pfm", "scene.json": "json"}[target]
        folder = tmp_path / f"scene_{target.replace('.', '_')}"
        reader = _scene_reader(valid["rig"], rig, folder, target)
        results[f"read_scene ({target})"] = fuzz(reader, valid[kind],
                                                 tmp_path / f"in_{target}", cases // 2,
                                                 seed=100 + len(results))
    results["read_opencv_stereo_yaml"] = _fuzz_yaml(valid["yaml"], tmp_path, cases, seed=200)
    return results


# The YAML reader runs in a child: OpenCV's parser may abort the process on some inputs.
_YAML_CHILD = textwrap.dedent("""
    import json, sys, warnings
    warnings.simplefilter("ignore")
    from srde_fusion.errors import SRDEError
    from srde_fusion.io import read_opencv_stereo_yaml
    for path in sys.argv[1:]:
        print("start", path, flush=True)
        try:
            read_opencv_stereo_yaml(path)
            outcome = "accepted"
        except SRDEError:
            outcome = "refused"
        except Exception as exc:
            outcome = "escaped " + type(exc).__name__ + ": " + str(exc)[:120]
        print("done", json.dumps(outcome), flush=True)
""")


def _fuzz_yaml(valid: bytes, tmp_path: Path, cases: int, seed: int) -> dict:
    rng = random.Random(seed)
    folder = tmp_path / "yaml"
    folder.mkdir()
    files, how = [], {}
    for i in range(cases):
        data, description = mutate(valid, rng)
        path = folder / f"case{i}.yml"
        path.write_bytes(data)
        files.append(str(path))
        how[str(path)] = description
    counts = {"cases": 0, "accepted": 0, "refused": 0, "escaped": 0}
    escapes = []
    pending = list(files)
    while pending:
        done = subprocess.run([sys.executable, "-c", _YAML_CHILD, *pending],
                              capture_output=True, text=True, cwd=Path(__file__).parents[1])
        started = None
        for line in done.stdout.splitlines():
            if line.startswith("start "):
                started = line[6:]
            elif line.startswith("done "):
                outcome = json.loads(line[5:])
                counts["cases"] += 1
                key = outcome.split()[0]
                counts[key] += 1
                if key == "escaped":
                    escapes.append(f"{how[started]}: {outcome[8:]}")
                pending.remove(started)
                started = None
        if started is not None:  # the child died inside this case
            counts["cases"] += 1
            counts["escaped"] += 1
            escapes.append(f"{how[started]}: process ended with code {done.returncode}")
            pending.remove(started)
        elif done.returncode != 0:
            raise AssertionError(f"YAML fuzz child failed: {done.stderr[-500:]}")
    counts["escapes"] = escapes[:10]
    return counts


def _report(results: dict[str, dict]) -> str:
    lines = [f"{'reader':40s} {'cases':>6s} {'accepted':>9s} {'refused':>8s} {'escaped':>8s}"]
    for name, c in results.items():
        lines.append(f"{name:40s} {c['cases']:6d} {c['accepted']:9d} {c['refused']:8d} "
                     f"{c['escaped']:8d}")
        lines += [f"    {e}" for e in c["escapes"]]
    total = {k: sum(c[k] for c in results.values()) for k in ("cases", "escaped")}
    lines.append(f"total: {total['cases']} cases, {total['escaped']} escaped")
    return "\n".join(lines)


def _check(results: dict[str, dict]) -> None:
    text = _report(results)
    print("\n" + text)
    assert all(c["escaped"] == 0 for c in results.values()), text
    # Every reader both accepted and refused something: the mutations reach the parser.
    for name, c in results.items():
        assert c["refused"] > 0, f"{name}: no mutation was refused\n{text}"


def test_mutated_files_give_content_or_an_srde_error(valid, rig, tmp_path):
    _check(_run_all(valid, rig, tmp_path, DEFAULT_CASES))


@pytest.mark.slow
def test_mutated_files_give_content_or_an_srde_error_many(valid, rig, tmp_path):
    _check(_run_all(valid, rig, tmp_path, SLOW_CASES))


def test_the_mutations_are_seeded(valid):
    first = [mutate(valid["pfm"], random.Random(3)) for _ in range(5)]
    again = [mutate(valid["pfm"], random.Random(3)) for _ in range(5)]
    assert first == again


def test_an_escape_is_reported(tmp_path):
    def broken(path: Path) -> None:
        raise KeyError("not an SRDEError")

    counts = fuzz(broken, b"PF\n1 1\n-1.0\n0000", tmp_path / "x.pfm", 3, seed=0)
    assert counts["escaped"] == 3 and "KeyError" in counts["escapes"][0]
    with pytest.raises(RigError):
        CameraRig.from_json(tmp_path / "missing.json")
