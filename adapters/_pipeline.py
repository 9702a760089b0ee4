"""Pre- and post-processing shared by the ONNX and torch adapters.

Everything a :class:`~srde_fusion.adapters.spec.StereoSpec` declares is applied here, in
numpy/OpenCV, so both runtimes behave identically and the runtime-specific classes only
feed arrays in and hand raw outputs back.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from srde_fusion._checks import check_disparity_sign, check_image
from srde_fusion.errors import BackboneError, ImageError

from .consistency import fill_left_right, mirrored_pair
from .large_images import (
    MEMORY_FRACTION,
    LargeImagePlan,
    check_max_pixels,
    default_max_pixels,
    log_plan,
    machine_memory_bytes,
    plan_large_image,
    run_plan,
)
from .propagation import OFFSETS_PX, census_pair, propagate_disparity
from .segment_planes import SEGMENT_PX, fit_segment_planes
from .spec import StereoSpec

__all__ = ["Geometry", "ModelInputs", "StereoAdapter", "check_pair", "prepare_inputs",
           "prepare_pair", "finish_disparity"]

logger = logging.getLogger(__name__)

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
    coarse_hw : (int, int), optional
        Height and width of the coarse pair of a two-stage model (None: one stage).
    """

    image_hw: tuple[int, int]
    model_hw: tuple[int, int]
    pad_tblr: tuple[int, int, int, int]
    coarse_hw: tuple[int, int] | None = None

    @property
    def padded_hw(self) -> tuple[int, int]:
        """Height and width of the tensor fed to the model."""
        t, b, left, r = self.pad_tblr
        return self.model_hw[0] + t + b, self.model_hw[1] + left + r


