"""The one place the command turns a name, model file or module into a backbone callable.

The core never imports :mod:`srde_fusion.adapters` (DESIGN §6); the command does, here.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import fields
from pathlib import Path
from typing import Any

from .._json import load_json_source
from ..adapters import PRESETS, StereoSpec, load_backbone, preset
from ..errors import BackboneError

__all__ = ["backbone_from", "providers_for", "spec_from_file", "add_spec_options",
           "spec_from_args"]

#: The key of a spec file that names a preset as the base its other keys override.
SPEC_PRESET_KEY = "preset"
# StereoSpec compares these with numbers; a string there would be a TypeError, not a message.
_NUMBER_FIELDS = ("value_scale", "pad_value", "output_sign", "output_scale")


def spec_from_file(source: str | os.PathLike) -> StereoSpec:
    """Read a model's conventions from a JSON file (or a JSON object given as text).

    Parameters
    ----------
    source : str or path-like
        A ``.json`` file holding one object: any :class:`~srde_fusion.adapters.StereoSpec`
        field (``"pad_multiple": 16``, ``"output_sign": -1``, ``"mean": [123.7, 116.3,
        103.5]``, ``"extra_inputs": {"iters": 12}``, ...) and optionally ``"preset":
        NAME``, a preset the other fields override. Without ``"name"`` the spec is named
        after the preset, or else after the file. A string starting with ``{`` is read
        as the JSON itself.

    Returns
    -------
    StereoSpec

    Raises
    ------
    BackboneError
        A missing file or invalid JSON; not an object; a key that is neither a
        StereoSpec field nor ``"preset"`` (the message lists the valid fields); an unknown
        preset; a value StereoSpec refuses (its own message). Every message names the file.
    """
    data = load_json_source(source, "spec", BackboneError)
    inline = isinstance(source, str) and source.lstrip().startswith("{")
    where = "spec JSON" if inline else str(source)
    if not isinstance(data, dict):
        raise BackboneError(f"{where}: expected a JSON object of StereoSpec fields, got "
                            f"{type(data).__name__}")
    valid = [f.name for f in fields(StereoSpec)]
    unknown = [key for key in data if key not in valid and key != SPEC_PRESET_KEY]
    if unknown:
        raise BackboneError(
            f"{where}: expected StereoSpec fields ({', '.join(valid)}) or "
            f"{SPEC_PRESET_KEY!r}, got unknown {', '.join(repr(k) for k in unknown)}")
    changes = dict(data)
    base = changes.pop(SPEC_PRESET_KEY, None)
    for key in (k for k in _NUMBER_FIELDS if k in changes):
        value = changes[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise BackboneError(f"{where}: {key}: expected a number, got {value!r}")
    if "name" in changes and not isinstance(changes["name"], str):
        raise BackboneError(f"{where}: name: expected a string, got {changes['name']!r}")
    if base is None and "name" not in changes:
        changes["name"] = "spec" if inline else Path(source).stem
    try:
        spec = StereoSpec() if base is None else preset(base)
        return spec.replace(**changes)
    except BackboneError as exc:
        raise BackboneError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:  # a value of a type StereoSpec does not check
        raise BackboneError(f"{where}: expected values of the StereoSpec field types, got "
                            f"{exc}") from None


def add_spec_options(p: argparse.ArgumentParser) -> None:
    """Add ``--preset`` and ``--spec`` (one or the other) to a command that runs a model."""
    group = p.add_mutually_exclusive_group()
    group.add_argument("--preset", default=None,
                       help=f"conventions of the .onnx model: {', '.join(PRESETS)}")
    group.add_argument("--spec", default=None, metavar="SPEC.json",
                       help="conventions of the model as a JSON object of StereoSpec fields, "
                       "optionally with \"preset\": NAME as the base they override")


def spec_from_args(args: argparse.Namespace) -> str | StereoSpec | None:
    """Return what ``--preset`` or ``--spec`` asked for (None: the model's default)."""
    return spec_from_file(args.spec) if args.spec is not None else args.preset


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
