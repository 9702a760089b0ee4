"""File plumbing shared by the readers and writers.

Existence checks, bytes in and out,
image codecs. Every failure is a :class:`~srde_fusion.errors.FileFormatError` naming the file.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import PIL.Image

from .._atomic import write_atomic
from .._checks import MAX_IMAGE_PIXELS
from ..errors import FileFormatError


# ---------------------------------------------------------------------- helpers
def path_exists(path: Path, kind: str) -> bool:
    # A path the OS refuses to look up (name too long, no permission on a parent folder)
    # is reported like a missing one, as a FileFormatError, not as an OSError.
    try:
        return path.is_dir() if kind == "dir" else path.is_file()
    except OSError:
        return False


def existing_file(path: str | os.PathLike, what: str) -> Path:
    p = Path(path)
    if not path_exists(p, "file"):
        raise FileFormatError(f"{p}: expected an existing {what} file, got no such file")
    return p


def read_bytes(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"{path}: expected a readable {what} file, got {exc}") from None


def write_bytes(path: Path, data: bytes) -> None:
    write_atomic(path, data)


def load_npy(path: Path, what: str) -> np.ndarray:
    """Load a ``.npy`` array (no pickles); any failure is a FileFormatError naming the file."""
    existing_file(path, what)
    try:
        return np.load(path, allow_pickle=False)
    # numpy parses the header with Python's own parser: a damaged or empty file can raise
    # SyntaxError, tokenize.TokenError, EOFError, MemoryError, ... besides I/O errors.
    except Exception as exc:
        raise FileFormatError(
            f"{path}: expected a numpy .npy array, got an unreadable file: "
            f"{type(exc).__name__}: {exc}"
        ) from None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _declared_size(data: bytes) -> tuple[int, int] | None:
    """Return ``(width, height)`` from the file header, without decoding the pixels.

    PNG's IHDR is read directly; other formats through Pillow's lazy header parsing.
    None when the header cannot be read (OpenCV then decides).
    """
    if data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR" and len(data) >= 24:
        return struct.unpack(">II", data[16:24])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PIL.Image.DecompressionBombWarning)
            with PIL.Image.open(io.BytesIO(data)) as header:
                return header.size
    except PIL.Image.DecompressionBombError:  # over twice Pillow's own limit
        return (2**31, 2**31)
    except Exception:  # not a format Pillow knows, or a damaged header
        return None


def decode_image(path: Path, what: str, *, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Decode an image file with OpenCV, untouched (bit depth and channels as stored).

    The size the header declares is checked against ``max_pixels`` before any pixel
    is decoded.
    """
    data = read_bytes(existing_file(path, what), what)
    size = _declared_size(data) if data else None
    if size is not None and size[0] * size[1] > max_pixels:
        raise FileFormatError(
            f"{path}: expected a {what} of at most {max_pixels:,} pixels, got a header "
            f"declaring {size[0]}x{size[1]} ({size[0] * size[1]:,} pixels); raise max_pixels "
            f"if the image is real")
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


def encode_image(path: Path, image: np.ndarray) -> None:
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
    write_bytes(path, buf.tobytes())
