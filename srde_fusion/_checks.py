"""Input checks shared by the public entry points.

Each ``check_*`` function validates one argument and returns it normalised, raising an
:class:`~srde_fusion.errors.SRDEError` subclass whose message names the argument and says
what was expected and what was given. Checks run once, at the public boundary; internal
functions trust their inputs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import DisparityError, ImageError, LightError, MaskError, SRDEError

__all__ = [
    "MAX_IMAGE_PIXELS",
    "check_number",
    "check_keys",
    "check_image",
    "Views",
    "check_views",
    "check_mask",
    "check_disparity",
    "check_disparity_sign",
    "check_point3",
]


#: Largest image, pixels, that a file may declare or a rig may describe (a 200-megapixel
#: frame is about 600 MB as uint8 RGB): a small file can declare a huge size and exhaust
#: memory when decoded, and a rig's image size sizes every per-pixel array.
MAX_IMAGE_PIXELS = 200_000_000


def _describe(array: Any) -> str:
    if isinstance(array, np.ndarray):
        return f"array of shape {array.shape} and dtype {array.dtype}"
    return f"{type(array).__name__}"


def check_number(value: Any, name: str, error: type[SRDEError], *, positive: bool = False
                 ) -> float:
    """Validate a finite real number (``bool`` is not one) and return it as ``float``.

    Parameters
    ----------
    value : Any
    name : str
        The field's name in error messages.
    error : type of SRDEError
        Raised on failure (``RigError`` for rig.json, ``BoardError`` for board.json, ...).
    positive : bool
        Require ``value > 0``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"{name}: expected a number, got {type(value).__name__} {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise error(f"{name}: expected a finite number, got {value}")
    if positive and value <= 0:
        raise error(f"{name}: expected a positive number, got {value}")
    return value


def check_keys(data: Any, allowed: set[str], required: set[str], where: str,
               error: type[SRDEError]) -> dict:
    """Validate a JSON object's keys: no unknown ones, none of ``required`` missing.

    Returns the object. Unknown keys are an error rather than ignored, so a typo in a
    configuration file is caught instead of silently falling back to a default.
    """
    if not isinstance(data, dict):
        raise error(f"{where}: expected an object, got {type(data).__name__}")
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise error(f"{where}: unknown key(s) {unknown}; expected only {sorted(allowed)}")
    missing = sorted(required - set(data))
    if missing:
        raise error(f"{where}: missing key(s) {missing}")
    return data


