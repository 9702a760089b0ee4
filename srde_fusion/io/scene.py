"""Scene folders: what the commands and the evaluation read and write.

A scene folder holds ``rig.json``, one image per camera named after it (``cam0.png``),
optional ``mask.png``, ``gt_disparity.pfm`` (or ``.npy``) and ``scene.json`` metadata; a
dataset is a folder of scene folders (DESIGN §5). Two layouts of public stereo datasets
are read as scenes too: a Middlebury 2014/2021 folder is one scene, a KITTI folder
(``image_2/``, ``image_3/``) is a dataset whose frames are addressed as
``KITTI_DIR/<frame>``. Every problem with a file raises
:class:`~srde_fusion.errors.FileFormatError` naming the file and what was expected.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._checks import check_disparity, check_views
from ..errors import FileFormatError, MaskError, RigError
from ..geometry import CameraRig
from ._files import path_exists, read_bytes, write_bytes
from .calibration_files import read_kitti_calib, read_middlebury_calib
from .disparity import read_disparity, write_disparity
from .images import (
    IMAGE_EXTENSIONS,
    check_labels,
    labels_from_masks,
    masks_from_labels,
    read_image,
    read_mask,
    write_image,
    write_mask,
)

__all__ = [
    "RIG_FILE",
    "MASK_FILE",
    "GT_DISPARITY_STEM",
    "METADATA_FILE",
    "SceneData",
    "write_scene",
    "read_scene",
    "list_scenes",
    "is_kitti_folder",
    "kitti_frames",
]

RIG_FILE = "rig.json"
MASK_FILE = "mask.png"
GT_DISPARITY_STEM = "gt_disparity"
METADATA_FILE = "scene.json"
#: A Middlebury 2014/2021 scene folder is recognised by this file (with im0 and im1).
MIDDLEBURY_CALIB_FILE = "calib.txt"
#: A KITTI stereo folder is recognised by these two folders (left and right colour views).
KITTI_LEFT_DIR, KITTI_RIGHT_DIR = "image_2", "image_3"
#: The KITTI stereo benchmarks' frames with ground truth end in this (``_11`` is the next
#: frame in time, without it).
KITTI_FRAME_SUFFIX = "_10"
#: Where a KITTI frame's rig comes from, first found wins: a ``rig.json`` beside
#: ``image_2`` (the whole rig, light included), a per-frame calibration file in one of
#: these folders (``NNNNNN.txt``), or one calibration file for every frame.
KITTI_FRAME_CALIB_DIRS = ("calib_cam_to_cam", "calib")
KITTI_CALIB_FILE = "calib_cam_to_cam.txt"
#: Ground truth of a frame, first found wins (KITTI 2015, then 2012 names).
KITTI_GT_DIRS = ("disp_occ_0", "disp_occ")


# ---------------------------------------------------------------------- scene folders
@dataclass(frozen=True)
class SceneData:
    """One scene folder, loaded.

    Attributes
    ----------
    path : pathlib.Path
        The folder.
    name : str
        The folder's name.
    rig : CameraRig
    views : tuple of numpy.ndarray, each (H, W, 3) or (H, W) uint8
        One image per camera, in the rig's order.
    mask_labels : numpy.ndarray, (H, W) int32, or None
        Instance labels of the reference view (0 = background).
    gt_disparity : numpy.ndarray, (H, W) float32, or None
        Ground-truth disparity in pixels, NaN = invalid.
    metadata : dict
        Contents of ``scene.json`` (empty if absent).
    """

    path: Path
    name: str
    rig: CameraRig
    views: tuple[np.ndarray, ...]
    mask_labels: np.ndarray | None = None
    gt_disparity: np.ndarray | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def masks(self) -> list[np.ndarray]:
        """One ``(H, W)`` bool mask per object (empty list without a mask)."""
        return [] if self.mask_labels is None else masks_from_labels(self.mask_labels)


def _camera_file_stem(name: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9_.\-]+", name) or name.startswith("."):
        raise RigError(
            "camera name: expected letters, digits, '_', '-' or '.' to name an image file, "
            f"got {name!r}"
        )
    return name


def write_scene(
    folder: str | os.PathLike,
    views: Sequence[np.ndarray],
    rig: CameraRig,
    *,
    mask: np.ndarray | Sequence[np.ndarray] | None = None,
    gt_disparity: np.ndarray | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write a scene folder that :func:`read_scene` reads back.

    Parameters
    ----------
    folder : str or path-like
        Created if needed; existing files of the same names are overwritten.
    views : sequence of numpy.ndarray, (H, W, 3) RGB or (H, W), uint8 or float in [0, 1]
        One image per rig camera, written as ``<camera name>.png``.
    rig : CameraRig
        Written as ``rig.json``.
    mask : numpy.ndarray (H, W) int/bool labels, or sequence of (H, W) bool masks, optional
        Objects in the reference view, written as 8-bit labels to ``mask.png``.
    gt_disparity : numpy.ndarray, (H, W), float, optional
        Ground truth in pixels (NaN = invalid), written to ``gt_disparity.pfm``.
    metadata : dict, optional
        JSON-serialisable extras (e.g. virtual light, planes), written to ``scene.json``.

    Returns
    -------
    pathlib.Path
        The folder.

    Raises
    ------
    ImageError, MaskError, DisparityError
        Views, mask or ground truth that do not fit the rig.
    FileFormatError
        Metadata that is not a JSON-serialisable dict, or a write failure.
    """
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    checked = check_views(views, rig.n_cameras, rig.image_size)
    hw = (rig.height, rig.width)
    labels = None
    if mask is not None:
        labels = (
            check_labels(mask, "mask") if isinstance(mask, np.ndarray) else labels_from_masks(mask)
        )
        if labels.shape != hw:
            raise MaskError(f"mask: expected shape {hw} (the rig's image size), got {labels.shape}")
    gt = None if gt_disparity is None else check_disparity(gt_disparity, hw, "gt_disparity")
    meta_text = None
    if metadata is not None:
        if not isinstance(metadata, Mapping):
            raise FileFormatError(
                f"metadata: expected a JSON-serialisable dict, got {type(metadata).__name__}"
            )
        try:
            meta_text = json.dumps(dict(metadata), indent=2, allow_nan=False) + "\n"
        except (TypeError, ValueError) as exc:
            raise FileFormatError(
                f"metadata: expected a JSON-serialisable dict, got {exc}"
            ) from None
    stems = [_camera_file_stem(name) for name in rig.camera_names]

    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"{out}: could not create the scene folder: {exc}") from None
    write_bytes(out / RIG_FILE, rig.to_json().encode("utf-8"))
    for stem, image in zip(stems, checked, strict=True):
        write_image(out / f"{stem}.png", image)
    if labels is not None:
        write_mask(out / MASK_FILE, labels)
    if gt is not None:
        write_disparity(out / f"{GT_DISPARITY_STEM}.pfm", gt)
    if meta_text is not None:
        write_bytes(out / METADATA_FILE, meta_text.encode("utf-8"))
    return out


