"""Declared input/output conventions of a stereo model (:class:`StereoSpec`) and presets.

A stereo network is more than its weights: it expects a channel order, a value range, a
size divisible by some stride, and it returns disparity with its own sign, channel and
resolution. :class:`StereoSpec` writes those conventions down as data, so an adapter can
undo every quirk and return the one backbone contract of the library: an ``(H, W)``
float32 map of positive disparity in pixels at input resolution.

The presets follow the published inference code of each model family as users hold
it -- the torch module with its forward signature (``iters``, ``test_mode``, nested
outputs) and its usual ONNX exports (fixed or dynamic size, two-stage CREStereo, stacked
HITNET input); see :data:`PRESETS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal

from srde_fusion.errors import BackboneError

__all__ = ["StereoSpec", "PRESETS", "preset"]

ChannelOrder = Literal["RGB", "BGR", "grey"]
Layout = Literal["NCHW", "NHWC"]
PadMode = Literal["replicate", "constant"]
PadSide = Literal["both", "after", "before"]
CallStyle = Literal["positional", "keywords", "dict"]
InputMode = Literal["pair", "stacked"]

_CHANNEL_ORDERS = ("RGB", "BGR", "grey")
_LAYOUTS = ("NCHW", "NHWC")
_PAD_MODES = ("replicate", "constant")
_PAD_SIDES = ("both", "after", "before")
_CALL_STYLES = ("positional", "keywords", "dict")
_INPUT_MODES = ("pair", "stacked")
# Python values a torch forward keyword may take (iters=32, test_mode=True, a mode name)
_KWARG_TYPES = (bool, int, float, str, type(None))


def _pairs(value: Any, name: str) -> tuple[tuple[str, Any], ...]:
    """Turn a mapping or (name, value) pairs into a tuple of pairs (hashable, frozen)."""
    if isinstance(value, Mapping):
        value = tuple(value.items())
    try:
        return tuple((str(k), v) for k, v in value)
    except (TypeError, ValueError):
        raise BackboneError(
            f"{name}: expected a mapping or pairs of (name, value), got {value!r}"
        ) from None


def _output_key_ok(key: Any) -> bool:
    return isinstance(key, str) or (isinstance(key, int) and not isinstance(key, bool))


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
    channel order (or luminance for ``"grey"``); ``(x - mean) / std`` per channel (if
    given, in the model's channel order); resize to ``input_size`` for fixed-size models,
    otherwise pad to a multiple of ``pad_multiple``; layout; for ``input_mode="stacked"``
    left and right concatenated along the channel axis. Postprocessing undoes it: select
    ``output`` and ``output_channel``; times ``output_sign * output_scale``; upsample
    low-resolution outputs bilinearly and multiply by the factor; remove the padding; for
    fixed-size models resize back and multiply by the width ratio.

    Parameters
    ----------
    name : str
        Label shown by ``describe()``.
    input_names : tuple of str, optional
        Names of the (left, right) image inputs (one name for ``input_mode="stacked"``).
        ``None``: the model's first inputs that are neither extra nor coarse inputs, in
        order. For torch modules called with ``call="keywords"`` or ``"dict"`` they are
        the argument names or dict keys.
    input_mode : {"pair", "stacked"}
        ``"pair"``: left and right are two inputs. ``"stacked"``: one input holding left
        then right along the channel axis (HITNET: ``(1, 6, H, W)``, or ``(1, 2, H, W)``
        with ``channel_order="grey"``).
    call : {"positional", "keywords", "dict"}
        How a torch module is called: ``module(left, right, *extras)``,
        ``module(**{names: tensors, **extras})``, or ``module({names: tensors, **extras})``.
        ONNX models always take named inputs.
    channel_order : {"RGB", "BGR", "grey"}
        Channel order the model was trained with (CREStereo's original code feeds BGR);
        ``"grey"``: one luminance channel (ITU-R BT.601 weights, as OpenCV's RGB2GRAY).
    value_scale : float
        Images in [0, 1] are multiplied by this (255 for the published models).
    mean, std : (float, float, float), optional
        Per-channel normalisation applied after scaling, in the model's channel order
        (a grey model uses the first value).
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
    extra_inputs : mapping or tuple of (str, bool, int or float)
        Constant inputs the model needs besides the images, such as an iteration count:
        inputs of an ONNX model (fed in the input's own element type and shape), keyword
        arguments of a torch module.
    forward_kwargs : mapping or tuple of (str, value)
        Keyword arguments of a torch module's ``forward`` that are not inputs of its ONNX
        exports (those bake them in): ``iters=32``, ``test_mode=True``. Values are bools,
        numbers, strings or None. Ignored by ONNX models.
    output : int, str or tuple of int/str
        Which output holds disparity: an index into the outputs (negative counts from
        the end; ``-1`` is the last element of a tuple/list) or an output name / dict key.
        A torch module's nested output takes a path, ``(1, -1)`` = the last element of
        the second output. A torch selection that is itself a list of predictions (an
        iterative model outside ``test_mode``) gives its last, final element.
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
    coarse_factor : int
        Two-stage models (CREStereo): the pair is also run at ``1/coarse_factor`` size
        and that coarse prediction initialises the full-size one. 1 = one stage.
    coarse_input_names : tuple of str, optional
        ONNX exports that hold both stages (CREStereo's combined export): the names of
        the coarse (left, right) inputs, fed the pair at ``1/coarse_factor`` size. Used
        when the model has them; the full-size pair then goes to the other inputs.
    flow_init : str, optional
        Name of the input (ONNX) or forward keyword (torch) taking an initial flow at
        ``1/coarse_factor`` resolution. A torch module with ``coarse_factor > 1`` gets the
        coarse pass's output there (the two-stage call of CREStereo's demo); an ONNX model
        with that input and no coarse inputs gets zeros of its shape (with a warning: its
        coarse stages are skipped).
    bytes_per_px : float, optional
        Peak memory of one run per input pixel, if measured (the bundled stand-in: about
        680 B/px on CPU). Sets the adapters' default ``max_pixels``; ``None``: unknown.
    left_right_check : bool
        Also run the mirrored pair to get the right view's disparity; average the left
        disparities it confirms (within ``left_right_max_diff_px``) with it, and replace
        those it contradicts or that point outside the right image by the row's
        background (:func:`~srde_fusion.adapters.consistency.fill_left_right`): the output
        stays dense. Runs the model twice. On for the bundled stand-in.
    left_right_max_diff_px : float
        Tolerance of ``left_right_check``, px.
    census_propagation : bool
        After the model (and the left-right check), let each pixel take its own best
        census match over a wider window (where the right view confirms it) or a
        neighbour's disparity, where the images' census matching cost is clearly lower
        there (:func:`~srde_fusion.adapters.propagation.propagate_disparity`): mends the
        foreground a smooth network spreads over the background beside edges and through
        gaps. On for the bundled stand-in.
    segment_planes : bool
        Last, let each pixel take the robust disparity plane of its colour segment where
        the segment is planar, the plane is within a few pixels of its value and the
        census cost does not prefer its own value
        (:func:`~srde_fusion.adapters.segment_planes.fit_segment_planes`): evens out the
        blotches a network leaves on weakly textured surfaces. On for the bundled
        stand-in.

    Examples
    --------
    >>> spec = StereoSpec(name="mine", pad_multiple=16, output_sign=-1.0)
    >>> spec.pad_multiple, spec.output_sign
    (16, -1.0)
    >>> preset("raft-stereo").output_sign
    -1.0
    """

    name: str = "generic"
    input_names: tuple[str, ...] | None = None
    input_mode: InputMode = "pair"
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
    extra_inputs: tuple[tuple[str, bool | int | float], ...] = field(default=())
    forward_kwargs: tuple[tuple[str, Any], ...] = field(default=())
    output: int | str | tuple[int | str, ...] = -1
    output_channel: int = 0
    output_sign: float = 1.0
    output_scale: float = 1.0
    output_stride: int | None = None
    input_size: tuple[int, int] | None = None
    coarse_factor: int = 1
    coarse_input_names: tuple[str, str] | None = None
    flow_init: str | None = None
    bytes_per_px: float | None = None
    left_right_check: bool = False
    left_right_max_diff_px: float = 1.0
    census_propagation: bool = False
    segment_planes: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalise fields once, here
        if self.input_mode not in _INPUT_MODES:
            raise BackboneError(
                f"input_mode: expected one of {', '.join(_INPUT_MODES)}, got {self.input_mode!r}"
            )
        n_images = 1 if self.input_mode == "stacked" else 2
        for attr, count, what in (("input_names", n_images,
                                   "one name (the stacked input)" if n_images == 1
                                   else "two names (left, right)"),
                                  ("coarse_input_names", 2, "two names (left, right)")):
            value = getattr(self, attr)
            if value is None:
                continue
            names = (value,) if isinstance(value, str) else tuple(value)
            if len(names) != count or not all(isinstance(n, str) and n for n in names):
                raise BackboneError(f"{attr}: expected {what}, got {value!r}")
            set_(self, attr, names)
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
        extras = _pairs(self.extra_inputs, "extra_inputs")
        for key, value in extras:
            if not isinstance(value, (bool, int, float)):
                raise BackboneError(
                    f"extra_inputs[{key!r}]: expected a bool, int or float constant, "
                    f"got {value!r}"
                )
        set_(self, "extra_inputs", extras)
        kwargs = _pairs(self.forward_kwargs, "forward_kwargs")
        for key, value in kwargs:
            if not isinstance(value, _KWARG_TYPES):
                raise BackboneError(
                    f"forward_kwargs[{key!r}]: expected a bool, number, string or None, "
                    f"got {value!r}"
                )
        clash = {k for k, _ in kwargs} & {k for k, _ in extras}
        if clash:
            raise BackboneError(
                f"forward_kwargs: expected names not also in extra_inputs, got "
                f"{', '.join(sorted(clash))} in both"
            )
        set_(self, "forward_kwargs", kwargs)
        output = self.output
        if isinstance(output, list):
            output = tuple(output)
        if isinstance(output, tuple):
            if not output or not all(_output_key_ok(k) for k in output):
                raise BackboneError(
                    f"output: expected an index, a name or a non-empty path of them, "
                    f"got {self.output!r}"
                )
            if len(output) == 1:
                output = output[0]
        elif not _output_key_ok(output):
            raise BackboneError(f"output: expected an index or a name, got {self.output!r}")
        set_(self, "output", output)
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
        if not (isinstance(self.coarse_factor, int) and self.coarse_factor >= 1):
            raise BackboneError(
                f"coarse_factor: expected an integer >= 1, got {self.coarse_factor!r}"
            )
        if self.coarse_factor > 1 and self.input_mode == "stacked":
            raise BackboneError(
                "coarse_factor: expected 1 for input_mode='stacked', got "
                f"{self.coarse_factor}"
            )
        if self.flow_init is not None and not (isinstance(self.flow_init, str)
                                               and self.flow_init):
            raise BackboneError(f"flow_init: expected None or an input name, got "
                                f"{self.flow_init!r}")
        if self.bytes_per_px is not None and not (
            isinstance(self.bytes_per_px, (int, float)) and not isinstance(self.bytes_per_px, bool)
            and self.bytes_per_px > 0
        ):
            raise BackboneError(
                f"bytes_per_px: expected None or a positive number, got {self.bytes_per_px!r}"
            )
        for attr in ("left_right_check", "census_propagation", "segment_planes"):
            if not isinstance(getattr(self, attr), bool):
                raise BackboneError(
                    f"{attr}: expected True or False, got {getattr(self, attr)!r}"
                )
        diff = self.left_right_max_diff_px
        if not (isinstance(diff, (int, float)) and not isinstance(diff, bool) and diff >= 0):
            raise BackboneError(
                f"left_right_max_diff_px: expected a number >= 0 (px), got {diff!r}"
            )

    @property
    def image_channels(self) -> int:
        """Channels of one image as the model sees it (1 for grey, else 3)."""
        return 1 if self.channel_order == "grey" else 3

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
#:   on both sides), output ``(B, 1, H, W)`` positive disparity. The module's
#:   ``forward(image1, image2, iters=12, flow_init=None, test_mode=False)`` returns
#:   ``(init_disp, [disp per iteration])`` unless ``test_mode=True``; the demo calls it
#:   with ``iters=32, test_mode=True``, and so does the preset.
#: - ``"raft-stereo"``: as IGEV, but with ``test_mode=True`` the module returns
#:   ``(flow_low, flow_up)`` and the flow is *negative* horizontal displacement (its demo
#:   saves ``-flow_up``); demo and preset call ``iters=32, test_mode=True``.
#: - ``"crestereo"``: BGR 0..255 (the original test script reads with ``cv2.imread``),
#:   sizes divisible by 8, output ``(B, 2, H, W)`` flow whose channel 0 is *positive*
#:   disparity. The PyTorch port's ``forward(image1, image2, flow_init=None, iters=10,
#:   upsample=True, test_mode=False)`` returns its list of predictions (coarse first)
#:   unless built with ``test_mode=True``: the preset reads the last, final one. Its demo
#:   runs two stages -- the pair at half size, then full size with ``flow_init`` set to
#:   the half-size flow -- with ``iters=20``; the preset does the same. ONNX exports come
#:   as one stage (``left``, ``right``), with a ``flow_init`` input (fed zeros), or
#:   combined (``init_left``/``init_right`` at half size, ``next_left``/``next_right``).
#: - ``"nmrf"``: RGB 0..255, divisible by 8, called with a dict ``{"img1", "img2"}`` and
#:   returning a dict whose key ``"disp"`` holds ``(B, H, W)`` positive disparity.
#: - ``"foundationstereo"``: RGB 0..255, divisible by 32; the module's ``forward`` returns
#:   ``(init_disp, [disp per iteration])`` unless ``test_mode=True`` (demo: ``iters=32,
#:   test_mode=True``, as the preset); its ONNX export has one output ``disp`` (some
#:   exports add a confidence output after it, hence output 0), usually at a fixed size.
#: - ``"hitnet"``: one stacked input, left then right along the channels, values 0..1:
#:   ``(1, 6, H, W)`` RGB, or ``(1, 2, H, W)`` grey (read from an ONNX model's channel
#:   count); output 0 is the left disparity, positive. Exports are fixed-size.
#: - ``"generic"``: RGB 0..255, no padding, last output, positive disparity.
_ITERATIVE_DEMO = {"iters": 32, "test_mode": True}
PRESETS: dict[str, StereoSpec] = {
    "generic": StereoSpec(name="generic"),
    "igev": StereoSpec(name="igev", pad_multiple=32, forward_kwargs=_ITERATIVE_DEMO),
    "igev++": StereoSpec(name="igev++", pad_multiple=32, forward_kwargs=_ITERATIVE_DEMO),
    "raft-stereo": StereoSpec(name="raft-stereo", pad_multiple=32, output=-1, output_sign=-1.0,
                              forward_kwargs=_ITERATIVE_DEMO),
    "crestereo": StereoSpec(
        name="crestereo", channel_order="BGR", pad_multiple=8, output=-1, output_channel=0,
        forward_kwargs={"iters": 20, "test_mode": True}, coarse_factor=2,
        coarse_input_names=("init_left", "init_right"), flow_init="flow_init",
    ),
    "nmrf": StereoSpec(
        name="nmrf", input_names=("img1", "img2"), call="dict", pad_multiple=8, output="disp"
    ),
    "foundationstereo": StereoSpec(name="foundationstereo", pad_multiple=32, output=0,
                                   forward_kwargs=_ITERATIVE_DEMO),
    "hitnet": StereoSpec(name="hitnet", input_mode="stacked", value_scale=1.0,
                         pad_multiple=32, output=0),
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
