"""Backbone adapters: ONNX and torch stereo models, and OpenCV SGBM, behind one contract.

Every adapter is ``backbone(left, right) -> (H, W) float32`` disparity in pixels,
positive, at input resolution, for rectified ``(H, W, 3)`` uint8 RGB images (floats in
[0, 1] and grey images are accepted). A :class:`StereoSpec` declares a model's
conventions (channel order, value range, padding, which output, sign, resolution,
fixed input size); :data:`PRESETS` holds those of IGEV, IGEV++, RAFT-Stereo, CREStereo,
NMRF and FoundationStereo. :class:`SGBMStereo` runs OpenCV's semi-global block matching
with the parameters of an :class:`SGBMSpec` (``load_backbone("sgbm")``).

The stand-in network, its procedural training data, its training and its bundled weights
live in :mod:`.standin`; they and the torch adapter import torch only when used, so
``import srde_fusion.adapters`` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

from .loading import default_model_info, default_weights_path, load_backbone
from .onnx_backend import OnnxStereo
from .sgbm import SGBMSpec, SGBMStereo
from .spec import PRESETS, StereoSpec, preset
from .torch_backend import TorchStereo

__all__ = [
    "StereoSpec",
    "PRESETS",
    "preset",
    "OnnxStereo",
    "TorchStereo",
    "SGBMSpec",
    "SGBMStereo",
    "load_backbone",
    "default_weights_path",
    "default_model_info",
    "StandinConfig",
    "StandinStereo",
    "STANDIN_SIZES",
    "build_standin",
    "TrainingConfig",
    "train_standin",
    "export_standin_onnx",
    "random_stereo_pair",
]

# Names that need torch, resolved on first access (PEP 562).
_LAZY = {
    "StandinConfig": ".standin.network",
    "StandinStereo": ".standin.network",
    "STANDIN_SIZES": ".standin.network",
    "build_standin": ".standin.network",
    "TrainingConfig": ".standin.training",
    "train_standin": ".standin.training",
    "export_standin_onnx": ".standin.training",
    "random_stereo_pair": ".standin.procedural",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
