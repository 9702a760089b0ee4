"""The one place the command turns a name, model file or module into a backbone callable.

The core never imports :mod:`srde_fusion.adapters` (DESIGN §6); the command does, here.
"""

from __future__ import annotations

import sys
from typing import Any

from ..adapters import load_backbone
from ..errors import BackboneError

__all__ = ["backbone_from", "providers_for"]


def providers_for(device: str) -> list[str]:
    """Onnxruntime execution providers for ``"cpu"`` or ``"cuda[:N]"``."""
    if device == "cpu":
        return ["CPUExecutionProvider"]
    if device.startswith("cuda"):
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    raise BackboneError(f"--device: expected cpu or cuda[:N], got {device!r}")


def backbone_from(source: Any, preset: str | None = None, *, threads: int | None = None,
                  device: str = "cpu") -> Any:
    """Return a backbone callable for what the user named.

    Parameters
    ----------
    source : str, path, torch module or callable
        ``"default"`` (the bundled stand-in), ``"sgbm"`` (OpenCV's semi-global block
        matching), a model file, a torch module, or a ready ``backbone(left, right)``
        callable (returned as it is).
    preset : str, optional
        The model family's conventions (``"igev"``, ``"raft-stereo"``, ...).
    threads : int, optional
        Threads of the model's onnxruntime session (one evaluation worker's share of
        the cores); onnxruntime's default when None.
    device : str
        ``"cpu"`` or ``"cuda[:N]"``: the torch device of a module, the onnxruntime
        providers of a model file. A device this machine lacks is a BackboneError now,
        not a failure on the first pair.

    Returns
    -------
    callable
        ``backbone(left, right) -> (H, W)`` disparity in pixels.
    """
    torch = sys.modules.get("torch")  # a torch module can only exist if torch is imported
    is_module = torch is not None and isinstance(source, torch.nn.Module)
    if callable(source) and not is_module:
        return source
    if is_module:
        return load_backbone(source, preset, device=device)
    if isinstance(source, str) and source.strip().lower() == "sgbm":
        return load_backbone(source, preset)  # OpenCV on the CPU: no session, no device
    providers = providers_for(device)
    if threads is None:
        return load_backbone(source, preset, providers=providers)
    # onnxruntime loads only when worker threads are set (a heavy import for the CLI).
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return load_backbone(source, preset, session_options=options, providers=providers)
