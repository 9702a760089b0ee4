"""Stereo models as torch modules behind the backbone contract."""

from __future__ import annotations

import inspect
import logging
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from srde_fusion.errors import BackboneError

from ._pipeline import ModelInputs, ModelOutOfMemory, StereoAdapter
from .spec import StereoSpec, preset

__all__ = ["TorchStereo"]

logger = logging.getLogger(__name__)

_OUT_OF_MEMORY_MARKERS = ("out of memory", "failed to allocate", "bad_alloc")


class TorchStereo(StereoAdapter):
    """A torch stereo module as a ``backbone(left, right) -> disparity`` callable.

    The module is put in eval mode and run without gradients. A torch module reveals
    little about its conventions before it runs: its ``forward`` signature is read (which
    keyword arguments it takes), the rest of the spec is trusted and the output is
    checked on every call.

    Parameters
    ----------
    module : torch.nn.Module
        The network. It is called as the spec's ``call`` style says, with float32
        image tensors in the spec's layout (``(1, 3, H, W)`` for ``NCHW``, one stacked
        tensor for ``input_mode="stacked"``) on ``device``; ``spec.extra_inputs`` and
        ``spec.forward_kwargs`` are passed as keyword arguments (never positionally, so
        ``iters`` cannot land in a ``flow_init`` slot). Forward keywords the module's
        ``forward`` does not take are left out, with a logged note (a preset's
        ``test_mode`` on a module without it); an extra input it does not take is an
        error. With ``spec.coarse_factor > 1`` and a ``forward`` taking ``spec.flow_init``,
        the module runs twice as CREStereo's demo does: on the pair shrunk by the factor
        (bilinear, corners aligned), then at full size with the coarse output as initial
        flow.
    spec_or_preset : StereoSpec or str
        The model's conventions, or a preset name (see :data:`PRESETS`).
    device : str or torch.device
        Where the module runs; the module is moved there.
    max_pixels : int, "auto" or None
        Pixel budget of one run, as for :class:`OnnxStereo` (``"auto"`` counts the
        device's memory for CUDA).
    large_images : {"tile", "downscale"}
        What to do with pairs over ``max_pixels``.

    Raises
    ------
    BackboneError
        ``module`` is not a torch module, the device is not available, or an extra input
        is not a parameter of ``module.forward``.
    """

    def __init__(self, module: Any, spec_or_preset: StereoSpec | str = "generic", *,
                 device: Any = "cpu", max_pixels: int | str | None = "auto",
                 large_images: str = "tile") -> None:
        import torch

        if not isinstance(module, torch.nn.Module):
            raise BackboneError(
                f"module: expected a torch.nn.Module, got {type(module).__name__}"
            )
        self.spec = preset(spec_or_preset)
        if self.spec.call != "positional" and self.spec.input_names is None:
            raise BackboneError(
                f"spec.input_names: expected names for call={self.spec.call!r}, got None"
            )
        try:
            self.device = torch.device(device)
        except (TypeError, RuntimeError):
            raise BackboneError(f"device: expected a torch device such as 'cpu', 'cuda' or "
                                f"'cuda:1', got {device!r}") from None
        # Fail now, with the reason, rather than with torch's message on the first call.
        memory_bytes = None
        if self.device.type == "cuda":
            if not torch.cuda.is_available():
                raise BackboneError(f"device: expected an available device, got {device!r} "
                                    f"(this torch build or machine has no CUDA)")
            index = self.device.index or 0
            if index >= torch.cuda.device_count():
                raise BackboneError(f"device: expected one of the {torch.cuda.device_count()} "
                                    f"CUDA devices, got {device!r}")
            memory_bytes = torch.cuda.get_device_properties(index).total_memory
        self.module = module.to(self.device).eval()
        self.model_size = self.spec.input_size
        self._notes: list[str] = []
        self._kwargs = self._forward_keywords()
        self._cascade = (self.spec.coarse_factor > 1 and self.spec.flow_init is not None
                         and self._takes(self.spec.flow_init))
        if self._cascade:
            self._notes.append(
                f"two stages: the pair at 1/{self.spec.coarse_factor} size, then full size "
                f"with {self.spec.flow_init}= the coarse output"
            )
        elif self.spec.coarse_factor > 1:
            self._notes.append(f"one stage: forward takes no {self.spec.flow_init!r}")
        self.pad_multiple = self.spec.pad_multiple * (self.spec.coarse_factor
                                                      if self._cascade else 1)
        self.last_output_structure: str | None = None
        self._structure_warned = False
        self._init_large_images(max_pixels, large_images, memory_bytes)

    # ------------------------------------------------------------------ signature
    def _parameters(self) -> tuple[set[str], bool]:
        try:
            params = inspect.signature(self.module.forward).parameters.values()
        except (TypeError, ValueError):  # a forward without a readable signature
            return set(), True
        names = {p.name for p in params
                 if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        return names, any(p.kind == p.VAR_KEYWORD for p in params)

    def _takes(self, name: str) -> bool:
        names, any_keyword = self._parameters()
        return any_keyword or name in names

    def _forward_keywords(self) -> dict[str, Any]:
        spec = self.spec
        signature = f"{type(self.module).__name__}.forward"
        kwargs: dict[str, Any] = {}
        for name, value in spec.extra_inputs:
            if spec.call == "dict":
                continue  # extra inputs go into the dict with the images
            if not self._takes(name):
                raise BackboneError(
                    f"spec.extra_inputs: expected keyword arguments of {signature}, got "
                    f"{name!r}"
                )
            kwargs[name] = value
        dropped = []
        for name, value in spec.forward_kwargs:
            if self._takes(name):
                kwargs[name] = value
            else:
                dropped.append(name)
        if kwargs:
            self._notes.append(
                "forward called with " + ", ".join(f"{k}={v!r}" for k, v in kwargs.items())
            )
        if dropped:
            note = (f"forward_kwargs {', '.join(dropped)} left out: not parameters of "
                    f"{signature}")
            self._notes.append(note)
            logger.info("%s (spec %s)", note, spec.name)
        return kwargs

    # ------------------------------------------------------------------ running
    def _call(self, images: Sequence[Any], **extra: Any) -> Any:
        spec = self.spec
        kwargs = {**self._kwargs, **extra}
        if spec.input_mode == "stacked":
            return self.module(images[0], **kwargs)
        if spec.call == "positional":
            return self.module(images[0], images[1], **kwargs)
        named = {spec.input_names[0]: images[0], spec.input_names[1]: images[1]}
        if spec.call == "keywords":
            return self.module(**named, **kwargs)
        return self.module({**named, **dict(spec.extra_inputs)}, **kwargs)

    def _run(self, inputs: ModelInputs) -> np.ndarray:
        import torch
        import torch.nn.functional as F

        spec = self.spec
        images = [torch.from_numpy(x).to(self.device) for x in inputs.images]
        try:
            with torch.inference_mode():
                if self._cascade:
                    h, w = images[0].shape[-2:]
                    size = (h // spec.coarse_factor, w // spec.coarse_factor)
                    # as CREStereo's demo shrinks the pair for its first stage
                    small = [F.interpolate(x, size=size, mode="bilinear", align_corners=True)
                             for x in images]
                    coarse = self._select(self._call(small, **{spec.flow_init: None}))
                    out = self._call(images, **{spec.flow_init: coarse})
                else:
                    out = self._call(images)
        except BackboneError:
            raise
        # The module's own exception (a shape it cannot take, a missing argument) becomes
        # the adapter contract's error; the original stays attached as its cause.
        except Exception as exc:
            text = str(exc).strip()
            shape = tuple(images[0].shape)
            if any(marker in text.lower() for marker in _OUT_OF_MEMORY_MARKERS):
                raise ModelOutOfMemory(
                    f"{type(self.module).__name__}: expected memory for inputs of shape "
                    f"{shape}, got {type(exc).__name__}: {text[:300]}"
                ) from exc
            raise BackboneError(
                f"{type(self.module).__name__} (torch, spec {spec.name}): expected the module "
                f"to run on inputs of shape {shape}, got {type(exc).__name__}: {text[:500]}"
            ) from exc
        return _to_numpy(self._select(out))

    def _select(self, out: Any) -> Any:
        """Return the spec's output of a (possibly nested) module output, as a tensor."""
        self.last_output_structure = _structure(out)
        value, final_of = _select_output(out, self.spec)
        if final_of and "final" not in " ".join(self._notes):
            self._notes.append(f"output {self.spec.output!r} is a list of {final_of} "
                               f"predictions: the last (final) one is used")
        self._warn_if_before_refinement(out)
        return value

    def _warn_if_before_refinement(self, out: Any) -> None:
        """Warn when an index picks a tensor that a later list of predictions refines.

        IGEV and FoundationStereo outside ``test_mode`` return ``(init_disp, [disp per
        iteration])``: output 0 is the disparity before refinement.
        """
        key = self.spec.output
        if (self._structure_warned or not isinstance(key, int)
                or not isinstance(out, (list, tuple))):
            return
        index = key % len(out) if -len(out) <= key < len(out) else None
        later = out[index + 1:] if index is not None else []
        if any(isinstance(x, (list, tuple)) for x in later):
            self._structure_warned = True
            warnings.warn(
                f"{type(self.module).__name__}: output {key} of {_structure(out)} is used; "
                f"the list after it usually holds the refined predictions -- call the "
                f"module with test_mode=True (spec.forward_kwargs) or select "
                f"output=({index + 1}, -1)",
                UserWarning, stacklevel=5,
            )

    def describe(self) -> str:
        """Say which spec is in use, what the module's signature told, what it cannot."""
        lines = [
            f"TorchStereo({type(self.module).__name__}, device={str(self.device)!r})",
            self.spec.summary(),
            "read from the module:",
        ]
        lines += [f"  {note}" for note in self._notes] or ["  (nothing beyond the spec)"]
        if self.last_output_structure is not None:
            lines.append(f"  last output: {self.last_output_structure}")
        lines += [
            "not inferable from a torch module (checked on each call): input names, "
            "fixed or dynamic size, output structure, rank, channels and resolution",
            "runtime:",
            *self._runtime_lines(),
        ]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"TorchStereo({type(self.module).__name__}, spec={self.spec.name!r})"


def _structure(out: Any, depth: int = 0) -> str:
    """Short text of a nested output: ``tuple(tensor(1, 1, 64, 96), list[12 x ...])``."""
    import torch

    if isinstance(out, torch.Tensor):
        return f"tensor{tuple(out.shape)}"
    if isinstance(out, Mapping):
        inner = ", ".join(f"{k!r}: {_structure(v, depth + 1)}" for k, v in out.items())
        return f"dict({inner})"
    if isinstance(out, (list, tuple)):
        name = type(out).__name__
        if out and depth > 0 and all(isinstance(x, torch.Tensor) for x in out):
            return f"{name}[{len(out)} x {_structure(out[-1], depth + 1)}]"
        return f"{name}(" + ", ".join(_structure(x, depth + 1) for x in out) + ")"
    return type(out).__name__


def _select_output(out: Any, spec: StereoSpec) -> tuple[Any, int]:
    """Follow ``spec.output`` (an index, a name or a path) into a nested output.

    Returns the selected value and, when that was a list of predictions whose last
    element was taken, their count (else 0).
    """
    import torch

    path = spec.output if isinstance(spec.output, tuple) else (spec.output,)
    value = out
    for depth, key in enumerate(path):
        if isinstance(value, torch.Tensor):
            if depth == 0 and key in (0, -1) and len(path) == 1:
                return value, 0
            raise BackboneError(
                f"spec.output: expected 0 or -1 for a model returning one tensor, got "
                f"{spec.output!r}" if depth == 0 else
                f"spec.output: expected the path {spec.output!r} to end at a tensor, got a "
                f"tensor after {path[:depth]!r}"
            )
        if isinstance(value, Mapping):
            if key not in value:
                raise BackboneError(
                    f"spec.output: expected one of the keys {list(value)} of the model's "
                    f"dict output, got {key!r}"
                )
            value = value[key]
        elif isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
            if isinstance(key, str) or not -len(value) <= key < len(value):
                raise BackboneError(
                    f"spec.output: expected an index into the model's {len(value)} outputs, "
                    f"got {key!r}"
                )
            value = value[key]
        else:
            raise BackboneError(
                f"model output: expected a tensor, a tuple/list or a dict, got "
                f"{type(value).__name__}"
            )
    if (isinstance(value, (list, tuple)) and value
            and all(isinstance(x, torch.Tensor) for x in value)):
        # a list of iterative predictions (a model outside test_mode): the last is final
        return value[-1], len(value)
    return value, 0


def _to_numpy(value: Any) -> np.ndarray:
    import torch

    if not isinstance(value, torch.Tensor):
        raise BackboneError(
            f"model output: expected the selected output to be a tensor, "
            f"got {type(value).__name__}"
        )
    return value.detach().float().cpu().numpy()
