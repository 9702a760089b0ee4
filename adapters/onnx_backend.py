"""Stereo models exported to ONNX, run with onnxruntime behind the backbone contract."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from srde_fusion.errors import BackboneError

from ._pipeline import Geometry, ModelInputs, ModelOutOfMemory, StereoAdapter
from .spec import StereoSpec, preset

__all__ = ["OnnxStereo"]

# onnxruntime type strings of the image inputs we can feed (cast from float32)
_FLOAT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16,
                "tensor(double)": np.float64}
_INT_TYPES = {"tensor(int64)": np.int64, "tensor(int32)": np.int32}
# Words of onnxruntime's allocation failures (CPU arena, CUDA, std::bad_alloc)
_OUT_OF_MEMORY_MARKERS = ("failed to allocate", "bad_alloc", "out of memory")
_ASPECT_TOLERANCE = 0.01  # a fixed-size resize changing the aspect ratio by more is reported


def _static(dim: Any) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


class OnnxStereo(StereoAdapter):
    """An ONNX stereo model as a ``backbone(left, right) -> disparity`` callable.

    What the model file reveals is read once and checked against the spec: the input
    names and count, whether height and width are fixed, the input element type and
    channel count (a stacked input with 2 channels is a grey pair), coarse inputs of a
    two-stage export, an initial-flow input (fed zeros), and the number, rank and channel
    count of the outputs. A mismatch raises :class:`~srde_fusion.BackboneError` at
    construction, not on the first image.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.onnx`` file.
    spec_or_preset : StereoSpec or str
        The model's conventions, or a preset name (see :data:`PRESETS`).
    providers : sequence of str
        onnxruntime execution providers, in order of preference.
    session_options : onnxruntime.SessionOptions, optional
        Passed to the inference session (threads, graph optimisation level).
    max_pixels : int, "auto" or None
        Most model-input pixels (after padding) one run may take; larger pairs are run
        as ``large_images`` says (:mod:`.large_images`), and the plan is kept as
        ``last_plan``. ``"auto"``: from ``spec.bytes_per_px`` and half this machine's
        memory, or no limit when the model's memory per pixel is unknown. A run that
        still fails to allocate memory is retried on half the pixels. Fixed-size models
        are fed their own size whatever the image, so no limit applies.
    large_images : {"tile", "downscale"}
        ``"tile"``: strips of full width with overlapping rows (downscaled when even a
        thin strip would not fit); ``"downscale"``: the whole pair shrunk to fit.

    Raises
    ------
    BackboneError
        Missing file, a file that is not an ONNX model, or a model whose inputs or
        outputs do not fit the spec.

    Examples
    --------
    >>> from srde_fusion.adapters import OnnxStereo, default_weights_path
    >>> model = OnnxStereo(default_weights_path(), "igev")
    >>> model.model_size is None  # dynamic height and width
    True
    """

    def __init__(self, path: str | os.PathLike, spec_or_preset: StereoSpec | str = "generic", *,
                 providers: Sequence[str] = ("CPUExecutionProvider",),
                 session_options: Any = None, max_pixels: int | str | None = "auto",
                 large_images: str = "tile") -> None:
        import onnxruntime as ort

        self.spec = preset(spec_or_preset)
        self.path = Path(path)
        available = ort.get_available_providers()
        missing = [p for p in providers if p not in available]
        if missing:
            raise BackboneError(f"providers: expected onnxruntime execution providers this "
                                f"installation has ({', '.join(available)}), got {missing}")
        if not self.path.is_file():
            raise BackboneError(f"model: expected an existing .onnx file, got {str(path)!r}")
        try:
            self.session = ort.InferenceSession(
                str(self.path), sess_options=session_options, providers=list(providers)
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            text = str(exc).strip()
            first_line = text.splitlines()[0] if text else type(exc).__name__
            raise BackboneError(
                f"model: expected an ONNX model file, got {self.path.name!r} that onnxruntime "
                f"cannot load ({first_line[:200]})"
            ) from None
        self._notes: list[str] = []
        self._unknown: list[str] = []
        self._resize_warned: set[tuple[int, int]] = set()
        self._inspect_inputs()
        self._inspect_outputs()
        self._init_large_images(max_pixels, large_images)

    # ------------------------------------------------------------------ inspection
    def _inspect_inputs(self) -> None:
        spec = self.spec
        inputs = {i.name: i for i in self.session.get_inputs()}
        extra_names = [name for name, _ in spec.extra_inputs]
        for name in extra_names:
            if name not in inputs:
                raise BackboneError(
                    f"spec.extra_inputs: expected names among the model inputs "
                    f"{list(inputs)}, got {name!r}"
                )
        coarse_names = self._inspect_coarse(inputs)
        flow_name = spec.flow_init if spec.flow_init in inputs else None
        if flow_name is not None and self.uses_coarse:
            raise BackboneError(
                f"model inputs: expected either coarse inputs {list(coarse_names)} or a "
                f"{flow_name!r} input, got both in {list(inputs)}"
            )
        n_images = 1 if spec.input_mode == "stacked" else 2
        reserved = set(extra_names) | set(coarse_names) | {flow_name}
        if spec.input_names is not None:
            image_names = list(spec.input_names)
            for name in image_names:
                if name not in inputs:
                    raise BackboneError(
                        f"spec.input_names: expected names among the model inputs "
                        f"{list(inputs)}, got {name!r}"
                    )
        else:
            candidates = [n for n in inputs if n not in reserved]
            if len(candidates) < n_images:
                wanted = ("one stacked image input" if n_images == 1
                          else "two image inputs (left, right)")
                raise BackboneError(f"model inputs: expected {wanted}, got {list(inputs)}")
            image_names = candidates[:n_images]
            self._notes.append(f"image inputs taken in model order: {image_names}")
        fed = set(image_names) | reserved
        missing = [n for n in inputs if n not in fed]
        if missing:
            raise BackboneError(
                f"model inputs: expected every input to be fed, got unfed {missing}; "
                f"name the images in spec.input_names and constants in spec.extra_inputs"
            )
        self.input_names = tuple(image_names)
        self._check_channels(inputs, image_names)

        _, h_axis, w_axis = self._axes()
        sizes = [(_static(inputs[n].shape[w_axis]), _static(inputs[n].shape[h_axis]))
                 for n in image_names]
        self._input_dtype = _FLOAT_TYPES[inputs[image_names[0]].type]
        if len(set(sizes)) != 1:
            raise BackboneError(
                f"model inputs: expected left and right of the same size, got {sizes[0]} "
                f"and {sizes[1]}"
            )
        width, height = sizes[0]
        if (width is None) != (height is None):
            raise BackboneError(
                f"model inputs: expected both height and width fixed or both dynamic, "
                f"got shape {inputs[image_names[0]].shape}"
            )
        fixed = (width, height) if width is not None else None
        if spec.input_size is not None and fixed is not None and spec.input_size != fixed:
            raise BackboneError(
                f"spec.input_size: expected the model's fixed size {fixed[0]}x{fixed[1]}, "
                f"got {spec.input_size[0]}x{spec.input_size[1]}"
            )
        self.model_size = fixed or spec.input_size
        self.pad_multiple = spec.pad_multiple
        if self.model_size is not None:
            origin = ("fixed input size" if fixed is not None
                      else "dynamic model run at spec.input_size")
            self._notes.append(
                f"{origin} {self.model_size[0]}x{self.model_size[1]}: images are resized to "
                f"it (both axes, each by its own ratio) and disparity is rescaled by the width "
                f"ratio; spec.pad_multiple ({spec.pad_multiple}) is not applied"
            )
        else:
            if self.uses_coarse:
                # the coarse pair (1/coarse_factor) must be a multiple of pad_multiple too
                self.pad_multiple = spec.pad_multiple * spec.coarse_factor
            self._notes.append(
                f"dynamic height and width: images padded to a multiple of {self.pad_multiple}"
                + ("" if spec.pad_multiple > 1 else
                   " (no padding: a model that needs sizes divisible by 8 or 32 fails on "
                   "other sizes; set pad_multiple or use its preset)")
            )
        self._coarse_feed_names = coarse_names
        self._inspect_coarse_size(inputs)
        self._flow_init = self._inspect_flow_init(inputs, flow_name)
        self._extra_feed = self._extra_feeds(inputs)

    def _axes(self) -> tuple[int, int, int]:
        """Channel, height and width axes of an image input in the spec's layout."""
        return (1, 2, 3) if self.spec.layout == "NCHW" else (3, 1, 2)

    def _inspect_coarse(self, inputs: dict[str, Any]) -> tuple[str, ...]:
        spec = self.spec
        self.uses_coarse = False
        if spec.coarse_input_names is None:
            return ()
        present = [n for n in spec.coarse_input_names if n in inputs]
        if not present:
            if spec.coarse_factor > 1:
                self._notes.append(
                    f"one-stage export (no coarse inputs {list(spec.coarse_input_names)})"
                )
            return ()
        if len(present) != 2:
            raise BackboneError(
                f"spec.coarse_input_names: expected both {list(spec.coarse_input_names)} "
                f"among the model inputs, got only {present} in {list(inputs)}"
            )
        if spec.coarse_factor < 2:
            raise BackboneError(
                f"spec.coarse_factor: expected >= 2 for a model with coarse inputs "
                f"{present}, got {spec.coarse_factor}"
            )
        self.uses_coarse = True
        self._notes.append(
            f"two-stage export: coarse inputs {present} get the pair at "
            f"1/{spec.coarse_factor} size"
        )
        return tuple(spec.coarse_input_names)

    def _inspect_coarse_size(self, inputs: dict[str, Any]) -> None:
        self.coarse_size = None
        if not self.uses_coarse:
            return
        _, h_axis, w_axis = self._axes()
        shape = inputs[self._coarse_feed_names[0]].shape
        width, height = _static(shape[w_axis]), _static(shape[h_axis])
        if width is None or height is None:
            return  # dynamic: 1/coarse_factor of the padded size, on each call
        self.coarse_size = (width, height)
        if self.model_size is None:
            raise BackboneError(
                f"model inputs: expected the coarse inputs to be dynamic like the full-size "
                f"ones, got fixed shape {shape}"
            )

    def _inspect_flow_init(self, inputs: dict[str, Any], name: str | None
                           ) -> tuple[str, list[int | None], type] | None:
        if name is None:
            return None
        info = inputs[name]
        if info.type not in _FLOAT_TYPES or len(info.shape) != 4:
            raise BackboneError(
                f"model input {name!r}: expected a 4-D float flow tensor, got {info.type} "
                f"with shape {info.shape}"
            )
        shape = [_static(d) for d in info.shape]
        channel_axis = self._axes()[0]
        if shape[channel_axis] is None:
            shape[channel_axis] = 2  # a flow field: (dx, dy)
        message = (
            f"model input {name!r} (initial flow) is fed zeros: this export skips the "
            f"coarse stages a two-stage run would give it, so expect coarser disparity"
        )
        self._notes.append(message)
        warnings.warn(f"{self.path.name}: {message}", UserWarning, stacklevel=3)
        return name, shape, _FLOAT_TYPES[info.type]

    def _check_channels(self, inputs: dict[str, Any], image_names: list[str]) -> None:
        spec = self.spec
        channel_axis = self._axes()[0]
        per_image = 2 if spec.input_mode == "stacked" else 1
        for name in image_names:
            info = inputs[name]
            if info.type not in _FLOAT_TYPES:
                raise BackboneError(
                    f"model input {name!r}: expected a float tensor, got {info.type}"
                )
            if len(info.shape) != 4:
                raise BackboneError(
                    f"model input {name!r}: expected a 4-D {spec.layout} image tensor, "
                    f"got shape {info.shape}"
                )
            channels = _static(info.shape[channel_axis])
            if channels is None:
                self._unknown.append(f"channel count of input {name!r} (dimension is symbolic)")
                continue
            if spec.input_mode == "stacked" and channels == 2 and spec.channel_order != "grey":
                # HITNET ships grey exports (1, 2, H, W) beside colour ones (1, 6, H, W)
                self.spec = spec = spec.replace(channel_order="grey")
                self._notes.append(
                    f"input {name!r} has 2 channels: a grey pair (channel_order 'grey')"
                )
            expected = spec.image_channels * per_image
            if channels != expected:
                what = ("left and right stacked" if per_image == 2 else "one image")
                hint = ("" if spec.input_mode == "stacked" or channels not in (2, 6) else
                        "; a model taking both images in one input needs "
                        "input_mode='stacked'")
                if channels == 1 and spec.input_mode == "pair":
                    hint = "; a one-channel model needs channel_order='grey'"
                raise BackboneError(
                    f"model input {name!r}: expected {expected} channels on axis "
                    f"{channel_axis} ({spec.layout}, {what}, {spec.channel_order}), got "
                    f"shape {info.shape}{hint}"
                )

    def _extra_feeds(self, inputs: dict[str, Any]) -> dict[str, np.ndarray]:
        feeds = {}
        for name, value in self.spec.extra_inputs:
            info = inputs[name]
            if info.type == "tensor(bool)":
                dtype: Any = np.bool_
            elif info.type in _INT_TYPES:
                dtype = _INT_TYPES[info.type]
            elif info.type in _FLOAT_TYPES:
                dtype = _FLOAT_TYPES[info.type]
            else:
                raise BackboneError(
                    f"model input {name!r}: expected a bool, int or float tensor for an extra "
                    f"input, got {info.type}"
                )
            shape = [1 if not isinstance(d, int) else d for d in info.shape]
            feeds[name] = np.full(shape, value, dtype=dtype)
        return feeds

    def _inspect_outputs(self) -> None:
        spec = self.spec
        outputs = self.session.get_outputs()
        names = [o.name for o in outputs]
        if isinstance(spec.output, tuple):
            raise BackboneError(
                f"spec.output: expected an index or a name for an ONNX model (its outputs "
                f"are a flat list {names}), got the path {spec.output!r}"
            )
        if isinstance(spec.output, str):
            if spec.output not in names:
                raise BackboneError(
                    f"spec.output: expected one of the model outputs {names}, got {spec.output!r}"
                )
            index = names.index(spec.output)
        else:
            if not -len(names) <= spec.output < len(names):
                raise BackboneError(
                    f"spec.output: expected an index into the {len(names)} model outputs "
                    f"{names}, got {spec.output}"
                )
            index = spec.output % len(names)
        self.output_name = names[index]
        info = outputs[index]
        shape = info.shape
        if shape is not None and len(shape) > 0:
            if not 2 <= len(shape) <= 4:
                raise BackboneError(
                    f"model output {info.name!r}: expected rank 2 to 4 (disparity map), "
                    f"got shape {shape}"
                )
            if len(shape) == 4:
                channel_axis = 3 if spec.layout == "NHWC" else 1
                channels = _static(shape[channel_axis])
                if channels is not None and spec.output_channel >= channels:
                    raise BackboneError(
                        f"model output {info.name!r}: expected at least "
                        f"{spec.output_channel + 1} channels (spec.output_channel="
                        f"{spec.output_channel}), got shape {shape}"
                    )
        else:
            self._unknown.append(f"rank of output {info.name!r}")
        if spec.output_stride is None:
            self._unknown.append(
                "output resolution (stride inferred from the output shape on each call)"
            )
        self._unknown.append("sign and scale of the output (taken from the spec)")
        self._notes.append(f"disparity read from output {info.name!r} with shape {shape}")

    # ------------------------------------------------------------------ running
    def _run(self, inputs: ModelInputs) -> np.ndarray:
        self._warn_anisotropic(inputs.geometry)
        feed = {name: image.astype(self._input_dtype, copy=False)
                for name, image in zip(self.input_names, inputs.images, strict=True)}
        if inputs.coarse is not None:
            pairs = zip(self._coarse_feed_names, inputs.coarse, strict=True)
            feed.update({name: image.astype(self._input_dtype, copy=False)
                         for name, image in pairs})
        if self._flow_init is not None:
            name, shape, dtype = self._flow_init
            padded_h, padded_w = inputs.geometry.padded_hw
            _, h_axis, w_axis = self._axes()
            factor = self.spec.coarse_factor
            full = list(shape)
            full[0] = full[0] or 1
            full[h_axis] = full[h_axis] or padded_h // factor
            full[w_axis] = full[w_axis] or padded_w // factor
            feed[name] = np.zeros(full, dtype=dtype)
        feed.update(self._extra_feed)
        try:
            (raw,) = self.session.run([self.output_name], feed)
        # onnxruntime raises its own exception types (Fail, InvalidArgument, RuntimeException)
        # from the model's graph; the caller gets the one contract's error, naming the model.
        except Exception as exc:
            text = str(exc).strip()
            shape = tuple(inputs.images[0].shape)
            if any(marker in text.lower() for marker in _OUT_OF_MEMORY_MARKERS):
                raise ModelOutOfMemory(
                    f"{self.spec.name} model: expected memory for inputs of shape {shape}, "
                    f"got {type(exc).__name__}: {text[:300]}"
                ) from exc
            hint = ""
            padded_h, padded_w = inputs.geometry.padded_hw
            if self.model_size is None and (padded_h % 32 or padded_w % 32):
                hint = (f"; if the model needs sizes divisible by 8 or 32, set "
                        f"spec.pad_multiple (now {self.spec.pad_multiple}) or use its preset")
            raise BackboneError(
                f"{self.spec.name} model: expected onnxruntime to run it on inputs of shape "
                f"{shape}, got {type(exc).__name__}: {text[:500]}{hint}"
            ) from exc
        return raw

    def _warn_anisotropic(self, geometry: Geometry) -> None:
        """Say once per image size when a fixed-size model distorts the aspect ratio."""
        if self.model_size is None or geometry.image_hw in self._resize_warned:
            return
        self._resize_warned.add(geometry.image_hw)
        (image_h, image_w), (model_h, model_w) = geometry.image_hw, geometry.model_hw
        sx, sy = model_w / image_w, model_h / image_h
        if abs(sx / sy - 1.0) > _ASPECT_TOLERANCE:
            warnings.warn(
                f"{self.path.name}: {image_w}x{image_h} images are resized to the model's "
                f"fixed {model_w}x{model_h} (x by {sx:.3f}, y by {sy:.3f}: the aspect ratio "
                f"changes); disparity is rescaled by the width ratio",
                UserWarning, stacklevel=4,
            )

    def describe(self) -> str:
        """Say what was read from the model file, what the spec supplies, and what is unknown.

        Returns
        -------
        str
            Several lines of plain text.
        """
        lines = [f"OnnxStereo({self.path.name!r})", self.spec.summary(), "inferred from the model:"]
        lines += [f"  {note}" for note in self._notes]
        lines.append("not inferable from the model:")
        lines += [f"  {item}" for item in self._unknown]
        lines.append("runtime:")
        lines += self._runtime_lines()
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"OnnxStereo({str(self.path)!r}, spec={self.spec.name!r})"
