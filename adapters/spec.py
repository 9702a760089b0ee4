"""Declared input/output conventions of a stereo model (:class:`StereoSpec`) and presets.

A stereo network is more than its weights: it expects a channel order, a value range, a
size divisible by some stride, and it returns disparity with its own sign, channel and
resolution. :class:`StereoSpec` writes those conventions down as data, so an adapter can
undo every quirk and return the one backbone contract of the library: an ``(H, W)``
float32 map of positive disparity in pixels at input resolution.

The presets follow the published inference code of each model family (see
:data:`PRESETS`). All of them take RGB (or BGR) values in 0..255 as ``(B, 3, H, W)``
float32 and normalise inside the network.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal

from srde_fusion.errors import BackboneError

__all__ = ["StereoSpec", "PRESETS", "preset"]

ChannelOrder = Literal["RGB", "BGR"]
Layout = Literal["NCHW", "NHWC"]
PadMode = Literal["replicate", "constant"]
PadSide = Literal["both", "after", "before"]
CallStyle = Literal["positional", "keywords", "dict"]

_CHANNEL_ORDERS = ("RGB", "BGR")
_LAYOUTS = ("NCHW", "NHWC")
_PAD_MODES = ("replicate", "constant")
_PAD_SIDES = ("both", "after", "before")
_CALL_STYLES = ("positional", "keywords", "dict")


def _as_triple(value: Any, name: str) -> tuple[float, float, float] | None:
    if value is None:
        return None
    try:
        triple = tuple(float(v) for v in value)
    except TypeError:
        triple = (float(value),) * 3
    if len(triple) != 3:
        raise BackboneError(f"{name}: expected 3 numbers (one per channel), got {value!r}")
    return triple


@dataclass(frozen=True)
class StereoSpec:
    """How a stereo model wants its images and how its disparity must be read.

    Preprocessing runs in this order: image to float32 in [0, 1]; times ``value_scale``;
    channel order; ``(x - mean) / std`` per channel (if given, in the model's channel
    order); resize to ``input_size`` for fixed-size models, otherwise pad to a multiple
    of ``pad_multiple``; layout. Postprocessing undoes it: select ``output`` and
    ``output_channel``; times ``output_sign * output_scale``; upsample low-resolution
    outputs bilinearly and multiply by the factor; remove the padding; for fixed-size
    models resize back and multiply by the width ratio.

    Parameters
    ----------
    name : str
        Label shown by ``describe()``.
    input_names : tuple of str, optional
        Names of the (left, right) image inputs. ``None``: the model's first two inputs
        that are not extra inputs, in order. For torch modules called with
        ``call="keywords"`` or ``"dict"`` they are the argument names or dict keys.
    call : {"positional", "keywords", "dict"}
        How a torch module is called: ``module(left, right, *extras)``,
        ``module(**{names: tensors, **extras})``, or ``module({names: tensors, **extras})``.
        ONNX models always take named inputs.
    channel_order : {"RGB", "BGR"}
        Channel order the model was trained with (CREStereo's original code feeds BGR).
    value_scale : float
        Images in [0, 1] are multiplied by this (255 for the published models).
    mean, std : (float, float, float), optional
        Per-channel normalisation applied after scaling, in the model's channel order.
    layout : {"NCHW", "NHWC"}
        Tensor layout of the image inputs (and of 4-D outputs).
    pad_multiple : int
        Pad height and width up to a multiple of this (1 = no padding).
    pad_mode : {"replicate", "constant"}
        Border handling of the padding.
    pad_value : float
        Fill value for ``pad_mode="constant"``, in the model's value range.
    pad_side : {"both", "after", "before"}
        ``"both"`` splits the padding between top/bottom and left/right as the
        ``InputPadder`` of RAFT-Stereo and IGEV does; ``"after"`` pads bottom/right;
        ``"before"`` pads top/left. The padding is cropped off the output.
    extra_inputs : mapping or tuple of (str, int or float)
        Constant inputs the model needs besides the images, such as an iteration count.
        Integers are fed as int64 scalars, floats as float32 scalars.
    output : int or str
        Which output holds disparity: an index into the outputs (negative counts from
        the end; ``-1`` is the last element of a tuple/list) or an output name / dict key.
    output_channel : int
        Channel of a multi-channel output (CREStereo: channel 0 of its 2-channel flow).
    output_sign : {1.0, -1.0}
        ``-1`` for models that return negative horizontal flow (RAFT-Stereo).
    output_scale : float
        Multiplies the output after the sign (e.g. for fixed-point outputs).
    output_stride : int, optional
        Resolution factor of the output relative to the model input. ``None``: inferred
        from the output shape at run time (it must be an integer factor in both axes).
    input_size : (int, int), optional
        ``(width, height)`` of a fixed-size model. ``None``: taken from the model when it
        has fixed dimensions, otherwise the model is run at the (padded) input size.

    Examples
    --------
    >>> spec = StereoSpec(name="mine", pad_multiple=16, output_sign=-1.0)
    >>> spec.pad_multiple, spec.output_sign
    (16, -1.0)
    >>> preset("raft-stereo").output_sign
    -1.0
    """

    name: str = "generic"
    input_names: tuple[str, str] | None = None
    call: CallStyle = "positional"
    channel_order: ChannelOrder = "RGB"
    value_scale: float = 255.0
    mean: tuple[float, float, float] | None = None
    std: tuple[float, float, float] | None = None
    layout: Layout = "NCHW"
    pad_multiple: int = 1
    pad_mode: PadMode = "replicate"
    pad_value: float = 0.0
    pad_side: PadSide = "both"
    extra_inputs: tuple[tuple[str, int | float], ...] = field(default=())
    output: int | str = -1
    output_channel: int = 0
    output_sign: float = 1.0
    output_scale: float = 1.0
    output_stride: int | None = None
    input_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalise fields once, here
        if self.input_names is not None:
            names = tuple(self.input_names)
            if len(names) != 2 or not all(isinstance(n, str) and n for n in names):
                raise BackboneError(
                    f"input_names: expected two names (left, right), got {self.input_names!r}"
                )
            set_(self, "input_names", names)
        for attr, allowed in (
            ("call", _CALL_STYLES),
            ("channel_order", _CHANNEL_ORDERS),
            ("layout", _LAYOUTS),
            ("pad_mode", _PAD_MODES),
            ("pad_side", _PAD_SIDES),
        ):
            if getattr(self, attr) not in allowed:
                raise BackboneError(
                    f"{attr}: expected one of {', '.join(allowed)}, got {getattr(self, attr)!r}"
                )
        if not (isinstance(self.pad_multiple, int) and self.pad_multiple >= 1):
            raise BackboneError(
                f"pad_multiple: expected an integer >= 1, got {self.pad_multiple!r}"
            )
        if not self.value_scale > 0:
            raise BackboneError(
                f"value_scale: expected a positive number, got {self.value_scale!r}"
            )
        set_(self, "mean", _as_triple(self.mean, "mean"))
        std = _as_triple(self.std, "std")
        if std is not None and min(std) <= 0:
            raise BackboneError(f"std: expected positive numbers, got {self.std!r}")
        set_(self, "std", std)
        extras = self.extra_inputs
        if isinstance(extras, Mapping):
            extras = tuple(extras.items())
        try:
            extras = tuple((str(k), v) for k, v in extras)
        except (TypeError, ValueError):
            raise BackboneError(
                f"extra_inputs: expected a mapping or pairs of (name, number), got {extras!r}"
            ) from None
        for key, value in extras:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise BackboneError(
                    f"extra_inputs[{key!r}]: expected an int or float constant, got {value!r}"
                )
        set_(self, "extra_inputs", extras)
        if isinstance(self.output, bool) or not isinstance(self.output, (int, str)):
            raise BackboneError(f"output: expected an index or a name, got {self.output!r}")
        if not (isinstance(self.output_channel, int) and self.output_channel >= 0):
            raise BackboneError(
                f"output_channel: expected an integer >= 0, got {self.output_channel!r}"
            )
        if self.output_sign not in (1.0, -1.0):
            raise BackboneError(f"output_sign: expected 1 or -1, got {self.output_sign!r}")
        set_(self, "output_sign", float(self.output_sign))
        if not self.output_scale > 0:
            raise BackboneError(
                f"output_scale: expected a positive number, got {self.output_scale!r}"
            )
        if self.output_stride is not None and not (
            isinstance(self.output_stride, int) and self.output_stride >= 1
        ):
            raise BackboneError(
                f"output_stride: expected None or an integer >= 1, got {self.output_stride!r}"
            )
        if self.input_size is not None:
            size = tuple(self.input_size)
            if len(size) != 2 or not all(isinstance(s, int) and s >= 2 for s in size):
                raise BackboneError(
                    f"input_size: expected (width, height) as two integers >= 2, "
                    f"got {self.input_size!r}"
                )
            set_(self, "input_size", size)

    def replace(self, **changes: Any) -> StereoSpec:
        """Return a copy with some fields changed (and validated again)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise BackboneError(
                f"StereoSpec: expected field names, got unknown {', '.join(sorted(unknown))}"
            )
        return replace(self, **changes)

    def summary(self) -> str:
        """One line per non-default field, for ``describe()`` and logs."""
        default = StereoSpec()
        lines = [f"spec {self.name!r}:"]
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "name" and value != getattr(default, f.name):
                lines.append(f"  {f.name} = {value!r}")
        if len(lines) == 1:
            lines.append("  (all defaults)")
        return "\n".join(lines)


#: Conventions of the published model families, from their inference code.
#:
#: - ``"igev"`` / ``"igev++"``: RGB 0..255, ``InputPadder(divis_by=32)`` (replicate, split
#:   on both sides), output ``(B, 1, H, W)`` positive disparity.
#: - ``"raft-stereo"``: as IGEV, but the model returns ``(flow_low, flow_up)`` and the
#:   flow is *negative* horizontal displacement (its demo saves ``-flow_up``).
#: - ``"crestereo"``: BGR 0..255 (the original test script reads with ``cv2.imread``),
#:   sizes divisible by 8, output ``(B, 2, H, W)`` flow whose channel 0 is *positive*
#:   disparity (its training loss compares it with ``concat([disp, 0])``). Exports are
#:   usually fixed-size; the original script resizes and rescales by the width ratio.
#: - ``"nmrf"``: RGB 0..255, divisible by 8, called with a dict ``{"img1", "img2"}`` and
#:   returning a dict whose key ``"disp"`` holds ``(B, H, W)`` positive disparity.
#: - ``"foundationstereo"``: RGB 0..255, divisible by 32, first output ``(B, 1, H, W)``
#:   positive disparity (some exports add a confidence output after it); usually exported
#:   at a fixed size, which is read from the ONNX model.
#: - ``"generic"``: RGB 0..255, no padding, last output, positive disparity.
PRESETS: dict[str, StereoSpec] = {
    "generic": StereoSpec(name="generic"),
    "igev": StereoSpec(name="igev", pad_multiple=32),
    "igev++": StereoSpec(name="igev++", pad_multiple=32),
    "raft-stereo": StereoSpec(name="raft-stereo", pad_multiple=32, output=-1, output_sign=-1.0),
    "crestereo": StereoSpec(
        name="crestereo", channel_order="BGR", pad_multiple=8, output=0, output_channel=0
    ),
    "nmrf": StereoSpec(
        name="nmrf", input_names=("img1", "img2"), call="dict", pad_multiple=8, output="disp"
    ),
    "foundationstereo": StereoSpec(name="foundationstereo", pad_multiple=32, output=0),
}


def preset(name: str | StereoSpec) -> StereoSpec:
    """Return the :class:`StereoSpec` of a model family (a spec is returned unchanged).

    Parameters
    ----------
    name : str or StereoSpec
        One of the keys of :data:`PRESETS` (case-insensitive).

    Returns
    -------
    StereoSpec

    Raises
    ------
    BackboneError
        Unknown preset name.

    Examples
    --------
    >>> preset("CREStereo").channel_order
    'BGR'
    """
    if isinstance(name, StereoSpec):
        return name
    if not isinstance(name, str):
        raise BackboneError(
            f"spec: expected a StereoSpec or a preset name, got {type(name).__name__}"
        )
    key = name.strip().lower()
    if key not in PRESETS:
        raise BackboneError(
            f"spec: expected one of the presets {', '.join(PRESETS)}, got {name!r}"
        )
    return PRESETS[key]