def check_image(image: Any, name: str = "image") -> np.ndarray:
    """Validate one camera image and return it as a numpy array.

    Parameters
    ----------
    image : array_like, (H, W) or (H, W, 3), uint8 or float in [0, 1]
        A grey or RGB image.
    name : str
        How the argument is named in error messages.

    Returns
    -------
    numpy.ndarray
        The same image, as a numpy array (uint8 kept, floats as float32).

    Raises
    ------
    ImageError
        Wrong type, dtype, shape, non-finite or out-of-range float values.
    """
    if not isinstance(image, np.ndarray):
        raise ImageError(
            f"{name}: expected a numpy array (H, W) or (H, W, 3), got {_describe(image)}"
        )
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ImageError(f"{name}: expected shape (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] < 2 or image.shape[1] < 2:
        raise ImageError(f"{name}: expected at least 2x2 pixels, got {image.shape[:2]}")
    if image.dtype == np.uint8:
        return image
    if np.issubdtype(image.dtype, np.floating):
        # Checked before the cast to float32, which would overflow on huge values.
        if not np.all(np.isfinite(image)):
            raise ImageError(f"{name}: expected finite float values in [0, 1], got NaN or inf")
        lo, hi = float(image.min()), float(image.max())
        if lo < 0.0 or hi > 1.0:
            raise ImageError(
                f"{name}: expected float values in [0, 1], got range [{lo:.4g}, {hi:.4g}]"
            )
        return image.astype(np.float32, copy=False)
    raise ImageError(f"{name}: expected dtype uint8 or float in [0, 1], got {image.dtype}")


class Views(tuple):
    """Views that :func:`check_views` has validated: a tuple of images, ``(H, W[, 3])``.

    Inner layers (fusion -> SRDE -> refinement) pass this type on, so each public entry
    point can call :func:`check_views` without reading the pixels again: validating a
    ``Views`` of the expected count and size costs nothing. The images are the caller's
    arrays (not copies) and must not be modified while in use.
    """

    __slots__ = ()

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` of every view, pixels."""
        h, w = self[0].shape[:2]
        return (w, h)


def check_views(
    views: Any, n_cameras: int | None = None, image_size: tuple[int, int] | None = None
) -> Views:
    """Validate the list of views of a rig.

    Parameters
    ----------
    views : sequence of arrays
        One image per camera, in the rig's camera order.
    n_cameras : int, optional
        Number of cameras the rig has.
    image_size : (int, int), optional
        Expected ``(width, height)``.

    Returns
    -------
    Views
        The validated images; given a ``Views`` of the expected count and size, the
        same object, without another pass over the pixels.
    """
    if isinstance(views, Views) and (n_cameras is None or len(views) == n_cameras) and (
            image_size is None or views.image_size == tuple(image_size)):
        return views
    if isinstance(views, np.ndarray) and views.ndim in (3, 4) and views.shape[0] != 0:
        views = list(views)
    if not isinstance(views, Sequence) or isinstance(views, (str, bytes)):
        raise ImageError(f"views: expected a sequence of images, got {_describe(views)}")
    if n_cameras is not None and len(views) != n_cameras:
        raise ImageError(
            f"views: expected {n_cameras} images (one per rig camera), got {len(views)}"
        )
    if len(views) == 0:
        raise ImageError("views: expected at least one image, got none")
    checked = [check_image(v, f"views[{i}]") for i, v in enumerate(views)]
    shape0 = checked[0].shape[:2]
    for i, v in enumerate(checked):
        if v.shape[:2] != shape0:
            raise ImageError(
                f"views[{i}]: expected the same size as views[0] ({shape0[1]}x{shape0[0]}), "
                f"got {v.shape[1]}x{v.shape[0]}"
            )
    if image_size is not None and (shape0[1], shape0[0]) != tuple(image_size):
        raise ImageError(
            f"views: expected images of the rig's size {image_size[0]}x{image_size[1]}, "
            f"got {shape0[1]}x{shape0[0]}"
        )
    return Views(checked)


def check_mask(
    mask: Any, shape: tuple[int, int], name: str = "mask", *, allow_empty: bool = False
) -> np.ndarray:
    """Validate a binary mask of the reference view and return it as bool.

    Parameters
    ----------
    mask : array_like, (H, W), bool or integer (non-zero = inside)
    shape : (int, int)
        Expected ``(H, W)``.
    """
    if not isinstance(mask, np.ndarray):
        raise MaskError(f"{name}: expected a numpy array of shape {shape}, got {_describe(mask)}")
    if mask.shape != tuple(shape):
        raise MaskError(f"{name}: expected shape {tuple(shape)}, got {mask.shape}")
    if mask.dtype != bool:
        if not (np.issubdtype(mask.dtype, np.integer) or np.issubdtype(mask.dtype, np.floating)):
            raise MaskError(f"{name}: expected a bool or integer mask, got dtype {mask.dtype}")
        mask = np.nan_to_num(mask) != 0
    if not allow_empty and not mask.any():
        raise MaskError(f"{name}: expected at least one pixel inside the mask, got an empty mask")
    return mask


def check_disparity(
    disparity: Any, shape: tuple[int, int] | None = None, name: str = "disparity"
) -> np.ndarray:
    """Validate a disparity map and return it as float32 (NaN = invalid).

    Non-finite and negative values are allowed in the input and mean *invalid*;
    they are turned into NaN in the returned copy.
    """
    if not isinstance(disparity, np.ndarray):
        raise DisparityError(f"{name}: expected a numpy array (H, W), got {_describe(disparity)}")
    if disparity.ndim == 3 and disparity.shape[0] == 1:
        disparity = disparity[0]
    if disparity.ndim != 2:
        raise DisparityError(f"{name}: expected shape (H, W), got {disparity.shape}")
    if np.issubdtype(disparity.dtype, np.integer):
        # Integer disparity is almost always fixed point: OpenCV's StereoBM/SGBM return
        # int16 x 16, KITTI PNGs hold uint16 x 256. Taking it as pixels would be silently
        # wrong by that factor.
        raise DisparityError(
            f"{name}: expected float disparity in pixels, got dtype {disparity.dtype}; "
            "fixed-point maps need scaling first (OpenCV StereoSGBM: divide by 16; "
            "KITTI PNG: use read_kitti_disparity)"
        )
    if not np.issubdtype(disparity.dtype, np.floating):
        raise DisparityError(f"{name}: expected a float array, got dtype {disparity.dtype}")
    if shape is not None and disparity.shape != tuple(shape):
        raise DisparityError(f"{name}: expected shape {tuple(shape)}, got {disparity.shape}")
    # A float64 value beyond float32's range becomes inf, i.e. invalid, without a warning.
    with np.errstate(over="ignore", invalid="ignore"):
        out = disparity.astype(np.float32, copy=True)
        check_disparity_sign(out, name)
        out[~np.isfinite(out) | (out < 0)] = np.nan
    return out


#: A disparity map whose finite values are negative for more than this fraction, and vary,
#: is in another sign convention (negative horizontal flow), not a map with invalid pixels.
MAX_NEGATIVE_FRACTION = 0.5


def check_disparity_sign(disparity: np.ndarray, name: str = "disparity",
                         error: type[SRDEError] = DisparityError, *,
                         allow_sentinel: bool = True) -> None:
    """Refuse a disparity map that is mostly negative: a flow-convention output.

    Negative values mark invalid pixels in some pipelines, and a constant sentinel (all
    -1, say) stays that. But when most finite values are negative *and differ*, the map
    is horizontal flow (RAFT-Stereo's convention), and taking its negatives as invalid
    would silently keep almost nothing. A model's raw output has no sentinels: with
    ``allow_sentinel=False`` a constant negative map is refused too.

    Raises
    ------
    DisparityError (or ``error``)
        More than half of the finite values are negative and they are not one sentinel
        value; the message names ``output_sign``.
    """
    finite = disparity[np.isfinite(disparity)]
    negative = finite[finite < 0]
    if finite.size == 0 or negative.size <= MAX_NEGATIVE_FRACTION * finite.size:
        return
    if allow_sentinel and float(negative.min()) == float(negative.max()):
        return  # one sentinel value: invalid pixels, not a convention
    raise error(
        f"{name}: expected positive disparity in pixels (d = fx B / z), got "
        f"{negative.size / finite.size:.0%} of the {finite.size} finite values negative "
        f"(median {float(np.median(finite)):.3g} px); a model that returns negative "
        f"horizontal flow (RAFT-Stereo's convention) needs output_sign=-1 in its StereoSpec"
    )


def check_point3(point: Any, name: str, error: type[SRDEError] = LightError) -> np.ndarray:
    """Validate a 3D point in metres and return it as float64 ``(3,)``.

    ``error`` is the :class:`SRDEError` subclass raised; points are most often light
    positions, hence the default.
    """
    try:
        arr = np.asarray(point, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name}: expected 3 numbers (x, y, z) in metres, got {point!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise error(f"{name}: expected 3 finite numbers (x, y, z) in metres, got {point!r}")
    return arr
