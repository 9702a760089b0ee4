"""Stereo models exported to ONNX, run with onnxruntime behind the backbone contract."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from srde_fusion.errors import BackboneError

from ._pipeline import StereoAdapter
from .spec import StereoSpec, preset

__all__ = ["OnnxStereo"]

# onnxruntime type strings of the image inputs we can feed (cast from float32)
_FLOAT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16,
                "tensor(double)": np.float64}
_INT_TYPES = {"tensor(int64)": np.int64, "tensor(int32)": np.int32}


def _static(dim: Any) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


class OnnxStereo(StereoAdapter):
    """An ONNX stereo model as a ``backbone(left, right) -> disparity`` callable.

    What the model file reveals is read once and checked against the spec: the input
    names and count, whether height and width are fixed, the input element type, and the
    number, rank and channel count of the outputs. A mismatch raises
    :class:`~srde_fusion.BackboneError` at construction, not on the first image.

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
                 session_options: Any = None) -> None:
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
        self._inspect_inputs()
        self._inspect_outputs()

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
        if spec.input_names is not None:
            image_names = list(spec.input_names)
            for name in image_names:
                if name not in inputs:
                    raise BackboneError(
                        f"spec.input_names: expected names among the model inputs "
                        f"{list(inputs)}, got {name!r}"
                    )
        else:
            candidates = [n for n in inputs if n not in extra_names]
            if len(candidates) < 2:
                raise BackboneError(
                    f"model inputs: expected two image inputs (left, right), got {list(inputs)}"
                )
            image_names = candidates[:2]
            self._notes.append(f"image inputs taken in model order: {image_names}")
        fed = set(image_names) | set(extra_names)
        missing = [n for n in inputs if n not in fed]
        if missing:
            raise BackboneError(
                f"model inputs: expected every input to be fed, got unfed {missing}; "
                f"name the images in spec.input_names and constants in spec.extra_inputs"
            )
        self.input_names = tuple(image_names)

        channel_axis, h_axis, w_axis = (1, 2, 3) if spec.layout == "NCHW" else (3, 1, 2)
        sizes = []
        for name in image_names:
            info = inputs[name]
            if info.type not in _FLOAT_TYPES:
                raise BackboneError(
                    f"model input {name!r}: expected a float tensor, got {info.type}"
                )
            shape = info.shape
            if len(shape) != 4:
                raise BackboneError(
                    f"model input {name!r}: expected a 4-D {spec.layout} image tensor, "
                    f"got shape {shape}"
                )
            channels = _static(shape[channel_axis])
            if channels is not None and channels != 3:
                raise BackboneError(
                    f"model input {name!r}: expected 3 channels on axis {channel_axis} "
                    f"({spec.layout}), got shape {shape}"
                )
            if channels is None:
                self._unknown.append(f"channel count of input {name!r} (dimension is symbolic)")
            sizes.append((_static(shape[w_axis]), _static(shape[h_axis])))
        self._input_dtype = _FLOAT_TYPES[inputs[image_names[0]].type]
        if sizes[0] != sizes[1]:
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
        if fixed is not None:
            self._notes.append(
                f"fixed input size {fixed[0]}x{fixed[1]}: images are resized to it and "
                f"disparity is rescaled by the width ratio"
            )
        elif spec.input_size is not None:
            self._notes.append(
                f"dynamic model run at spec.input_size {spec.input_size[0]}x{spec.input_size[1]}"
            )
        else:
            self._notes.append(
                f"dynamic height and width: images padded to a multiple of {spec.pad_multiple}"
            )

        self._extra_feed: dict[str, np.ndarray] = {}
        for name, value in spec.extra_inputs:
            info = inputs[name]
            if info.type in _INT_TYPES:
                dtype = _INT_TYPES[info.type]
            elif info.type in _FLOAT_TYPES:
                dtype = _FLOAT_TYPES[info.type]
            else:
                raise BackboneError(
                    f"model input {name!r}: expected an int or float tensor for an extra "
                    f"input, got {info.type}"
                )
            shape = [1 if not isinstance(d, int) else d for d in info.shape]
            self._extra_feed[name] = np.full(shape, value, dtype=dtype)

    def _inspect_outputs(self) -> None:
        spec = self.spec
        outputs = self.session.get_outputs()
        names = [o.name for o in outputs]
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
    def _run(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        feed = {self.input_names[0]: left.astype(self._input_dtype, copy=False),
                self.input_names[1]: right.astype(self._input_dtype, copy=False),
                **self._extra_feed}
        try:
            (raw,) = self.session.run([self.output_name], feed)
        # onnxruntime raises its own exception types (Fail, InvalidArgument, RuntimeException)
        # from the model's graph; the caller gets the one contract's error, naming the model.
        except Exception as exc:
            raise BackboneError(
                f"{self.spec.name} model: expected onnxruntime to run it on inputs of shape "
                f"{tuple(left.shape)}, got {type(exc).__name__}: {str(exc).strip()[:500]}"
            ) from exc
        return raw

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
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"OnnxStereo({str(self.path)!r}, spec={self.spec.name!r})"
