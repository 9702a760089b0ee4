"""Photometry of 8-bit camera images: sRGB decoding, luminance, saturation.

Camera images are gamma-encoded; anything photometric (weighted centroids, lobe fits,
thresholds meant as brightness) works on linear intensity (DESIGN §2).
"""

from __future__ import annotations

import cv2
import numpy as np

from .errors import ImageError

__all__ = [
    "srgb_to_linear",
    "linear_to_srgb",
    "to_float",
    "to_linear",
    "luminance",
    "saturation_mask",
    "REC709_LUMA",
    "IMAGE_ENCODINGS",
    "SATURATION_LEVEL_U8",
    "SRGB_TO_LINEAR_U8",
    "LINEAR_U8",
]

#: Rec. 709 / sRGB luminance weights for linear RGB.
REC709_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
_REC709_ROW = REC709_LUMA.reshape(1, 3)  # as cv2.transform takes it

#: How image values can encode intensity (the rig's ``image_encoding``).
IMAGE_ENCODINGS = ("srgb", "linear")

#: A uint8 value at or above this is treated as clipped (saturated).
SATURATION_LEVEL_U8 = 254


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear intensity in [0, 1] (IEC 61966-2-1)."""
    encoded = np.asarray(encoded, dtype=np.float32)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4).astype(
        np.float32
    )


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Encode linear intensity in [0, 1] to sRGB values in [0, 1]."""
    linear = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    return np.where(
        linear <= 0.0031308, linear * 12.92, 1.055 * np.power(linear, 1.0 / 2.4) - 0.055
    ).astype(np.float32)


#: Linear value of every uint8 sRGB code, (256,) float32: decoding is a single gather.
SRGB_TO_LINEAR_U8 = srgb_to_linear(np.arange(256, dtype=np.float32) / 255.0)


def to_float(image: np.ndarray) -> np.ndarray:
    """Image as float32 in [0, 1], still in its own encoding."""
    if image.dtype == np.uint8:
        return image.astype(np.float32) / 255.0
    return image.astype(np.float32, copy=False)


#: Linear value of every uint8 code of a linearly encoded image, (256,) float32.
LINEAR_U8 = np.arange(256, dtype=np.float32) / 255.0


def to_linear(image: np.ndarray, encoding: str = "srgb") -> np.ndarray:
    """Linear intensity of an image, channels kept.

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3), uint8 or float in [0, 1]
    encoding : {"srgb", "linear"}
        How the image values encode intensity.

    Returns
    -------
    numpy.ndarray, same shape as ``image``, float32
        Linear intensity in [0, 1]; a float32 linear image is returned as it is.

    Raises
    ------
    ImageError
        An unknown ``encoding``.

    Examples
    --------
    >>> import numpy as np
    >>> to_linear(np.array([[0, 255]], np.uint8)).tolist()
    [[0.0, 1.0]]
    """
    if encoding not in IMAGE_ENCODINGS:
        raise ImageError(f"encoding: expected one of {list(IMAGE_ENCODINGS)}, got {encoding!r}")
    if image.dtype == np.uint8:
        table = SRGB_TO_LINEAR_U8 if encoding == "srgb" else LINEAR_U8
        if image.size == 0 or image.ndim == 0:  # OpenCV takes no empty or 0-d arrays
            return table[image]
        # OpenCV's table lookup is several times faster than numpy's gather (the same
        # values); it drops a trailing channel axis of length 1, hence the reshape.
        return cv2.LUT(image, table).reshape(image.shape)
    if encoding == "srgb":
        return srgb_to_linear(image)
    return image.astype(np.float32, copy=False)


def luminance(image: np.ndarray, encoding: str = "srgb") -> np.ndarray:
    """Linear luminance of a grey or RGB image.

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3), uint8 or float32 in [0, 1]
    encoding : {"srgb", "linear"}
        How the image values encode intensity.

    Returns
    -------
    numpy.ndarray, (H, W), float32
        Linear luminance in [0, 1].

    Raises
    ------
    ImageError
        An unknown ``encoding`` (a typo must not silently skip the sRGB decoding).

    Examples
    --------
    >>> import numpy as np
    >>> float(luminance(np.full((2, 2, 3), 255, np.uint8))[0, 0])
    1.0
    """
    lin = to_linear(image, encoding)
    if lin.ndim == 3:
        if lin.size == 0:  # OpenCV takes no empty arrays
            return np.zeros(lin.shape[:2], dtype=np.float32)
        # OpenCV's per-pixel channel mix: every pixel gets the same arithmetic wherever it
        # sits, so a crop's luminance equals the same pixels' in a larger crop, and it runs
        # several times faster than numpy's product over the channel axis. (It reads rows
        # with any step, but the pixels of a row must be packed.)
        if lin.strides[1:] != (3 * lin.itemsize, lin.itemsize):
            lin = np.ascontiguousarray(lin)
        return cv2.transform(lin, _REC709_ROW).reshape(lin.shape[:2])
    return lin.astype(np.float32, copy=False)


def saturation_mask(image: np.ndarray) -> np.ndarray:
    """Pixels where any channel is clipped at the top of the range, (H, W) bool."""
    if image.dtype == np.uint8 and image.ndim == 3:
        # OpenCV's range test gives the same mask an order of magnitude faster than
        # numpy's any(axis=2), strided crops included.
        below = (SATURATION_LEVEL_U8 - 1,) * image.shape[2]
        return cv2.inRange(image, (0,) * image.shape[2], below) == 0
    if image.dtype == np.uint8:
        sat = image >= SATURATION_LEVEL_U8
    else:
        sat = image >= SATURATION_LEVEL_U8 / 255.0
    return sat.any(axis=2) if sat.ndim == 3 else sat
