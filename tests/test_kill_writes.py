"""Killing a writing command at any point leaves the old file or the new one, never a part.

Every file the library writes goes to a temporary file in its folder and is renamed
into place (``srde_fusion._atomic``). Here each writer runs over the outputs of an
earlier run with the rename failing at its 1st, 2nd, ... call: an interruption
(``_Killed``, a ``BaseException`` as an interrupt is) between a file's write and its
rename. Afterwards every file must hold exactly its old bytes or exactly its new bytes
(or be absent where the run would remove or had not yet written it), and no temporary
file may remain.

A real ``kill -9`` cannot run the clean-up: it leaves a hidden ``.<name>.*.tmp`` beside
the intact target; the target itself is the same as here.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from srde_fusion import _atomic
from srde_fusion._json import dump_json
from srde_fusion.calibration import Board, write_board
from srde_fusion.calibration import captures as captures_module
from srde_fusion.calibration.captures import calibrate_light_files
from srde_fusion.evaluation import evaluate_dataset
from srde_fusion.geometry import CameraRig
from srde_fusion.io import (
    write_disparity,
    write_image,
    write_mask,
    write_pfm,
    write_ply,
    write_scene,
)
from srde_fusion.synthetic import render_dataset
from srde_fusion.workflows import fuse_scene, srde_scene

H, W = 24, 32


class _Killed(BaseException):
    """The interruption injected between a write and its rename."""


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _temporaries(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]


def _count_renames(monkeypatch, run: Callable[[], object]) -> int:
    calls = []

    def replace(src, dst):
        calls.append(dst)
        os.replace(src, dst)

    monkeypatch.setattr(_atomic, "_replace", replace)
    run()
    monkeypatch.setattr(_atomic, "_replace", os.replace)
    return len(calls)


def check_kills(monkeypatch, tmp_path: Path, prepare: Callable[[Path], None],
                run: Callable[[Path], object], *, removed_by_design: bool = False) -> int:
    """Run ``run`` over ``prepare``'s folder, killed at every rename; check each outcome.

    Returns the number of kill points checked.
    """
    old_dir = tmp_path / "old"
    prepare(old_dir)
    old = _snapshot(old_dir)
    new_dir = tmp_path / "new"
    shutil.copytree(old_dir, new_dir)
    n = _count_renames(monkeypatch, lambda: run(new_dir))
    new = _snapshot(new_dir)
    assert n > 0 and new != old, "the writer must write something new"
    for k in range(1, n + 1):
        trial = tmp_path / f"kill{k}"
        shutil.copytree(old_dir, trial)
        calls = []

        def replace(src, dst, calls=calls, k=k):
            calls.append(dst)
            if len(calls) == k:
                raise _Killed(dst)
            os.replace(src, dst)

        monkeypatch.setattr(_atomic, "_replace", replace)
        with pytest.raises(_Killed):
            run(trial)
        monkeypatch.setattr(_atomic, "_replace", os.replace)
        got = _snapshot(trial)
        assert _temporaries(trial) == [], (k, _temporaries(trial))
        for name in set(old) | set(new) | set(got):
            if name not in got:
                # absent: never written yet, or removed as the new run would remove it
                assert name not in old or name not in new or removed_by_design, (k, name)
                continue
            assert got[name] in (old.get(name), new.get(name)), (k, name, "a partial file")
        shutil.rmtree(trial)
    return n


# ---------------------------------------------------------------------- single files
def _disparity(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(1.0, 60.0, (H, W)).astype(np.float32)


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), np.uint8)


def _rig(light=(0.05, -0.3, 0.0)) -> CameraRig:
    return CameraRig.grid(1, 3, baseline_m=0.1, fx=40.0, image_size=(W, H), light_position_m=light)


SINGLE_WRITERS = {
    "write_pfm": lambda path, s: write_pfm(path / "d.pfm", _disparity(s)),
    "write_disparity PFM": lambda path, s: write_disparity(path / "d.pfm", _disparity(s)),
    "write_disparity KITTI PNG": lambda path, s: write_disparity(path / "d.png", _disparity(s)),
    "write_disparity npy": lambda path, s: write_disparity(path / "d.npy", _disparity(s)),
    "write_image": lambda path, s: write_image(path / "i.png", _image(s)),
    "write_mask": lambda path, s: write_mask(path / "m.png",
                                             (_disparity(s) > 30).astype(np.uint8)),
    "write_ply": lambda path, s: write_ply(
        path / "p.ply", np.random.default_rng(s).normal(size=(50, 3)),
        np.random.default_rng(s).integers(0, 255, (50, 3), np.uint8)),
    "CameraRig.to_json": lambda path, s: _rig((0.05 * s, -0.3, 0.0)).to_json(path / "rig.json"),
    "Board.to_json": lambda path, s: Board.corner_layout(marker_size_m=0.04 + 0.01 * s)
    .to_json(path / "board.json"),
    "dump_json": lambda path, s: dump_json({"seed": s, "values": list(range(s + 3))},
                                           path / "x.json"),
}


@pytest.mark.parametrize("name", list(SINGLE_WRITERS))
def test_single_file_writers(monkeypatch, tmp_path, name):
    write = SINGLE_WRITERS[name]

    def prepare(folder: Path) -> None:
        folder.mkdir()
        write(folder, 1)

    assert check_kills(monkeypatch, tmp_path, prepare, lambda folder: write(folder, 2)) == 1


def test_a_failed_rename_of_the_system_leaves_the_old_file(monkeypatch, tmp_path):
    """An OSError at the rename (a full disk, say) is an SRDEError naming the file."""
    path = write_pfm(tmp_path / "d.pfm", _disparity(1))
    before = path.read_bytes()

    def replace(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_atomic, "_replace", replace)
    from srde_fusion.errors import FileFormatError

    with pytest.raises(FileFormatError, match=r"d.pfm: could not write the file: .*No space"):
        write_pfm(path, _disparity(2))
    assert path.read_bytes() == before and _temporaries(tmp_path) == []


def test_the_check_catches_a_file_written_in_place(monkeypatch, tmp_path):
    """A writer that writes one file in place around an atomic one is caught."""
    def prepare(folder: Path) -> None:
        folder.mkdir()
        (folder / "a.bin").write_bytes(b"old a")

    def run(folder: Path) -> None:
        (folder / "a.bin").write_bytes(b"new a, first half")
        _atomic.write_atomic(folder / "b.bin", b"new b")
        (folder / "a.bin").write_bytes(b"new a, complete")

    with pytest.raises(AssertionError, match="a partial file"):
        check_kills(monkeypatch, tmp_path, prepare, run)


# ---------------------------------------------------------------------- folders
def _scene(folder: Path, seed: int) -> None:
    rig = _rig()
    views = [_image(seed + j) for j in range(rig.n_cameras)]
    labels = np.zeros((H, W), np.uint8)
    labels[5:15, 8:20] = 1
    write_scene(folder, views, rig, mask=labels, gt_disparity=_disparity(seed),
                metadata={"seed": seed})


def test_write_scene(monkeypatch, tmp_path):
    n = check_kills(monkeypatch, tmp_path, lambda f: _scene(f, 1), lambda f: _scene(f, 2))
    assert n == 7  # rig.json, 3 views, mask.png, gt_disparity.pfm, scene.json


def test_write_board(monkeypatch, tmp_path):
    def prepare(folder: Path) -> None:
        write_board(Board.corner_layout(), folder, dpi=40)

    def run(folder: Path) -> None:
        write_board(Board.corner_layout(marker_size_m=0.06), folder, dpi=40, overwrite=True)

    assert check_kills(monkeypatch, tmp_path, prepare, run) == 2


def test_calibrate_light_rig_write(monkeypatch, tmp_path):
    """The rig file with the light: the old rig.json or the new; backups never partial."""

    class _Estimate:
        position_m = np.array([0.2, -0.4, 0.1])

    monkeypatch.setattr(captures_module, "estimate_light", lambda *a, **k: _Estimate())

    def prepare(folder: Path) -> None:
        folder.mkdir()
        _rig().to_json(folder / "rig.json")
        Board.corner_layout().to_json(folder / "board.json")

    def run(folder: Path) -> None:
        calibrate_light_files([folder], folder / "board.json", folder / "rig.json")

    # two renames: the backup (written atomically too, absent before the run) and rig.json
    assert check_kills(monkeypatch, tmp_path, prepare, run) == 2


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("scene") / "scene"
    _scene(folder, 3)
    return folder


def test_fuse_outputs(monkeypatch, tmp_path, scene_dir):
    def prepare(folder: Path) -> None:
        fuse_scene(scene_dir, folder, disparity=_disparity(1))

    def run(folder: Path) -> None:
        fuse_scene(scene_dir, folder, disparity=_disparity(2))

    assert check_kills(monkeypatch, tmp_path, prepare, run) >= 7


def test_srde_outputs_over_fuse_outputs(monkeypatch, tmp_path, scene_dir):
    """SRDE alone into a fusion folder: its stale files go, the others are old or new."""
    def prepare(folder: Path) -> None:
        fuse_scene(scene_dir, folder, disparity=_disparity(1))

    def run(folder: Path) -> None:
        srde_scene(scene_dir, folder)

    assert check_kills(monkeypatch, tmp_path, prepare, run, removed_by_design=True) >= 3


def test_render_dataset(monkeypatch, tmp_path):
    """Rendering into an empty folder: every file present is whole."""
    rig = CameraRig.grid(1, 2, baseline_m=0.085, fx=60.0, image_size=(W, H))

    def run(folder: Path) -> None:
        render_dataset(folder, n_scenes=1, seed=0, rig=rig, progress=False)

    assert check_kills(monkeypatch, tmp_path, lambda folder: folder.mkdir(), run) >= 6


def test_eval_outputs(monkeypatch, tmp_path, scene_dir):
    dataset = tmp_path / "dataset"
    shutil.copytree(scene_dir, dataset / "scene_0000")

    def flat(value: float):
        return lambda left, right: np.full(left.shape[:2], value, np.float32)

    def prepare(folder: Path) -> None:
        evaluate_dataset(dataset, flat(5.0), progress=False).write(folder, "old")

    def run(folder: Path) -> None:
        evaluate_dataset(dataset, flat(9.0), progress=False).write(folder, "new")

    assert check_kills(monkeypatch, tmp_path, prepare, run) == 2