@dataclass(frozen=True)
class ModelInputs:
    """The image tensors of one call, in the spec's layout, with their geometry.

    Attributes
    ----------
    images : tuple of numpy.ndarray
        ``(left, right)``, each ``(1, C, H, W)`` (NCHW) float32, or ``(stacked,)`` with
        ``2 C`` channels for ``input_mode="stacked"``.
    coarse : tuple of numpy.ndarray, optional
        ``(left, right)`` at ``geometry.coarse_hw`` for a combined two-stage export.
    geometry : Geometry
    """

    images: tuple[np.ndarray, ...]
    coarse: tuple[np.ndarray, np.ndarray] | None
    geometry: Geometry


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
                  model_size: tuple[int, int] | None, *, pad_multiple: int | None = None,
                  coarse: bool = False,
                  coarse_size: tuple[int, int] | None = None) -> Geometry:
    """Resize/pad plan for one image size.

    ``model_size`` and ``coarse_size`` are ``(width, height)`` of fixed-size inputs or
    None; ``pad_multiple`` overrides the spec's (a two-stage model pads to a multiple of
    ``pad_multiple * coarse_factor`` so that its coarse pair is a multiple too).
    """
    if model_size is not None:
        # Fixed-size models get the image resized to their size; no padding is needed.
        model_hw = (model_size[1], model_size[0])
        pad = (0, 0, 0, 0)
    else:
        multiple = pad_multiple or spec.pad_multiple
        top, bottom = _padding(image_hw[0], multiple, spec.pad_side)
        left, right = _padding(image_hw[1], multiple, spec.pad_side)
        model_hw, pad = image_hw, (top, bottom, left, right)
    geometry = Geometry(image_hw, model_hw, pad)
    if not coarse:
        return geometry
    if coarse_size is not None:
        coarse_hw = (coarse_size[1], coarse_size[0])
    else:
        padded_h, padded_w = geometry.padded_hw
        coarse_hw = (padded_h // spec.coarse_factor, padded_w // spec.coarse_factor)
    return Geometry(image_hw, model_hw, pad, coarse_hw)


def _prepare_hwc(image: np.ndarray, spec: StereoSpec, geometry: Geometry) -> np.ndarray:
    """(H, W, 3) [0, 1] -> (H', W', C) float32 in the model's values, resized and padded."""
    x = image
    if geometry.model_hw != geometry.image_hw:
        x = cv2.resize(x, (geometry.model_hw[1], geometry.model_hw[0]),
                       interpolation=cv2.INTER_LINEAR)
    x = x * np.float32(spec.value_scale)
    if spec.channel_order == "BGR":
        x = x[:, :, ::-1]
    elif spec.channel_order == "grey":
        # (H, W, 3) -> (H, W, 1), BT.601 luminance as OpenCV's RGB2GRAY computes it
        x = cv2.cvtColor(np.ascontiguousarray(x), cv2.COLOR_RGB2GRAY)[:, :, None]
    channels = x.shape[2]
    if spec.mean is not None:
        x = x - np.asarray(spec.mean[:channels], dtype=np.float32)
    if spec.std is not None:
        x = x / np.asarray(spec.std[:channels], dtype=np.float32)
    t, b, left, r = geometry.pad_tblr
    if t or b or left or r:
        x = np.ascontiguousarray(x)
        if spec.pad_mode == "replicate":
            x = cv2.copyMakeBorder(x, t, b, left, r, cv2.BORDER_REPLICATE)
        else:
            x = cv2.copyMakeBorder(x, t, b, left, r, cv2.BORDER_CONSTANT,
                                   value=(spec.pad_value,) * 4)
        if x.ndim == 2:  # OpenCV drops a single channel axis
            x = x[:, :, None]
    return x


def _to_layout(x: np.ndarray, spec: StereoSpec) -> np.ndarray:
    if spec.layout == "NCHW":
        x = x.transpose(2, 0, 1)  # (H, W, C) -> (C, H, W)
    return np.ascontiguousarray(x[None], dtype=np.float32)  # add the batch axis


def _shrink(x: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    small = cv2.resize(x, (hw[1], hw[0]), interpolation=cv2.INTER_LINEAR)
    return small[:, :, None] if small.ndim == 2 else small


def prepare_inputs(left: np.ndarray, right: np.ndarray, spec: StereoSpec,
                   model_size: tuple[int, int] | None, *, pad_multiple: int | None = None,
                   coarse: bool = False,
                   coarse_size: tuple[int, int] | None = None) -> ModelInputs:
    """Turn a checked (H, W, 3) [0, 1] pair into the model's input tensors.

    The coarse pair of a two-stage model is the prepared full-size pair resized
    bilinearly to ``coarse_hw``, as the published CREStereo exports are fed.
    """
    geometry = plan_geometry(left.shape[:2], spec, model_size, pad_multiple=pad_multiple,
                             coarse=coarse, coarse_size=coarse_size)
    if spec.input_mode == "stacked":
        # left then right along the channels: (H, W, C) x 2 -> (H, W, 2C)
        stacked = np.concatenate([_prepare_hwc(left, spec, geometry),
                                  _prepare_hwc(right, spec, geometry)], axis=2)
        return ModelInputs((_to_layout(stacked, spec),), None, geometry)
    images, coarse = [], []
    for image in (left, right):  # one at a time: a single full-size temporary alive
        hwc = _prepare_hwc(image, spec, geometry)
        if geometry.coarse_hw is not None:
            coarse.append(_to_layout(_shrink(hwc, geometry.coarse_hw), spec))
        images.append(_to_layout(hwc, spec))
    coarse_pair = (coarse[0], coarse[1]) if coarse else None
    return ModelInputs((images[0], images[1]), coarse_pair, geometry)


def prepare_pair(left: np.ndarray, right: np.ndarray, spec: StereoSpec,
                 model_size: tuple[int, int] | None) -> tuple[np.ndarray, np.ndarray, Geometry]:
    """Turn a checked (H, W, 3) [0, 1] pair into the two model input tensors."""
    inputs = prepare_inputs(left, right, spec, model_size)
    if len(inputs.images) != 2:
        raise BackboneError(f"prepare_pair: expected input_mode='pair', got "
                            f"{spec.input_mode!r}")
    return inputs.images[0], inputs.images[1], inputs.geometry


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


class ModelOutOfMemory(BackboneError):
    """The runtime could not allocate memory for one model call (retried smaller)."""


# Retry a call that ran out of memory at half the pixels, at most this many times.
_OUT_OF_MEMORY_RETRIES = 4


class StereoAdapter:
    """Base of the adapters: checks, large-image plan, preprocessing, ``_run``, postprocessing.

    Subclasses set ``spec``, ``model_size``, ``pad_multiple`` (the multiple actually
    applied), ``coarse_size`` and ``uses_coarse`` (a combined two-stage model), call
    ``_init_large_images`` and implement ``_run(inputs)`` returning the raw output selected
    by ``spec.output``; a runtime allocation failure there raises
    :class:`ModelOutOfMemory`, and the call is retried on fewer pixels.
    """

    spec: StereoSpec
    model_size: tuple[int, int] | None = None
    pad_multiple: int = 1
    uses_coarse: bool = False
    coarse_size: tuple[int, int] | None = None
    max_pixels: int | None = None
    large_images: str = "tile"
    #: How the last call was run (whole, in strips, or downscaled), and why.
    last_plan: LargeImagePlan | None = None
    #: Share of the pixels the left-right check replaced in the last call (None: no check).
    last_filled_fraction: float | None = None
    #: Share of the pixels census propagation changed in the last call (None: not run).
    last_propagated_fraction: float | None = None
    #: Share of the pixels segment planes changed in the last call (None: not run).
    last_planes_fraction: float | None = None

    def _init_large_images(self, max_pixels: Any, large_images: Any,
                           memory_bytes: int | None = None) -> None:
        if isinstance(max_pixels, str) and max_pixels == "auto":
            max_pixels = default_max_pixels(self.spec.bytes_per_px, memory_bytes)
            self._max_pixels_source = (
                f"max_pixels {max_pixels:,} from {self.spec.bytes_per_px:g} B/px and "
                f"{MEMORY_FRACTION:.0%} of {memory_bytes or machine_memory_bytes() or 0:,} B"
                if max_pixels is not None
                else "max_pixels: none (memory per pixel of this model unknown; set "
                     "max_pixels or spec.bytes_per_px to bound it)"
            )
        else:
            self._max_pixels_source = (
                f"max_pixels {max_pixels:,} (given)" if isinstance(max_pixels, int)
                else f"max_pixels {max_pixels!r} (given)"
            )
        self.max_pixels, self.large_images = check_max_pixels(max_pixels, large_images)

    def __call__(self, left: Any, right: Any) -> np.ndarray:
        """Disparity of a rectified stereo pair.

        Parameters
        ----------
        left, right : numpy.ndarray, (H, W, 3) or (H, W), uint8 or float in [0, 1]
            Rectified RGB (or grey) images of the left and right camera.

        Returns
        -------
        numpy.ndarray, (H, W), float32, pixels
            Disparity of the left image, positive, at input resolution. With
            ``spec.left_right_check`` the model also runs on the mirrored pair; the pixels
            the right view contradicts hold the background fill, the others the mean of
            both views (:func:`~.consistency.fill_left_right`); ``last_filled_fraction``
            says how many were filled. With ``spec.census_propagation`` a pixel then
            takes a neighbour's disparity where the images match it clearly better
            (:func:`~.propagation.propagate_disparity`); ``last_propagated_fraction``
            says how many did. With ``spec.segment_planes`` a pixel last takes its
            colour segment's plane where the images do not prefer its own value
            (:func:`~.segment_planes.fit_segment_planes`); ``last_planes_fraction`` says
            how many did.

        Raises
        ------
        ImageError
            Wrong image type, dtype, shape or mismatched sizes.
        BackboneError
            The model's output does not fit the spec, or the model fails.
        """
        left01, right01 = check_pair(left, right)
        disparity_px = self._planned(left01, right01)
        if self.spec.left_right_check:
            right_px = self._planned(*mirrored_pair(left01, right01))[:, ::-1]
            checked = fill_left_right(disparity_px, right_px,
                                      max_diff_px=self.spec.left_right_max_diff_px)
            self.last_filled_fraction = checked.filled_fraction
            disparity_px = checked.disparity_px
        # Both image stages read the pair's census: computed once.
        census = (census_pair(left01, right01)
                  if self.spec.census_propagation or self.spec.segment_planes else None)
        if self.spec.census_propagation:
            propagated = propagate_disparity(left01, right01, disparity_px, census=census)
            self.last_propagated_fraction = propagated.changed_fraction
            disparity_px = propagated.disparity_px
        if self.spec.segment_planes:
            planes = fit_segment_planes(left01, right01, disparity_px, census=census)
            self.last_planes_fraction = planes.changed_fraction
            disparity_px = planes.disparity_px
        return disparity_px

    def _planned(self, left01: np.ndarray, right01: np.ndarray) -> np.ndarray:
        """Run the model on one checked pair: whole, in strips or downscaled."""
        max_pixels = self.max_pixels
        failure: ModelOutOfMemory | None = None
        for _ in range(_OUT_OF_MEMORY_RETRIES + 1):
            plan = plan_large_image(left01.shape[:2], max_pixels, multiple=self.pad_multiple,
                                    strategy=self.large_images,
                                    fixed_size=self.model_size is not None)
            try:
                disparity_px = run_plan(plan, left01, right01, self._disparity)
            except ModelOutOfMemory as exc:
                run_pixels = _padded_pixels(plan.run_hw, self.pad_multiple)
                if self.model_size is not None or run_pixels <= self.pad_multiple**2:
                    raise  # a fixed-size model (or one block) cannot be fed fewer pixels
                max_pixels = run_pixels // 2
                logger.warning("%s; retrying with max_pixels %s", exc, f"{max_pixels:,}")
                failure = exc
                continue
            if max_pixels != self.max_pixels:
                plan = replace(plan, reason=f"{plan.reason} (after running out of memory "
                                            f"with more pixels)")
            self.last_plan = plan
            log_plan(plan, self.spec.name)
            return disparity_px
        raise BackboneError(
            f"{self.spec.name} model: expected it to run within memory, got allocation "
            f"failures down to max_pixels {max_pixels:,} (last: {failure})"
        ) from failure

    def _disparity(self, left01: np.ndarray, right01: np.ndarray) -> np.ndarray:
        """Run the model on one checked (sub)pair: prepare, run, finish."""
        inputs = prepare_inputs(left01, right01, self.spec, self.model_size,
                                pad_multiple=self.pad_multiple, coarse=self.uses_coarse,
                                coarse_size=self.coarse_size)
        raw = self._run(inputs)
        return finish_disparity(raw, self.spec, inputs.geometry)

    def _runtime_lines(self) -> list[str]:
        """List the runtime settings for ``describe()``: large images, left-right check."""
        spec = self.spec
        check = (f"  left-right check: on (the mirrored pair too, so two runs per pair; pixels "
                 f"off by more than {spec.left_right_max_diff_px:g} px or matched outside "
                 f"the right image take the row's background, the others the mean of both "
                 f"views)" if spec.left_right_check
                 else "  left-right check: off")
        propagation = ("  census propagation: on (a pixel takes its own best census match "
                       "where the right view confirms it, or a neighbour's disparity, "
                       f"{'/'.join(map(str, OFFSETS_PX))} px along its row or column, where "
                       "the census cost is clearly lower)" if spec.census_propagation
                       else "  census propagation: off")
        planes = (f"  segment planes: on (a pixel takes the robust plane of its colour segment, "
                  f"about {SEGMENT_PX} px across, where the segment is planar and the census "
                  f"cost does not prefer its own value)" if spec.segment_planes
                  else "  segment planes: off")
        return [*self._large_image_lines(), check, propagation, planes]

    def _large_image_lines(self) -> list[str]:
        if self.model_size is not None:
            return ["  large images: none (fixed-size model, its input size is the same for "
                    "every image)"]
        return [f"  large images: {self._max_pixels_source}; beyond it: "
                f"{'strips of full width' if self.large_images == 'tile' else 'downscale'}"]

    def _run(self, inputs: ModelInputs) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


def _padded_pixels(hw: tuple[int, int], multiple: int) -> int:
    return (hw[0] + (-hw[0]) % multiple) * (hw[1] + (-hw[1]) % multiple)
