"""Pre- and post-processing shared by the ONNX and torch adapters.

Everything a :class:`~srde_fusion.adapters.spec.StereoSpec` declares is applied here, in
numpy/OpenCV, so both runtimes behave identically and the runtime-specific classes only
feed arrays in and hand raw outputs back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from srde_fusion._checks import check_disparity_sign, check_image
from srde_fusion.errors import BackboneError, ImageError

from .spec import StereoSpec

__all__ = ["Geometry", "StereoAdapter", "check_pair", "prepare_pair", "finish_disparity"]

_UINT8_MAX = 255.0


@dataclass(frozen=True)
class Geometry:
    """Where the model input came from, to map its output back.

    Attributes
    ----------
    image_hw : (int, int)
        Height and width of the caller's images.
    model_hw : (int, int)
        Height and width after resizing (equal to ``image_hw`` unless the model is
        fixed-size), before padding.
    pad_tblr : (int, int, int, int)
        Padding added at top, bottom, left and right, in model pixels.
    """

    image_hw: tuple[int, int]
    model_hw: tuple[int, int]
    pad_tblr: tuple[int, int, int, int]

    @property
    def padded_hw(self) -> tuple[int, int]:
        """Height and width of the tensor fed to the model."""
        t, b, left, r = self.pad_tblr
        return self.model_hw[0] + t + b, self.model_hw[1] + left + r


def check_pair(left: Any, right: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate a stereo pair and return both as (H, W, 3) float32 in [0, 1].

    Grey images are replicated to three channels.
    """
    left = check_image(left, "left")
    right = check_image(right, "right")
    if left.shape[:2] != right.shape[:2]:
        raise ImageError(
            f"right: expected the same size as left ({left.shape[1]}x{left.shape[0]}), "
            f"got {right.shape[1]}x{right.shape[0]}"
        )
    return _to_rgb01(left), _to_rgb01(right)