def _find_one(folder: Path, stem: str, extensions: Sequence[str], what: str) -> Path | None:
    found = [folder / f"{stem}{ext}" for ext in extensions if (folder / f"{stem}{ext}").is_file()]
    if len(found) > 1:
        raise FileFormatError(
            f"{folder}: expected one {what} file, got {len(found)}: {sorted(f.name for f in found)}"
        )
    return found[0] if found else None


def read_scene(folder: str | os.PathLike) -> SceneData:
    """Load a scene folder written by :func:`write_scene` (or by hand).

    Parameters
    ----------
    folder : str or path-like
        Holds ``rig.json``, one image per camera named after it (any of
        :data:`IMAGE_EXTENSIONS`), optional ``mask.png``, ``gt_disparity.pfm`` or
        ``gt_disparity.npy``, and ``scene.json``. A Middlebury 2014/2021 folder
        (``calib.txt``, ``im0.png``, ``im1.png``, optional ``disp0.pfm``) is read too:
        its rig has no light (give one, e.g. ``--light``), ``im1`` is shifted by the
        file's ``doffs`` so both views share one principal point as the rig does, and
        ``disp0.pfm`` becomes the ground truth in the rig's convention (``d + doffs``).
        A frame of a KITTI folder is read as ``KITTI_DIR/<frame>`` (e.g.
        ``training/000000_10``): views ``image_2/<frame>.png`` and ``image_3/<frame>.png``,
        the rig from ``KITTI_DIR/rig.json`` (with its light), else from a calibration file
        (``calib_cam_to_cam/NNNNNN.txt``, ``calib/NNNNNN.txt`` or ``calib_cam_to_cam.txt``,
        no light: give one, e.g. ``--light``), ground truth from ``disp_occ_0/`` or
        ``disp_occ/`` (KITTI 16-bit PNG).

    Returns
    -------
    SceneData

    Raises
    ------
    FileFormatError
        Missing folder, ``rig.json`` or view; two files for one camera; image files
        named like cameras the rig does not have; images, mask or ground truth whose
        size differs from the rig's; malformed ``scene.json``.
    RigError
        An invalid ``rig.json`` (the message names the file).
    """
    path = Path(folder)
    if is_kitti_folder(path.parent) and not path.is_dir():
        return _read_kitti_frame(path.parent, path.name)
    if is_kitti_folder(path):
        frames = kitti_frames(path)
        raise FileFormatError(f"{path}: expected one scene, got a KITTI folder of "
                              f"{len(frames)} frames: read one as {path / frames[0]}, or "
                              f"list them with list_scenes")
    if not path_exists(path, "dir"):
        raise FileFormatError(f"{path}: expected a scene folder, got no such directory")
    rig_path = path / RIG_FILE
    if not rig_path.is_file() and (path / MIDDLEBURY_CALIB_FILE).is_file():
        return _read_middlebury_scene(path)
    if not rig_path.is_file():
        raise FileFormatError(f"{path}: expected a scene folder with {RIG_FILE} (or a "
                              f"Middlebury folder with {MIDDLEBURY_CALIB_FILE}, im0.png and "
                              f"im1.png), got neither")
    try:
        rig = CameraRig.from_json(rig_path)
    except RigError as exc:
        message = str(exc)
        raise RigError(
            message if message.startswith(str(rig_path)) else f"{rig_path}: {message}"
        ) from None
    hw = (rig.height, rig.width)

    names = rig.camera_names
    views = []
    missing = []
    for name in names:
        found = _find_one(path, name, IMAGE_EXTENSIONS, f"image for camera {name!r}")
        if found is None:
            missing.append(name)
            continue
        image = read_image(found)
        if image.shape[:2] != hw:
            raise FileFormatError(
                f"{found}: expected the rig's image size {rig.width}x{rig.height}, "
                f"got {image.shape[1]}x{image.shape[0]}"
            )
        views.append(image)
    if missing:
        raise FileFormatError(
            f"{path}: expected one image per camera ({', '.join(n + '.png' for n in names)}), "
            f"missing {missing}"
        )
    # An image named like a camera the rig does not have (cam9.png next to cam0..cam8)
    # usually means the rig.json and the images do not belong together.
    prefixes = {m.group(1) for m in (re.fullmatch(r"(.*?)\d+", n) for n in names) if m}
    if prefixes:
        pattern = re.compile(rf"({'|'.join(re.escape(x) for x in sorted(prefixes))})\d+")
        extra = sorted(
            f.name
            for f in path.iterdir()
            if f.is_file()
            and f.suffix.lower() in IMAGE_EXTENSIONS
            and pattern.fullmatch(f.stem)
            and f.stem not in names
        )
        if extra:
            raise FileFormatError(
                f"{path}: expected images only for the rig's cameras {names}, got extra {extra}"
            )

    labels = None
    if (path / MASK_FILE).is_file():
        labels = read_mask(path / MASK_FILE)
        if labels.shape != hw:
            raise FileFormatError(
                f"{path / MASK_FILE}: expected the rig's image size {rig.width}x{rig.height}, "
                f"got {labels.shape[1]}x{labels.shape[0]}"
            )
    gt = None
    gt_path = _find_one(path, GT_DISPARITY_STEM, (".pfm", ".npy"), "ground-truth disparity")
    if gt_path is not None:
        gt = read_disparity(gt_path)
        if gt.shape != hw:
            raise FileFormatError(
                f"{gt_path}: expected the rig's image size {rig.width}x{rig.height}, "
                f"got {gt.shape[1]}x{gt.shape[0]}"
            )
    metadata: dict[str, Any] = {}
    meta_path = path / METADATA_FILE
    if meta_path.is_file():
        try:
            metadata = json.loads(read_bytes(meta_path, "scene metadata").decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FileFormatError(
                f"{meta_path}: expected valid JSON, got a parse error: {exc}"
            ) from None
        if not isinstance(metadata, dict):
            raise FileFormatError(
                f"{meta_path}: expected a JSON object, got {type(metadata).__name__}"
            )
    return SceneData(
        path=path,
        name=path.name,
        rig=rig,
        views=tuple(views),
        mask_labels=labels,
        gt_disparity=gt,
        metadata=metadata,
    )


def list_scenes(dataset_dir: str | os.PathLike) -> list[Path]:
    """Scenes of a dataset: its sub-folders that hold a ``rig.json``, sorted by name.

    Sub-folders in the Middlebury layout count too. A KITTI folder's scenes are its
    frames, ``dataset_dir/<frame>`` (see :func:`kitti_frames`), which :func:`read_scene`
    reads.

    Raises
    ------
    FileFormatError
        The folder does not exist or holds no scene folder.
    """
    root = Path(dataset_dir)
    if not path_exists(root, "dir"):
        raise FileFormatError(f"{root}: expected a dataset folder, got no such directory")
    if is_kitti_folder(root):
        return [root / frame for frame in kitti_frames(root)]
    scenes = sorted(p for p in root.iterdir() if p.is_dir() and (
        (p / RIG_FILE).is_file() or (p / MIDDLEBURY_CALIB_FILE).is_file()))
    if not scenes:
        hint = " (it is itself a scene folder)" if (root / RIG_FILE).is_file() else ""
        raise FileFormatError(f"{root}: expected sub-folders holding {RIG_FILE}, got none{hint}")
    return scenes


def _read_middlebury_scene(path: Path) -> SceneData:
    """Read a Middlebury-style folder (calib.txt, im0, im1, optional disp0.pfm) as a scene."""
    views = []
    for stem in ("im0", "im1"):
        found = _find_one(path, stem, IMAGE_EXTENSIONS, f"Middlebury view {stem}")
        if found is None:
            raise FileFormatError(f"{path}: expected {stem}.png beside "
                                  f"{MIDDLEBURY_CALIB_FILE}, got none")
        views.append(read_image(found))
    h, w = views[0].shape[:2]
    calib = read_middlebury_calib(path / MIDDLEBURY_CALIB_FILE, image_size=(w, h))
    rig = calib.rig
    for stem, view in zip(("im0", "im1"), views, strict=True):
        if view.shape[:2] != (rig.height, rig.width):
            raise FileFormatError(f"{path}: {stem}: expected {_size_text(rig)}, got "
                                  f"{view.shape[1]}x{view.shape[0]}")
    # Middlebury's right camera has cx1 = cx0 + doffs; shifting im1 by doffs px to the
    # right gives it the reference's principal point, which the rig assumes.
    shift = np.float32([[1.0, 0.0, calib.doffs_px], [0.0, 1.0, 0.0]])
    views[1] = cv2.warpAffine(views[1], shift, (rig.width, rig.height),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    gt = None
    gt_path = _find_one(path, "disp0", (".pfm",), "Middlebury ground truth")
    if gt_path is not None:
        gt = calib.to_rig_disparity(read_disparity(gt_path))
        if gt.shape != (rig.height, rig.width):
            raise FileFormatError(f"{gt_path}: expected {_size_text(rig)}, got "
                                  f"{gt.shape[1]}x{gt.shape[0]}")
    return SceneData(path=path, name=path.name, rig=rig, views=tuple(views), gt_disparity=gt,
                     metadata={"format": "middlebury", "doffs_px": calib.doffs_px,
                               "im1_shifted_px": calib.doffs_px})


def _size_text(rig: CameraRig) -> str:
    """Say the calibration's image size, for messages."""
    return f"the calibration's size {rig.width}x{rig.height}"


# ---------------------------------------------------------------------- KITTI
def is_kitti_folder(path: str | os.PathLike) -> bool:
    """Say whether ``path`` is a KITTI stereo folder (it holds ``image_2/`` and ``image_3/``)."""
    root = Path(path)
    return path_exists(root / KITTI_LEFT_DIR, "dir") and path_exists(root / KITTI_RIGHT_DIR, "dir")


def _image_files(folder: Path) -> dict[str, Path]:
    return {f.stem: f for f in sorted(folder.iterdir())
            if f.is_file() and f.suffix.lower() in IMAGE_EXTENSIONS}


def kitti_frames(kitti_dir: str | os.PathLike) -> list[str]:
    """Names of the frames of a KITTI folder, sorted: ``image_2`` images with an ``image_3`` twin.

    When some names end in ``_10`` (the stereo benchmarks' frames with ground truth),
    only those are listed; their ``_11`` neighbours in time are not stereo frames to score.

    Raises
    ------
    FileFormatError
        Not a KITTI folder, or no image in ``image_2`` has a twin in ``image_3``.
    """
    root = Path(kitti_dir)
    if not is_kitti_folder(root):
        raise FileFormatError(f"{root}: expected a KITTI folder with {KITTI_LEFT_DIR}/ and "
                              f"{KITTI_RIGHT_DIR}/, got none")
    left, right = _image_files(root / KITTI_LEFT_DIR), _image_files(root / KITTI_RIGHT_DIR)
    frames = sorted(set(left) & set(right))
    benchmark = [f for f in frames if f.endswith(KITTI_FRAME_SUFFIX)]
    frames = benchmark or frames
    if not frames:
        raise FileFormatError(f"{root}: expected images of the same names in "
                              f"{KITTI_LEFT_DIR}/ and {KITTI_RIGHT_DIR}/, got "
                              f"{len(left)} and {len(right)} images with none in common")
    return frames


def _kitti_view(root: Path, folder: str, frame: str) -> Path:
    found = _find_one(root / folder, frame, IMAGE_EXTENSIONS, f"KITTI view {folder}/{frame}")
    if found is None:
        raise FileFormatError(f"{root}: expected {folder}/{frame}.png, got no such image "
                              f"(frames are named after the images in {KITTI_LEFT_DIR}/)")
    return found


def _kitti_rig(root: Path, frame: str, image_size: tuple[int, int]) -> tuple[CameraRig, Path]:
    """Return the frame's rig and the file it came from (see :data:`KITTI_FRAME_CALIB_DIRS`)."""
    rig_path = root / RIG_FILE
    if rig_path.is_file():
        try:
            rig = CameraRig.from_json(rig_path)
        except RigError as exc:
            message = str(exc)
            raise RigError(message if message.startswith(str(rig_path))
                           else f"{rig_path}: {message}") from None
        if rig.n_cameras != 2 or rig.stereo_pair != (0, 1):
            raise FileFormatError(f"{rig_path}: expected a two-camera rig with stereo_pair "
                                  f"[0, 1] ({KITTI_LEFT_DIR}, {KITTI_RIGHT_DIR}), got "
                                  f"{rig.n_cameras} cameras, stereo_pair "
                                  f"{list(rig.stereo_pair)}")
        return rig, rig_path
    # Per-frame files are named after the frame's number: 000000_10 -> 000000.txt.
    number = frame[: -len(KITTI_FRAME_SUFFIX)] if frame.endswith(KITTI_FRAME_SUFFIX) else frame
    candidates = [root / d / f"{number}.txt" for d in KITTI_FRAME_CALIB_DIRS]
    candidates.append(root / KITTI_CALIB_FILE)
    for path in candidates:
        if path.is_file():
            return read_kitti_calib(path, image_size=image_size), path
    raise FileFormatError(
        f"{root}: expected the rig of frame {frame} in {RIG_FILE} or a KITTI calibration "
        f"file, got none of {', '.join(str(p.relative_to(root)) for p in [rig_path, *candidates])}")


def _read_kitti_frame(root: Path, frame: str) -> SceneData:
    """Read one frame of a KITTI folder as a two-camera scene (see :func:`read_scene`)."""
    files = [_kitti_view(root, folder, frame) for folder in (KITTI_LEFT_DIR, KITTI_RIGHT_DIR)]
    views = [read_image(f) for f in files]
    h, w = views[0].shape[:2]
    if views[1].shape[:2] != (h, w):
        raise FileFormatError(f"{files[1]}: expected the size of {files[0].name}, {w}x{h}, "
                              f"got {views[1].shape[1]}x{views[1].shape[0]}")
    rig, source = _kitti_rig(root, frame, (w, h))
    if (rig.width, rig.height) != (w, h):
        raise FileFormatError(f"{files[0]}: expected the image size of {source}, "
                              f"{rig.width}x{rig.height}, got {w}x{h}")
    gt = None
    for folder in KITTI_GT_DIRS:
        if (root / folder).is_dir():
            found = _find_one(root / folder, frame, (".png",), "KITTI ground truth")
            if found is not None:
                gt = read_disparity(found)
                if gt.shape != (h, w):
                    raise FileFormatError(f"{found}: expected the views' size {w}x{h}, got "
                                          f"{gt.shape[1]}x{gt.shape[0]}")
                break
    return SceneData(path=root / frame, name=frame, rig=rig, views=tuple(views),
                     gt_disparity=gt, metadata={"format": "kitti", "frame": frame,
                                                "rig_from": source.name})
