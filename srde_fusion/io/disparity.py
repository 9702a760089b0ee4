"""Disparity maps in files: PFM, KITTI 16-bit PNG and ``.npy``.

``read_pfm``/``write_pfm`` move raw float32 values, top row first in memory (the file
stores the bottom row first); they do not touch invalid pixels. ``read_disparity`` and
``write_disparity`` dispatch on the extension and are the *only* functions that translate
the invalid marker: NaN in memory, ``inf`` in a PFM (as Middlebury writes it), 0 in a
KITTI PNG, NaN in ``.npy`` (DESIGN §5).
"""

from __future__ import annotations

import io
import math
import os
import re
from pathlib import Path

import numpy as np

from .._checks import check_disparity
from ..errors import FileFormatError
from ._files import (
    decode_image,
    encode_image,
    existing_file,
    load_npy,
    read_bytes,
    write_bytes,
)

__all__ = [
    "KITTI_DISPARITY_SCALE",
    "KITTI_DISPARITY_MAX_PX",
    "DISPARITY_EXTENSIONS",
    "read_pfm",
    "write_pfm",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_disparity",
    "write_disparity",
]

#: KITTI stores disparity in 16-bit PNG as ``round(d * 256)``; 0 marks an invalid pixel.
KITTI_DISPARITY_SCALE = 256.0


#: Largest disparity a KITTI PNG can hold, pixels.
KITTI_DISPARITY_MAX_PX = np.iinfo(np.uint16).max / KITTI_DISPARITY_SCALE


#: File extensions understood by :func:`read_disparity` / :func:`write_disparity`.
DISPARITY_EXTENSIONS = (".pfm", ".png", ".npy")


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
    p = existing_file(path, "PFM")
    data = read_bytes(p, "PFM")
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
    write_bytes(p, header + raster)
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
    raw = decode_image(p, "KITTI disparity PNG")
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
    encode_image(p, scaled)
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
        raw = load_npy(p, "disparity .npy")
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
    buffer = io.BytesIO()
    np.save(buffer, d, allow_pickle=False)
    write_bytes(p, buffer.getvalue())
    return p
