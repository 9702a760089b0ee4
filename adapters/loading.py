"""One entry point from a model file, a torch module, ``"default"`` or ``"sgbm"`` to a backbone."""

from __future__ import annotations

import json
import os
import sys
import warnings
from pathlib import Path
from typing import Any

from srde_fusion.errors import BackboneError

from ._pipeline import StereoAdapter
from .onnx_backend import OnnxStereo
from .sgbm import SGBMSpec, SGBMStereo
from .spec import PRESETS, StereoSpec, preset
from .torch_backend import TorchStereo

__all__ = ["load_backbone", "default_weights_path", "default_model_info",
           "STANDIN_BYTES_PER_PX"]

_WEIGHTS_DIR = Path(__file__).resolve().parent / "standin" / "weights"
_DEFAULT_MODEL = "standin.onnx"
_DEFAULT_INFO = "standin.json"
# The stand-in follows IGEV's conventions (RGB 0..255, pad to 32, positive disparity).
_DEFAULT_PRESET = "igev"
#: Peak memory of the bundled stand-in per input pixel on a CPU (onnxruntime): 624 MB
#: more at 1280x960 than at 640x480 (0.92 MP more), about 0.68 GB per megapixel (most of
#: it the full-resolution census step).
STANDIN_BYTES_PER_PX = 680.0
# load_backbone options that are StereoSpec fields rather than adapter options
_SPEC_OPTIONS = ("left_right_check", "left_right_max_diff_px", "census_propagation",
                 "segment_planes")


def default_weights_path() -> Path:
    """Path of the bundled stand-in stereo network (ONNX).

    Raises
    ------
    BackboneError
        The file is missing from the installation.
    """
    path = _WEIGHTS_DIR / _DEFAULT_MODEL
    if not path.is_file():
        raise BackboneError(
            f"default model: expected the bundled {_DEFAULT_MODEL} next to the adapters, "
            f"got no file at {path}; recreate it with `srde-fusion train-standin --out {path}`"
        )
    return path


def default_model_info() -> dict[str, Any]:
    """Return the stand-in's record: architecture, training command and measured metrics."""
    path = _WEIGHTS_DIR / _DEFAULT_INFO
    if not path.is_file():
        return {}
    return json.loads(path.read_text(encoding="utf-8"))


def load_backbone(source: Any, spec: StereoSpec | SGBMSpec | str | None = None,
                  **options: Any) -> StereoAdapter | SGBMStereo:
    """Make a backbone callable from a model file, a torch module, or a named backbone.

    Parameters
    ----------
    source : str, os.PathLike or torch.nn.Module
        ``"default"`` for the bundled stand-in network, ``"sgbm"`` for OpenCV's
        semi-global block matching, a path to an ``.onnx`` file, or a torch module.
    spec : StereoSpec, SGBMSpec or str, optional
        Conventions of the model or a preset name; for ``"sgbm"`` an :class:`SGBMSpec`
        (or None, or ``"sgbm"``). ``None``: the stand-in's own preset for
        ``"default"``; for a model file or module, ``"generic"`` with a warning.
    **options
        Passed on to :class:`OnnxStereo` (``providers``, ``session_options``) or
        :class:`TorchStereo` (``device``), and to both ``max_pixels`` and
        ``large_images`` (the bundled stand-in's default budget comes from its measured
        memory per pixel, :data:`STANDIN_BYTES_PER_PX`); ``left_right_check`` and
        ``left_right_max_diff_px`` set those fields of the spec (the bundled stand-in
        has the check on, as its record's ``inference`` says:
        ``load_backbone("default", left_right_check=False)`` turns it off); for
        ``"sgbm"``, fields of :class:`SGBMSpec` (``block_size=7``,
        ``left_right_check=True``, ...).

    Returns
    -------
    OnnxStereo, TorchStereo or SGBMStereo
        ``backbone(left, right) -> (H, W) float32`` disparity in pixels.

    Raises
    ------
    BackboneError
        Unknown source type or extension, missing or unreadable model.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion.adapters import load_backbone
    >>> backbone = load_backbone("default")
    >>> left = np.zeros((40, 60, 3), np.uint8)
    >>> backbone(left, left).shape
    (40, 60)
    """
    if isinstance(source, str) and source.strip().lower() == "sgbm":
        if spec is None or (isinstance(spec, str) and spec.strip().lower() == "sgbm"):
            spec = SGBMSpec()
        if not isinstance(spec, SGBMSpec):
            raise BackboneError(
                f"spec: expected an SGBMSpec (or None) for the 'sgbm' backbone, got {spec!r}"
            )
        return SGBMStereo(spec, **options)
    if isinstance(spec, SGBMSpec):
        raise BackboneError(
            f"spec: expected a StereoSpec or a preset name for source {source!r}, got an "
            f"SGBMSpec (it goes with source 'sgbm')"
        )
    spec_changes = {name: options.pop(name) for name in _SPEC_OPTIONS if name in options}
    if isinstance(source, str) and source == "default":
        info = default_model_info()
        if not isinstance(spec, StereoSpec):
            # a preset name (or none): the stand-in's own inference settings apply
            spec = preset(spec or info.get("preset", _DEFAULT_PRESET)).replace(
                **{k: v for k, v in info.get("inference", {}).items() if k in _SPEC_OPTIONS})
        if spec.bytes_per_px is None:
            spec = spec.replace(bytes_per_px=STANDIN_BYTES_PER_PX)
        return OnnxStereo(default_weights_path(), spec.replace(**spec_changes), **options)
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if path.suffix.lower() != ".onnx":
            raise BackboneError(
                f"source: expected 'default', 'sgbm', a .onnx file or a torch.nn.Module, "
                f"got {str(source)!r}"
            )
        backbone = OnnxStereo(path, preset(spec or "generic").replace(**spec_changes),
                              **options)
        if spec is None:
            _warn_generic_assumed(path.name)
        return backbone
    torch = sys.modules.get("torch")  # a torch module can only exist if torch is imported
    if torch is not None and isinstance(source, torch.nn.Module):
        backbone = TorchStereo(source, preset(spec or "generic").replace(**spec_changes),
                               **options)
        if spec is None:
            _warn_generic_assumed(type(source).__name__)
        return backbone
    raise BackboneError(
        f"source: expected 'default', 'sgbm', a .onnx file or a torch.nn.Module, "
        f"got {type(source).__name__}"
    )


def _warn_generic_assumed(what: str) -> None:
    """Say that a model without a spec or preset is read with ``"generic"``."""
    warnings.warn(
        f"{what}: no spec or preset given, 'generic' assumed (RGB 0..255, no padding, last "
        f"output, positive disparity); pass the model family's preset ({', '.join(PRESETS)}) "
        f"or a StereoSpec",
        UserWarning, stacklevel=3,
    )