def _to_rgb01(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        image = image.astype(np.float32) * np.float32(1.0 / _UINT8_MAX)
    if image.ndim == 2:
        # (H, W) -> (H, W, 3): the models were all trained on colour images
        image = np.repeat(image[:, :, None], 3, axis=2)
    return image


def _padding(size: int, multiple: int, side: str) -> tuple[int, int]:
    total = (-size) % multiple
    if side == "after":
        return 0, total
    if side == "before":
        return total, 0
    return total // 2, total - total // 2


def plan_geometry(image_hw: tuple[int, int], spec: StereoSpec,
                  model_size: tuple[int, int] | None) -> Geometry:
    """Resize/pad plan for one image size (``model_size`` is (width, height) or None)."""
    if model_size is not None:
        # Fixed-size models get the image resized to their size; no padding is needed.
        return Geometry(image_hw, (model_size[1], model_size[0]), (0, 0, 0, 0))
    top, bottom = _padding(image_hw[0], spec.pad_multiple, spec.pad_side)
    left, right = _padding(image_hw[1], spec.pad_multiple, spec.pad_side)
    return Geometry(image_hw, image_hw, (top, bottom, left, right))


def _prepare_one(image: np.ndarray, spec: StereoSpec, geometry: Geometry) -> np.ndarray:
    x = image
    if geometry.model_hw != geometry.image_hw:
        x = cv2.resize(x, (geometry.model_hw[1], geometry.model_hw[0]),
                       interpolation=cv2.INTER_LINEAR)
    x = x * np.float32(spec.value_scale)
    if spec.channel_order == "BGR":
        x = x[:, :, ::-1]
    if spec.mean is not None:
        x = x - np.asarray(spec.mean, dtype=np.float32)
    if spec.std is not None:
        x = x / np.asarray(spec.std, dtype=np.float32)
    t, b, left, r = geometry.pad_tblr
    if t or b or left or r:
        if spec.pad_mode == "replicate":
            x = cv2.copyMakeBorder(np.ascontiguousarray(x), t, b, left, r, cv2.BORDER_REPLICATE)
        else:
            x = cv2.copyMakeBorder(np.ascontiguousarray(x), t, b, left, r, cv2.BORDER_CONSTANT,
                                   value=(spec.pad_value,) * 3)
    if spec.layout == "NCHW":
        x = x.transpose(2, 0, 1)  # (H, W, 3) -> (3, H, W)
    return np.ascontiguousarray(x[None], dtype=np.float32)  # add the batch axis


def prepare_pair(left: np.ndarray, right: np.ndarray, spec: StereoSpec,
                 model_size: tuple[int, int] | None) -> tuple[np.ndarray, np.ndarray, Geometry]:
    """Turn a checked (H, W, 3) [0, 1] pair into the two model input tensors."""
    geometry = plan_geometry(left.shape[:2], spec, model_size)
    return _prepare_one(left, spec, geometry), _prepare_one(right, spec, geometry), geometry


def _select_channel(raw: np.ndarray, spec: StereoSpec) -> np.ndarray:
    """(B, C, H, W) / (B, H, W) / (H, W) with B = 1 -> (H, W)."""
    arr = raw
    if arr.ndim == 4:
        if arr.shape[0] != 1:
            raise BackboneError(f"model output: expected batch size 1, got shape {raw.shape}")
        arr = arr[0]
        channels_axis = 2 if spec.layout == "NHWC" else 0
        n_channels = arr.shape[channels_axis]
        if spec.output_channel >= n_channels:
            raise BackboneError(
                f"model output: expected at least {spec.output_channel + 1} channels "
                f"(spec output_channel={spec.output_channel}), got shape {raw.shape}"
            )
        arr = np.take(arr, spec.output_channel, axis=channels_axis)
    elif arr.ndim == 3:
        if arr.shape[0] != 1:
            raise BackboneError(
                f"model output: expected (1, H, W) for a 3-D output, got shape {raw.shape}"
            )
        arr = arr[0]
    elif arr.ndim != 2:
        raise BackboneError(
            f"model output: expected (1, C, H, W), (1, H, W) or (H, W), got shape {raw.shape}"
        )
    return arr


def finish_disparity(raw: Any, spec: StereoSpec, geometry: Geometry) -> np.ndarray:
    """Turn the raw model output into (H, W) float32 disparity at the caller's size."""
    raw = np.asarray(raw)
    if not (np.issubdtype(raw.dtype, np.floating) or np.issubdtype(raw.dtype, np.integer)):
        raise BackboneError(f"model output: expected a numeric array, got dtype {raw.dtype}")
    disp = _select_channel(raw, spec).astype(np.float32)
    factor = np.float32(spec.output_sign * spec.output_scale)
    if factor != 1.0:
        disp = disp * factor
    padded_h, padded_w = geometry.padded_hw
    out_h, out_w = disp.shape
    stride = spec.output_stride
    if stride is None:
        stride = padded_w // out_w if out_w and padded_w % out_w == 0 else 0
    if stride < 1 or out_h * stride != padded_h or out_w * stride != padded_w:
        expected = (f"{padded_w // spec.output_stride}x{padded_h // spec.output_stride}"
                    if spec.output_stride else f"{padded_w}x{padded_h} or an integer fraction")
        raise BackboneError(
            f"model output: expected disparity of size {expected} for an input of "
            f"{padded_w}x{padded_h}, got {out_w}x{out_h} (shape {raw.shape})"
        )
    if stride > 1:
        # Disparity is in output pixels: upsampling by s multiplies it by s.
        disp = cv2.resize(disp, (padded_w, padded_h), interpolation=cv2.INTER_LINEAR)
        disp *= np.float32(stride)
    t, b, left, r = geometry.pad_tblr
    if t or b or left or r:
        disp = disp[t:padded_h - b, left:padded_w - r]
    if geometry.model_hw != geometry.image_hw:
        image_h, image_w = geometry.image_hw
        disp = cv2.resize(disp, (image_w, image_h), interpolation=cv2.INTER_LINEAR)
        disp *= np.float32(image_w / geometry.model_hw[1])
    check_disparity_sign(disp, f"model output ({spec.name})", BackboneError,
                         allow_sentinel=False)
    return np.ascontiguousarray(disp, dtype=np.float32)


class StereoAdapter:
    """Base of the adapters: checks, preprocessing, ``_run``, postprocessing.

    Subclasses set ``spec`` and ``model_size`` and implement ``_run(left, right)``
    returning the raw output selected by ``spec.output``.
    """

    spec: StereoSpec
    model_size: tuple[int, int] | None = None

    def __call__(self, left: Any, right: Any) -> np.ndarray:
        """Disparity of a rectified stereo pair.

        Parameters
        ----------
        left, right : numpy.ndarray, (H, W, 3) or (H, W), uint8 or float in [0, 1]
            Rectified RGB (or grey) images of the left and right camera.

        Returns
        -------
        numpy.ndarray, (H, W), float32, pixels
            Disparity of the left image, positive, at input resolution.

        Raises
        ------
        ImageError
            Wrong image type, dtype, shape or mismatched sizes.
        BackboneError
            The model's output does not fit the spec.
        """
        left01, right01 = check_pair(left, right)
        left_in, right_in, geometry = prepare_pair(left01, right01, self.spec, self.model_size)
        raw = self._run(left_in, right_in)
        return finish_disparity(raw, self.spec, geometry)

    def _run(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError
