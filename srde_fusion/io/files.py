"""Reading and writing disparity maps, images, masks, rigs and scene folders.

Formats (DESIGN §5):

* **PFM** (Portable Float Map): ``read_pfm``/``write_pfm`` move raw float32 values, top row
  first in memory (the file stores the bottom row first). They do not touch invalid pixels.
* **Disparity files**: ``read_disparity``/``write_disparity`` dispatch on the extension
  (``.pfm``, ``.png``, ``.npy``) and are the *only* functions that translate the invalid
  marker. In memory an invalid pixel is NaN; in a PFM it is ``inf`` (as Middlebury writes
  it), in a KITTI 16-bit PNG it is 0, in ``.npy`` it stays NaN.
* **Images**: 8-bit PNG/JPEG/... read as ``(H, W, 3)`` uint8 RGB or ``(H, W)`` uint8 grey.
* **Masks**: ``mask.png`` with instance labels (0 = background, 1..K = objects; a binary
  mask with 255 = object reads as label 1).
* **Rigs from elsewhere**: Middlebury ``calib.txt`` and OpenCV stereo calibration YAML.
* **Scene folders**: ``rig.json``, one image per camera named after it (``cam0.png``),
  optional ``mask.png``, ``gt_disparity.pfm`` (or ``.npy``) and ``scene.json`` metadata.

Every problem with a file (missing, truncated, wrong magic, wrong bit depth) raises
:class:`~srde_fusion.errors.FileFormatError` naming the file and what was expected.
"""

from __future__ import annotations

import json
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

from .._checks import check_disparity, check_image, check_views
from ..errors import FileFormatError, MaskError, RigError
from ..geometry import Camera, CameraRig, Intrinsics

__all__ = [
    "KITTI_DISPARITY_SCALE",
    "KITTI_DISPARITY_MAX_PX",
    "DISPARITY_EXTENSIONS",
    "IMAGE_EXTENSIONS",
    "RIG_FILE",
    "MASK_FILE",
    "GT_DISPARITY_STEM",
    "METADATA_FILE",
    "read_pfm",
    "write_pfm",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_disparity",
    "write_disparity",
    "read_image",
    "write_image",
    "read_mask",
    "write_mask",
    "masks_from_labels",
    "labels_from_masks",
    "MiddleburyCalib",
    "read_middlebury_calib",
    "read_opencv_stereo_yaml",
    "SceneData",
    "write_scene",
    "read_scene",
    "list_scenes",
]

#: KITTI stores disparity in 16-bit PNG as ``round(d * 256)``; 0 marks an invalid pixel.
KITTI_DISPARITY_SCALE = 256.0
#: Largest disparity a KITTI PNG can hold, pixels.
KITTI_DISPARITY_MAX_PX = np.iinfo(np.uint16).max / KITTI_DISPARITY_SCALE
#: File extensions understood by :func:`read_disparity` / :func:`write_disparity`.
DISPARITY_EXTENSIONS = (".pfm", ".png", ".npy")
#: Extensions read as camera images in a scene folder (write_scene writes PNG).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

RIG_FILE = "rig.json"
MASK_FILE = "mask.png"
GT_DISPARITY_STEM = "gt_disparity"
METADATA_FILE = "scene.json"

# Largest instance label a uint8 mask.png can hold.
_MAX_LABEL_U8 = 255
# A Middlebury calib.txt's doffs must match cx1 - cx0 to this tolerance, pixels.
_DOFFS_TOL_PX = 0.05
# Intrinsics of the two cameras of a "rectified" file must agree to this, pixels.
_RECTIFIED_TOL_PX = 0.5
# A baseline longer than this with units_per_m=1 is most likely in mm: warn, do not guess.
_PLAUSIBLE_BASELINE_M = 5.0


# ---------------------------------------------------------------------- helpers
def _exists(path: Path, kind: str) -> bool:
    # A path the OS refuses to look up (name too long, no permission on a parent folder)
    # is reported like a missing one, as a FileFormatError, not as an OSError.
    try:
        return path.is_dir() if kind == "dir" else path.is_file()
    except OSError:
        return False


def _existing_file(path: str | os.PathLike, what: str) -> Path:
    p = Path(path)
    if not _exists(p, "file"):
        raise FileFormatError(f"{p}: expected an existing {what} file, got no such file")
    return p


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"{path}: expected a readable {what} file, got {exc}") from None


def _write_bytes(path: Path, data: bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    except OSError as exc:
        raise FileFormatError(f"{path}: could not write the file: {exc}") from None


def _decode_image(path: Path, what: str) -> np.ndarray:
    """Decode an image file with OpenCV, untouched (bit depth and channels as stored)."""
    data = _read_bytes(_existing_file(path, what), what)
    # imdecode on the bytes (rather than imread on the path) handles non-ASCII paths
    # and gives us one place to turn a failed decode into a FileFormatError.
    image = None
    if data:
        # OpenCV logs its decoder's complaints straight to stderr; the FileFormatError
        # below says it once, so a command's failure stays one line.
        log_level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        try:
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            image = None
        finally:
            cv2.utils.logging.setLogLevel(log_level)
    if image is None:
        raise FileFormatError(f"{path}: expected a readable {what}, got undecodable data")
    return image


def _encode_image(path: Path, image: np.ndarray) -> None:
    ext = path.suffix.lower()
    try:
        ok, buf = cv2.imencode(ext, image)
    except cv2.error as exc:
        raise FileFormatError(
            f"{path}: could not encode an image of shape {image.shape} and dtype {image.dtype} "
            f"as {ext!r}: {exc}"
        ) from None
    if not ok:
        raise FileFormatError(f"{path}: could not encode the image as {ext!r}")
    _write_bytes(path, buf.tobytes())


# ---------------------------------------------------------------------- PFM
def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM file as raw float32 values.

    Values are returned as stored: ``inf`` stays ``inf`` (use :func:`read_disparity`
    to get NaN for invalid disparity). Rows are flipped to top-first order.

    Parameters
    ----------
    path : str or path-like
        A ``PF`` (colour) or ``Pf`` (grey) file, either byte order (a negative scale in
        the header means little endian). The scale's magnitude is not applied.

    Returns
    -------
    numpy.ndarray, (H, W) or (H, W, 3), float32
        Native byte order, row 0 at the top.

    Raises
    ------
    FileFormatError
        Missing file, wrong magic, malformed header or too little data.
    """
    p = _existing_file(path, "PFM")
    data = _read_bytes(p, "PFM")
    # The header is three whitespace-separated tokens after the magic; one line break
    # (or whitespace byte) separates it from the raster. CRLF files exist in the wild.
    match = re.match(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)(?:\r\n|\s)", data)
    if match is None:
        head = data[:20]
        if not head.startswith((b"PF", b"Pf")):
            raise FileFormatError(
                f"{p}: expected a PFM file starting with 'PF' or 'Pf', got {head!r}"
            )
        raise FileFormatError(
            f"{p}: expected a PFM header 'PF|Pf <width> <height> <scale>', got {head!r}"
        )
    magic, width, height, scale_text = match.groups()
    width, height = int(width), int(height)
    try:
        scale = float(scale_text)
    except ValueError:
        raise FileFormatError(f"{p}: expected a numeric PFM scale, got {scale_text!r}") from None
    if width <= 0 or height <= 0 or scale == 0.0 or not math.isfinite(scale):
        raise FileFormatError(
            f"{p}: expected positive width/height and a non-zero scale, got "
            f"{width}x{height}, scale {scale}"
        )
    channels = 3 if magic == b"PF" else 1
    dtype = np.dtype("<f4") if scale < 0 else np.dtype(">f4")
    count = width * height * channels
    raster = data[match.end() :]
    if len(raster) < count * 4:
        raise FileFormatError(
            f"{p}: expected {count * 4} bytes of {width}x{height}x{channels} float data, "
            f"got {len(raster)} (truncated file)"
        )
    values = np.frombuffer(raster, dtype=dtype, count=count).astype(np.float32)
    shape = (height, width, 3) if channels == 3 else (height, width)
    # PFM stores the bottom row first.
    return np.ascontiguousarray(values.reshape(shape)[::-1])


def write_pfm(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write an ``(H, W)`` or ``(H, W, 3)`` array as a little-endian PFM, values as given.

    No value is translated (NaN stays NaN); use :func:`write_disparity` to write
    invalid disparity as ``inf`` like Middlebury does.

    Parameters
    ----------
    path : str or path-like
    array : numpy.ndarray, (H, W) or (H, W, 3), real
        Converted to float32.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    p = Path(path)
    arr = np.asarray(array)
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise FileFormatError(f"{p}: expected a real array to write as PFM, got dtype {arr.dtype}")
    if arr.ndim == 3 and arr.shape[2] == 3:
        magic = b"PF"
    elif arr.ndim == 2:
        magic = b"Pf"
    else:
        raise FileFormatError(
            f"{p}: expected an (H, W) or (H, W, 3) array for PFM, got shape {arr.shape}"
        )
    height, width = arr.shape[:2]
    header = magic + f"\n{width} {height}\n-1.0\n".encode("ascii")
    raster = np.ascontiguousarray(arr[::-1], dtype="<f4").tobytes()
    _write_bytes(p, header + raster)
    return p


# ---------------------------------------------------------------------- KITTI PNG
def read_kitti_disparity(path: str | os.PathLike) -> np.ndarray:
    """Read a KITTI 16-bit disparity PNG.

    Returns
    -------
    numpy.ndarray, (H, W), float32
        Disparity in pixels (stored value / :data:`KITTI_DISPARITY_SCALE`); NaN where
        the file holds 0 (invalid).

    Raises
    ------
    FileFormatError
        Missing or undecodable file, not single-channel, or not 16-bit (an 8-bit PNG
        has lost the fixed-point scale and is refused).
    """
    p = Path(path)
    raw = _decode_image(p, "KITTI disparity PNG")
    if raw.dtype != np.uint16:
        raise FileFormatError(
            f"{p}: expected a 16-bit KITTI disparity PNG (value / {KITTI_DISPARITY_SCALE:g}), "
            f"got dtype {raw.dtype}"
        )
    if raw.ndim != 2:
        raise FileFormatError(
            f"{p}: expected a single-channel disparity PNG, got shape {raw.shape}"
        )
    disparity = raw.astype(np.float32) / np.float32(KITTI_DISPARITY_SCALE)
    disparity[raw == 0] = np.nan
    return disparity


def write_kitti_disparity(path: str | os.PathLike, disparity_px: np.ndarray) -> Path:
    """Write disparity as a KITTI 16-bit PNG (``round(d * 256)``, 0 = invalid).

    NaN, inf and negative values are written as 0 (invalid). A valid disparity below
    half a step (1/512 px) is written as 1 rather than 0, so it stays valid, as the
    KITTI development kit does.

    Parameters
    ----------
    path : str or path-like
        Should end in ``.png``.
    disparity_px : numpy.ndarray, (H, W), float

    Raises
    ------
    DisparityError
        Not an ``(H, W)`` real array.
    FileFormatError
        A valid value above :data:`KITTI_DISPARITY_MAX_PX` (about 256 px), which the
        16-bit format cannot hold.
    """
    p = Path(path)
    d = check_disparity(disparity_px, name="disparity_px")
    valid = np.isfinite(d)
    if valid.any() and float(d[valid].max()) > KITTI_DISPARITY_MAX_PX:
        raise FileFormatError(
            f"{p}: expected disparities <= {KITTI_DISPARITY_MAX_PX:.3f} px for a 16-bit KITTI PNG, "
            f"got a maximum of {float(d[valid].max()):.3f} px"
        )
    scaled = np.zeros(d.shape, dtype=np.uint16)
    scaled[valid] = np.maximum(np.rint(d[valid].astype(np.float64) * KITTI_DISPARITY_SCALE), 1)
    _encode_image(p, scaled)
    return p


# ---------------------------------------------------------------------- disparity
def _disparity_ext(path: Path) -> str:
    ext = path.suffix.lower()
    if ext not in DISPARITY_EXTENSIONS:
        raise FileFormatError(
            f"{path}: expected a disparity file ending in one of {list(DISPARITY_EXTENSIONS)}, "
            f"got {ext or 'no extension'!r}"
        )
    return ext


def read_disparity(path: str | os.PathLike) -> np.ndarray:
    """Read a disparity map from ``.pfm``, KITTI ``.png`` or ``.npy``.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    numpy.ndarray, (H, W), float32
        Disparity in pixels; NaN = invalid. Non-finite values (PFM ``inf``), KITTI 0 and
        negative values all become NaN.

    Raises
    ------
    FileFormatError
        Unknown extension, unreadable file, or not a single-channel map.
    """
    p = Path(path)
    ext = _disparity_ext(p)
    if ext == ".png":
        return read_kitti_disparity(p)
    if ext == ".pfm":
        raw = read_pfm(p)
    else:
        _existing_file(p, "disparity .npy")
        try:
            raw = np.load(p, allow_pickle=False)
        # numpy parses the header with Python's own parser: a damaged header can raise
        # SyntaxError, tokenize.TokenError, MemoryError, ... besides the usual I/O errors.
        except Exception as exc:
            raise FileFormatError(
                f"{p}: expected a numpy .npy array, got an unreadable file: {exc}"
            ) from None
    if raw.ndim != 2 or not (
        np.issubdtype(raw.dtype, np.floating) or np.issubdtype(raw.dtype, np.integer)
    ):
        raise FileFormatError(
            f"{p}: expected a single-channel (H, W) real disparity map, got shape {raw.shape} "
            f"and dtype {raw.dtype}"
        )
    return check_disparity(raw, name=str(p))


def write_disparity(path: str | os.PathLike, disparity_px: np.ndarray) -> Path:
    """Write a disparity map; the format follows the extension.

    ``.pfm`` writes invalid pixels (NaN, inf, negative) as ``inf``; ``.png`` writes a
    KITTI 16-bit PNG (see :func:`write_kitti_disparity`); ``.npy`` writes float32 with NaN.

    Parameters
    ----------
    path : str or path-like
    disparity_px : numpy.ndarray, (H, W), float
        Disparity in pixels, NaN = invalid.

    Returns
    -------
    pathlib.Path
        The path written.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> d = np.array([[1.5, np.nan], [2.0, 3.25]], np.float32)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     back = read_disparity(write_disparity(Path(tmp) / "d.pfm", d))
    >>> back.tolist()
    [[1.5, nan], [2.0, 3.25]]
    """
    p = Path(path)
    ext = _disparity_ext(p)
    d = check_disparity(disparity_px, name="disparity_px")
    if ext == ".png":
        return write_kitti_disparity(p, d)
    if ext == ".pfm":
        # Middlebury marks invalid disparity with inf.
        return write_pfm(p, np.where(np.isnan(d), np.float32(np.inf), d))
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        np.save(p, d, allow_pickle=False)
    except OSError as exc:
        raise FileFormatError(f"{p}: could not write the file: {exc}") from None
    return p


# ---------------------------------------------------------------------- images
def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit image as RGB (or grey).

    Parameters
    ----------
    path : str or path-like
        Any format OpenCV decodes (PNG, JPEG, BMP, TIFF, ...).

    Returns
    -------
    numpy.ndarray, (H, W, 3) uint8 RGB or (H, W) uint8
        A fully opaque alpha channel is dropped.

    Raises
    ------
    FileFormatError
        Missing or undecodable file, a bit depth other than 8, or an alpha channel
        that is not fully opaque (transparency has no meaning for a camera image).
    """
    p = Path(path)
    image = _decode_image(p, "8-bit image")
    if image.dtype != np.uint8:
        raise FileFormatError(
            f"{p}: expected an 8-bit image, got dtype {image.dtype}; convert it to 8 bits "
            "(for a disparity PNG use read_disparity)"
        )
    if image.ndim == 2:
        return image
    channels = image.shape[2]
    if channels == 1:
        return image[:, :, 0]
    if channels == 4:
        if not np.all(image[:, :, 3] == np.iinfo(np.uint8).max):
            raise FileFormatError(
                f"{p}: expected an opaque image, got an alpha channel with transparency"
            )
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    if channels == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    raise FileFormatError(f"{p}: expected a grey or RGB image, got {channels} channels")


def _to_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    return np.rint(image * np.float32(np.iinfo(np.uint8).max)).astype(np.uint8)


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB or grey image; the format follows the extension.

    Parameters
    ----------
    path : str or path-like
    image : numpy.ndarray, (H, W, 3) RGB or (H, W), uint8 or float in [0, 1]
        Floats are scaled to 0..255 and rounded.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ImageError
        Wrong shape or dtype (see :func:`~srde_fusion._checks.check_image`).
    """
    p = Path(path)
    image = _to_uint8(check_image(image, "image"))
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    _encode_image(p, image)
    return p


# ---------------------------------------------------------------------- masks
def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Read an instance-label mask of the reference view.

    Parameters
    ----------
    path : str or path-like
        8- or 16-bit single-channel image (a 3-channel image with equal channels is
        accepted). 0 = background, 1..K = objects; a binary mask whose only non-zero
        value is 255 reads as label 1.

    Returns
    -------
    numpy.ndarray, (H, W), int32
        Instance labels.

    Raises
    ------
    FileFormatError
        Missing or undecodable file, or colour channels that differ.
    """
    p = Path(path)
    raw = _decode_image(p, "mask image")
    if raw.ndim == 3:
        if not all(np.array_equal(raw[:, :, 0], raw[:, :, c]) for c in range(1, raw.shape[2])):
            raise FileFormatError(
                f"{p}: expected a single-channel label mask, "
                f"got {raw.shape[2]} channels that differ"
            )
        raw = raw[:, :, 0]
    if raw.dtype not in (np.uint8, np.uint16):
        raise FileFormatError(f"{p}: expected an 8- or 16-bit label mask, got dtype {raw.dtype}")
    labels = raw.astype(np.int32)
    if raw.dtype == np.uint8:
        values = np.unique(labels)
        # The usual binary mask (0/255) means one object, not object number 255.
        if values[-1] == _MAX_LABEL_U8 and np.all(np.isin(values, (0, _MAX_LABEL_U8))):
            labels[labels == _MAX_LABEL_U8] = 1
    return labels


def masks_from_labels(labels: np.ndarray) -> list[np.ndarray]:
    """Split an instance-label image into one boolean mask per object.

    Parameters
    ----------
    labels : numpy.ndarray, (H, W), integer or bool
        0 = background.

    Returns
    -------
    list of numpy.ndarray, each (H, W) bool
        One mask per distinct non-zero label, in increasing label order (gaps in the
        numbering are skipped). Empty if there is no object.

    Examples
    --------
    >>> import numpy as np
    >>> [int(m.sum()) for m in masks_from_labels(np.array([[0, 2], [2, 5]]))]
    [2, 1]
    """
    labels = _check_labels(labels, "labels")
    return [labels == value for value in np.unique(labels) if value != 0]


def labels_from_masks(masks: Sequence[np.ndarray]) -> np.ndarray:
    """Combine boolean object masks into one instance-label image (object k -> label k+1).

    Parameters
    ----------
    masks : sequence of numpy.ndarray, each (H, W) bool
        Non-overlapping, same shape.

    Returns
    -------
    numpy.ndarray, (H, W), int32

    Raises
    ------
    MaskError
        No masks, different shapes, or overlapping masks.
    """
    if isinstance(masks, np.ndarray) or not isinstance(masks, Sequence) or len(masks) == 0:
        raise MaskError(
            f"masks: expected a non-empty sequence of (H, W) bool masks, got {type(masks).__name__}"
        )
    arrays = [np.asarray(m) for m in masks]
    shape = arrays[0].shape
    labels = np.zeros(shape, dtype=np.int32)
    for k, m in enumerate(arrays):
        if m.shape != shape or m.ndim != 2:
            raise MaskError(f"masks[{k}]: expected shape {shape} like masks[0], got {m.shape}")
        if m.dtype != bool:
            raise MaskError(f"masks[{k}]: expected dtype bool, got {m.dtype}")
        if np.any(labels[m] != 0):
            raise MaskError(
                f"masks[{k}]: expected non-overlapping masks, "
                "got pixels shared with an earlier mask"
            )
        labels[m] = k + 1
    return labels


def _check_labels(labels: Any, name: str) -> np.ndarray:
    if not isinstance(labels, np.ndarray) or labels.ndim != 2:
        shape = labels.shape if isinstance(labels, np.ndarray) else type(labels).__name__
        raise MaskError(f"{name}: expected an (H, W) integer label array, got {shape}")
    if labels.dtype == bool:
        return labels.astype(np.int32)
    if not np.issubdtype(labels.dtype, np.integer):
        raise MaskError(
            f"{name}: expected integer labels (0 = background), got dtype {labels.dtype}"
        )
    if labels.size and labels.min() < 0:
        raise MaskError(f"{name}: expected labels >= 0, got {int(labels.min())}")
    return labels


def write_mask(path: str | os.PathLike, labels: np.ndarray) -> Path:
    """Write instance labels (0..255) as an 8-bit single-channel PNG.

    Parameters
    ----------
    path : str or path-like
    labels : numpy.ndarray, (H, W), integer or bool
        0 = background, 1..K = objects.

    Raises
    ------
    MaskError
        Not an ``(H, W)`` integer/bool array, or labels outside 0..255.
    """
    labels = _check_labels(labels, "labels")
    if labels.size and labels.max() > _MAX_LABEL_U8:
        raise MaskError(
            f"labels: expected at most {_MAX_LABEL_U8} objects for an 8-bit mask, "
            f"got label {int(labels.max())}"
        )
    p = Path(path)
    _encode_image(p, labels.astype(np.uint8))
    return p


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
    p = _existing_file(path, "Middlebury calib.txt")
    text = _read_bytes(p, "Middlebury calib.txt").decode("utf-8", errors="replace")
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
        mat = node.mat()
        if mat is None:
            raise FileFormatError(
                f"{path}: {name}: expected an OpenCV matrix, got a non-matrix node"
            )
        mat = np.asarray(mat, dtype=np.float64)
        if shape is not None and mat.size != int(np.prod(shape)):
            raise FileFormatError(f"{path}: {name}: expected {shape} values, got shape {mat.shape}")
        if not np.all(np.isfinite(mat)):
            raise FileFormatError(f"{path}: {name}: expected finite values, got NaN or inf")
        return mat.reshape(shape) if shape is not None else mat
    if required:
        raise FileFormatError(f"{path}: expected a matrix named {' or '.join(names)}, got none")
    return None


def _fs_image_size(fs: Any, path: Path) -> tuple[int, int] | None:
    for name in ("image_size", "imageSize"):
        node = fs.getNode(name)
        if node.empty():
            continue
        values = node.mat() if node.isMap() else [node.at(i).real() for i in range(node.size())]
        values = np.asarray(values, dtype=np.float64).ravel()
        if values.size == 2:
            return int(values[0]), int(values[1])
        raise FileFormatError(f"{path}: {name}: expected [width, height], got {values.tolist()}")
    w, h = fs.getNode("image_width"), fs.getNode("image_height")
    if not w.empty() and not h.empty():
        return int(w.real()), int(h.real())
    return None


def read_opencv_stereo_yaml(
    path: str | os.PathLike, *, units_per_m: float = 1.0, image_size: tuple[int, int] | None = None
) -> CameraRig:
    """Read a two-camera rig from an OpenCV stereo calibration file (YAML/XML/JSON).

    The file holds ``K1, D1, K2, D2, R, T`` as ``cv2.stereoCalibrate`` returns them
    (``M1``/``M2`` are accepted for ``K1``/``K2``). The library works on rectified
    images, so the images are assumed to be rectified already with ``K1`` as the
    shared camera matrix: distortion and rotation are *not* applied, and a
    ``UserWarning`` says so on every load.

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
        Missing or unparsable file, missing matrices, no image size, or a second camera
        that lies to the left of the first (swap the cameras).
    """
    p = _existing_file(path, "OpenCV stereo calibration")
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
    ignored = []
    if any(d is not None and np.any(d != 0) for d in (d1, d2)):
        ignored.append("non-zero distortion D1/D2")
    if not np.allclose(rot, np.eye(3), atol=1e-6):
        ignored.append("rotation R")
    if not np.allclose(k1, k2, atol=_RECTIFIED_TOL_PX):
        ignored.append("K2 != K1")
    warnings.warn(
        f"{p}: rectified images assumed; K1 is used for both cameras and the baseline is |T|"
        + (f" ({', '.join(ignored)} ignored)" if ignored else ""),
        UserWarning,
        stacklevel=2,
    )
    # x2 = R x1 + T, so the second camera's centre in the first's frame is -R^T T.
    center2 = -rot.T @ trans
    if center2[0] <= 0:
        raise FileFormatError(
            f"{p}: expected the second camera to the right of the first (T_x < 0), got "
            f"T = {trans.tolist()}; swap the cameras"
        )
    baseline_m = float(np.linalg.norm(trans)) / float(units_per_m)
    if baseline_m > _PLAUSIBLE_BASELINE_M:
        warnings.warn(
            f"{p}: baseline of {baseline_m:g} m with units_per_m={units_per_m:g}; if T is in "
            "millimetres, pass units_per_m=1000",
            UserWarning,
            stacklevel=2,
        )
    try:
        intrinsics = Intrinsics(k1[0, 0], k1[1, 1], k1[0, 2], k1[1, 2])
        return CameraRig(
            size,
            intrinsics,
            (Camera("left", (0.0, 0.0, 0.0)), Camera("right", (baseline_m, 0.0, 0.0))),
        )
    except RigError as exc:
        raise FileFormatError(f"{p}: {exc}") from None


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
            _check_labels(mask, "mask") if isinstance(mask, np.ndarray) else labels_from_masks(mask)
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
    _write_bytes(out / RIG_FILE, rig.to_json().encode("utf-8"))
    for stem, image in zip(stems, checked, strict=True):
        write_image(out / f"{stem}.png", image)
    if labels is not None:
        write_mask(out / MASK_FILE, labels)
    if gt is not None:
        write_disparity(out / f"{GT_DISPARITY_STEM}.pfm", gt)
    if meta_text is not None:
        _write_bytes(out / METADATA_FILE, meta_text.encode("utf-8"))
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
        ``gt_disparity.npy``, and ``scene.json``.

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
    if not _exists(path, "dir"):
        raise FileFormatError(f"{path}: expected a scene folder, got no such directory")
    rig_path = path / RIG_FILE
    if not rig_path.is_file():
        raise FileFormatError(f"{path}: expected a scene folder with {RIG_FILE}, got none")
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
            metadata = json.loads(_read_bytes(meta_path, "scene metadata").decode("utf-8"))
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
    """Scene folders of a dataset: its sub-folders that hold a ``rig.json``, sorted by name.

    Raises
    ------
    FileFormatError
        The folder does not exist or holds no scene folder.
    """
    root = Path(dataset_dir)
    if not _exists(root, "dir"):
        raise FileFormatError(f"{root}: expected a dataset folder, got no such directory")
    scenes = sorted(p for p in root.iterdir() if p.is_dir() and (p / RIG_FILE).is_file())
    if not scenes:
        hint = " (it is itself a scene folder)" if (root / RIG_FILE).is_file() else ""
        raise FileFormatError(f"{root}: expected sub-folders holding {RIG_FILE}, got none{hint}")
    return scenes
