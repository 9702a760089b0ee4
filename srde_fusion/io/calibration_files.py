"""Two-camera rigs from other tools' calibration files.

Middlebury ``calib.txt`` (cam0/cam1 matrices, baseline in mm, doffs), KITTI calibration
files (the rectified projections of cameras 2 and 3) and OpenCV stereo calibration YAML
(K1, D1, K2, D2, R, T; rectified input assumed, said so on load).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._checks import MAX_IMAGE_PIXELS, check_disparity
from ..errors import FileFormatError, RigError
from ..geometry import Camera, CameraRig, Intrinsics
from ._files import existing_file, read_bytes

__all__ = [
    "MiddleburyCalib",
    "read_middlebury_calib",
    "read_kitti_calib",
    "read_opencv_stereo_yaml",
]

# A Middlebury calib.txt's doffs must match cx1 - cx0 to this tolerance, pixels.
_DOFFS_TOL_PX = 0.05


# Intrinsics of the two cameras of a "rectified" file must agree to this, pixels.
_RECTIFIED_TOL_PX = 0.5


# A baseline longer than this with units_per_m=1 is most likely in mm: warn, do not guess.
_PLAUSIBLE_BASELINE_M = 5.0


# ---------------------------------------------------------------------- Middlebury
@dataclass(frozen=True)
class MiddleburyCalib:
    """A two-camera rig read from a Middlebury ``calib.txt``, with the file's extras.

    Middlebury rectifies with *different* principal points: ``cx1 = cx0 + doffs``, and
    its disparities satisfy ``z = f * B / (d + doffs)``. Our rigs share one principal
    point, so our disparity is ``d_rig = d_file + doffs_px`` (:meth:`to_rig_disparity`),
    and the right image (``im1``) would have to be shifted ``doffs_px`` to the right
    to follow the rig exactly.

    Attributes
    ----------
    rig : CameraRig
        Cameras ``cam0`` (reference, at the origin) and ``cam1`` at ``+x``; intrinsics
        of ``cam0``; baseline in metres.
    doffs_px : float
        ``cx1 - cx0`` in pixels.
    ndisp : int or None
        The file's conservative disparity bound, pixels.
    vmin, vmax : float or None
        The file's tight disparity bounds, pixels.
    extras : dict
        Other ``key=value`` lines, as text.
    """

    rig: CameraRig
    doffs_px: float
    ndisp: int | None = None
    vmin: float | None = None
    vmax: float | None = None
    extras: Mapping[str, str] = field(default_factory=dict)

    def to_rig_disparity(self, disparity_px: np.ndarray) -> np.ndarray:
        """Convert a disparity map in the file's convention to the rig's, ``(H, W)`` float32."""
        return check_disparity(disparity_px, name="disparity_px") + np.float32(self.doffs_px)
_MATRIX_RE = re.compile(r"^\[(.*)\]$")


def _parse_calib_matrix(text: str, key: str, path: Path) -> np.ndarray:
    match = _MATRIX_RE.match(text.strip())
    rows = match.group(1).split(";") if match else []
    try:
        matrix = np.array([[float(x) for x in row.split()] for row in rows], dtype=np.float64)
    except ValueError:
        matrix = np.empty(0)
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise FileFormatError(
            f"{path}: {key}: expected a 3x3 matrix '[f 0 cx; 0 f cy; 0 0 1]', got {text!r}"
        )
    return matrix


def read_middlebury_calib(
    path: str | os.PathLike, *, image_size: tuple[int, int] | None = None
) -> MiddleburyCalib:
    """Read a Middlebury stereo ``calib.txt`` (2014/2021 layout).

    Parameters
    ----------
    path : str or path-like
        Lines ``key=value``: ``cam0``, ``cam1`` (3x3 matrices), ``baseline`` (mm),
        ``doffs`` (px), ``width``, ``height``, ``ndisp``, ``vmin``, ``vmax``, ...
    image_size : (int, int), optional
        ``(width, height)`` for files without ``width``/``height``; if the file has them,
        they must agree.

    Returns
    -------
    MiddleburyCalib
        The rig plus ``doffs_px``: ground-truth disparities from the dataset must be
        converted with :meth:`MiddleburyCalib.to_rig_disparity` before comparing them
        with disparities in the rig's convention.

    Raises
    ------
    FileFormatError
        Missing file, missing keys, malformed numbers or matrices, cameras that are not
        rectified (different focal length or ``cy``), or ``doffs`` inconsistent with the
        principal points.
    """
    p = existing_file(path, "Middlebury calib.txt")
    text = read_bytes(p, "Middlebury calib.txt").decode("utf-8", errors="replace")
    entries: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise FileFormatError(f"{p}: line {number}: expected 'key=value', got {line!r}")
        entries[key.strip()] = value.strip()
    missing = [k for k in ("cam0", "cam1", "baseline") if k not in entries]
    if missing:
        raise FileFormatError(f"{p}: expected keys cam0, cam1 and baseline, missing {missing}")

    def number(key: str) -> float | None:
        if key not in entries:
            return None
        try:
            value = float(entries[key])
        except ValueError:
            raise FileFormatError(f"{p}: {key}: expected a number, got {entries[key]!r}") from None
        if not math.isfinite(value):
            raise FileFormatError(f"{p}: {key}: expected a finite number, got {entries[key]!r}")
        return value

    k0 = _parse_calib_matrix(entries["cam0"], "cam0", p)
    k1 = _parse_calib_matrix(entries["cam1"], "cam1", p)
    for (r, c), label in (((0, 0), "fx"), ((1, 1), "fy"), ((1, 2), "cy")):
        if abs(k0[r, c] - k1[r, c]) > _RECTIFIED_TOL_PX:
            raise FileFormatError(
                f"{p}: expected rectified cameras with equal {label}, got cam0 {k0[r, c]:g} "
                f"and cam1 {k1[r, c]:g}"
            )
    doffs = float(k1[0, 2] - k0[0, 2])
    doffs_file = number("doffs")
    if doffs_file is not None and abs(doffs_file - doffs) > _DOFFS_TOL_PX:
        raise FileFormatError(
            f"{p}: expected doffs = cx1 - cx0 = {doffs:g} px, got doffs={doffs_file:g}"
        )
    baseline_mm = number("baseline")
    if baseline_mm is None or baseline_mm <= 0:
        raise FileFormatError(
            f"{p}: baseline: expected a positive baseline in mm, got {entries['baseline']!r}"
        )
    width, height = number("width"), number("height")
    if width is not None and height is not None:
        if width != int(width) or height != int(height) or width <= 0 or height <= 0:
            raise FileFormatError(
                f"{p}: expected positive integer width/height, got {width:g}x{height:g}"
            )
        size = (int(width), int(height))
        if image_size is not None and tuple(image_size) != size:
            raise FileFormatError(
                f"{p}: expected image_size {tuple(image_size)} to match the file's "
                f"width/height, got {size}"
            )
    elif image_size is not None:
        size = tuple(image_size)
    else:
        raise FileFormatError(
            f"{p}: expected width and height in the file or image_size=(W, H), got neither"
        )
    ndisp = number("ndisp")
    try:
        intrinsics = Intrinsics(k0[0, 0], k0[1, 1], k0[0, 2], k0[1, 2])
        rig = CameraRig(
            size,
            intrinsics,
            (Camera("cam0", (0.0, 0.0, 0.0)), Camera("cam1", (baseline_mm / 1000.0, 0.0, 0.0))),
        )
    except RigError as exc:
        raise FileFormatError(f"{p}: {exc}") from None
    known = {"cam0", "cam1", "baseline", "doffs", "width", "height", "ndisp", "vmin", "vmax"}
    return MiddleburyCalib(
        rig=rig,
        doffs_px=doffs,
        ndisp=None if ndisp is None else int(ndisp),
        vmin=number("vmin"),
        vmax=number("vmax"),
        extras={k: v for k, v in entries.items() if k not in known},
    )


# ---------------------------------------------------------------------- KITTI
#: Keys of the rectified projections of the left and right colour cameras: the raw and
#: scene-flow releases' ``calib_cam_to_cam`` files use the first, the object and
#: odometry releases' ``calib/`` files the second.
KITTI_PROJECTION_KEYS = (("P_rect_02", "P_rect_03"), ("P2", "P3"))


def read_kitti_calib(path: str | os.PathLike, *, image_size: tuple[int, int]) -> CameraRig:
    r"""Read the rig of KITTI's colour cameras 2 and 3 from a KITTI calibration file.

    Parameters
    ----------
    path : str or path-like
        Lines ``KEY: v1 v2 ...``. The rectified 3x4 projections of camera 2 (left,
        ``image_2``) and camera 3 (right, ``image_3``) are read from ``P_rect_02`` and
        ``P_rect_03`` (``calib_cam_to_cam.txt``) or from ``P2`` and ``P3`` (the object
        and odometry releases' ``calib/NNNNNN.txt``); other lines are ignored.
    image_size : (int, int)
        ``(width, height)`` of the rectified images (KITTI's sizes differ between
        drives, and the projections do not say).

    Returns
    -------
    CameraRig
        ``image_2`` (reference, at the origin) and ``image_3`` at ``(B, 0, 0)`` with
        ``B = (P2[0, 3] - P3[0, 3]) / fx`` metres; intrinsics of camera 2. The
        projections place both cameras relative to KITTI's camera 0, with vertical and
        depth offsets of a few millimetres left by its rectification; they are dropped,
        as the rectified images have no vertical disparity. No light.

    Raises
    ------
    FileFormatError
        Missing file, no pair of projections, malformed numbers, projections that do not
        share one camera matrix, or a camera 3 that is not to the right of camera 2.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> text = ("P_rect_02: 721.5 0 609.6 44.86 0 721.5 172.9 0.2164 0 0 1 0.002746\n"
    ...         "P_rect_03: 721.5 0 609.6 -339.5 0 721.5 172.9 2.2 0 0 1 0.00273\n")
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "calib_cam_to_cam.txt"
    >>> _ = path.write_text(text)
    >>> rig = read_kitti_calib(path, image_size=(1242, 375))
    >>> round(rig.baseline_m, 4), rig.camera_names
    (0.5327, ['image_2', 'image_3'])
    """
    p = existing_file(path, "KITTI calibration")
    text = read_bytes(p, "KITTI calibration").decode("utf-8", errors="replace")
    entries: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep:
            entries[key.strip()] = value.strip()
    keys = next((pair for pair in KITTI_PROJECTION_KEYS if all(k in entries for k in pair)),
                None)
    if keys is None:
        wanted = " or ".join(" and ".join(pair) for pair in KITTI_PROJECTION_KEYS)
        raise FileFormatError(f"{p}: expected the rectified projections {wanted}, got keys "
                              f"{sorted(entries)[:12]}")
    left, right = (_kitti_projection(entries[k], k, p) for k in keys)
    if not np.allclose(left[:, :3], right[:, :3], atol=_RECTIFIED_TOL_PX):
        raise FileFormatError(
            f"{p}: expected {keys[0]} and {keys[1]} to share one camera matrix (rectified "
            f"cameras), got {left[:, :3].round(2).tolist()} and {right[:, :3].round(2).tolist()}")
    fx, fy, cx, cy = left[0, 0], left[1, 1], left[0, 2], left[1, 2]
    # P = K [I | t]: camera j sits at x = -t_x = -P[0, 3] / fx in KITTI's camera-0 frame.
    baseline_m = float(left[0, 3] - right[0, 3]) / fx
    if not baseline_m > 0:
        raise FileFormatError(
            f"{p}: expected camera 3 to the right of camera 2 ({keys[1]}[0, 3] < "
            f"{keys[0]}[0, 3]), got {right[0, 3]:g} and {left[0, 3]:g}")
    try:
        return CameraRig(tuple(image_size), Intrinsics(fx, fy, cx, cy),
                         (Camera("image_2", (0.0, 0.0, 0.0)),
                          Camera("image_3", (baseline_m, 0.0, 0.0))))
    except RigError as exc:
        raise FileFormatError(f"{p}: {exc}") from None


def _kitti_projection(text: str, key: str, path: Path) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        values = np.empty(0)
    if values.size != 12 or not np.all(np.isfinite(values)):
        raise FileFormatError(f"{path}: {key}: expected 12 numbers (a 3x4 projection "
                              f"matrix, row by row), got {text[:80]!r}")
    projection = values.reshape(3, 4)
    if not (projection[0, 0] > 0 and projection[1, 1] > 0):
        raise FileFormatError(f"{path}: {key}: expected positive focal lengths, got fx "
                              f"{projection[0, 0]:g}, fy {projection[1, 1]:g}")
    return projection


# ---------------------------------------------------------------------- OpenCV YAML
def _cv_error_text(exc: BaseException) -> str:
    # OpenCV's own error may be wrapped (SystemError from a constructor): report the cause.
    inner = exc.__cause__ or exc.__context__ or exc
    lines = str(inner).strip().splitlines()
    return lines[-1] if lines else type(inner).__name__


def _fs_matrix(
    fs: Any,
    names: Sequence[str],
    path: Path,
    shape: tuple[int, ...] | None,
    *,
    required: bool = True,
) -> np.ndarray | None:
    for name in names:
        node = fs.getNode(name)
        if node.empty():
            continue
        mat = np.asarray(_node_values(node, name, path), dtype=np.float64)
        if shape is not None and mat.size != int(np.prod(shape)):
            raise FileFormatError(f"{path}: {name}: expected {shape} values, got shape {mat.shape}")
        if not np.all(np.isfinite(mat)):
            raise FileFormatError(f"{path}: {name}: expected finite values, got NaN or inf")
        return mat.reshape(shape) if shape is not None else mat
    if required:
        raise FileFormatError(f"{path}: expected a matrix named {' or '.join(names)}, got none")
    return None


def _node_values(node: Any, name: str, path: Path) -> np.ndarray:
    """Read a FileStorage matrix node after checking its structure.

    ``FileNode.mat()`` on an ``opencv-matrix`` map that lacks ``rows``, ``cols`` or
    ``data`` can corrupt OpenCV's heap and abort the process, so the map is checked
    first; a plain sequence of numbers is read element by element.
    """
    if node.isSeq():
        items = [node.at(i) for i in range(node.size())]
        if not all(item.isReal() or item.isInt() for item in items):
            raise FileFormatError(f"{path}: {name}: expected a sequence of numbers, got "
                                  f"other nodes in it")
        return np.array([item.real() for item in items])
    if not node.isMap():
        raise FileFormatError(f"{path}: {name}: expected an OpenCV matrix, got a non-matrix "
                              f"node")
    parts = {key: node.getNode(key) for key in ("rows", "cols", "dt", "data")}
    missing = [key for key, part in parts.items() if part.empty()]
    if missing:
        raise FileFormatError(f"{path}: {name}: expected an opencv-matrix with rows, cols, dt "
                              f"and data, got none for {', '.join(missing)}")
    rows, cols, data = parts["rows"], parts["cols"], parts["data"]
    if not (rows.isInt() and cols.isInt() and data.isSeq()):
        raise FileFormatError(f"{path}: {name}: expected integer rows and cols and a data "
                              f"sequence, got other node types")
    n_rows, n_cols = int(rows.real()), int(cols.real())
    if n_rows < 1 or n_cols < 1 or data.size() != n_rows * n_cols:
        raise FileFormatError(f"{path}: {name}: expected {n_rows} x {n_cols} data values, got "
                              f"{data.size()}")
    mat = node.mat()
    if mat is None:
        raise FileFormatError(f"{path}: {name}: expected an OpenCV matrix, got a non-matrix node")
    return mat


def _fs_image_size(fs: Any, path: Path) -> tuple[int, int] | None:
    for name in ("image_size", "imageSize"):
        node = fs.getNode(name)
        if node.empty():
            continue
        values = node.mat() if node.isMap() else [node.at(i).real() for i in range(node.size())]
        values = np.asarray(values, dtype=np.float64).ravel()
        if values.size == 2:
            return _image_size(values, name, path)
        raise FileFormatError(f"{path}: {name}: expected [width, height], got {values.tolist()}")
    w, h = fs.getNode("image_width"), fs.getNode("image_height")
    if not w.empty() and not h.empty():
        return _image_size(np.array([w.real(), h.real()]), "image_width/image_height", path)
    return None


def _image_size(values: np.ndarray, name: str, path: Path) -> tuple[int, int]:
    """Check a ``[width, height]`` read from a file: two positive whole numbers."""
    if not (np.all(np.isfinite(values)) and np.all(values == np.round(values))
            and np.all(values > 0) and np.all(values <= MAX_IMAGE_PIXELS)):
        raise FileFormatError(f"{path}: {name}: expected [width, height] as two positive "
                              f"integers, got {values.tolist()}")
    return int(values[0]), int(values[1])


def read_opencv_stereo_yaml(
    path: str | os.PathLike, *, units_per_m: float = 1.0, image_size: tuple[int, int] | None = None
) -> CameraRig:
    """Read a two-camera rig from an OpenCV stereo calibration file (YAML/XML/JSON).

    The file holds ``K1, D1, K2, D2, R, T`` as ``cv2.stereoCalibrate`` returns them
    (``M1``/``M2`` are accepted for ``K1``/``K2``), and may hold ``P1, P2`` from
    ``cv2.stereoRectify``. The library works on rectified images. With ``P1``/``P2`` the
    rectified camera matrix and baseline come from them (``P2[0, 3] = -fx B``); without,
    the images are assumed to be rectified already with ``K1`` as the shared camera
    matrix (distortion and rotation are *not* applied). A ``UserWarning`` says which on
    every load.

    Parameters
    ----------
    path : str or path-like
    units_per_m : float
        Length units of ``T`` per metre. ``T`` comes in the units of the calibration
        pattern's square size: 1.0 (default) for metres, 1000.0 for millimetres.
        The unit is never guessed; a baseline over 5 m with the default gets a warning.
    image_size : (int, int), optional
        ``(width, height)``; required unless the file has ``image_size``/``imageSize``
        or ``image_width``/``image_height``.

    Returns
    -------
    CameraRig
        ``left`` (reference, at the origin) and ``right`` at ``(|T| / units_per_m, 0, 0)``.

    Raises
    ------
    FileFormatError
        Missing or unparsable file, missing or malformed matrices, no image size, P1 and
        P2 with different camera matrices, or a second camera that lies to the left of
        the first (swap the cameras).
    """
    p = existing_file(path, "OpenCV stereo calibration")
    if (
        isinstance(units_per_m, bool)
        or not isinstance(units_per_m, (int, float))
        or not (math.isfinite(units_per_m) and units_per_m > 0)
    ):
        raise RigError(
            f"units_per_m: expected a positive number (1000 for mm), got {units_per_m!r}"
        )
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    # A parse error surfaces as cv2.error or, from the constructor, as SystemError.
    except (cv2.error, SystemError) as exc:
        raise FileFormatError(
            f"{p}: expected an OpenCV FileStorage YAML/XML file, got a parse error: "
            f"{_cv_error_text(exc)}"
        ) from None
    if not opened:
        raise FileFormatError(
            f"{p}: expected an OpenCV FileStorage YAML/XML file, could not open it"
        )
    try:
        k1 = _fs_matrix(fs, ("K1", "M1"), p, (3, 3))
        k2 = _fs_matrix(fs, ("K2", "M2"), p, (3, 3))
        d1 = _fs_matrix(fs, ("D1",), p, None, required=False)
        d2 = _fs_matrix(fs, ("D2",), p, None, required=False)
        rot = _fs_matrix(fs, ("R",), p, (3, 3))
        trans = _fs_matrix(fs, ("T",), p, (3,))
        proj1 = _fs_matrix(fs, ("P1",), p, (3, 4), required=False)
        proj2 = _fs_matrix(fs, ("P2",), p, (3, 4), required=False)
        size = _fs_image_size(fs, p)
    except cv2.error as exc:
        raise FileFormatError(
            f"{p}: expected OpenCV matrices K1, D1, K2, D2, R, T, got an error: "
            f"{_cv_error_text(exc)}"
        ) from None
    finally:
        fs.release()
    if image_size is not None:
        size = tuple(image_size)
    if size is None:
        raise FileFormatError(
            f"{p}: expected an image size in the file or image_size=(W, H), got neither"
        )
    try:
        if proj1 is not None and proj2 is not None:
            intrinsics, baseline_m = _rectified_projections(proj1, proj2, p, units_per_m)
        else:
            intrinsics, baseline_m = _from_calibration(k1, k2, d1, d2, rot, trans, p,
                                                       units_per_m)
    except RigError as exc:
        raise FileFormatError(f"{p}: {exc}") from None
    if baseline_m > _PLAUSIBLE_BASELINE_M:
        warnings.warn(
            f"{p}: baseline of {baseline_m:g} m with units_per_m={units_per_m:g}; if T is in "
            "millimetres, pass units_per_m=1000",
            UserWarning,
            stacklevel=2,
        )
    try:
        return CameraRig(
            size,
            intrinsics,
            (Camera("left", (0.0, 0.0, 0.0)), Camera("right", (baseline_m, 0.0, 0.0))),
        )
    except RigError as exc:
        raise FileFormatError(f"{p}: {exc}") from None


def _rectified_projections(proj1: np.ndarray, proj2: np.ndarray, path: Path,
                           units_per_m: float) -> tuple[Intrinsics, float]:
    """Intrinsics and baseline from ``cv2.stereoRectify``'s P1 and P2 (rectified images)."""
    fx, fy, cx, cy = proj1[0, 0], proj1[1, 1], proj1[0, 2], proj1[1, 2]
    if not np.allclose(proj2[:, :3], proj1[:, :3], atol=_RECTIFIED_TOL_PX):
        raise FileFormatError(
            f"{path}: expected P2 to share P1's camera matrix (rectified with "
            f"CALIB_ZERO_DISPARITY), got P1 {proj1[:, :3].round(2).tolist()} and P2 "
            f"{proj2[:, :3].round(2).tolist()}")
    # P2 = K [I | t] with t = (-B, 0, 0) in T's units: P2[0, 3] = -fx B.
    baseline = -proj2[0, 3] / proj2[0, 0]
    if baseline <= 0:
        raise FileFormatError(
            f"{path}: expected the second camera to the right of the first (P2[0, 3] < 0), "
            f"got P2[0, 3] = {proj2[0, 3]:g}; swap the cameras")
    warnings.warn(
        f"{path}: rectified images assumed; the rectified projections P1/P2 are used (fx "
        f"{fx:.2f}, fy {fy:.2f}, cx {cx:.2f}, cy {cy:.2f}, baseline from P2), K1/K2, D1/D2 "
        f"and R describe the raw images and are not used",
        UserWarning,
        stacklevel=3,
    )
    return Intrinsics(fx, fy, cx, cy), float(baseline) / float(units_per_m)


def _from_calibration(k1, k2, d1, d2, rot, trans, path: Path, units_per_m: float
                      ) -> tuple[Intrinsics, float]:
    """Intrinsics and baseline from K1 and T, for a file without P1/P2."""
    ignored = []
    if any(d is not None and np.any(d != 0) for d in (d1, d2)):
        ignored.append("non-zero distortion D1/D2")
    if not np.allclose(rot, np.eye(3), atol=1e-6):
        ignored.append("rotation R")
    if not np.allclose(k1, k2, atol=_RECTIFIED_TOL_PX):
        ignored.append("K2 != K1")
    warnings.warn(
        f"{path}: rectified images assumed; K1 is used for both cameras and the baseline is |T|"
        + (f" ({', '.join(ignored)} ignored)" if ignored else "")
        + "; no P1/P2 in the file",
        UserWarning,
        stacklevel=3,
    )
    # x2 = R x1 + T, so the second camera's centre in the first's frame is -R^T T.
    center2 = -rot.T @ trans
    if center2[0] <= 0:
        raise FileFormatError(
            f"{path}: expected the second camera to the right of the first (T_x < 0), got "
            f"T = {trans.tolist()}; swap the cameras"
        )
    intrinsics = Intrinsics(k1[0, 0], k1[1, 1], k1[0, 2], k1[1, 2])
    return intrinsics, float(np.linalg.norm(trans)) / float(units_per_m)
