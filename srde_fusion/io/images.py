"""Images and object masks in files.

Images: 8-bit PNG/JPEG/... read as ``(H, W, 3)`` uint8 RGB or ``(H, W)`` uint8 grey.
Masks: ``mask.png`` with instance labels (0 = background, 1..K = objects; a binary
mask with 255 = object reads as label 1).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._checks import check_image
from ..errors import FileFormatError, MaskError
from ._files import MAX_IMAGE_PIXELS, decode_image, encode_image

__all__ = [
    "IMAGE_EXTENSIONS",
    "read_image",
    "write_image",
    "read_mask",
    "write_mask",
    "masks_from_labels",
    "labels_from_masks",
]

#: Extensions read as camera images in a scene folder (write_scene writes PNG).
#: Image formats whose compression changes pixel values: never a label mask.
LOSSY_EXTENSIONS = (".jpg", ".jpeg", ".webp")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


# Largest instance label a uint8 mask.png can hold.
_MAX_LABEL_U8 = 255


# ---------------------------------------------------------------------- images
def read_image(path: str | os.PathLike, *, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Read an 8-bit image as RGB (or grey).

    Parameters
    ----------
    path : str or path-like
        Any format OpenCV decodes (PNG, JPEG, BMP, TIFF, ...).
    max_pixels : int
        Largest image accepted, checked on the header before decoding (a guard against
        files that declare a huge size, as Pillow's decompression-bomb check is).

    Returns
    -------
    numpy.ndarray, (H, W, 3) uint8 RGB or (H, W) uint8
        A fully opaque alpha channel is dropped.

    Raises
    ------
    FileFormatError
        Missing or undecodable file, a header declaring more than ``max_pixels``, a bit
        depth other than 8, or an alpha channel
        that is not fully opaque (transparency has no meaning for a camera image).
    """
    p = Path(path)
    image = decode_image(p, "8-bit image", max_pixels=max_pixels)
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
    encode_image(p, image)
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
        Missing or undecodable file, a lossy format (JPEG, WebP), or colour channels
        that differ.
    """
    p = Path(path)
    if p.suffix.lower() in LOSSY_EXTENSIONS:
        raise FileFormatError(
            f"{p}: expected a lossless label image (PNG, TIFF, BMP or .npy), got "
            f"{p.suffix.lower()[1:].upper()}: lossy compression turns object edges into "
            f"spurious labels")
    raw = decode_image(p, "mask image")
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
    labels = check_labels(labels, "labels")
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


def check_labels(labels: Any, name: str) -> np.ndarray:
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
    labels = check_labels(labels, "labels")
    if labels.size and labels.max() > _MAX_LABEL_U8:
        raise MaskError(
            f"labels: expected at most {_MAX_LABEL_U8} objects for an 8-bit mask, "
            f"got label {int(labels.max())}"
        )
    p = Path(path)
    encode_image(p, labels.astype(np.uint8))
    return p
