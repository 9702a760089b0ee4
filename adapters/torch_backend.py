"""Stereo models as torch modules behind the backbone contract."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from srde_fusion.errors import BackboneError

from ._pipeline import StereoAdapter
from .spec import StereoSpec, preset

__all__ = ["TorchStereo"]


class TorchStereo(StereoAdapter):
    """A torch stereo module as a ``backbone(left, right) -> disparity`` callable.

    The module is put in eval mode and run without gradients. A torch module reveals
    nothing about its conventions before it runs, so the spec is trusted and the output
    is checked on every call.

    Parameters
    ----------
    module : torch.nn.Module
        The network. It is called as the spec's ``call`` style says, with float32
        image tensors in the spec's layout (``(1, 3, H, W)`` for ``NCHW``) on
        ``device``, and extra inputs as the Python numbers the spec holds.
    spec_or_preset : StereoSpec or str
        The model's conventions, or a preset name (see :data:`PRESETS`).
    device : str or torch.device
        Where the module runs; the module is moved there.

    Raises
    ------
    BackboneError
        ``module`` is not a torch module.
    """

    def __init__(self, module: Any, spec_or_preset: StereoSpec | str = "generic", *,
                 device: Any = "cpu") -> None:
        import torch

        if not isinstance(module, torch.nn.Module):
            raise BackboneError(
                f"module: expected a torch.nn.Module, got {type(module).__name__}"
            )
        self.spec = preset(spec_or_preset)
        if self.spec.call != "positional" and self.spec.input_names is None:
            raise BackboneError(
                f"spec.input_names: expected two names for call={self.spec.call!r}, got None"
            )
        try:
            self.device = torch.device(device)
        except (TypeError, RuntimeError):
            raise BackboneError(f"device: expected a torch device such as 'cpu', 'cuda' or "
                                f"'cuda:1', got {device!r}") from None
        # Fail now, with the reason, rather than with torch's message on the first call.
        if self.device.type == "cuda":
            if not torch.cuda.is_available():
                raise BackboneError(f"device: expected an available device, got {device!r} "
                                    f"(this torch build or machine has no CUDA)")
            index = self.device.index or 0
            if index >= torch.cuda.device_count():
                raise BackboneError(f"device: expected one of the {torch.cuda.device_count()} "
                                    f"CUDA devices, got {device!r}")
        self.module = module.to(self.device).eval()
        self.model_size = self.spec.input_size

    def _run(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        import torch

        spec = self.spec
        left_t = torch.from_numpy(left).to(self.device)
        right_t = torch.from_numpy(right).to(self.device)
        extras = dict(spec.extra_inputs)
        try:
            with torch.inference_mode():
                if spec.call == "positional":
                    out = self.module(left_t, right_t, *extras.values())
                else:
                    inputs = {spec.input_names[0]: left_t, spec.input_names[1]: right_t,
                              **extras}
                    out = (self.module(**inputs) if spec.call == "keywords"
                           else self.module(inputs))
        # The module's own exception (a shape it cannot take, a missing argument) becomes
        # the adapter contract's error; the original stays attached as its cause.
        except Exception as exc:
            raise BackboneError(
                f"{type(self.module).__name__} (torch, spec {spec.name}): expected the module "
                f"to run on inputs of shape {tuple(left_t.shape)}, got {type(exc).__name__}: "
                f"{str(exc).strip()[:500]}"
            ) from exc
        return _to_numpy(_select_output(out, spec))

    def describe(self) -> str:
        """Say which spec is in use and what a torch module cannot reveal before it runs."""
        return "\n".join([
            f"TorchStereo({type(self.module).__name__}, device={str(self.device)!r})",
            self.spec.summary(),
            "not inferable from a torch module (checked on each call): input names, "
            "fixed or dynamic size, output structure, rank, channels and resolution",
        ])

    def __repr__(self) -> str:
        return f"TorchStereo({type(self.module).__name__}, spec={self.spec.name!r})"


def _select_output(out: Any, spec: StereoSpec) -> Any:
    import torch

    key = spec.output
    if isinstance(out, torch.Tensor):
        if key not in (0, -1):
            raise BackboneError(
                f"spec.output: expected 0 or -1 for a model returning one tensor, got {key!r}"
            )
        return out
    if isinstance(out, Mapping):
        if key not in out:
            raise BackboneError(
                f"spec.output: expected one of the keys {list(out)} of the model's dict "
                f"output, got {key!r}"
            )
        return out[key]
    if isinstance(out, Sequence) and not isinstance(out, (str, bytes)):
        if isinstance(key, str) or not -len(out) <= key < len(out):
            raise BackboneError(
                f"spec.output: expected an index into the model's {len(out)} outputs, "
                f"got {key!r}"
            )
        return out[key]
    raise BackboneError(
        f"model output: expected a tensor, a tuple/list or a dict, got {type(out).__name__}"
    )


def _to_numpy(value: Any) -> np.ndarray:
    import torch

    if not isinstance(value, torch.Tensor):
        raise BackboneError(
            f"model output: expected the selected output to be a tensor, "
            f"got {type(value).__name__}"
        )
    return value.detach().float().cpu().numpy()
