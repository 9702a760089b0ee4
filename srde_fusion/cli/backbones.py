"""The one place the command turns a name, model file or module into a backbone callable.

The core never imports :mod:`srde_fusion.adapters` (DESIGN §6); the command does, here.
"""

from __future__ import annotations

import sys
from typing import Any

from ..adapters import load_backbone

__all__ = ["backbone_from"]


def backbone_from(source: Any, preset: str | None = None, *, threads: int | None = None) -> Any:
    """Return a backbone callable for what the user named.

    Parameters
    ----------
    source : str, path, torch module or callable
        ``"default"`` (the bundled stand-in), a model file, a torch module, or a ready
        ``backbone(left, right)`` callable (returned as it is).
    preset : str, optional
        The model family's conventions (``"igev"``, ``"raft-stereo"``, ...).
    threads : int, optional
        Threads of the model's onnxruntime session (one evaluation worker's share of
        the cores); onnxruntime's default when None.

    Returns
    -------
    callable
        ``backbone(left, right) -> (H, W)`` disparity in pixels.
    """
    torch = sys.modules.get("torch")  # a torch module can only exist if torch is imported
    is_module = torch is not None and isinstance(source, torch.nn.Module)
    if callable(source) and not is_module:
        return source
    if threads is None:
        return load_backbone(source, preset)
    # onnxruntime loads only when worker threads are set (a heavy import for the CLI).
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return load_backbone(source, preset, session_options=options)
