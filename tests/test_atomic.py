"""Writes are atomic: a failure between writing and renaming leaves the old file."""

from __future__ import annotations

import numpy as np
import pytest

import srde_fusion._atomic as atomic
from srde_fusion._atomic import backup_path, write_atomic
from srde_fusion.errors import FileFormatError
from srde_fusion.geometry import CameraRig
from srde_fusion.io import write_disparity, write_image


def _fail_rename(monkeypatch):
    def refuse(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic, "_replace", refuse)


@pytest.mark.parametrize("write", [
    lambda p: write_atomic(p, "new"),
    lambda p: write_disparity(p.with_suffix(".pfm"), np.ones((4, 5), np.float32)),
    lambda p: write_disparity(p.with_suffix(".png"), np.ones((4, 5), np.float32)),
    lambda p: write_disparity(p.with_suffix(".npy"), np.ones((4, 5), np.float32)),
    lambda p: write_image(p.with_suffix(".png"), np.zeros((4, 5, 3), np.uint8)),
    lambda p: CameraRig.stereo(0.1, fx=100.0, image_size=(5, 4)).to_json(p.with_suffix(".json")),
], ids=["text", "pfm", "kitti-png", "npy", "image", "rig-json"])
def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch, write):
    for suffix in (".txt", ".pfm", ".png", ".npy", ".json"):
        (tmp_path / f"out{suffix}").write_bytes(b"old")
    _fail_rename(monkeypatch)
    with pytest.raises(FileFormatError, match="could not write the file: .*No space left"):
        write(tmp_path / "out.txt")
    assert all((tmp_path / f"out{s}").read_bytes() == b"old"
               for s in (".txt", ".pfm", ".png", ".npy", ".json"))
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "out.json", "out.npy", "out.pfm", "out.png", "out.txt"]


def test_write_atomic_replaces_and_creates_folders(tmp_path):
    path = write_atomic(tmp_path / "a" / "b.txt", "one")
    write_atomic(path, b"two")
    assert path.read_bytes() == b"two" and list(path.parent.iterdir()) == [path]


def test_backups_are_numbered_never_overwritten(tmp_path):
    target = tmp_path / "rig.json"
    assert backup_path(target) == tmp_path / "rig.json.bak"
    (tmp_path / "rig.json.bak").write_text("1")
    (tmp_path / "rig.json.bak1").write_text("2")
    assert backup_path(target) == tmp_path / "rig.json.bak2"
